"""The default RUL estimator (rulkit.fleet.monitoring.unit_trend) against independent oracles:
the posterior against weighted least squares by numpy's lstsq, the quantiles against a
brute-force search of scipy's Student-t CDF, the closed-form t CDF and quantiles against
scipy, the interval's coverage on fleets drawn from the model, the band against the
interval, and the three ways of running it against one update per row."""

import numpy as np
import pytest
from scipy import stats

from rulkit.fleet.monitoring.unit_trend import (
    NU_BLOCK,
    NU_TABLE,
    TrendConfig,
    TrendPosterior,
    TrendState,
    first_crossing,
    hi_quantiles,
    rul_quantiles,
    t_cdf,
    t_quantile,
    t_quantiles,
    trend_posterior,
    trend_run,
    trend_update,
)


def fleet(rng, b, k, sd=0.01):
    """b units, k irregular acquisitions each: HI = exp(a + b t) + additive noise."""
    counts = rng.integers(1, k + 1, b)
    seg = np.concatenate([[0], np.cumsum(counts)])
    t, hi = [], []
    for n in counts:
        tt = np.cumsum(rng.uniform(0.5, 2.0, n)) + rng.uniform(0, 1e3)
        rate = rng.uniform(0.005, 0.05)
        a0 = np.log(rng.uniform(0.1, 0.5)) - rate * tt[0]
        t.append(tt)
        hi.append(np.clip(np.exp(a0 + rate * tt) + rng.normal(0, sd, n), 0.0, 3.0))
    return seg, np.concatenate(t), np.concatenate(hi)


def equal_lengths(seg, t, hi, k):
    """The first ``k`` rows of every unit that has them (every unit at every rank: the ranks'
    direct path)."""
    keep = np.diff(seg) >= k
    idx = (seg[:-1][keep][:, None] + np.arange(k)).ravel()
    return np.arange(0, int(keep.sum()) * k + 1, k), t[idx], hi[idx]


@pytest.mark.parametrize("equal", [False, True])
@pytest.mark.parametrize("strategy", ["python", "jit", "ranks", None])
def test_run_equals_one_update_per_row(strategy, equal):
    rng = np.random.default_rng(0)
    cfg = TrendConfig(forgetting=0.9)
    seg, t, hi = fleet(rng, 30, 25)
    if equal:
        seg, t, hi = equal_lengths(seg, t, hi, 16)
        assert seg.size > 10
    b = seg.size - 1
    cut = seg[:-1] + np.diff(seg) // 2
    ref = TrendState.empty(b)
    rows_ref = []
    for part in range(2):  # from fresh, then from the stored state
        lo, hi_end = (seg[:-1], cut) if part == 0 else (cut, seg[1:])
        counts = hi_end - lo
        for r in range(int(counts.max(initial=0))):
            have = counts > r
            tt, hh = np.full(b, np.nan), np.full(b, np.nan)
            tt[have], hh[have] = t[lo[have] + r], hi[lo[have] + r]
            ref = trend_update(ref, tt, hh, cfg)
            rows_ref += [(int(lo[u] + r), ref.s[u].copy()) for u in np.flatnonzero(have)]
    state = TrendState.empty(b)
    got = np.empty((t.size, 7))
    for part in range(2):
        lo, hi_end = (seg[:-1], cut) if part == 0 else (cut, seg[1:])
        idx = np.concatenate([np.arange(a, e) for a, e in zip(lo, hi_end, strict=True)])
        sub_seg = np.concatenate([[0], np.cumsum(hi_end - lo)])
        state, rows = trend_run(state, sub_seg, t[idx], hi[idx], cfg, strategy=strategy)
        got[idx] = rows.s
    for i, s in rows_ref:
        np.testing.assert_array_equal(got[i], s)
    np.testing.assert_array_equal(state.s, ref.s)
    np.testing.assert_array_equal(state.n, ref.n)
    np.testing.assert_array_equal(state.t, ref.t)


