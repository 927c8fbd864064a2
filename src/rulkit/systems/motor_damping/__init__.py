"""Reaction-wheel motor damping by a multi-scale EKF (seed 002; docs/systems/motor-damping.md).

- :mod:`.motor`: the DC motor with a degrading viscous damping coefficient;
- :mod:`.pullup`: reading and validating a user's pull-up test data;
- :mod:`.micro`: the micro EKF, the damping of each pull-up cycle;
- :mod:`.macro`: the macro EKF across cycles and the RUL in cycles;
- :mod:`.analysis`: the two-scale estimate on a user's own data;
- :mod:`.reproduce`, :mod:`.report` and :mod:`.figures`: the seed reproduction
  (``MotorDampingConfig``, ``run``), its report (``write_report``) and figures;
- :mod:`.cli`: ``rulkit motor ...`` and ``rulkit reproduce motor-damping``.
"""
