"""Per-unit regression baseline (docs/fleet-models.md eq. (11)) against weighted least
squares computed directly."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.learned.growth_filter import boxcox
from rulkit.fleet.learned.histories import histories_from_frame
from rulkit.fleet.learned.regression import RegressionModel, SumsState, fit_regression


def _hist(rng, n_units=4):
    rows = []
    for u in range(n_units):
        t = np.sort(rng.uniform(1, 100, 12))
        hi = 0.1 * np.exp(0.02 * t) * np.exp(0.05 * rng.standard_normal(t.size))
        rows.append(pd.DataFrame({"component": f"u{u}", "time": t, "hi": hi}))
    df = pd.concat(rows, ignore_index=True)
    df.loc[df.index[-1], "hi"] = 1.1
    return histories_from_frame(df)


def test_forgotten_sums_give_the_weighted_least_squares_line():
    """(a, b) from the sums = numpy's weighted least squares with weights rho^(k - j)."""
    h = _hist(np.random.default_rng(0))
    m = RegressionModel(shape=0.0, window=5.0, noise_var=1e-3, time_scale=50.0)
    st = m.replay(h)
    g = m.gaussian(st)
    rho = 1 - 1 / 5.0
    for u in range(h.n_units):
        sl = h.rows(u)
        x, z = h.t[sl] / 50.0, boxcox(h.hi[sl], 0.0)
        k = x.size - 1
        w = rho ** (k - np.arange(x.size))
        X = np.column_stack([np.ones_like(x), x])
        coef = np.linalg.solve(X.T @ (w[:, None] * X), X.T @ (w * z))
        last = sl.stop - 1
        assert g.m[last, 1] == pytest.approx(coef[1], rel=1e-9)  # the rate
        assert g.m[last, 0] == pytest.approx(coef[0] + coef[1] * x[-1], rel=1e-9)  # the level


def test_update_equals_replay_and_round_trip():
    h = _hist(np.random.default_rng(1))
    m = RegressionModel(shape=0.5, window=10.0, noise_var=1e-3, time_scale=50.0)
    sl = h.rows(0)
    st = m.empty_state(1)
    for t, hi in zip(h.t[sl], h.hi[sl], strict=True):
        st = m.update(st, np.array([t]), np.array([hi]))
    ref = m.replay(h).take(np.array([sl.stop - 1]))
    np.testing.assert_allclose(st.s, ref.s, rtol=1e-12)
    back = m.state_from_columns(st.columns())
    assert isinstance(back, SumsState)
    np.testing.assert_array_equal(back.s, st.s)
    assert RegressionModel.from_dict(m.to_dict()) == m


def test_too_few_acquisitions_mean_an_open_interval():
    """Fewer than three acquisitions: the rate is unknown, half the mass never fails."""
    m = RegressionModel(shape=0.0, window=10.0, noise_var=1e-3, time_scale=50.0)
    st = m.update(m.empty_state(1), np.array([5.0]), np.array([0.3]))
    med, lo, hi = m.rul_quantiles(st)
    assert np.isinf(med[0]) and np.isinf(hi[0]) and 0 <= lo[0] < np.inf


def test_fit_chooses_settings_on_the_training_units():
    h = _hist(np.random.default_rng(2), 6)
    m = fit_regression(h)
    assert m.window in (5.0, 10.0, 20.0, 40.0) and m.paris_exponent in (0.0, 1.0, 2.0, 3.0)
