"""Reaction-wheel bearing lubrication (seeds 000 and 001; docs/systems/reaction-wheel.md).

Grouped by what each part estimates:

- :mod:`.wheel`: the Ithaco type-A wheel (speed, current, torques), its noise and the Table 3
  validation path; :mod:`.wheel_kernels` the same physics compiled for the filters;
- :mod:`.lubrication`: lubricant-loss physics, the two fault scenarios and the temperature
  paths over months;
- :mod:`.telemetry`: reading and validating a user's telemetry file;
- :mod:`.temperature`: step 1, the lubricant temperature (particle filters of the seeds, the
  Rao-Blackwellised PF, the EKF, the estimator over a user's record, the Table 5 study);
- :mod:`.degradation`: step 2, the lubricant-loss parameters b and beta0 (window quadrature,
  one-step and two-step PFs and the RB-PF, the T^ shortcut, the Table 6 study);
- :mod:`.rul`: step 3, the RUL under a lubrication fault (forecast, the Table 7 study);
- :mod:`.pipeline`: streaming a long record through the steps;
- :mod:`.reproduce` and :mod:`.report`: the seed reproduction (Tables 5-7) and its report;
- :mod:`.cli`: ``rulkit rw ...`` and ``rulkit reproduce rw-lubrication``.
"""
