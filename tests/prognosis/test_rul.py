"""Tests of rulkit.prognosis.rul against closed forms (linear growth, Brownian first passage)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import stats

from rulkit.estimation.base import Posterior
from rulkit.prognosis.rul import RULDistribution, propagate_to_threshold


def linear_step(x, u, t, dt, rng):
    """Deterministic damage growth: damage += rate * dt."""
    out = x.copy()
    out[:, 0] += x[:, 1] * dt
    return out


def damage(x):
    return x[:, 0]


# ------------------------------------------------------------------ propagate_to_threshold
def test_linear_growth_exact_crossing_times():
    d0 = np.array([0.0, 0.25, 0.5, 0.9, 0.33])
    rate = np.array([0.01, 0.03, 0.07, 0.013, 0.011])
    x0 = np.column_stack([d0, rate])
    # dt does not divide the crossing times: the interpolation must still be exact
    dist = propagate_to_threshold(
        x0, linear_step, damage, 1.0, t0=5.0, dt=0.7, horizon=200.0,
        rng=np.random.default_rng(0),
    )
    expected = (1.0 - d0) / rate
    np.testing.assert_allclose(dist.samples, expected, rtol=1e-12, atol=1e-12)
    assert dist.n_censored == 0
    assert dist.horizon == 200.0


def test_last_step_is_shortened_to_the_horizon():
    # horizon 10 with dt 3: steps at 3, 6, 9, then a 1-long step to 10
    x0 = np.array([[0.0, 0.1], [0.0, 0.1 / 0.95], [0.0, 0.05]])
    dist = propagate_to_threshold(
        x0, linear_step, damage, 1.0, dt=3.0, horizon=10.0, rng=np.random.default_rng(0)
    )
    # 10.0 exactly at the horizon (crossing at the end of the short step), 9.5 inside it
    np.testing.assert_allclose(dist.samples[:2], [10.0, 9.5], rtol=1e-12)
    assert dist.censored.tolist() == [False, False, True]
    assert dist.samples[2] == 10.0


def test_censoring_count_and_failed_at_t0():
    d0 = np.array([1.2, 1.0, 0.0, 0.0, 0.0, 0.5])
    rate = np.array([0.1, 0.1, 0.2, 0.01, 0.0, 0.001])
    dist = propagate_to_threshold(
        np.column_stack([d0, rate]), linear_step, damage, 1.0, dt=0.5, horizon=10.0,
        rng=np.random.default_rng(1),
    )
    # samples 0, 1 already failed (>= threshold) -> RUL 0; sample 2 at t = 5;
    # samples 3 (needs 100), 4 (never), 5 (needs 500) censored at the horizon
    np.testing.assert_allclose(dist.samples, [0, 0, 5, 10, 10, 10], atol=1e-12)
    assert dist.censored.tolist() == [False, False, False, True, True, True]
    assert dist.n_censored == 3
    assert dist.fraction_censored == pytest.approx(0.5)
    # mean is the restricted mean of min(RUL, horizon)
    assert dist.mean == pytest.approx((0 + 0 + 5 + 30) / 6)
    assert dist.mean_uncensored == pytest.approx(5 / 3)
    assert dist.median == pytest.approx(5.0)  # F(5) = 0.5 exactly
    assert dist.quantile(0.51) == math.inf


def test_threshold_never_reached_all_censored():
    x0 = np.column_stack([np.zeros(4), np.zeros(4)])
    dist = propagate_to_threshold(
        x0, linear_step, damage, 1.0, dt=1.0, horizon=7.5, rng=np.random.default_rng(0)
    )
    assert dist.n_censored == 4 and dist.fraction_censored == 1.0
    assert np.all(dist.samples == 7.5)
    assert dist.median == math.inf
    assert dist.interval(0.9) == (math.inf, math.inf)
    assert dist.mean == 7.5  # restricted mean = horizon (lower bound)
    assert math.isnan(dist.mean_uncensored)
    with pytest.raises(ValueError, match="distinct uncensored"):
        dist.pdf(np.linspace(0, 10, 5))


def test_direction_down():
    # health decreasing from 1 at rate r: crosses 0.2 at (1 - 0.2) / r
    r = np.array([0.1, 0.04])
    x0 = np.column_stack([np.ones(2), r])

    def step(x, u, t, dt, rng):
        out = x.copy()
        out[:, 0] -= x[:, 1] * dt
        return out

    dist = propagate_to_threshold(
        x0, step, damage, 0.2, dt=0.3, horizon=100.0, rng=np.random.default_rng(0),
        direction="down",
    )
    np.testing.assert_allclose(dist.samples, 0.8 / r, rtol=1e-12)


def test_brownian_drift_first_passage_matches_inverse_gaussian():
    # X_t = mu t + sigma W_t from 0; first passage of a > 0 is IG(mean a/mu, shape a^2/sigma^2)
    mu, sigma, a, dt, n = 1.0, 0.3, 1.0, 1e-3, 8000
    sq = sigma * math.sqrt(dt)

    def step(x, u, t, h, rng):
        return x + mu * h + math.sqrt(h / dt) * sq * rng.standard_normal(x.shape)

    dist = propagate_to_threshold(
        np.zeros((n, 1)), step, lambda x: x[:, 0], a, dt=dt, horizon=4.0,
        rng=np.random.default_rng(42),
    )
    assert dist.n_censored == 0
    mean_exact = a / mu
    sd_exact = math.sqrt(a * sigma**2 / mu**3)
    se = sd_exact / math.sqrt(n)
    # discrete monitoring overshoots the barrier by ~0.5826 sigma sqrt(dt) (Siegmund); the
    # interpolated time is late by at most that over mu
    bias_bound = 0.5826 * sigma * math.sqrt(dt) / mu
    assert abs(dist.mean - mean_exact) < 4 * se + bias_bound
    assert dist.std == pytest.approx(sd_exact, rel=0.06)
    ig = stats.invgauss(mu=(mean_exact / (a**2 / sigma**2)), scale=a**2 / sigma**2)
    assert ig.mean() == pytest.approx(mean_exact)
    for q in (0.1, 0.5, 0.9):
        assert abs(dist.quantile(q) - ig.ppf(q)) < 0.02


def test_reproducible_from_seed_and_weights_attached():
    def step(x, u, t, dt, rng):
        out = x.copy()
        out[:, 0] += x[:, 1] * dt + 0.01 * rng.standard_normal(x.shape[0])
        return out

    x0 = np.column_stack([np.zeros(50), np.full(50, 0.1)])
    w = np.arange(1.0, 51.0)
    post = Posterior.from_samples(x0, w)
    a = propagate_to_threshold(post, step, damage, 1.0, dt=0.5, horizon=30.0,
                               rng=np.random.default_rng(3))
    b = propagate_to_threshold(post, step, damage, 1.0, dt=0.5, horizon=30.0,
                               rng=np.random.default_rng(3))
    np.testing.assert_array_equal(a.samples, b.samples)
    np.testing.assert_allclose(a.weights, w / w.sum())


def test_propagate_input_errors():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="empty batch"):
        propagate_to_threshold(np.zeros((0, 2)), linear_step, damage, 1.0, dt=1.0,
                               horizon=10.0, rng=rng)
    with pytest.raises(ValueError, match="x0: non-finite value at row 1"):
        propagate_to_threshold(np.array([[0, 1.0], [np.nan, 1.0]]), linear_step, damage, 1.0,
                               dt=1.0, horizon=10.0, rng=rng)
    with pytest.raises(ValueError, match="dt"):
        propagate_to_threshold(np.zeros((2, 2)), linear_step, damage, 1.0, dt=0.0,
                               horizon=10.0, rng=rng)
    with pytest.raises(ValueError, match="horizon"):
        propagate_to_threshold(np.zeros((2, 2)), linear_step, damage, 1.0, dt=1.0,
                               horizon=np.inf, rng=rng)
    with pytest.raises(ValueError, match="x0: a Gaussian posterior has no samples"):
        propagate_to_threshold(Posterior(np.zeros(2), np.eye(2)), linear_step, damage, 1.0,
                               dt=1.0, horizon=5.0, rng=rng)
    with pytest.raises(ValueError, match="direction"):
        propagate_to_threshold(np.zeros((2, 2)), linear_step, damage, 1.0, dt=1.0,
                               horizon=5.0, rng=rng, direction="sideways")

    def diverging(x, u, t, dt, rng):
        out = x.copy()
        out[1, 0] = np.nan
        return out

    with pytest.raises(ValueError, match=r"step 1 .* sample 1"):
        propagate_to_threshold(np.zeros((3, 2)), diverging, damage, 1.0, dt=1.0,
                               horizon=5.0, rng=rng)
    with pytest.raises(ValueError, match="indicator: expected shape"):
        propagate_to_threshold(np.zeros((3, 2)), linear_step, lambda x: x, 1.0, dt=1.0,
                               horizon=5.0, rng=rng)


# ------------------------------------------------------------------ RULDistribution
def test_quantile_matches_numpy_inverted_cdf_for_equal_weights():
    s = np.random.default_rng(5).gamma(2.0, 3.0, size=101)
    d = RULDistribution(s)
    q = np.linspace(0, 1, 37)
    np.testing.assert_array_equal(d.quantile(q), np.quantile(s, q, method="inverted_cdf"))
    assert d.mean == pytest.approx(s.mean())
    assert d.std == pytest.approx(s.std())


def test_weighted_quantile_hand_computed_and_equal_to_repeats():
    d = RULDistribution([3.0, 1.0, 2.0], weights=[0.3, 0.2, 0.5])
    assert d.quantile(0.2) == 1.0
    assert d.quantile(0.21) == 2.0
    assert d.quantile(0.7) == 2.0
    assert d.quantile(0.71) == 3.0
    assert d.quantile(0.0) == 1.0 and d.quantile(1.0) == 3.0
    assert d.mean == pytest.approx(0.3 * 3 + 0.2 + 1.0)
    # integer weights == repeated samples
    rep = RULDistribution(np.repeat([3.0, 1.0, 2.0], [3, 2, 5]))
    q = np.linspace(0, 1, 23)
    np.testing.assert_array_equal(d.quantile(q), rep.quantile(q))
    assert d.std == pytest.approx(rep.std)
    assert d.effective_sample_size == pytest.approx(1 / (0.09 + 0.04 + 0.25))
    # zero-weight samples are never returned
    z = RULDistribution([1.0, 2.0, 3.0, 4.0], weights=[0.0, 0.5, 0.0, 0.5])
    assert z.quantile(0.0) == 2.0 and z.quantile(0.5) == 2.0 and z.quantile(0.51) == 4.0


def test_interval_and_cdf():
    d = RULDistribution(np.arange(1.0, 101.0))
    assert d.interval(0.9) == (5.0, 95.0)
    assert d.cdf(10.0) == pytest.approx(0.1)
    assert d.cdf(0.5) == 0.0
    np.testing.assert_allclose(d.cdf([10.0, 50.5]), [0.1, 0.5])
    with pytest.raises(ValueError, match="level"):
        d.interval(1.5)
    with pytest.raises(ValueError, match="q"):
        d.quantile(1.1)


def test_pdf_integrates_to_uncensored_mass_and_matches_normal():
    rng = np.random.default_rng(7)
    s = rng.normal(50.0, 5.0, size=4000)
    d = RULDistribution(s)
    grid = np.linspace(20, 80, 601)
    f = d.pdf(grid)
    assert np.trapezoid(f, grid) == pytest.approx(1.0, abs=2e-3)
    assert np.max(np.abs(f - stats.norm(50, 5).pdf(grid))) < 0.006  # peak is 0.0798
    # a quarter censored at horizon 60: the density covers the other 3/4
    s2 = np.concatenate([rng.uniform(0, 40, 300), np.full(100, 60.0)])
    c = np.r_[np.zeros(300, bool), np.ones(100, bool)]
    d2 = RULDistribution(s2, censored=c, horizon=60.0)
    g2 = np.linspace(-40, 80, 2401)
    assert np.trapezoid(d2.pdf(g2), g2) == pytest.approx(0.75, abs=2e-3)


@pytest.mark.parametrize("horizon", [60.0, math.inf])
def test_json_and_csv_round_trip_exactly(tmp_path, horizon):
    rng = np.random.default_rng(11)
    s = rng.uniform(0, 50, 40)
    c = rng.random(40) < 0.2
    s[c] = 55.0
    w = rng.random(40)
    d = RULDistribution(s, weights=w, censored=c, horizon=horizon)
    p = d.to_json(tmp_path / "rul.json")
    text = p.read_text()
    assert "Infinity" not in text and "NaN" not in text
    json.loads(text)  # strict JSON
    for back in (RULDistribution.from_json(p),
                 RULDistribution.from_csv(d.to_csv(tmp_path / "rul.csv"))):
        np.testing.assert_array_equal(back.samples, d.samples)
        np.testing.assert_array_equal(back.weights, d.weights)
        np.testing.assert_array_equal(back.censored, d.censored)
        assert back.horizon == d.horizon
        assert back.median == d.median and back.mean == d.mean


def test_validation_errors(tmp_path):
    with pytest.raises(ValueError, match="empty"):
        RULDistribution(np.array([]))
    with pytest.raises(ValueError, match="non-finite value nan at index 1"):
        RULDistribution([1.0, np.nan])
    with pytest.raises(ValueError, match="negative RUL"):
        RULDistribution([1.0, -2.0])
    with pytest.raises(ValueError, match="1-D"):
        RULDistribution(np.ones((2, 2)))
    with pytest.raises(ValueError, match=r"weights: expected shape \(2,\)"):
        RULDistribution([1.0, 2.0], weights=[1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="negative weight"):
        RULDistribution([1.0, 2.0], weights=[1.0, -0.5])
    with pytest.raises(ValueError, match="weights: non-finite"):
        RULDistribution([1.0, 2.0], weights=[1.0, np.nan])
    with pytest.raises(ValueError, match="all zero"):
        RULDistribution([1.0, 2.0], weights=[0.0, 0.0])
    with pytest.raises(ValueError, match=r"censored: expected shape \(2,\)"):
        RULDistribution([1.0, 2.0], censored=[True])
    with pytest.raises(ValueError, match="exceeds the horizon"):
        RULDistribution([1.0, 20.0], horizon=10.0)
    with pytest.raises(ValueError, match="horizon"):
        RULDistribution([1.0], horizon=-1.0)
    with pytest.raises(ValueError, match="format"):
        RULDistribution.from_dict({"samples": [1.0]})
    empty = tmp_path / "empty.json"
    empty.write_text("")
    with pytest.raises(ValueError, match="empty file"):
        RULDistribution.from_json(empty)
    bad = tmp_path / "bad.csv"
    bad.write_text("# rulkit.RULDistribution v1\n# horizon=inf\nrul,weight,censored\n1.0,x,0\n")
    with pytest.raises(ValueError, match="line 4"):
        RULDistribution.from_csv(bad)


def test_arrays_are_read_only():
    s = np.array([1.0, 2.0])
    d = RULDistribution(s)
    s[0] = 100.0  # the caller's array is copied
    assert d.samples[0] == 1.0
    with pytest.raises(ValueError):
        d.samples[0] = 5.0


@pytest.mark.parametrize("blowup", [np.inf, -np.inf, np.nan])
@pytest.mark.parametrize("direction", ["up", "down"])
def test_crossed_sample_diverging_later_keeps_its_crossing_time(blowup, direction):
    """Samples are stepped after they cross (no compaction): an indicator that becomes
    +-inf or NaN afterwards must neither raise nor overwrite the recorded crossing time, while
    the samples still running are unaffected (exact linear crossing times)."""
    sign = 1.0 if direction == "up" else -1.0
    d0 = np.array([0.9, 0.0, 0.5, 0.2])
    rate = np.array([0.2, 0.01, 0.04, 0.05])

    def step(x, u, t, dt, rng):
        out = linear_step(x, u, t, dt, rng)
        out[x[:, 0] >= 1.0, 0] = blowup  # crossed at the previous step: diverges now
        return out

    dist = propagate_to_threshold(
        np.column_stack([d0, rate]), step, lambda x: sign * x[:, 0], sign * 1.0, dt=0.3,
        horizon=150.0, rng=np.random.default_rng(0), direction=direction,
    )
    np.testing.assert_allclose(dist.samples, (1.0 - d0) / rate, rtol=1e-12)
    assert dist.n_censored == 0


# ------------------------------------------------------------------ model=, freezing, weights
class _Paris:
    """Super-linear growth a' = c a^2 (blows up in finite time 1 / (c a0)); the crossing of
    threshold A from a0 is at (1/a0 - 1/A) / c. ``as_batch``-like check: refuses non-finite."""

    dt = 0.5
    threshold = 2.0

    def __init__(self, c: float = 0.1) -> None:
        self.c = c

    def step(self, x, u, t, dt, rng=None):
        if not np.all(np.isfinite(x)):  # the user's own check (issue 10, stumble 1)
            bad = np.argwhere(~np.isfinite(x))[0]
            raise ValueError(f"x: non-finite value at row {bad[0]}")
        a = x[:, 0]
        # exact solution of a' = c a^2 over dt while finite; overflows once c a dt >= 1
        with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
            nxt = np.where(self.c * a * dt < 1, a / (1 - self.c * a * dt), np.inf)
        return nxt[:, None] * x[:, 1:2] ** 0 * np.ones_like(x)

    def health(self, x):
        return x[:, 0]


def test_crossed_samples_are_frozen_so_superlinear_growth_never_overflows() -> None:
    """Stumble 1: stepping samples after they crossed overflowed inside the user's step."""
    model = _Paris()
    a0 = np.array([0.5, 1.0, 1.5, 0.2])
    x0 = np.column_stack([a0, np.ones(4)])
    exact = (1 / a0 - 1 / model.threshold) / model.c
    with pytest.raises(ValueError, match="x: non-finite value"):
        propagate_to_threshold(x0, model=model, horizon=100.0, rng=np.random.default_rng(0),
                               after_crossing="continue")
    for mode in ("hold", "drop"):
        dist = propagate_to_threshold(x0, model=model, horizon=100.0,
                                      rng=np.random.default_rng(0), after_crossing=mode)
        assert dist.n_censored == 0
        # the chord of a convex path reaches the threshold first: early by less than a step
        assert np.all(dist.samples <= exact + 1e-12) and np.all(dist.samples > exact - 0.5)