def test_ranks_of_equal_length_from_a_mixed_state_equal_one_update_per_row():
    """The ranks' direct path (every unit at every rank) from a state where some units have
    sums and others none, and with a NaN row (each unit's rows then run as the general
    path): the sums after every row those of trend_update, bit for bit."""
    rng = np.random.default_rng(3)
    cfg = TrendConfig(forgetting=0.93)
    b, k = 12, 9
    start = TrendState.empty(b)
    old = rng.random(b) < 0.5  # these units have 4 earlier acquisitions
    for r in range(4):
        start = trend_update(start, np.where(old, r - 10.0, np.nan),
                             np.where(old, rng.uniform(0.1, 0.5, b), np.nan), cfg)
    t = (np.arange(k) + rng.uniform(0.0, 0.5, (b, k))).ravel()
    hi = rng.uniform(0.05, 0.6, b * k)
    seg = np.arange(0, b * k + 1, k)
    for bad in (False, True):
        h = hi.copy()
        if bad:
            h[5] = np.nan  # unit 0's sixth row: trend_update keeps its state there
        ref = start
        want = np.empty((b * k, 7))
        for r in range(k):
            ref = trend_update(ref, t[r::k], h[r::k], cfg)
            want[r::k] = ref.s
        state, rows = trend_run(start, seg, t, h, cfg, strategy="ranks")
        np.testing.assert_array_equal(rows.s, want)
        np.testing.assert_array_equal(state.s, ref.s)


@pytest.mark.parametrize("forgetting", [1.0, 0.8])
def test_posterior_is_weighted_least_squares(forgetting):
    """a, b, their covariance and the degrees of freedom of (EI-17), computed from the raw
    rows with numpy's lstsq (weights forgetting^age hi^2, x = t - t_last)."""
    rng = np.random.default_rng(1)
    cfg = TrendConfig(forgetting=forgetting, min_points=3)
    t = np.cumsum(rng.uniform(0.5, 2.0, 12)) + 1e6  # epoch-like offsets: no cancellation
    hi = np.exp(-1.5 + 0.03 * (t - t[0])) * np.exp(rng.normal(0, 0.05, t.size))
    state, _ = trend_run(TrendState.empty(1), np.array([0, t.size]), t, hi, cfg)
    post = trend_posterior(state, cfg)
    w = forgetting ** np.arange(t.size)[::-1] * hi**2
    x = np.column_stack([np.ones(t.size), t - t[-1]])
    sw = np.sqrt(w)
    coef, res, *_ = np.linalg.lstsq(x * sw[:, None], np.log(hi) * sw, rcond=None)
    n_eff = (forgetting ** np.arange(t.size)).sum()
    cov = res[0] / (n_eff - 2.0) * np.linalg.inv(x.T @ (w[:, None] * x))
    assert post.a[0] == pytest.approx(coef[0], rel=1e-9)
    assert post.b[0] == pytest.approx(coef[1], rel=1e-9)
    np.testing.assert_allclose([post.vaa[0], post.vab[0], post.vbb[0]],
                               [cov[0, 0], cov[0, 1], cov[1, 1]], rtol=1e-7)
    assert post.nu[0] == np.floor(n_eff - 2.0)


def test_posterior_keeps_the_bits_of_its_formulas():
    """trend_posterior against (EI-17) written plainly, element by element, on states with
    few points, one time only (a degenerate design), a perfect fit and zeros: the same
    bits."""
    rng = np.random.default_rng(7)
    cfg = TrendConfig(forgetting=0.9, min_points=4)
    b, k = 64, 9
    t = np.cumsum(rng.uniform(0.1, 2.0, (b, k)), axis=1)
    t[:4] = 5.0 + np.arange(k) * 1e-300  # no spread in time
    hi = np.clip(0.2 * np.exp(0.05 * t) + rng.normal(0, 0.01, (b, k)), 0.0, 2.0)
    hi[4:8] = 0.2 * np.exp(0.05 * t[4:8])  # a perfect fit but for the rounding
    hi[8:10] = 0.0
    counts = rng.integers(0, k + 1, b)
    idx = np.concatenate([np.arange(c) + u * k for u, c in enumerate(counts)])
    seg = np.concatenate([[0], np.cumsum(counts)])
    state, _ = trend_run(TrendState.empty(b), seg, t.ravel()[idx], hi.ravel()[idx], cfg)
    got = trend_posterior(state, cfg)
    with np.errstate(invalid="ignore", divide="ignore"):
        n_, s0, s1, s2, sz, sxz, szz = state.s.T
        det = s0 * s2 - s1 * s1
        ok = (state.n >= cfg.min_points) & (det > 1e-12 * s0 * s2) & (n_ > 3.0)
        bb = (s0 * sxz - s1 * sz) / det
        a = (sz - bb * s1) / s0
        sig2 = np.maximum(np.maximum(szz - a * sz - bb * sxz, 0.0) / (n_ - 2.0),
                          1e-24 * np.maximum(szz / s0, 1e-300))
        want = (a, bb, sig2 * s2 / det, -sig2 * s1 / det, sig2 * s0 / det, np.floor(n_ - 2.0))
    assert ok.any() and not ok.all()
    for name, g, w in zip(("a", "b", "vaa", "vab", "vbb", "nu"), got.__dict__.values(), want,
                          strict=True):
        assert g.tobytes() == np.where(ok, w, np.nan).tobytes(), name


