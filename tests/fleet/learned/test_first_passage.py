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


@pytest.mark.parametrize("c,n,theta", [(0.002, 30, 0.5), (0.01, 400, 0.25), (0.05, 5, 0.0),
                                       (0.3, 30, 0.8), (1.0, 2, 0.5), (1.0, 1, 0.1),
                                       (3.0, 100, 0.3), (3.0, 1, 0.9), (19.0, 3, 0.02)])
def test_earliest_reading_moments_against_draws(c, n, theta):
    """mu*, sigma* of min((1 - theta) eps_0 + theta eps', min_k c (theta + k) + eps_k),
    k < n, against 20000 draws (se about 0.007); theta = 0 is a reading at the horizon and
    n - 1 before it."""
    rng = np.random.default_rng(0)
    e0 = rng.standard_normal(20_000)
    y = np.minimum((1.0 - theta) * e0 + theta * rng.standard_normal(e0.size), c * theta + e0)
    for k in range(1, n):  # a running minimum: no (draws, n) array
        y = np.minimum(y, c * (theta + k) + rng.standard_normal(y.size))
    mu, sd = ystar_moments(np.array([c]), np.array([float(n)]), np.array([theta]))
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
    """At the brute force's 5 %, 50 % and 95 % quantiles the model's CDF is within 0.015 of
    the level (sampling error 0.001 to 0.0025; 0.010 the largest seen, the rest eq. (5b)'s
    approximations), and
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
    np.testing.assert_allclose(f, levels, atol=0.015)
    one = UnitState(m=st.m, p=st.p, t=st.t, hi=st.hi, n=np.array([1]))
    f_one = model.rul_cdf(one, q[None, :])[0]
    if n >= 200:
        assert np.abs(f - levels).max() < np.abs(f_one - levels).max()


def test_first_step_closed_form_against_brute_force():
    """Before the next reading the crossing is interpolated between the last reading (known,
    here 0.97, below the posterior's level) and the next: one Gaussian, exact for a linear
    growth scale and additive noise. Its CDF inside the first step against 40000 brute-force
    paths (sampling sd at most 0.0025): within 0.01, and far from the CDF that starts from
    the posterior's level instead of the reading."""
    model = HiNoiseModel(noise="additive", shape=1.0, mean=(-0.5, 2.0), cov=(1e-3, 0.0, 0.05),
                         hi_noise_sd=0.02, log_noise_sd=0.0, walk_sd=0.0, time_scale=300.0)
    st = UnitState(m=np.array([[-0.02, 2.0]]), p=np.array([[1e-4, 0.0, 0.05]]),
                   t=np.array([280.0]), hi=np.array([0.97]), n=np.array([100]))
    d = 2.8
    truth = _first_crossing(model, st, 40_000, 2)
    r = d * np.array([[0.2, 0.4, 0.6, 0.8, 0.999]])
    f = model.rul_cdf(st, r)[0]
    emp = (truth[:, None] <= r).mean(axis=0)
    np.testing.assert_allclose(f, emp, atol=0.01)
    assert emp[-1] > 0.2  # the first step holds a good part of the mass
    level = UnitState(m=st.m, p=st.p, t=st.t, hi=np.array([0.98]), n=st.n)
    assert np.abs(model.rul_cdf(level, r)[0] - emp).max() > 0.03


def test_without_measurement_noise_it_is_eq_5():
    """s -> 0: a monotone path's first crossing is its marginal crossing: the quantiles equal
    eq. (5) of the latent level (a law without measurement noise) beyond the next reading;
    before it the crossing is the chord between the last reading and the next on the HI
    scale, whose median is the chord of the mean path."""
    model = HiNoiseModel(noise="additive", shape=0.0, mean=(-2.3, 2.0), cov=(1e-3, 0.0, 0.05),
                         hi_noise_sd=1e-9, log_noise_sd=0.0, walk_sd=0.0, time_scale=300.0)
    latent = SimpleNamespace(walk_sd=0.0, threshold=0.0, time_scale=300.0)
    st = UnitState(m=np.array([[-0.5, 2.0], [-0.1, 1.0], [-0.004, 1.0]]),
                   p=np.array([[1e-4, 0.0, 0.02], [1e-6, 0.0, 1e-4], [1e-18, 0.0, 1e-8]]),
                   t=np.array([150.0, 200.0, 280.0]), hi=np.exp([-0.5, -0.1, -0.004]),
                   n=np.array([50, 100, 100]))  # the last readings: the levels (s -> 0)
    levels = (0.5, 0.05, 0.95)
    for a, b in zip(model.rul_quantiles(st, levels), rul_quantiles(latent, st, levels),
                    strict=True):
        np.testing.assert_allclose(a[:2], b[:2], rtol=1e-6)
    d = 280.0 / 100.0 / 300.0
    h0, h1 = math.exp(-0.004), math.exp(-0.004 + 1.0 * d)
    med = model.rul_quantiles(st, (0.5,))[0][2]
    assert med == pytest.approx(300.0 * d * (1.0 - h0) / (h1 - h0), rel=1e-9)
    assert med < 2.8  # before the next reading (t / n)


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


def _mixed_states(rng: np.random.Generator, model: HiNoiseModel, size: int) -> UnitState:
    """Units filtered through 2 to 40 acquisitions of an exponential HI at cadences from
    dense to sparse (c = b d / s from about 0.05 to above the table's 20), then edge cases:
    at the threshold's doorstep (the first step), failed (hi >= 1), a negative rate (never
    fails), one acquisition (no cadence) and none."""
    st = model.empty_state(size)
    t = np.zeros(size)
    gap = np.exp(rng.uniform(np.log(2.0), np.log(400.0), size))
    n_acq = rng.integers(2, 41, size)
    rate = rng.uniform(0.5, 3.0, size)
    for j in range(40):
        go = np.flatnonzero(j < n_acq)
        t[go] += gap[go] * rng.uniform(0.5, 1.5, go.size)
        hi = np.clip(0.1 * np.exp(rate[go] * t[go] / model.time_scale)
                     * np.exp(0.04 * rng.standard_normal(go.size))
                     + 0.01 * rng.standard_normal(go.size), 0.01, 0.99)
        upd = model.update(st.take(go), t[go], hi)
        st.m[go], st.p[go], st.t[go], st.hi[go], st.n[go] = upd.m, upd.p, upd.t, upd.hi, upd.n
    edge = UnitState(m=np.array([[-0.01, 2.0], [0.05, 2.0], [-0.3, -1.0], [-0.5, 1.0],
                                 [-0.5, 1.0]]),
                     p=np.array([[1e-4, 0.0, 0.01]] * 5), t=np.array([300.0] * 5),
                     hi=np.array([0.99, 1.02, 0.74, 0.6, 0.6]), n=np.array([100, 100, 30, 1, 0]))
    return UnitState(m=np.concatenate([st.m, edge.m]), p=np.concatenate([st.p, edge.p]),
                     t=np.concatenate([st.t, edge.t]), hi=np.concatenate([st.hi, edge.hi]),
                     n=np.concatenate([st.n, edge.n]))


@pytest.mark.parametrize("noise", [(0.01, 0.04), (1e-7, 0.0), (0.05, 0.0)])
def test_compiled_quantiles_equal_the_bisection_of_the_cdf(noise):
    """The compiled search against the numpy bisection of :func:`rul_cdf` (eq. (5b)) to 1e-9
    relative, over random units and the edge cases of :func:`_mixed_states` (tiny s, c beyond
    the table, the first step, failed, never failing, one acquisition, none), at levels from
    0.1 % to 99.9 %. (5b)'s S may rise by a little between readings (its Gaussian Y*'s sd dips
    half way between them, by up to 1e-5 in the body on a known path, more in the far tail):
    where the two searches find different roots, both must be roots of the CDF."""
    kind = "mixed" if all(noise) else "additive"
    model = HiNoiseModel(noise=kind, shape=0.0, mean=(-2.3, 1.5), cov=(0.01, 0.0, 0.2),
                         hi_noise_sd=noise[0], log_noise_sd=noise[1], walk_sd=0.05,
                         time_scale=1000.0)
    st = _mixed_states(np.random.default_rng(3), model, 120)
    levels = (0.5, 0.001, 0.05, 0.95, 0.999)
    fast = model.rul_quantiles(st, levels)
    ref = rul_quantiles(model, st, levels, method="bisect", iterations=80)
    for lev, x, y in zip(levels, fast, ref, strict=True):
        np.testing.assert_array_equal(np.isnan(x), np.isnan(y))
        np.testing.assert_array_equal(np.isinf(x), np.isinf(y))
        fin = np.isfinite(y)
        other = fin & ~np.isclose(x, y, rtol=1e-9, atol=1e-12)
        assert other.sum() <= 2
        np.testing.assert_allclose(x[fin & ~other], y[fin & ~other], rtol=1e-9, atol=1e-12)
        for b in np.flatnonzero(other):
            f = model.rul_cdf(st.take(np.array([b])), np.array([[x[b], y[b]]]))
            np.testing.assert_allclose(f, lev, atol=1e-9)
    med, low = fast[0], fast[2]
    assert low[-5] < st.t[-5] / st.n[-5]  # at the doorstep: inside the first step
    assert med[-4] == 0.0 and np.isinf(med[-3]) and np.isnan(med[-1])


def test_latent_quantiles_against_brent_on_eq_5():
    """s = 0 (no measurement noise): the compiled search against scipy's brentq on eq. (5)'s
    log S(w) - log S(0) - log(1 - p) unit by unit (an independent root finder and log_ndtr),
    from 1e-6 (below, the level itself is lost in S(0)'s rounding) to 1 - 1e-9 (the tails of
    the search's k = -Phi^-1(S))."""
    from scipy.optimize import brentq
    from scipy.special import log_ndtr

    rng = np.random.default_rng(4)
    n = 40
    latent = SimpleNamespace(walk_sd=0.2, threshold=0.0, time_scale=1.0)
    m = np.column_stack([rng.uniform(-3.0, -0.05, n), rng.uniform(0.2, 3.0, n)])
    p = np.column_stack([rng.uniform(1e-4, 0.1, n), rng.uniform(-1e-3, 1e-3, n),
                         rng.uniform(1e-3, 0.05, n)])
    st = UnitState(m=m, p=p, t=np.full(n, 10.0), hi=np.full(n, 0.5), n=np.full(n, 5))
    levels = (1e-6, 0.05, 0.5, 0.95, 1.0 - 1e-9)
    got = rul_quantiles(latent, st, levels)

    def log_s(w: float, b: int) -> float:
        v = p[b, 0] + 2.0 * w * p[b, 1] + w * w * p[b, 2] + 0.04 * w
        return float(log_ndtr(-(m[b, 0] + m[b, 1] * w) / math.sqrt(v)))

    for b in range(n):
        for lev, q in zip(levels, got, strict=True):
            target = log_s(0.0, b) + math.log1p(-lev)
            if target <= float(log_ndtr(-m[b, 1] / math.sqrt(p[b, 2]))):
                assert np.isinf(q[b])
                continue
            hi = 1.0
            while log_s(hi, b) > target:
                hi *= 2.0
            ref = brentq(lambda w, b=b, t=target: log_s(w, b) - t, 0.0, hi, xtol=1e-15,
                         rtol=1e-14)
            assert q[b] == pytest.approx(ref, rel=1e-9, abs=1e-13)


def test_kernel_quantiles_nondecreasing_in_level():
    """The kernel's own roots (before :func:`monotone_in_level`) rise with the level, on and
    after the first step, for random units of a mixed-noise model at 41 levels."""
    from rulkit.fleet.learned.degradation import _event, growth_scale_of
    from rulkit.fleet.learned.filter_kernels import first_passage_quantiles
    from rulkit.fleet.learned.first_passage import kernel_table

    model = HiNoiseModel(noise="mixed", shape=0.0, mean=(-2.3, 1.5), cov=(0.01, 0.0, 0.2),
                         hi_noise_sd=0.01, log_noise_sd=0.04, walk_sd=0.05, time_scale=1000.0)
    st = _mixed_states(np.random.default_rng(5), model, 200)
    s, delta = _event(model, st)
    levels = np.linspace(0.001, 0.999, 41)
    w = np.empty((levels.size, len(st)))
    first_passage_quantiles(st.m, st.p, st.hi, growth_scale_of(model), delta,
                            model.walk_sd**2, model.threshold, s, levels, *kernel_table(), 200,
                            w)
    ok = st.n > 0
    assert np.all(w[1:, ok] >= w[:-1, ok])  # inf >= inf: the never-failing levels
    assert (w[:, ok] < delta[ok]).any() and np.isfinite(w[:, ok]).any()


def test_a_level_does_not_depend_on_the_levels_asked_with_it():
    """Same state, same level, same bits: each level's search starts from its own eq. (6)."""
    model = HiNoiseModel(noise="mixed", shape=0.0, mean=(-2.3, 1.5), cov=(0.01, 0.0, 0.2),
                         hi_noise_sd=0.01, log_noise_sd=0.04, walk_sd=0.05, time_scale=1000.0)
    st = _mixed_states(np.random.default_rng(6), model, 100)
    med, low, high = model.rul_quantiles(st)
    for lev, q in ((0.05, low), (0.95, high), (0.5, med)):
        np.testing.assert_array_equal(model.rul_quantiles(st, (lev,))[0], q)
