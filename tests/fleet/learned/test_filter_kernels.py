"""The iterated-EKF likelihood of HI-scale noise (docs/fleet-models.md eq. (7)-(9)) against
independent oracles: the joint Gaussian density where the measurement is linear, a brute-force
2-D quadrature of the exact likelihood where it is not, and the onset mixture computed by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats
from scipy.special import logsumexp

from rulkit.fleet.learned.filter_kernels import negative_log_likelihood, replay, step_units
from rulkit.fleet.learned.growth_filter import GrowthParams, boxcox, onset_prior


def _params(r_log=0.0, r_hi=0.02**2, q=0.0, mean=(-0.8, 0.6), cov=(0.01, 0.001, 0.02),
            onset=(0.5, 0.3)):
    return GrowthParams(mean=mean, cov=cov, r_log=r_log, r_hi=r_hi, q=q, onset_mean=onset[0],
                        onset_sd=onset[1])


def _units(rng, n_units=4):
    xs, ys, start = [], [], [0]
    for _ in range(n_units):
        x = np.sort(rng.uniform(0.05, 1.2, rng.integers(2, 8)))
        xs.append(x)
        ys.append(np.clip(0.2 + 0.6 * x + 0.02 * rng.standard_normal(x.size), 0.01, None))
        start.append(start[-1] + x.size)
    return np.concatenate(xs), np.concatenate(ys), np.array(start, dtype=np.int64)


@pytest.mark.parametrize(("r_hi", "q"), [(4e-4, 0.0), (4e-4, 0.05), (1e-3, 0.02)])
def test_linear_law_equals_the_joint_gaussian_density(r_hi, q):
    """lam = 1 (linear growth) with additive noise: hi = 1 + z is linear in the state, so the
    filter is exact: hi ~ N(1 + X mu, X S X' + q min(x_i, x_j) + r_hi I) per unit (scipy
    oracle)."""
    p = _params(r_log=0.0, r_hi=r_hi, q=q)
    x, y, start = _units(np.random.default_rng(0))
    nll = negative_log_likelihood(p.theta(), x, y, start, 1.0, np.zeros(1))
    s0 = np.array([[p.cov[0], p.cov[1]], [p.cov[1], p.cov[2]]])
    ref = 0.0
    for u in range(start.size - 1):
        xu = x[start[u]:start[u + 1]]
        X = np.column_stack([np.ones_like(xu), xu])
        c = X @ s0 @ X.T + q * np.minimum.outer(xu, xu) + r_hi * np.eye(xu.size)
        ref -= stats.multivariate_normal(1.0 + X @ np.array(p.mean), c).logpdf(
            y[start[u]:start[u + 1]])
    assert nll == pytest.approx(ref, rel=1e-9)


def _brute(p, x, y, lam, additive):
    """-log of the exact likelihood of one unit without random walk: a 2-D quadrature over
    the unit's (level, rate) of the product of the exact measurement densities."""
    sa, sb = math.sqrt(p.cov[0]), math.sqrt(p.cov[2])
    a = np.linspace(p.mean[0] - 8 * sa, p.mean[0] + 8 * sa, 801)
    b = np.linspace(p.mean[1] - 8 * sb, p.mean[1] + 8 * sb, 801)
    aa, bb = np.meshgrid(a, b, indexing="ij")
    c = np.array([[p.cov[0], p.cov[1]], [p.cov[1], p.cov[2]]])
    lp = stats.multivariate_normal(p.mean, c).logpdf(np.stack([aa, bb], -1))
    for xk, yk in zip(x, y, strict=True):
        z = aa + bb * xk
        if additive:  # hi = g^-1(z) + e
            with np.errstate(over="ignore"):
                h = np.exp(z) if lam == 0 else np.maximum(1 + lam * z, 1e-300) ** (1 / lam)
            lp += stats.norm.logpdf(yk, h, math.sqrt(p.r_hi))
        else:  # hi = g^-1(z) exp(e): log-normal
            with np.errstate(divide="ignore", invalid="ignore"):
                lh = z if lam == 0 else np.log(np.maximum(1 + lam * z, 1e-300)) / lam
            lp += stats.norm.logpdf(math.log(yk), lh, math.sqrt(p.r_log)) - math.log(yk)
    mx = lp.max()
    return -(mx + math.log(np.exp(lp - mx).sum() * (a[1] - a[0]) * (b[1] - b[0])))