def test_no_estimate_before_min_points():
    cfg = TrendConfig(min_points=5)
    t = np.arange(6.0)
    state = TrendState.empty(1)
    for k in range(6):
        state = trend_update(state, t[k:k + 1], np.array([0.2 + 0.01 * k]), cfg)
        med = rul_quantiles(trend_posterior(state, cfg))[0]
        assert np.isnan(med[0]) == (k < 4)


def brute_quantile(post, p, grid):
    """The smallest r with P(a + b r >= 0) = T_nu(h(r)) >= p (scipy's t CDF): the first grid
    point past it, then bisection between the grid points around it."""
    out = []
    for i in range(post.a.size):
        def cdf(r, i=i):
            sd = np.sqrt(post.vaa[i] + 2 * r * post.vab[i] + r**2 * post.vbb[i])
            return stats.t.cdf((post.a[i] + post.b[i] * r) / sd, post.nu[i])

        hit = np.flatnonzero(cdf(grid) >= p)
        if hit.size == 0 or hit[0] == 0:
            out.append(np.inf if hit.size == 0 else 0.0)
            continue
        lo, hi = grid[hit[0] - 1], grid[hit[0]]
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if cdf(mid) >= p else (mid, hi)
        out.append(hi)
    return np.array(out)


def random_posteriors(rng, n):
    a = -rng.uniform(0.01, 3.0, n)
    b = rng.normal(0.02, 0.03, n)
    sa, sb = rng.uniform(0.01, 0.5, n), rng.uniform(1e-4, 0.02, n)
    rho = rng.uniform(-0.9, 0.9, n)
    return TrendPosterior(a=a, b=b, vaa=sa**2, vab=rho * sa * sb, vbb=sb**2,
                          nu=rng.integers(1, 60, n).astype(float))


def test_quantiles_against_a_brute_force_search():
    rng = np.random.default_rng(2)
    post = random_posteriors(rng, 60)
    grid = np.linspace(0.0, 2000.0, 4001)
    for p in (0.05, 0.5, 0.95):
        got = rul_quantiles(post, (p,))[0]
        ref = brute_quantile(post, p, grid)
        inf = np.isinf(ref)
        # a crossing past the grid's end counts as none on the grid
        assert np.all(np.isinf(got[inf]) | (got[inf] > 2000.0)), p
        np.testing.assert_allclose(got[~inf], ref[~inf], rtol=1e-8, atol=1e-9, err_msg=str(p))
    med, low, high = rul_quantiles(post, (0.5, 0.05, 0.95))
    assert np.all(low >= 0) and np.all(low <= med) and np.all(med <= high)


def test_levels_at_once_equal_one_level_at_a_time():
    """The batch's quantiles of every level in one broadcast pass have the bits of one
    t-quantile lookup and one crossing per level (NaN degrees of freedom included)."""
    rng = np.random.default_rng(5)
    post = random_posteriors(rng, 80)
    nu = post.nu.copy()
    nu[::7] = np.nan
    post = TrendPosterior(post.a, post.b, post.vaa, post.vab, post.vbb, nu)
    levels = (0.5, 0.05, 0.95, 0.2)
    table = t_quantiles(nu, levels)
    got = rul_quantiles(post, levels)
    for j, p in enumerate(levels):
        c = t_quantile(nu, p)
        assert table[j].tobytes() == c.tobytes(), p
        one = first_crossing(post.a, post.b, post.vaa, 2.0 * post.vab, post.vbb, c)
        assert got[j].tobytes() == one.tobytes(), p


