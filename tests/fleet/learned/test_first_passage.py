"""The first measured crossing over the cadence (eq. (5a)-(5b)) against brute force."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from rulkit.fleet.learned.degradation import UnitState, rul_quantiles
from rulkit.fleet.learned.first_passage import ystar_moments
from rulkit.fleet.learned.growth_filter import boxcox_inverse
from rulkit.fleet.learned.hi_noise import HiNoiseModel


@pytest.mark.parametrize("c,j", [(0.002, 30), (0.01, 400), (0.05, 5), (0.3, 30), (1.0, 2),
                                 (3.0, 100)])
def test_earliest_reading_moments_against_draws(c, j):
    """mu*, sigma* of min_k (c k + eps_k), k < J, against 20000 draws (se about 0.004)."""
    rng = np.random.default_rng(0)
    y = np.full(20_000, np.inf)
    for k in range(j):  # a running minimum: no (draws, J) array
        y = np.minimum(y, c * k + rng.standard_normal(y.size))
    mu, sd = ystar_moments(np.array([c]), np.array([float(j)]))
    assert mu[0] == pytest.approx(y.mean(), abs=0.015)
    assert sd[0] == pytest.approx(y.std(), abs=0.015)


def _first_crossing(model: HiNoiseModel, st: UnitState, n: int, seed: int) -> np.ndarray:
    """Brute force: draws of (level, rate) from the state, the walk and readings on the HI
    scale (``g^-1(z) exp(e1) + e2``) every t/n after the last acquisition; the RUL is the first
    reading >= 1, its time interpolated from the reading before (as the truth of ``rulkit
    evaluate``)."""
    rng = np.random.default_rng(seed)
    tau, d = model.time_scale, st.t[0] / st.n[0] / model.time_scale
    cov = np.array([[st.p[0, 0], st.p[0, 1]], [st.p[0, 1], st.p[0, 2]]])
    x = st.m[0] + rng.standard_normal((n, 2)) @ np.linalg.cholesky(cov).T
    z, b = x[:, 0].copy(), x[:, 1]
    prev, out = np.full(n, st.hi[0]), np.full(n, np.inf)
    j = 0
    while np.isinf(out).any() and j < 2000:
        j += 1
        z += b * d + model.walk_sd * math.sqrt(d) * rng.standard_normal(n)
        h = (boxcox_inverse(z, model.shape) * np.exp(model.log_noise_sd * rng.standard_normal(n))
             + model.hi_noise_sd * rng.standard_normal(n))
        hit = np.isinf(out) & (h >= 1.0)
        frac = np.clip((1.0 - prev) / (h - prev), 0.0, 1.0)
        out[hit] = (j - 1 + frac[hit]) * d * tau
        prev = h
    return out


CASES = [  # noise (additive, log), walk; state (level, rate var, age, acquisitions)
    ((0.02, 0.0), 0.0, (-0.5, 0.02, 150.0, 50)),
    ((0.01, 0.04), 0.0, (-0.15, 0.005, 270.0, 200)),
    ((0.01, 0.04), 0.05, (-0.2, 0.01, 250.0, 80)),
    ((0.0, 0.04), 0.0, (-0.5, 0.2, 150.0, 50)),
]


@pytest.mark.parametrize("noise,walk,state", CASES)
def test_first_crossing_against_brute_force(noise, walk, state):
    """At the brute force's 5 %, 50 % and 95 % quantiles the model's CDF is within 0.03 of
    the level (sampling error about 0.003; the rest is eq. (5b)'s approximations), and
    closer than one measurement's eq. (5) (the event before: no cadence, state n = 1) where
    readings are dense near the crossing."""
    kind = "mixed" if all(noise) else ("additive" if noise[0] else "multiplicative")
    model = HiNoiseModel(noise=kind, shape=0.0, mean=(-2.3, 2.0), cov=(1e-3, 0.0, 0.05),
                         hi_noise_sd=noise[0], log_noise_sd=noise[1], walk_sd=walk,
                         time_scale=300.0)
    mz, pbb, t, n = state
    st = UnitState(m=np.array([[mz, 2.0]]), p=np.array([[4e-4, 0.0, pbb]]), t=np.array([t]),
                   hi=np.array([math.exp(mz)]), n=np.array([n]))
    levels = np.array([0.05, 0.5, 0.95])
    q = np.quantile(_first_crossing(model, st, 40_000, 1), levels)
    f = model.rul_cdf(st, q[None, :])[0]
    np.testing.assert_allclose(f, levels, atol=0.03)
    one = UnitState(m=st.m, p=st.p, t=st.t, hi=st.hi, n=np.array([1]))
    f_one = model.rul_cdf(one, q[None, :])[0]
    if n >= 200:
        assert np.abs(f - levels).max() < np.abs(f_one - levels).max()


def test_without_measurement_noise_it_is_eq_5():
    """s -> 0: a monotone path's first crossing is its marginal crossing: the quantiles equal
    eq. (5) of the latent level (a law without measurement noise), including a unit whose
    crossing comes before its next reading; the interpolation inside the first cadence step is
    exact for a straight line."""
    model = HiNoiseModel(noise="additive", shape=0.0, mean=(-2.3, 2.0), cov=(1e-3, 0.0, 0.05),
                         hi_noise_sd=1e-9, log_noise_sd=0.0, walk_sd=0.0, time_scale=300.0)
    latent = SimpleNamespace(walk_sd=0.0, threshold=0.0, time_scale=300.0)
    st = UnitState(m=np.array([[-0.5, 2.0], [-0.1, 1.0], [-0.004, 1.0]]),
                   p=np.array([[1e-4, 0.0, 0.02], [1e-6, 0.0, 1e-4], [1e-12, 0.0, 1e-8]]),
                   t=np.array([150.0, 200.0, 280.0]), hi=np.array([0.6, 0.9, 0.996]),
                   n=np.array([50, 100, 100]))
    levels = (0.5, 0.05, 0.95)
    for a, b in zip(model.rul_quantiles(st, levels), rul_quantiles(latent, st, levels),
                    strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-6)
    assert model.rul_quantiles(st, (0.5,))[0][2] < 2.8  # before the next reading (t / n)


def test_quantiles_invert_the_cdf_on_and_after_the_first_step():
    model = HiNoiseModel(noise="mixed", shape=0.0, mean=(-2.3, 2.0), cov=(1e-3, 0.0, 0.05),
                         hi_noise_sd=0.01, log_noise_sd=0.04, walk_sd=0.05, time_scale=300.0)
    st = UnitState(m=np.array([[-0.5, 2.0], [-0.02, 2.0], [-0.3, -1.0]]),
                   p=np.array([[4e-4, 0.0, 0.02], [4e-4, 1e-5, 0.01], [4e-4, 0.0, 0.01]]),
                   t=np.array([150.0, 280.0, 100.0]), hi=np.array([0.6, 0.98, 0.74]),
                   n=np.array([50, 100, 20]))
    med, lo, hi = model.rul_quantiles(st)
    assert lo[1] < 2.8  # the first reading (t / n = 2.8) is likely >= 1
    f = model.rul_cdf(st.take(np.arange(2)), np.column_stack([lo, med, hi])[:2])
    np.testing.assert_allclose(f, [[0.05, 0.5, 0.95]] * 2, atol=1e-6)
    assert np.isinf(med[2])  # the rate is almost surely negative: never fails
