"""The estimator in force and its HI forecast (rulkit.fleet.monitoring.estimators): which
estimator each choice resolves to, what it is labelled, and forecasts whose band meets the
threshold where the RUL interval lies (the fitted model's against Monte Carlo draws)."""

import numpy as np
import pytest

from rulkit.fleet.learned.degradation import DegradationModel, UnitState, update_state
from rulkit.fleet.monitoring.estimators import (
    ComponentStates,
    estimator_in_force,
    forecast_horizons,
    hi_forecast,
    model_hi_quantiles,
)
from rulkit.fleet.monitoring.rules import MonitoringRules
from rulkit.fleet.monitoring.unit_trend import TrendState
from rulkit.fleet.tracking.tracker_chain import TrackerConfig, tracker_rul_interval

MODEL = DegradationModel(kind="paris", shape=0.0, mean=(-1.5, 0.8), cov=(0.04, 0.0, 0.01),
                         noise_sd=0.02, walk_sd=0.05, time_scale=100.0, time_unit="h")


def test_choice_resolution_and_labels():
    cfg = TrackerConfig()
    auto = MonitoringRules(time_unit="d")
    assert estimator_in_force(auto, cfg).kind == "trend"
    e = estimator_in_force(auto, cfg, MODEL)
    assert e.kind == "model" and e.time_unit == "h"  # the model's unit wins
    assert e.label == "fitted paris model: median [5 %, 95 %]"
    forced = estimator_in_force(MonitoringRules(estimator="trend"), cfg, MODEL)
    assert forced.kind == "trend" and forced.model is None and "(chosen)" in forced.label
    assert "no model fitted" in estimator_in_force(auto, cfg).label
    tr = estimator_in_force(MonitoringRules(estimator="tracker"), cfg, MODEL)
    assert tr.kind == "tracker" and tr.label.startswith("seed-004 tracker chain (chosen)")
    assert estimator_in_force(auto, cfg).warnings == ()


def states_after(model, t, hi):
    st = UnitState.empty(model, t.shape[0])
    for k in range(t.shape[1]):
        st = update_state(st, model, t[:, k], hi[:, k])
    return st


def test_model_forecast_quantiles_against_monte_carlo():
    rng = np.random.default_rng(0)
    t = np.tile(np.arange(0.0, 50.0, 10.0), (3, 1))
    hi = np.exp(-1.5 + 0.008 * np.array([[1.0], [0.8], [1.2]]) * t)
    st = states_after(MODEL, t, hi)
    r = np.array([[0.0, 40.0, 120.0]] * 3)
    med, lo, up = model_hi_quantiles(MODEL, st, r, (0.5, 0.05, 0.95))
    w = r / MODEL.time_scale
    for i in range(3):  # draw (level, rate) from the posterior, add the walk, map back
        mz, mb = st.m[i]
        cov = [[st.p[i, 0], st.p[i, 1]], [st.p[i, 1], st.p[i, 2]]]
        z0, b = rng.multivariate_normal([mz, mb], cov, 200_000).T
        for k in range(3):
            z = z0 + b * w[i, k] + rng.normal(0, MODEL.walk_sd * np.sqrt(w[i, k]), z0.size)
            q = np.quantile(np.exp(z), [0.5, 0.05, 0.95])  # paris with m = 2: hi = exp(z)
            np.testing.assert_allclose([med[i, k], lo[i, k], up[i, k]], q, rtol=0.01)


def test_tracker_forecast_meets_the_threshold_at_its_interval():
    cfg = TrackerConfig(hi_sigma=0.03, paris_exponent=3.0)
    fhi, frul = np.array([0.3, 0.6]), np.array([120.0, 40.0])
    rul, low, high = tracker_rul_interval(fhi, frul, cfg)
    est = estimator_in_force(MonitoringRules(estimator="tracker"), cfg)
    states = ComponentStates(trend=TrendState.empty(2), model=None, fhi=fhi, frul=frul)
    eps = 1e-6
    at = np.column_stack([rul, low, high]) * (1 - eps)
    med_p, low_p, up_p = hi_forecast(est, states, at)
    # each path just below 1 an instant before its own crossing, at 1 after
    np.testing.assert_allclose(med_p[:, 0], 1.0, atol=1e-4)
    np.testing.assert_allclose(up_p[:, 1], 1.0, atol=1e-4)
    np.testing.assert_allclose(low_p[:, 2], 1.0, atol=1e-4)
    after = hi_forecast(est, states, np.column_stack([rul, low, high]) * (1 + 1e-3))
    assert np.all(after[0][:, 0] == 1.0) and np.all(after[2][:, 1] == 1.0)


def test_forecast_horizons_end_at_the_interval():
    hz = forecast_horizons(np.array([10.0, 10.0, np.nan]), np.array([5.0, 5.0, np.nan]),
                           np.array([20.0, np.inf, np.nan]), np.array([7.0, 7.0, 7.0]),
                           points=5)
    assert hz[:, 0].tolist() == [0.0, 0.0, 0.0]
    assert hz[:, -1].tolist() == [20.0, 20.0, 7.0]


@pytest.mark.parametrize("kind", ["linear", "exponential"])
def test_model_forecast_other_kinds_map_back(kind):
    model = DegradationModel(kind=kind, shape=-0.2 if kind == "exponential" else 0.0,
                             mean=(0.3 if kind == "linear" else -0.5, 0.3),
                             cov=(0.01, 0.0, 0.01), noise_sd=0.01, walk_sd=0.0,
                             time_scale=10.0)
    st = states_after(model, np.array([[1.0, 2.0]]), np.array([[0.4, 0.45]]))
    med = model_hi_quantiles(model, st, np.array([[0.0]]), (0.5,))[0][0, 0]
    z = st.m[0, 0]
    assert med == pytest.approx(z if kind == "linear" else -0.2 + np.exp(z))