def test_quantile_blocks_hold_each_degree_of_freedoms_own_bits(monkeypatch):
    """A degree of freedom asked for brings its block of NU_BLOCK into the table, and every
    entry has the bits of a bisection of that degree of freedom alone, whichever were asked
    first."""
    from rulkit.fleet.monitoring import unit_trend

    monkeypatch.setattr(unit_trend, "_T_QUANTILES", {})
    got = t_quantiles(np.array([3.0, 150.0, 1e6]), (0.05, 0.5))
    blocks = [*range(1, NU_BLOCK + 1), *range(145, 161), NU_TABLE + 1]
    assert set(unit_trend._T_QUANTILES) == {(k, p) for k in blocks for p in (0.05, 0.5)}
    nus = np.array([1.0, 2.0, 3.0, 16.0, 17.0, 150.0, 199.0, 200.0])
    for p in (0.05, 0.5, 0.95):
        alone = np.array([unit_trend._t_quantiles(np.array([k]), np.array([p]))[0]
                          for k in nus])
        assert t_quantile(nus, p).tobytes() == alone.tobytes(), p
    assert got.tobytes() == t_quantiles(np.array([3.0, 150.0, 1e6]), (0.05, 0.5)).tobytes()


def test_first_crossing_cases():
    # a line without spread: the time the line reaches c * 0 = 0, for every c
    assert first_crossing(-1.0, 0.5, 0.0, 0.0, 0.0, 0.0) == pytest.approx(2.0)
    assert first_crossing(-1.0, -0.5, 1e-4, 0.0, 1e-6, 1.0) == np.inf  # moving away
    assert first_crossing(0.5, 0.1, 1e-2, 0.0, 1e-4, 1.645) == 0.0  # already there
    assert np.isnan(first_crossing(np.nan, 0.1, 1.0, 0.0, 1.0, 1.0))
    # the margin (a + b r) / sd(r) rises to b / sqrt(v2) = 2 only: a level above is never met
    assert first_crossing(-1.0, 0.2, 0.01, 0.0, 0.01, 2.5) == np.inf
    r = first_crossing(-1.0, 0.2, 0.01, 0.0, 0.01, 1.5)
    assert (-1.0 + 0.2 * r) / np.sqrt(0.01 + 0.01 * r * r) == pytest.approx(1.5)


def _first_crossing_before(a, b, v0, v1, v2, c):
    """first_crossing as it was before its line terms were computed once per unit: every
    term at the full (levels, units) shape (the reference for its bits)."""
    a, b, v0, v1, v2, c = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64)
                                                for x in (a, b, v0, v1, v2, c)))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        at0 = a >= c * np.sqrt(v0)
        c2 = c * c
        q2 = b * b - c2 * v2
        q1 = 2.0 * a * b - c2 * v1
        q0 = a * a - c2 * v0
        disc = q1 * q1 - 4.0 * q2 * q0
        real = disc >= -(1e-12 * (q1 * q1 + np.abs(4.0 * q2 * q0)))
        qq = -0.5 * (q1 + np.copysign(np.sqrt(np.maximum(disc, 0.0)), q1))
        lin = np.abs(q2) <= 1e-14 * (np.abs(q1) + np.abs(q0) + 1e-300)
        r1 = np.where(lin, -q0 / q1, qq / q2)
        r2 = np.where(lin, np.inf, q0 / qq)
        best = np.full(a.shape, np.inf)
        for r in (r1, r2):
            num = a + b * r
            sign_ok = (np.sign(num) == np.sign(c)) | (
                np.abs(num) <= 1e-7 * (np.abs(a) + np.abs(b * r)))
            ok = real & np.isfinite(r) & (r >= 0.0) & sign_ok
            best = np.where(ok & (r < best), r, best)
        best = np.where(c == 0.0, np.where(b > 0.0, -a / b, np.inf), best)
        out = np.where(at0, 0.0, best)
    bad = ~(np.isfinite(a) & np.isfinite(b) & np.isfinite(v0) & np.isfinite(v1)
            & np.isfinite(v2) & np.isfinite(c))
    return np.where(bad, np.nan, out)