def test_hold_and_continue_give_identical_samples_and_drop_the_same_law() -> None:
    """Holding crossed rows changes nothing for the running ones (same draws); dropping them
    changes the draws, not the distribution (two-sample KS test)."""
    def step(x, u, t, dt, rng):
        out = x.copy()
        out[:, 0] += x[:, 1] * dt + 0.05 * math.sqrt(dt) * rng.standard_normal(x.shape[0])
        return out

    x0 = np.column_stack([np.zeros(3000), np.full(3000, 0.1)])
    kw = dict(step=step, indicator=damage, threshold=1.0, dt=0.5, horizon=30.0)
    hold = propagate_to_threshold(x0, rng=np.random.default_rng(5), **kw)
    cont = propagate_to_threshold(x0, rng=np.random.default_rng(5), after_crossing="continue",
                                  **kw)
    drop = propagate_to_threshold(x0, rng=np.random.default_rng(6), after_crossing="drop",
                                  **kw)
    np.testing.assert_array_equal(hold.samples, cont.samples)
    assert stats.ks_2samp(hold.samples, drop.samples).pvalue > 1e-3
    with pytest.raises(ValueError, match="after_crossing"):
        propagate_to_threshold(x0, rng=np.random.default_rng(5), after_crossing="stop", **kw)


