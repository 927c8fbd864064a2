"""Friction-drive contact deterioration (seed 003; docs/systems/friction-drive.md).

- :mod:`.drive`: the roller-on-tire drive with contact-quality deterioration;
- :mod:`.reproduce`: augmented EKF, consistency checks, observability and Monte Carlo RUL;
- :mod:`.report`: the study's tables, figures and report;
- :mod:`.cli`: ``rulkit reproduce friction-drive``.
"""
