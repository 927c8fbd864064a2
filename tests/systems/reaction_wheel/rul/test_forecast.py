"""Step 3 of the reaction-wheel study: forecasts, thresholds and RUL against independent paths."""

from __future__ import annotations

import numpy as np
import pytest

from rulkit.systems.reaction_wheel.lubrication import (
    DAY_S,
    PATHS,
    SCENARIOS,
    WINDOW_S,
    true_window_increments,
)
from rulkit.systems.reaction_wheel.rul.forecast import (
    Forecaster,
    RULConfig,
    expected_cumulative,
    failure_threshold,
)
from rulkit.systems.reaction_wheel.rul.study import (
    rul_for_method,
)

ST3 = RULConfig(failure_day=20.0, prediction_days=(1.0, 2.0), table7_day=2.0,
                    forecast_horizon_days=40.0)


def test_expected_cumulative_matches_window_sums() -> None:
    W = 720  # two days of windows, through the fault
    for sid in (1, 2):
        X = np.cumsum(true_window_increments(PATHS[sid], SCENARIOS[sid], W))
        t = (np.arange(W) + 1) * WINDOW_S
        # the 0.05 s left sums and the integral differ by about half a sample (O(dt)), and the
        # 5 s grid places the fault jump to within a grid step
        rate_max = SCENARIOS[sid].beta0_fault * np.exp(-SCENARIOS[sid].b_fault / 40.0)
        np.testing.assert_allclose(expected_cumulative(sid, t), X, rtol=1e-9,
                                   atol=rate_max * 5.0)


def test_thresholds_fail_on_the_design_day() -> None:
    for sid in (1, 2):
        thr = failure_threshold(sid, ST3)
        assert thr > 0
        t = np.array([19.9, 20.0, 20.1]) * DAY_S
        if sid == 1:
            g = expected_cumulative(1, t)
        else:  # HI = X_healthy - X grows because the faulty loss rate is lower
            g = expected_cumulative(2, t, healthy=True) - expected_cumulative(2, t)
        assert g[0] < thr < g[2] and g[1] == pytest.approx(thr, rel=1e-12)


@pytest.mark.parametrize("sid", [1, 2])
def test_true_parameters_reach_threshold_on_the_design_day(sid: int) -> None:
    # forecast from day 2 with the true parameters and the expected X: RUL = 18 days
    t_k = 2.0 * DAY_S
    fc = Forecaster.build(sid, t_k, ST3)
    sc = SCENARIOS[sid]
    ind0 = fc.initial_indicator(expected_cumulative(sid, np.array([t_k])))
    d = fc.rul(np.array([sc.b_fault]), np.array([sc.beta0_fault]), ind0,
               np.random.default_rng(0))
    # the hour-window quadrature + linear interpolation within a 6 h step: error << 1 h
    assert d.samples[0] / DAY_S == pytest.approx(18.0, abs=0.01)


def test_engine_propagation_equals_vectorised_forecast() -> None:
    rng = np.random.default_rng(1)
    fc = Forecaster.build(1, 1.0 * DAY_S, ST3)
    b = rng.normal(25.0, 2.0, 50)
    beta0 = rng.normal(8.0e-6, 4e-7, 50)
    ind0 = np.full(50, float(expected_cumulative(1, np.array([DAY_S]))[0]))
    d = fc.rul(b, beta0, ind0, rng)
    tr = fc.trajectories(b, beta0, ind0)
    # independent crossing: first window where the cumsum passes the threshold, interpolated
    for i in range(50):
        j = int(np.argmax(tr[i] >= fc.threshold))
        if tr[i, -1] < fc.threshold:
            assert d.censored[i]
            continue
        frac = (fc.threshold - tr[i, j - 1]) / (tr[i, j] - tr[i, j - 1])
        assert d.samples[i] == pytest.approx((j - 1 + frac) * fc.window_s, rel=1e-10)


def test_point_mass_posterior_at_truth_gives_true_rul() -> None:
    sc = SCENARIOS[2]
    k = round(2.0 * DAY_S / WINDOW_S) - 1
    parts = np.empty((3, 20, 2))
    parts[..., 0], parts[..., 1] = sc.b_fault, sc.beta0_fault
    X = np.full(3, float(expected_cumulative(2, np.array([(k + 1) * WINDOW_S]))[0]))
    m = rul_for_method(2, "truth", {k: (parts, np.full((3, 20), 1 / 20))}, {k: X}, ST3, 0,
                       (sc.b_fault, sc.beta0_fault))
    np.testing.assert_allclose(m.pred_mean, m.truth, rtol=1e-12)
    assert m.metrics["interval_coverage"] == 1.0
    assert m.abs_error_pct.max() < 1e-9