@pytest.mark.parametrize("lam", [0.0, -0.5])
@pytest.mark.parametrize("additive", [True, False])
def test_nonlinear_law_close_to_the_exact_likelihood(lam, additive):
    """The linearisation's likelihood of 8 acquisitions is within 0.15 nats of the exact one
    (a brute-force quadrature) on a unit growing from hi = 0.2 to 0.9, for additive and for
    multiplicative (log-normal) noise."""
    rng = np.random.default_rng(1)
    z0, z1 = boxcox(np.array([0.2, 0.9]), lam)
    x = np.sort(rng.uniform(0.05, 1.0, 8))
    zt = z0 + (z1 - z0) * x
    cov = (0.01 * abs(z0) + 1e-3, 0.0, 0.02 * (z1 - z0) ** 2)
    if additive:
        p = _params(r_log=0.0, r_hi=0.02**2, mean=(z0, z1 - z0), cov=cov)
        h = np.exp(zt) if lam == 0 else (1 + lam * zt) ** (1 / lam)
        y = h + 0.02 * rng.standard_normal(x.size)
    else:
        p = _params(r_log=0.05**2, r_hi=0.0, mean=(z0, z1 - z0), cov=cov)
        h = np.exp(zt) if lam == 0 else (1 + lam * zt) ** (1 / lam)
        y = h * np.exp(0.05 * rng.standard_normal(x.size))
    nll = negative_log_likelihood(p.theta(), x, y, np.array([0, x.size]), lam, np.zeros(1))
    assert nll == pytest.approx(_brute(p, x, y, lam, additive), abs=0.15)


def test_onset_mixture_is_the_mixture_of_shifted_filters():
    """eq. (9): -log sum_k pi_k L_k with L_k the no-onset filter run on the effective ages
    max(x - s_k, 0) (computed here one onset value at a time, grid values past a unit's last
    age included), and at lam = 1 each L_k is the joint Gaussian density (scipy)."""
    p = _params(r_log=0.0, q=0.03)
    x, y, start = _units(np.random.default_rng(2))
    grid = np.linspace(0.0, 1.5, 7)
    logpi = onset_prior(grid, p.onset_mean, p.onset_sd)
    s0 = np.array([[p.cov[0], p.cov[1]], [p.cov[1], p.cov[2]]])
    for lam in (1.0, 0.5):
        nll = negative_log_likelihood(p.theta(), x, y, start, lam, grid)
        ref = 0.0
        for u in range(start.size - 1):
            sl = slice(start[u], start[u + 1])
            ll = []
            for k, s in enumerate(grid):
                xe = np.maximum(x[sl] - s, 0.0)
                if lam == 1.0:  # exact: hi = 1 + a + b xe + walk(xe) + noise
                    X = np.column_stack([np.ones_like(xe), xe])
                    c = X @ s0 @ X.T + p.q * np.minimum.outer(xe, xe) + p.r_hi * np.eye(
                        xe.size)
                    lk = stats.multivariate_normal(1.0 + X @ np.array(p.mean), c).logpdf(y[sl])
                else:
                    lk = -negative_log_likelihood(p.theta(), xe, y[sl],
                                                  np.array([0, xe.size]), lam, np.zeros(1))
                ll.append(logpi[k] + lk)
            ref -= logsumexp(ll)
        assert nll == pytest.approx(ref, rel=1e-9)


def test_online_steps_equal_the_replay():
    """step_units (one acquisition per unit per call) = replay (compiled, per row)."""
    p = _params(r_log=1e-3, q=0.03)
    x, y, start = _units(np.random.default_rng(3), 5)
    grid = np.linspace(0.0, 1.0, 5)
    m_ref, p_ref, lw_ref = replay(p.theta(), x, y, start, -0.5, grid)
    b = start.size - 1
    m = np.tile(np.array(p.mean), (b, grid.size, 1))
    pp = np.tile(np.array(p.cov), (b, grid.size, 1))
    lw = np.tile(onset_prior(grid, p.onset_mean, p.onset_sd), (b, 1))
    prev = np.zeros(b)
    for k in range(int(np.diff(start).max())):
        xs, ys = np.full(b, np.nan), np.full(b, np.nan)
        for u in range(b):
            if start[u] + k < start[u + 1]:
                xs[u], ys[u] = x[start[u] + k], y[start[u] + k]
        step_units(m, pp, lw, prev, xs, ys, -0.5, p, grid)
        prev = np.where(np.isfinite(xs), xs, prev)
    last = start[1:] - 1
    np.testing.assert_allclose(m, m_ref[last], rtol=1e-12)
    np.testing.assert_allclose(pp, p_ref[last], rtol=1e-12)
    np.testing.assert_allclose(lw, lw_ref[last], rtol=1e-12, atol=1e-12)


def test_parameter_vector_round_trip():
    p = _params(r_log=0.0, r_hi=1e-4, q=2e-3)
    th = p.theta()
    assert th[5] == -np.inf  # a zero variance is a fixed -inf
    back = GrowthParams.from_theta(th)
    assert back.r_log == 0.0
    np.testing.assert_allclose(back.cov, p.cov, rtol=1e-12)
    assert back.mean == p.mean and back.q == pytest.approx(p.q)