def test_a_weighted_estimate_carries_its_weights_into_propagation() -> None:
    """Propagating particles without their weights silently gave another median: the weights
    travel with the particles in a Posterior, the filter's state gives one, and propagation
    uses them."""
    from rulkit.estimation.particle import ParticleState

    x = np.column_stack([np.zeros(4), np.array([0.1, 0.2, 0.4, 0.5])])  # RULs 10, 5, 2.5, 2
    w = np.array([0.7, 0.1, 0.1, 0.1])
    st = ParticleState(particles=x, logw=np.log(w), weights=w, rng=np.random.default_rng(0),
                       ess=1 / np.sum(w**2))
    dist = propagate_to_threshold(st.posterior(), linear_step, damage, 1.0, dt=0.25,
                                  horizon=50.0, rng=np.random.default_rng(0))
    np.testing.assert_allclose(dist.weights, w)
    assert dist.median == pytest.approx(10.0)  # unweighted, it would be 2.5
    with pytest.raises(TypeError, match="weights"):  # no second source of weights
        propagate_to_threshold(st.posterior(), linear_step, damage, 1.0, dt=0.25,
                               horizon=50.0, rng=np.random.default_rng(0), weights=w)


def test_contract_step_gets_the_input() -> None:
    """One calling convention: ``step(x, u, t, dt, rng)`` gets ``u(t)``; the older
    four-parameter form is not guessed at (no signature inspection): it fails loudly."""
    seen = []

    def step(x, u, t, dt, rng):
        seen.append(u)
        out = x.copy()
        out[:, 0] += u * dt
        return out

    dist = propagate_to_threshold(np.zeros((2, 1)), step, lambda x: x[:, 0], 1.0, dt=0.5,
                                  horizon=10.0, rng=np.random.default_rng(0), u=lambda t: 0.25)
    np.testing.assert_allclose(dist.samples, 4.0)
    assert seen[0] == 0.25

    def legacy(x, t, dt, rng):
        return x

    with pytest.raises(TypeError):
        propagate_to_threshold(np.zeros((2, 2)), legacy, damage, 1.0, dt=0.5,
                               horizon=10.0, rng=np.random.default_rng(0))
    with pytest.raises(TypeError, match="give model="):
        propagate_to_threshold(np.zeros((2, 2)), horizon=10.0, rng=np.random.default_rng(0))


