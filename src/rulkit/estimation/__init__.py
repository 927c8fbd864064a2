"""Generic estimation algorithms (no physics): resampling, particle filters, Kalman family,
alpha-beta(-gamma) trackers."""
