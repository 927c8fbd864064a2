"""Reaction-wheel bearing lubrication (seeds 000 and 001; docs/systems/reaction-wheel.md).

- :mod:`.wheel`: the Ithaco type-A wheel (speed, current, torques) and its noise;
- :mod:`.lubrication`: lubricant-loss physics and the two fault scenarios;
- :mod:`.kernels`: numba kernels of the temperature particle filters (beside the physics they
  must match);
- :mod:`.telemetry`: reading and validating a user's telemetry file;
- :mod:`.temperature`: lubricant temperature by PF, adaptive-resampling PF, adaptive PF, EKF;
- :mod:`.rbpf`: the Rao-Blackwellised temperature filter;
- :mod:`.degradation`: lubricant-loss parameters by one-step and two-step PF;
- :mod:`.rul`: RUL under the two lubrication faults;
- :mod:`.reproduce`: the seed reproduction (Tables 5-7), report and figures;
- :mod:`.cli`: ``rulkit rw ...`` and ``rulkit reproduce rw-lubrication``.
"""
