"""What an operator reads: one RUL per component and the alert rules (docs/service.md).

- :mod:`.unit_trend`: the default RUL estimator while no model is fitted, a per-unit
  log-linear trend with a Student-t predictive (RUL never negative, the median inside its
  interval by construction);
- :mod:`.estimators`: the estimator in force (a fitted model, the trend, or the seed-004
  tracker chain by explicit choice) behind one interface: RUL quantiles and the HI forecast;
- :mod:`.rules`: the alert rules (alarm on the measured HI with persistence, warning on the
  RUL's lower quantile against a lead time, staleness, failed units) and time units.
"""