def test_particle_filter_posteriors_carry_their_weights() -> None:
    """The final set and every kept step of a particle-filter result come as a Posterior with
    their weights; propagating one uses the weights (equal to passing them by hand)."""
    from rulkit.estimation.particle import ParticleFilter

    pf = ParticleFilter(lambda x, k, rng: x, lambda x, y, k: -0.5 * ((y[0] - x[:, 0]) / 0.1) ** 2,
                        ess_threshold=0.0)  # never resample: the weights stay informative
    x0 = np.column_stack([np.linspace(0.0, 0.5, 50), np.full(50, 0.1)])
    res = pf.filter(np.array([[0.4], [0.4]]), x0, np.random.default_rng(0),
                    keep_particles=True)
    kw = dict(step=linear_step, indicator=damage, threshold=1.0, dt=0.5, horizon=30.0)
    for k in (0, 1, None):
        post = res.posterior(k)
        assert np.ptp(post.weights) > 0
        d = propagate_to_threshold(post, rng=np.random.default_rng(0), **kw)
        ref = propagate_to_threshold(post.samples, rng=np.random.default_rng(0), **kw)
        np.testing.assert_array_equal(d.samples, ref.samples)
        np.testing.assert_allclose(d.weights, post.weights)
        assert not np.allclose(d.weights, ref.weights)
    assert not hasattr(res, "particles") and not hasattr(res, "weights")


def test_propagation_has_a_step_budget() -> None:
    """dt = 1e-9 over a horizon of 500 used to set out on 5e11 steps: the budget
    horizon / dt <= max_steps is checked before any step runs, naming dt."""
    calls = []

    def step(x, u, t, dt, rng):
        calls.append(t)
        return x

    kw = dict(indicator=damage, threshold=1.0, horizon=500.0, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match=r"dt: horizon / dt = 500 / 1e-09 = 5e\+11 steps "
                                         r"exceeds the step budget max_steps = 1000000"):
        propagate_to_threshold(np.zeros((2, 2)), step, dt=1e-9, **kw)
    assert calls == []
    with pytest.raises(ValueError, match="max_steps = 10"):
        propagate_to_threshold(np.zeros((2, 2)), step, dt=1.0, max_steps=10, **kw)
    d = propagate_to_threshold(np.zeros((2, 2)), step, dt=1.0, max_steps=500, **kw)
    assert len(calls) == 500 and d.n_censored == 2
