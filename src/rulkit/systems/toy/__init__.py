"""A 2-state linear degradation model: the engine's worked example and benchmark problem.

- :mod:`.model`: the model (linear-Gaussian, so the exact Kalman filter is its oracle);
- :mod:`.example`: particle filter beside the Kalman filter, Monte Carlo RUL, metrics;
- :mod:`.cli`: ``rulkit example``.

CONTRIBUTING.md uses this package as the template for adding a system.
"""
