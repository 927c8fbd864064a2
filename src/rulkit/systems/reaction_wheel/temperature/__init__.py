"""Step 1: the bearing lubricant temperature from wheel speed and motor current
(docs/systems/reaction-wheel.md §3).

- :mod:`.particle`: the seeds' particle filters (PF, adaptive resampling, APF of eq. 28,
  tempered APF) in designs F1 and F2, with :mod:`.kernels` their compiled loop;
- :mod:`.rbpf`: the Rao-Blackwellised particle filter (beyond the seeds);
- :mod:`.ekf`: the reference extended Kalman filter;
- :mod:`.estimator`: any of them over a user's record, chunk by chunk;
- :mod:`.study`: the Table 5 study and its figures.
"""
