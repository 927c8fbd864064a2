"""Synthetic fleets with known truth: the closed-form failure times against an ODE solver."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from rulkit.fleet.learned.datasets import (
    GOAL_FLEETS,
    goal_fleet,
    paris_curve,
    paris_life,
    synthetic_growth_fleet,
)


@pytest.mark.parametrize("m", [0.0, 2.0, 3.0, 5.0])
def test_paris_life_and_curve_solve_the_growth_law(m):
    """dh/dt = c h^(m/2) from h0: scipy's solve_ivp reaches h = 1 at paris_life, and passes
    through paris_curve on the way."""
    h0, c = 0.2, 0.01
    life = float(paris_life(h0, np.array([c]), m)[0])
    sol = solve_ivp(lambda t, h: c * h ** (m / 2), (0, life), [h0], rtol=1e-10, atol=1e-12,
                    dense_output=True)
    assert sol.y[0, -1] == pytest.approx(1.0, rel=1e-7)
    t = np.linspace(0, life, 7)
    np.testing.assert_allclose(paris_curve(h0, c, m, t), sol.sol(t)[0], rtol=1e-7)


def test_onset_fleet_is_flat_before_its_onset_and_runs_to_failure():
    df, truth = synthetic_growth_fleet(np.random.default_rng(0), 30, h0=0.1, noise="additive",
                                       hi_noise_sd=1e-9, onset_frac=0.5, censor_frac=0.3)
    last = df.groupby("component").tail(1)
    failed = np.isfinite(truth)
    assert 0.5 < failed.mean() < 0.9
    assert (last["hi"].to_numpy()[failed] >= 1.0).all()  # a failed unit ends at hi >= 1
    assert (last["hi"].to_numpy()[~failed] < 1.0).all()
    first = df.groupby("component").head(3)["hi"].to_numpy()
    assert np.mean(np.abs(first - 0.1) < 1e-6) > 0.5  # most units still flat early on


def test_goal_fleets_are_seeded():
    for name in GOAL_FLEETS:
        a, ta = goal_fleet(name, np.random.default_rng(5), 6)
        b, tb = goal_fleet(name, np.random.default_rng(5), 6)
        assert a.equals(b) and np.array_equal(ta, tb, equal_nan=True)
    with pytest.raises(ValueError, match="goal fleet"):
        goal_fleet("bearing", np.random.default_rng(0))
