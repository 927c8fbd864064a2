"""Reaction-wheel bearing lubrication (seeds 000 and 001; docs/systems/reaction-wheel.md).

- :mod:`.wheel`: the Ithaco type-A wheel (speed, current, torques) and its noise;
- :mod:`.lubrication`: lubricant-loss physics and the two fault scenarios;
- :mod:`.kernels`: numba kernels of the temperature particle filters (beside the physics they
  must match);
- :mod:`.telemetry`: reading and validating a user's telemetry file;
- :mod:`.temperature`: lubricant temperature by PF, adaptive-resampling PF, adaptive PF, EKF;
- :mod:`.temperature_study`: the Table 5 study of the temperature estimators and its figures;
- :mod:`.rbpf`: the Rao-Blackwellised temperature filter;
- :mod:`.degradation`: lubricant-loss parameters by one-step and two-step PF and the RB-PF;
- :mod:`.degradation_study`: the Table 6 study of those trackers (T^ error statistics, shortcut
  validation, sensitivity to the unstated settings);
- :mod:`.rul`: RUL under the two lubrication faults;
- :mod:`.reproduce`: the seed reproduction (Tables 5-7), report and figures;
- :mod:`.cli`: ``rulkit rw ...`` and ``rulkit reproduce rw-lubrication``.
"""
