"""Learned degradation models (docs/fleet-models.md) against independent oracles."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from rulkit.fleet.learned.datasets import synthetic_paris_fleet
from rulkit.fleet.learned.degradation import (
    DegradationModel,
    UnitState,
    _nll_kernel,
    filtered_states,
    final_states,
    fit_model,
    rul_cdf,
    transform,
    update_state,
)
from rulkit.fleet.learned.histories import histories_from_frame


def _model(walk: float = 0.0, kind: str = "linear", shape: float = 0.0,
           mean=(0.1, 0.8), cov=(0.01, -0.001, 0.04), noise: float = 0.03) -> DegradationModel:
    return DegradationModel(kind=kind, shape=shape, mean=mean, cov=cov, noise_sd=noise,
                            walk_sd=walk, time_scale=10.0)


def _random_hist(rng, n_units=5, n_max=7):
    rows = []
    for u in range(n_units):
        n = int(rng.integers(1, n_max + 1))
        t = np.sort(rng.uniform(0.5, 12.0, n))
        t = np.unique(t)
        hi = np.abs(0.1 + 0.08 * t + 0.05 * rng.standard_normal(t.size))
        rows.append(pd.DataFrame({"component": f"u{u}", "time": t, "hi": hi}))
    df = pd.concat(rows, ignore_index=True)
    df.loc[df.index[-1], "hi"] = 1.2  # one failed unit
    return histories_from_frame(df)


def test_no_walk_posterior_is_bayesian_linear_regression():
    """sigma_w = 0: the filter's posterior of (a, b) equals the conjugate regression's."""
    rng = np.random.default_rng(0)
    h = _random_hist(rng)
    m = _model()
    st = final_states(m, h)
    s0 = np.array([[m.cov[0], m.cov[1]], [m.cov[1], m.cov[2]]])
    for u in range(h.n_units):
        s = h.rows(u)
        x = h.t[s] / m.time_scale
        X = np.column_stack([np.ones_like(x), x])
        prec = np.linalg.inv(s0) + X.T @ X / m.noise_sd**2
        cov = np.linalg.inv(prec)
        mean = cov @ (np.linalg.inv(s0) @ np.array(m.mean) + X.T @ h.hi[s] / m.noise_sd**2)
        # the filter holds (level at x_last, rate): level = a + b x_last
        J = np.array([[1.0, x[-1]], [0.0, 1.0]])
        np.testing.assert_allclose(st.m[u], J @ mean, rtol=1e-10, atol=1e-12)
        pj = J @ cov @ J.T
        np.testing.assert_allclose(st.p[u], [pj[0, 0], pj[0, 1], pj[1, 1]], rtol=1e-9,
                                   atol=1e-14)


@pytest.mark.parametrize("walk", [0.0, 0.2])
def test_marginal_likelihood_equals_gaussian_density(walk):
    """eq. (3): the filter's prediction-error likelihood = the joint Gaussian density of z with
    covariance X Sigma X^T + sigma_w^2 min(x_i, x_j) + sigma_e^2 I (scipy oracle)."""
    rng = np.random.default_rng(1)
    h = _random_hist(rng)
    m = _model(walk=walk)
    x = h.t / m.time_scale
    z = transform("linear", 0.0, h.hi)
    nll = _nll_kernel(np.array(m.mean), np.array(m.cov), walk**2, m.noise_sd**2, x, z,
                      h.start.astype(np.int64))
    s0 = np.array([[m.cov[0], m.cov[1]], [m.cov[1], m.cov[2]]])
    ref = 0.0
    for u in range(h.n_units):
        s = h.rows(u)
        xu = x[s]
        X = np.column_stack([np.ones_like(xu), xu])
        c = X @ s0 @ X.T + walk**2 * np.minimum.outer(xu, xu) + m.noise_sd**2 * np.eye(xu.size)
        ref -= stats.multivariate_normal(X @ np.array(m.mean), c).logpdf(z[s])
    assert nll == pytest.approx(ref, rel=1e-10)


def test_vectorised_update_equals_replay():
    """update_state (numpy, one acquisition per unit per call) = the compiled replay."""
    rng = np.random.default_rng(2)
    h = _random_hist(rng, n_units=6)
    m = _model(walk=0.3, kind="paris", shape=-0.5)
    ref = final_states(m, h)
    st = UnitState.empty(m, h.n_units)
    n_max = int(np.diff(h.start).max())
    for k in range(n_max):
        t = np.full(h.n_units, np.nan)
        hi = np.full(h.n_units, np.nan)
        for u in range(h.n_units):
            if h.start[u] + k < h.start[u + 1]:
                t[u], hi[u] = h.t[h.start[u] + k], h.hi[h.start[u] + k]
        st = update_state(st, m, t, hi)
    np.testing.assert_allclose(st.m, ref.m, rtol=1e-12)
    np.testing.assert_allclose(st.p, ref.p, rtol=1e-12)
    np.testing.assert_array_equal(st.n, np.diff(h.start))


def test_update_refuses_time_going_back():
    m = _model()
    st = update_state(UnitState.empty(m, 2), m, np.array([1.0, 1.0]), np.array([0.2, 0.2]))
    with pytest.raises(ValueError, match="unit index 1"):
        update_state(st, m, np.array([2.0, 0.5]), np.array([0.3, 0.3]))


def test_rul_cdf_matches_monte_carlo_of_the_model():
    """eq. (5) of the latent level (a law without measurement noise): S(r)/S(0) against
    draws of (level, rate) and the random walk."""
    noisy = _model(walk=0.3)
    m = SimpleNamespace(walk_sd=noisy.walk_sd, threshold=noisy.threshold,
                        time_scale=noisy.time_scale)
    st = UnitState(m=np.array([[0.6, 0.9]]), p=np.array([[0.002, 0.0005, 0.01]]),
                   t=np.array([5.0]), hi=np.array([0.6]), n=np.array([3]))
    rng = np.random.default_rng(3)
    n = 400_000
    lz = np.linalg.cholesky(np.array([[0.002, 0.0005], [0.0005, 0.01]]))
    d = st.m[0] + rng.standard_normal((n, 2)) @ lz.T
    r = np.array([2.0, 4.0, 8.0])
    w = r / m.time_scale
    below0 = d[:, 0] < 1.0
    cdf = rul_cdf(m, st, r[None, :])[0]
    for j, wj in enumerate(w):
        zr = d[:, 0] + d[:, 1] * wj + m.walk_sd * math.sqrt(wj) * rng.standard_normal(n)
        surv = np.mean(below0 & (zr < 1.0)) / np.mean(below0)
        # the formula conditions marginally: S(r)/S(0) with S(r) = P(z(r) < 1)
        surv_marg = np.mean(zr < 1.0) / np.mean(below0)
        assert 1 - cdf[j] == pytest.approx(surv_marg, abs=4e-3)
        assert surv <= surv_marg + 4e-3


def test_quantiles_invert_the_cdf_and_edge_cases():
    m = _model(walk=0.1)
    st = UnitState(m=np.array([[0.5, 0.9], [0.5, -0.5], [1.1, 0.9], [0.5, 0.9]]),
                   p=np.tile([0.001, 0.0, 0.01], (4, 1)), t=np.array([3.0, 3.0, 3.0, np.nan]),
                   hi=np.array([0.5, 0.5, 1.05, np.nan]), n=np.array([2, 2, 2, 0]))
    med, lo, hi = m.rul_quantiles(st)
    f = rul_cdf(m, st, np.column_stack([lo, med, hi]))
    np.testing.assert_allclose(f[0], [0.05, 0.5, 0.95], atol=1e-9)
    assert lo[0] < med[0] < hi[0]
    assert np.isinf(med[1]) and np.isinf(hi[1])  # rate mostly negative: censored mass
    assert med[2] == lo[2] == hi[2] == 0.0  # measured hi >= 1: failed
    assert np.isnan(med[3])  # no acquisition


def _test_stopped_fleet(rng, n=300, t_end=80.0):
    """Linear wear, all tests stopped at t_end (a unit that has not failed by then is
    censored: slow units are censored, the selection the spec warns about)."""
    a = 0.1 + 0.02 * rng.standard_normal(n)
    b = 0.01 * np.exp(0.3 * rng.standard_normal(n))
    rows = []
    for u in range(n):
        t = np.arange(5.0, t_end + 1e-9, 5.0)
        hi = a[u] + b[u] * t + 0.02 * rng.standard_normal(t.size)
        k = np.flatnonzero(hi >= 1.0)
        if k.size:
            t, hi = t[: k[0] + 1], hi[: k[0] + 1]
        rows.append(pd.DataFrame({"component": f"u{u}", "time": t, "hi": hi}))
    return pd.concat(rows, ignore_index=True), float(np.mean(b))


def test_fit_recovers_linear_fleet_and_censored_units_remove_selection_bias():
    """All units (failed + censored) recover the mean rate; failed-only is biased fast."""
    df, true_mean_rate = _test_stopped_fleet(np.random.default_rng(4))
    h = histories_from_frame(df)
    assert 0.2 < h.failed.mean() < 0.8
    m_all = fit_model(h, "linear")
    m_fail = fit_model(h.select(list(np.flatnonzero(h.failed))), "linear")
    rate_all = m_all.mean[1] / m_all.time_scale
    rate_fail = m_fail.mean[1] / m_fail.time_scale
    assert rate_all == pytest.approx(true_mean_rate, rel=0.03)
    assert rate_fail > 1.1 * true_mean_rate  # selection bias of the failed-only fit
    assert m_all.noise_sd == pytest.approx(0.02, rel=0.1)


def test_paris_profile_likelihood_recovers_the_exponent():
    rng = np.random.default_rng(5)
    df, _ = synthetic_paris_fleet(rng, 60, m=3.0, noise_sd=0.005)
    m = fit_model(histories_from_frame(df), "paris")
    assert m.paris_exponent == pytest.approx(3.0, abs=0.5)
    assert m.describe().startswith("paris model")


def test_model_dict_round_trip_and_validation():
    m = _model(walk=0.2, kind="exponential", shape=-0.1)
    assert DegradationModel.from_dict(m.to_dict()) == m
    with pytest.raises(ValueError, match="kind"):
        _model(kind="quadratic")
    with pytest.raises(ValueError, match="covariance"):
        _model(cov=(0.01, 0.5, 0.01))


def test_filtered_states_count_acquisitions():
    h = _random_hist(np.random.default_rng(6))
    st = filtered_states(_model(), h)
    np.testing.assert_array_equal(st.n[h.start[:-1]], 1)


@pytest.mark.parametrize("kind,shape", [("linear", 0.0), ("paris", -0.5), ("exponential", -0.1)])
def test_compiled_quantiles_equal_bisection(kind, shape):
    """The compiled search of eq. (5b) (Newton from eq. (6)'s root) against bisection on
    the CDF, over random states; where (5b)'s S rises a little between readings (its Gaussian
    Y*'s sd dips half way between them) and the two searches find different roots of a
    level, a few units at most, both are roots of the CDF."""
    rng = np.random.default_rng(7)
    m = _model(walk=0.2, kind=kind, shape=shape)
    b = 5000
    t1 = rng.uniform(1, 15, b)
    hi1 = rng.uniform(0.0, 1.0, b)
    st = update_state(UnitState.empty(m, b), m, t1, hi1)
    st = update_state(st, m, t1 + rng.uniform(0.1, 30, b),
                      np.clip(hi1 + rng.uniform(-0.1, 0.3, b), 0, 1.2))
    levels = (0.5, 0.05, 0.95, 0.999)
    fast = m.rul_quantiles(st, levels)
    ref = m.rul_quantiles(st, levels, method="bisect")
    for lev, x, y in zip(levels, fast, ref, strict=True):
        np.testing.assert_array_equal(np.isinf(x), np.isinf(y))
        fin = np.isfinite(y)
        other = fin & ~np.isclose(x, y, rtol=1e-9, atol=1e-12)
        assert other.sum() <= 3
        np.testing.assert_allclose(x[fin & ~other], y[fin & ~other], rtol=1e-9, atol=1e-12)
        idx = np.flatnonzero(other)
        f = m.rul_cdf(st.take(idx), np.column_stack([x[idx], y[idx]]))
        np.testing.assert_allclose(f, lev, atol=1e-9)


def test_quantiles_nondecreasing_in_level_for_a_nearly_exact_line():
    # a spread of 1e-8 around the crossing: eq. (6)'s near-double root carries ~1e-8
    # relative roundoff, more than the distance between the median and its 5 % / 95 %
    rng = np.random.default_rng(0)
    sd = 1e-8
    model = DegradationModel("linear", 0.0, (0.2, 0.5), (sd**2, 0.0, sd**2), sd, 0.0, 10.0)
    st = UnitState.empty(model, 2000)
    st.m[:] = np.column_stack([rng.uniform(0.1, 0.9, 2000), rng.uniform(0.01, 1.0, 2000)])
    st.p[:] = (sd**2, 0.0, sd**2)
    st.t[:], st.hi[:], st.n[:] = rng.uniform(0.0, 10.0, 2000), st.m[:, 0], 5  # hi: the level
    levels = (0.5, 0.05, 0.95, 0.25)
    med, lo, hi, q25 = model.rul_quantiles(st, levels)
    assert np.all((lo <= q25) & (q25 <= med) & (med <= hi))
    # the same numbers up to that roundoff: against the line's own crossing time
    np.testing.assert_allclose(med, (1.0 - st.m[:, 0]) / st.m[:, 1] * 10.0, rtol=1e-6)