def test_first_crossing_keeps_its_bits():
    """Random lines over many magnitudes with zeros, NaN, infinities and tiny slopes mixed in,
    a (levels, units) table of c and the scalar cases: the same bits as before."""
    rng = np.random.default_rng(5)
    n = 20_000

    def draw(*special):
        x = rng.normal(size=n) * rng.choice([1e-8, 1e-3, 1.0, 1e3], n)
        return np.where(rng.random(n) < 0.1, rng.choice(np.array(special), n), x)

    a, b = draw(0.0, np.nan, np.inf, -1.0), draw(0.0, np.nan, 1e-300, -1e-300)
    v0, v1, v2 = np.abs(draw(0.0, np.nan, np.inf)), draw(0.0, np.nan), np.abs(draw(0.0, 1e-300))
    c = np.stack([np.zeros(n), draw(0.0, np.nan, 1.645, -1.645), draw(np.inf, 2.0)])
    median = np.where(rng.random(n) < 0.1, np.nan, 0.0)  # the median's pass: no quadratic
    for args in ((a, b, v0, v1, v2, c), (a, b, v0, v1, v2, c[1]), (a, b, v0, v1, v2, 1.5),
                 (a, b, v0, v1, v2, c[0]), (a, b, v0, v1, v2, median),
                 (-1.0, 0.5, 0.0, 0.0, 0.0, 0.0), (-1.0, 0.2, 0.01, 0.0, 0.01, 1.5)):
        got, ref = first_crossing(*args), _first_crossing_before(*args)
        assert got.shape == ref.shape and got.tobytes() == ref.tobytes()


def test_t_cdf_and_quantiles_against_scipy():
    nu = np.arange(1.0, 201.0)
    for x in (-40.0, -2.5, -0.3, 0.0, 0.7, 3.0, 25.0):
        np.testing.assert_allclose(t_cdf(x, nu), stats.t.cdf(x, nu), rtol=1e-12, atol=1e-15)
    for p in (0.005, 0.05, 0.5, 0.9, 0.975):
        np.testing.assert_allclose(t_quantile(nu, p), stats.t.ppf(p, nu), rtol=1e-12,
                                   atol=1e-14, err_msg=str(p))
    got = t_quantile(np.array([201.0, 1e6, np.nan]), 0.95)
    assert got[0] == got[1] == pytest.approx(stats.norm.ppf(0.95), rel=1e-12)
    assert np.isnan(got[2])


def test_band_reaches_the_threshold_at_the_interval():
    post = random_posteriors(np.random.default_rng(3), 40)
    med, low, high = rul_quantiles(post, (0.5, 0.05, 0.95))
    ok = np.isfinite(high) & (low > 0)
    sub = TrendPosterior(*(getattr(post, f)[ok] for f in ("a", "b", "vaa", "vab", "vbb", "nu")))
    at = np.column_stack([med[ok], low[ok], high[ok]])
    h_med, h_up, h_low = hi_quantiles(sub, at, (0.5, 0.95, 0.05))
    np.testing.assert_allclose(h_med[:, 0], 1.0, rtol=1e-9)  # the median line at the median
    np.testing.assert_allclose(h_up[:, 1], 1.0, rtol=1e-9)  # the upper band at the low RUL
    np.testing.assert_allclose(h_low[:, 2], 1.0, rtol=1e-9)  # the lower band at the high RUL


def test_interval_coverage_on_fleets_drawn_from_the_model():
    """HI = exp(a + b t) + additive noise (EI-16 with forgetting 1): the 90 % interval holds
    the true RUL (the noise-free path's crossing) about 90 % of the time."""
    rng = np.random.default_rng(4)
    cfg = TrendConfig(forgetting=1.0, min_points=5)
    n, k = 2000, 12
    t = np.tile(np.arange(k, dtype=float), (n, 1)) * rng.uniform(0.5, 2.0, (n, 1))
    rate = rng.uniform(0.02, 0.08, n)
    a0 = np.log(rng.uniform(0.2, 0.5, n))
    truth_path = np.exp(a0[:, None] + rate[:, None] * t)
    hi = np.clip(truth_path + rng.normal(0, 0.01, (n, k)), 1e-3, None)
    state, _ = trend_run(TrendState.empty(n), np.arange(0, n * k + 1, k), t.ravel(),
                         hi.ravel(), cfg)
    med, low, high = rul_quantiles(trend_posterior(state, cfg), (0.5, 0.05, 0.95))
    true_rul = -a0 / rate - t[:, -1]
    running = true_rul > 0  # units whose path has not crossed yet (the others have failed)
    assert running.sum() > 1500
    inside = ((low <= true_rul) & (true_rul <= high))[running]
    assert 0.87 <= inside.mean() <= 0.93, inside.mean()
    assert np.median(np.abs(med - true_rul)[running] / true_rul[running]) < 0.1
