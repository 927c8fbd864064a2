"""Friction-drive contact deterioration (seed 003; docs/systems/friction-drive.md).

- :mod:`.drive`: the roller-on-tire drive with contact-quality deterioration;
- :mod:`.reproduce`: augmented EKF, consistency checks, observability and Monte Carlo RUL;
- :mod:`.report`: the study's tables, figures and report;
- :mod:`.machine`, :mod:`.record`, :mod:`.deterioration`, :mod:`.estimate`: ``rulkit drive`` on
  a user's record (the drive as a machine file, the record's checks, the compiled augmented
  EKF, the consistency checks and the RUL);
- :mod:`.cli`: ``rulkit reproduce friction-drive`` and ``rulkit drive``.
"""
