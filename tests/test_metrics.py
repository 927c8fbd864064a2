"""Tests of rulkit.metrics against hand-computed cases and closed forms."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy import integrate, stats

from rulkit.metrics import (
    alpha_lambda,
    convergence,
    crps_normal,
    crps_samples,
    cumulative_relative_accuracy,
    interval_coverage,
    prognostic_horizon,
    relative_accuracy,
    rmspe,
    rul_percentage_error,
)
from rulkit.prognosis.rul import RULDistribution


def test_rul_percentage_error_and_rmspe_hand_computed():
    np.testing.assert_allclose(rul_percentage_error([90.0, 110.0], [100.0, 100.0]), [10, -10])
    assert rmspe([110.0, 90.0, 100.0], [100.0] * 3) == pytest.approx(100 * math.sqrt(0.02 / 3))
    np.testing.assert_allclose(
        rmspe([[110.0, 90.0], [50.0, 50.0]], [[100.0, 100.0], [40.0, 50.0]], axis=1),
        [10.0, 100 * math.sqrt(0.0625 / 2)],
    )
    with pytest.raises(ValueError, match="zero at index"):
        rmspe([1.0], [0.0])
    with pytest.raises(ValueError, match="shapes differ"):
        rul_percentage_error([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="non-finite"):
        rmspe([np.nan], [1.0])


def test_relative_accuracy_and_cra():
    assert relative_accuracy(80.0, 100.0) == pytest.approx(0.8)
    np.testing.assert_allclose(relative_accuracy([80.0, 130.0], [100.0, 100.0]), [0.8, 0.7])
    assert cumulative_relative_accuracy([80.0, 130.0], [100.0, 100.0]) == pytest.approx(0.75)
    assert cumulative_relative_accuracy([80.0, 130.0], [100.0, 100.0], weights=[1, 3]) == (
        pytest.approx(0.8 * 0.25 + 0.7 * 0.75)
    )
    # after end of life r* < 0: 1 - |(-10) - (-12)| / (-10) = 1.2 would read "better than perfect"
    with pytest.raises(ValueError, match="rul_true: negative at index"):
        relative_accuracy(-12.0, -10.0)
    with pytest.raises(ValueError, match="negative"):
        cumulative_relative_accuracy([5.0, -12.0], [5.0, -10.0])


def test_alpha_lambda_points_and_distributions():
    times = np.array([0.0, 10.0, 20.0, 30.0, 40.0])
    # t_lambda = 0 + 0.5 * 100 = 50 -> latest prediction at 40, r* = 60, bounds [48, 72]
    res = alpha_lambda(times, [99, 88, 77, 66, 70.0], 100.0, alpha=0.2, lam=0.5)
    assert res.t_lambda == 50.0 and res.t_pred == 40.0
    assert (res.lower, res.upper) == pytest.approx((48.0, 72.0))
    assert res.passed
    assert not alpha_lambda(times, [99, 88, 77, 66, 73.0], 100.0, alpha=0.2, lam=0.5).passed
    # lam = 0.3 -> t_lambda = 30 exactly, prediction 66 vs r* = 70, bounds [56, 84]
    assert alpha_lambda(times, [0, 0, 0, 66, 0.0], 100.0, alpha=0.2, lam=0.3).passed
    # distributions: 60 % of the mass inside [48, 72] passes with beta = 0.5, not with 0.7
    inside = [50.0, 55.0, 60.0, 65.0, 70.0, 71.0]
    outside = [10.0, 20.0, 80.0, 90.0]
    d = RULDistribution(inside + outside)
    dists = [d] * 5
    r = alpha_lambda(times, dists, 100.0, alpha=0.2, lam=0.5, beta=0.5)
    assert r.prob_mass == pytest.approx(0.6) and r.passed
    assert not alpha_lambda(times, dists, 100.0, alpha=0.2, lam=0.5, beta=0.7).passed
    with pytest.raises(ValueError, match="not strictly increasing"):
        alpha_lambda([0.0, 0.0], [1.0, 1.0], 10.0)
    with pytest.raises(ValueError, match="rul_pred: non-finite value at index"):
        alpha_lambda([0.0, 1.0], [1.0, np.nan], 10.0)


def test_prognostic_horizon_hand_computed():
    times = np.array([0.0, 20.0, 40.0, 60.0, 80.0])
    # r* = [100, 80, 60, 40, 20]; absolute bounds r* +- 0.1 * 100
    res = prognostic_horizon(times, [130.0, 60.0, 65.0, 35.0, 21.0], 100.0, alpha=0.1)
    assert res.inside.tolist() == [False, False, True, True, True]
    assert res.horizon == 60.0 and res.index == 2
    # enters at 20, leaves at 40, re-enters at 60: first-entry PH 80, "stay" PH 40
    preds = [130.0, 85.0, 45.0, 42.0, 21.0]
    assert prognostic_horizon(times, preds, 100.0, alpha=0.1).horizon == 80.0
    assert prognostic_horizon(times, preds, 100.0, alpha=0.1, stay=True).horizon == 40.0
    # relative bounds (1 -+ 0.1) r*: 85 vs [72, 88] in, 42 vs [36, 44] in, 21 vs [18, 22] in
    rel = prognostic_horizon(times, preds, 100.0, alpha=0.1, bounds="relative")
    assert rel.inside.tolist() == [False, True, False, True, True]
    none = prognostic_horizon(times, [0.0] * 5, 100.0, alpha=0.01)
    assert math.isnan(none.horizon) and none.index == -1


def test_convergence_hand_computed():
    # M = [2, 1] on [0,1), [1,2): area 3, x_c = (1*2 + 3*1)/6, y_c = (4 + 1)/6
    c = convergence([0.0, 1.0, 2.0], [2.0, 1.0, 123.0])
    assert c == pytest.approx(math.hypot(5 / 6, 5 / 6))
    # constant M = c on [t_P, T] -> centroid (mid, c/2)
    assert convergence(np.linspace(10, 30, 11), np.full(11, 4.0)) == pytest.approx(
        math.hypot(10.0, 2.0)
    )
    # faster-shrinking error converges better
    t = np.linspace(0, 10, 21)
    assert convergence(t, np.exp(-t)) < convergence(t, np.exp(-0.1 * t))


def test_interval_coverage():
    assert interval_coverage([0, 0, 0, 0], [1, 1, 1, np.inf], [0.5, 1.0, 2.0, 1e9]) == 0.75
    with pytest.raises(ValueError, match="lower > upper at index 1"):
        interval_coverage([0, 2], [1, 1], [0, 0])


def test_crps_samples_hand_cases_and_bruteforce():
    # F = 1/2 delta_0 + 1/2 delta_1, y = 0: int_0^1 (1/2 - 1)^2 = 1/4
    assert crps_samples([0.0, 1.0], 0.0) == pytest.approx(0.25)
    # point mass: |x - y|
    assert crps_samples([3.0], 1.0) == pytest.approx(2.0)
    rng = np.random.default_rng(2)
    x = rng.normal(size=30)
    w = rng.random(30)
    y = 0.4
    wn = w / w.sum()
    brute = np.sum(wn * np.abs(x - y)) - 0.5 * np.sum(
        wn[:, None] * wn[None, :] * np.abs(x[:, None] - x[None, :])
    )
    assert crps_samples(x, y, weights=w) == pytest.approx(brute, rel=1e-12)
    # the integral definition int (F(z) - 1{z >= y})^2 dz, integrated piecewise exactly
    pts = np.sort(np.r_[x, y])
    order = np.argsort(x)
    total = 0.0
    for a, b in itertools.pairwise(pts):
        mid = 0.5 * (a + b)
        f = np.sum(wn[order][x[order] <= mid])
        total += (f - (1.0 if mid >= y else 0.0)) ** 2 * (b - a)
    assert crps_samples(x, y, weights=w) == pytest.approx(total, rel=1e-10)
    # integer weights == repeated samples; batched call == loop
    assert crps_samples([1.0, 2.0], 1.5, weights=[1, 3]) == pytest.approx(
        crps_samples([1.0, 2.0, 2.0, 2.0], 1.5)
    )
    xb = rng.normal(size=(4, 25))
    yb = rng.normal(size=4)
    np.testing.assert_allclose(crps_samples(xb, yb), [crps_samples(xb[i], yb[i]) for i in
                                                      range(4)])
    with pytest.raises(ValueError, match="do not match"):
        crps_samples(xb, 0.0)


def test_crps_samples_converges_to_normal_closed_form():
    rng = np.random.default_rng(9)
    mu, sigma = 2.0, 1.5
    x = rng.normal(mu, sigma, size=200_000)
    for y in (-1.0, 2.0, 5.5):
        # empirical CRPS error is O(sigma / sqrt(N)) ~ 0.003 here
        assert crps_samples(x, y) == pytest.approx(crps_normal(mu, sigma, y), abs=0.015)


@pytest.mark.parametrize(("mu", "sigma", "y"), [(0.0, 1.0, 0.0), (2.0, 0.5, 3.1),
                                                (-1.0, 3.0, -7.0)])
def test_crps_normal_vs_numerical_integration(mu, sigma, y):
    F = stats.norm(mu, sigma).cdf
    left, _ = integrate.quad(lambda z: F(z) ** 2, -np.inf, y)
    right, _ = integrate.quad(lambda z: (1 - F(z)) ** 2, y, np.inf)
    assert crps_normal(mu, sigma, y) == pytest.approx(left + right, rel=1e-8)
    with pytest.raises(ValueError, match="sigma"):
        crps_normal(0.0, 0.0, 1.0)


def test_prognostic_horizon_with_distributions_and_censored_mass():
    times = np.array([0.0, 50.0])
    # absolute bounds r* +- 0.1 * 100: [90, 110] at t = 0, [40, 60] at t = 50
    early = RULDistribution([10.0, 20.0, 95.0, 100.0])  # mass 0.5 in [90, 110]
    # censored sample bounded below by 45: may lie above 60, counts as outside
    late = RULDistribution([45.0, 50.0, 55.0, 200.0], censored=[True, False, False, False],
                           horizon=200.0)
    res = prognostic_horizon(times, [early, late], 100.0, alpha=0.1, beta=0.5)
    assert res.inside.tolist() == [True, True] and res.horizon == 100.0
    res = prognostic_horizon(times, [early, late], 100.0, alpha=0.1, beta=0.6)
    assert res.inside.tolist() == [False, False] and math.isnan(res.horizon)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"t_eol": math.nan}, "t_eol"),
        ({"t_eol": math.inf}, "t_eol"),
        ({"alpha": math.nan}, "alpha"),
        ({"alpha": 0.0}, "alpha"),
        ({"beta": math.nan}, "beta"),
        ({"beta": 0.0}, "beta"),
        ({"beta": 1.5}, "beta"),
    ],
)
def test_alpha_lambda_and_horizon_reject_bad_parameters(kwargs, match):
    # a NaN t_eol or alpha made every bound comparison False: "no horizon" / "failed", silently
    args = {"t_eol": 100.0, "alpha": 0.1, "beta": 0.5, **kwargs}
    t_eol = args.pop("t_eol")
    with pytest.raises(ValueError, match=match):
        prognostic_horizon([0.0, 10.0], [100.0, 90.0], t_eol, **args)
    with pytest.raises(ValueError, match=match):
        alpha_lambda([0.0, 10.0], [100.0, 90.0], t_eol, **args)


def test_convergence_rejects_non_finite_t_p():
    with pytest.raises(ValueError, match="t_p"):
        convergence([0.0, 1.0, 2.0], [1.0, 1.0, 1.0], t_p=math.nan)


def test_scalar_nan_and_zero_truth_are_refused():
    # np.argwhere of a 0-d array is empty: scalar NaN and r* = 0 used to pass unnoticed
    with pytest.raises(ValueError, match="rul_pred: non-finite"):
        relative_accuracy(np.nan, 5.0)
    with pytest.raises(ValueError, match="rul_true: zero at index"):
        relative_accuracy(1.0, 0.0)  # was -inf
    with pytest.raises(ValueError, match="mu: non-finite"):
        crps_normal(np.nan, 1.0, 0.0)
    with pytest.raises(ValueError, match="y: non-finite"):
        crps_samples([1.0, 2.0], np.inf)
    with pytest.raises(ValueError, match="zero"):
        rmspe(1.0, 0.0)


# ---------------------------------------------------------------------------- crps_rul
def _grid_crps(dist, y, upper, truth_censored):
    """Brute force: midpoint rule of (F(z) - 1{z >= y})^2 on a fine grid below ``upper``."""
    z = np.linspace(-1.0, upper, 400_001)
    zm = 0.5 * (z[1:] + z[:-1])
    F = dist.cdf(zm)
    ind = np.zeros_like(zm) if truth_censored else (zm >= y).astype(float)
    return float(np.sum((F - ind) ** 2 * np.diff(z)))


def test_crps_rul_equals_crps_samples_without_censoring() -> None:
    from rulkit.metrics import crps_rul, crps_samples
    from rulkit.prognosis.rul import RULDistribution

    rng = np.random.default_rng(0)
    s = rng.gamma(3.0, 2.0, 200)
    w = rng.uniform(0.1, 1.0, 200)
    d = RULDistribution(s, w)
    for y in (0.5, 6.0, 40.0):
        assert crps_rul(d, y) == pytest.approx(crps_samples(s, y, w), rel=1e-10)


def test_crps_rul_with_censored_forecast_and_truth_against_brute_force() -> None:
    from rulkit.metrics import crps_rul
    from rulkit.prognosis.rul import RULDistribution

    rng = np.random.default_rng(1)
    s = rng.uniform(0, 12, 50)
    cens = s > 10
    d = RULDistribution(np.minimum(s, 10.0), censored=cens, horizon=10.0)
    for y, tc in ((4.0, False), (11.0, False), (6.0, True), (15.0, True)):
        upper = min(10.0, y if tc else math.inf)
        assert crps_rul(d, y, truth_censored=tc) == pytest.approx(
            _grid_crps(d, y, upper, tc), rel=1e-4, abs=1e-6)


def test_a_forecast_with_every_sample_censored_scores_nan_with_a_warning() -> None:
    """A horizon too short for any sample to fail used to score a perfect CRPS of 0.0 (and a
    profile summary with crps_mean 0.0), silently: it scores NaN with a warning."""
    from rulkit.metrics import UninformativeForecastWarning, crps_rul

    d = RULDistribution(np.full(50, 10.0), censored=np.ones(50, bool), horizon=10.0)
    for y, truth_censored in ((25.0, False), (40.0, True), (5.0, False)):
        with pytest.warns(UninformativeForecastWarning, match="every sample of the forecast is "
                                                               "censored at the horizon 10"):
            assert np.isnan(crps_rul(d, y, truth_censored=truth_censored))
    one_crossed = RULDistribution(np.r_[3.0, np.full(49, 10.0)],
                                  censored=np.r_[False, np.ones(49, bool)], horizon=10.0)
    assert crps_rul(one_crossed, 25.0) > 0  # some information: scored


def test_profile_with_every_forecast_censored_has_no_perfect_score() -> None:
    from rulkit import GaussianNoise, StateSpaceModel, prognosis_profile
    from rulkit.metrics import UninformativeForecastWarning

    class Slow(StateSpaceModel):
        state_names, output_names, threshold, dt = ("d",), ("y",), 1.0, 1.0

        @property
        def noise(self):
            return GaussianNoise(Q=np.array([[1e-8]]), R=np.array([[1e-4]]))

        def step(self, x, u, t, dt, rng=None):
            return x + 0.001 * dt

        def output(self, x, u=None):
            return x.copy()

        def health(self, x):
            return x[:, 0]

    ys = 0.001 * np.arange(1.0, 31.0)[:, None]
    with pytest.warns(UninformativeForecastWarning):
        prof = prognosis_profile(Slow(), ys, "ekf", np.zeros(1), P0=[[1e-6]], times=[10, 20],
                                 horizon=5.0, t_eol=1000.0, rng=np.random.default_rng(0))
        summary = prof.summary()
    assert np.all([d.n_censored == d.n for d in prof.distributions])
    assert np.isnan(summary["crps_mean"])
