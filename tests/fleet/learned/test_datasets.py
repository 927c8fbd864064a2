"""Synthetic fleets with known truth: the closed-form failure times against an ODE solver."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from rulkit.fleet.learned.datasets import (
    GOAL_FLEETS,
    goal_fleet,
    growth_fleet_laws,
    paris_curve,
    paris_life,
    synthetic_growth_fleet,
    synthetic_linear_fleet,
    synthetic_paris_fleet,
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


def _check_run_to_failure(df, truth):
    """Every failed unit ends at its first measured hi >= 1, with nothing after it, and its
    failure time is the crossing of hi = 1 interpolated from the acquisition before (the truth
    ``rulkit evaluate`` scores); a censored unit measured no hi >= 1 and has no failure time.
    Returns each unit's last acquisition time."""
    last_t = []
    for u, (_, g) in enumerate(df.groupby("component", sort=False)):
        t, hi = g["time"].to_numpy(), g["hi"].to_numpy()
        assert (np.diff(t) > 0).all()
        above = np.flatnonzero(hi >= 1.0)
        if np.isnan(truth[u]):
            assert above.size == 0
        else:
            assert above.tolist() == [t.size - 1]  # the first hi >= 1 is the last acquisition
            crossing = t[-2] + (1.0 - hi[-2]) * (t[-1] - t[-2]) / (hi[-1] - hi[-2])
            assert truth[u] == pytest.approx(crossing, rel=1e-12)
            assert t[-2] < truth[u] <= t[-1]
        last_t.append(t[-1])
    return np.array(last_t)


@pytest.mark.parametrize("name", sorted(GOAL_FLEETS))
def test_a_failed_unit_ends_at_its_first_measured_failure_whenever_it_comes(name):
    """Each goal fleet's run-to-failure units, and the same fleets with 5 acquisitions per
    life, where most units need acquisitions past 1.05 x their law's life (the generator used
    to stop there and append a point at 1.1 x life as the truth): every failed unit is
    acquired on, on its cadence, until it measures hi >= 1."""
    ss = np.random.SeedSequence(0).spawn(2 + len(GOAL_FLEETS))
    k = list(GOAL_FLEETS).index(name)
    df, truth = goal_fleet(name, np.random.default_rng(ss[2 + k]), 40)
    _check_run_to_failure(df, truth)
    kw = {**GOAL_FLEETS[name], "n_acq": 5.0}
    df, truth = synthetic_growth_fleet(np.random.default_rng(ss[2 + k]), 40,
                                       **kw)  # type: ignore[arg-type]
    grow, onset = growth_fleet_laws(np.random.default_rng(ss[2 + k]), 40,
                                    onset_frac=float(kw.get("onset_frac", 0.0)))
    life = grow + onset
    last_t = _check_run_to_failure(df, truth)
    late = np.isfinite(truth) & (last_t > 1.05 * life)
    assert late.sum() >= 5
    assert not np.isclose(last_t[late], 1.1 * life[late], rtol=1e-12).any()


@pytest.mark.parametrize("gen", [synthetic_paris_fleet, synthetic_linear_fleet])
def test_paris_and_linear_fleets_end_at_their_first_measured_failure(gen):
    df, truth = gen(np.random.default_rng(2), 60, noise_sd=0.05)
    _check_run_to_failure(df, truth)
    assert 0.5 < np.isfinite(truth).mean() < 0.9
