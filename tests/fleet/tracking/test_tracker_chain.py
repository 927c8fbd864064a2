"""Health index and embedded RUL tracker chain (embedded-rul.md sections 1-3)."""

import math

import numpy as np
import pytest
from scipy import integrate, stats

from rulkit.fleet.tracking.health_index import (
    RAYLEIGH_UNIT_VARIANCE_BETA,
    HealthIndexModel,
    empirical_offset,
    nakagami_critical_value,
)
from rulkit.fleet.tracking.tracker_chain import (
    LEVEL_ALARM,
    LEVEL_NONE,
    LEVEL_WARNING,
    TrackerConfig,
    TrackerState,
    paris_rul,
    rul_confidence_limits,
    track_series,
    tracker_rul_interval,
    tracker_update,
    tracker_update_loop,
)

BETA = RAYLEIGH_UNIT_VARIANCE_BETA


def correlated_rayleigh(rng, n_obs, mix, offset):
    """Healthy CI model: CI = offset + M R, R IID unit-variance Rayleigh (seed section 3)."""
    r = rng.rayleigh(BETA, size=(n_obs, mix.shape[0]))
    return offset + r @ mix.T


def equicorrelated_mix(n, rho):
    cov = np.full((n, n), rho) + (1 - rho) * np.eye(n)
    return np.linalg.cholesky(cov)


# ---------------------------------------------------------------- section 1: CI -> HI
def test_rayleigh_beta_and_critical_value_against_gamma_closed_form():
    assert BETA == pytest.approx(1.5264, abs=5e-5)  # seed eq 6
    # unit variance: Var of Rayleigh(beta) = (2 - pi/2) beta^2
    assert stats.rayleigh(scale=BETA).var() == pytest.approx(1.0, rel=1e-12)
    for n in (1, 3, 6):
        for pfa in (1e-3, 1e-6):
            # ||Y||^2 = sum of n Exp(mean 2 beta^2) = Gamma(n, scale 2 beta^2)
            t_sq = stats.gamma.isf(pfa, n, scale=2 * BETA**2)
            assert nakagami_critical_value(n, pfa) == pytest.approx(math.sqrt(t_sq), rel=1e-9)


def test_whitening_gives_identity_covariance_and_hi_scaling():
    rng = np.random.default_rng(1)
    mix = np.array([[1.0, 0, 0], [0.8, 0.6, 0], [0.3, -0.5, 0.9]])
    ci = correlated_rayleigh(rng, 5000, mix, offset=np.array([2.0, 1.0, 0.5]))
    model = HealthIndexModel.fit(ci, pfa=1e-6, offset="cdf05")
    y = model.whiten(ci)
    # transpose convention: the sample covariance of Y must be exactly I on the fit data
    np.testing.assert_allclose(np.cov(y, rowvar=False), np.eye(3), atol=1e-10)
    # HI = 0.5 ||Y|| / T
    np.testing.assert_allclose(
        model.health_index(ci), 0.5 * np.linalg.norm(y, axis=1) / model.critical_value,
        rtol=1e-12,
    )
    # a single acquisition (n,) works too
    assert model.health_index(ci[0]).shape == (1,)
    # round trip through the JSON dict
    again = HealthIndexModel.from_dict(model.to_dict())
    np.testing.assert_array_equal(again.health_index(ci[:10]), model.health_index(ci[:10]))


def test_offset_is_the_five_percent_point_of_the_empirical_cdf():
    x = np.arange(1, 101, dtype=float)[:, None] * np.array([1.0, -1.0])
    off = empirical_offset(np.random.default_rng(0).permutation(x))
    # seed: sorted values indexed at round(0.05 N) (0-based) = index 5 -> 6th smallest
    np.testing.assert_array_equal(off, [6.0, -95.0])


def test_false_alarm_rate_matches_design_with_whitening_and_inflates_without():
    rng = np.random.default_rng(2024)
    n, pfa = 3, 2e-3
    mix = equicorrelated_mix(n, 0.9)
    offset = np.array([3.0, 1.0, 2.0])
    baseline = correlated_rayleigh(rng, 200_000, mix, offset)
    fresh = correlated_rayleigh(rng, 1_000_000, mix, offset)
    expected = pfa * fresh.shape[0]  # 2000 exceedances
    white = HealthIndexModel.fit(baseline, pfa=pfa, offset=offset)
    far_white = np.count_nonzero(white.health_index(fresh) > 0.5)
    # binomial sd = sqrt(2000) ~ 2.2 %; the covariance fitted on 2e5 rows has a ~0.3 % scale
    # error, which the steep tail (d ln PFA / d ln T ~ 16) turns into ~5 %: allow 15 %
    assert abs(far_white - expected) < 0.15 * expected, far_white
    plain = HealthIndexModel.fit(baseline, pfa=pfa, offset=offset, whiten=False)
    far_plain = np.count_nonzero(plain.health_index(fresh) > 0.5)
    # rho = 0.9: the unwhitened norm is dominated by one common factor -> heavier tail
    assert far_plain > 10 * expected, far_plain
    # the seed's cdf05 offset on a Rayleigh CI removes its own 5 % point: conservative
    cdf = HealthIndexModel.fit(baseline, pfa=pfa, offset="cdf05")
    assert np.count_nonzero(cdf.health_index(fresh) > 0.5) < expected


def test_independent_cis_whitening_not_needed():
    rng = np.random.default_rng(5)
    n, pfa = 2, 1e-3
    base = correlated_rayleigh(rng, 200_000, np.eye(n), np.zeros(n))
    fresh = correlated_rayleigh(rng, 500_000, np.eye(n), np.zeros(n))
    plain = HealthIndexModel.fit(base, pfa=pfa, offset="none", whiten=False)
    far = np.count_nonzero(plain.health_index(fresh) > 0.5)
    assert abs(far - 500) < 0.2 * 500  # binomial sd 4.5 % + fit error


def test_hi_model_bad_input():
    with pytest.raises(ValueError, match="non-finite value at row 1, column 0"):
        HealthIndexModel.fit(np.array([[1.0, 2.0], [np.nan, 1.0], [2.0, 3.0], [1.0, 1.0]]))
    with pytest.raises(ValueError, match="singular"):
        x = np.random.default_rng(0).normal(size=(50, 1))
        HealthIndexModel.fit(np.hstack([x, 2 * x]))
    with pytest.raises(ValueError, match="need more than 2 rows"):
        HealthIndexModel.fit(np.ones((2, 2)))
    with pytest.raises(ValueError, match="pfa"):
        nakagami_critical_value(2, 0.0)
    model = HealthIndexModel.fit(np.random.default_rng(0).rayleigh(size=(100, 2)))
    with pytest.raises(ValueError, match=r"ci: expected shape \(N, 2\)"):
        model.health_index(np.ones((4, 3)))


# ---------------------------------------------------------------- section 2: tracker chain
def exponential_hi(t, h0, k):
    return h0 * np.exp(k * t)


def test_paris_rul_closed_form_and_edges():
    # HI(t) = h0 exp(k t): time to 1 is -ln(h0)/k; with dHI = k HI, -HI ln HI / dHI is that.
    h0, k = 0.3, 0.02
    assert paris_rul(np.array([h0]), np.array([k * h0]))[0] == pytest.approx(-math.log(h0) / k)
    r = paris_rul(np.array([1.0, 1.5, 0.0, -0.2]), np.full(4, 0.01), hi_floor=1e-3)
    assert r[0] == 0.0 and r[1] == 0.0
    assert np.all(np.isfinite(r)) and r[2] == r[3] == pytest.approx(-1e-3 * math.log(1e-3) / 0.01)


@pytest.mark.parametrize("initiation", ["floor", "two-point"])
def test_vectorised_chain_equals_per_component_pseudocode(initiation):
    rng = np.random.default_rng(7)
    b, steps = 50, 30
    cfg = TrackerConfig(dt=1.0, lambda_hi=0.3, lambda_rul=0.5, design_life=1e4, hi_sigma=0.02,
                        initiation=initiation)
    t = np.cumsum(rng.uniform(0.5, 1.5, size=(steps, b)), axis=0)  # irregular, per component
    hi = exponential_hi(t, rng.uniform(0.05, 0.4, b), rng.uniform(0.005, 0.03, b))
    hi += rng.normal(0, 0.01, size=hi.shape)
    hi[rng.random(hi.shape) < 0.1] = np.nan  # missing acquisitions
    hi[3, 0] = -0.1  # HI <= 0 and HI >= 1 edge cases
    hi[4, 1] = 1.4
    vec = TrackerState.empty(b)
    ref = TrackerState.empty(b)
    for k in range(steps):
        vec, _ = tracker_update(vec, t[k], hi[k], cfg)
        ref = tracker_update_loop(ref, t[k], hi[k], cfg)
        for name, col in vec.columns().items():
            np.testing.assert_allclose(col, ref.columns()[name], rtol=1e-12, atol=1e-12,
                                       err_msg=f"{name} at step {k}")
    assert np.all(np.isfinite(vec.abg))


def test_components_are_independent_in_one_call():
    rng = np.random.default_rng(3)
    cfg = TrackerConfig(dt=1.0, lambda_hi=0.2, lambda_rul=0.2)
    t = np.arange(1.0, 41.0)
    hi = exponential_hi(t[:, None], np.array([0.1, 0.2, 0.3]), np.array([0.02, 0.03, 0.01]))
    hi = hi + rng.normal(0, 0.005, hi.shape)
    together = track_series(t, hi, cfg)
    for j in range(3):
        alone = track_series(t, hi[:, j : j + 1], cfg)
        for key in ("fhi", "dhi", "frul", "drul", "d2rul", "level"):
            np.testing.assert_array_equal(together[key][:, j], alone[key][:, 0])


def test_noise_free_exponential_converges_to_true_rul_valid_and_alerts():
    # Paris-law growth HI = 0.2 exp(0.01 t): HI = 1 at t* = ln(5)/0.01 = 160.94
    k, h0, dt = 0.01, 0.2, 1.0
    t_star = math.log(1 / h0) / k
    t = np.arange(0.0, 200.0, dt)
    cfg = TrackerConfig(dt=dt, lambda_hi=2.0, lambda_rul=2.0, design_life=1e4, warn_rul=40.0)
    h = track_series(t, exponential_hi(t, h0, k)[:, None], cfg)
    true_rul = t_star - t
    late = (t >= 60) & (t <= 150)
    # steady-state tracking lag of an exponential is small at these tracking indices
    np.testing.assert_allclose(h["frul"][late, 0], true_rul[late], rtol=0.03)
    np.testing.assert_allclose(h["drul"][late, 0], -1.0, atol=0.05)
    assert np.all(h["valid"][late, 0])
    assert not h["valid"][0, 0]  # a fresh component is never valid (dRUL starts at 0)
    level = h["level"][:, 0]
    first_warn = t[np.argmax(level == LEVEL_WARNING)]
    first_alarm = t[np.argmax(level == LEVEL_ALARM)]
    # warning once fHI >= 0.75 (t >= 132.2) and RUL < 40 (t > 120.9): at ~132
    assert 130 <= first_warn <= 136
    # alarm at the crossing (filtered HI lags by about a step)
    assert t_star <= first_alarm <= t_star + 3
    assert np.all(level[t < 120] == LEVEL_NONE)


def test_no_healing_floor_and_nan_skips():
    cfg = TrackerConfig(dt=1.0, lambda_hi=0.5, lambda_rul=0.5, design_life=200.0)
    t = np.arange(0.0, 30.0)
    hi = np.linspace(0.6, 0.3, t.size)  # "healing" component
    h = track_series(t, hi[:, None], cfg)
    assert np.all(h["dhi"] >= 1 / 200.0)
    np.testing.assert_allclose(h["dhi"][-5:, 0], 1 / 200.0)
    # NaN acquisition: state unchanged for that component only
    s0 = TrackerState.empty(2)
    s1, _ = tracker_update(s0, np.array([0.0, 0.0]), np.array([0.5, 0.4]), cfg)
    s2, out = tracker_update(s1, np.array([1.0, 1.0]), np.array([np.nan, 0.45]), cfg)
    assert out.updated.tolist() == [False, True]
    assert s2.t[0] == 0.0 and s2.n[0] == 1 and s2.fhi[0] == s1.fhi[0]
    assert s2.n[1] == 2
    # the input state is not modified
    assert s1.n.tolist() == [1, 1] and s1.t.tolist() == [0.0, 0.0]


def test_time_must_advance():
    cfg = TrackerConfig()
    s, _ = tracker_update(TrackerState.empty(3), np.zeros(3), np.full(3, 0.3), cfg)
    with pytest.raises(ValueError, match=r"component index 2: time 0\.0 is not after"):
        tracker_update(s, np.array([1.0, 1.0, 0.0]), np.full(3, 0.3), cfg)
    with pytest.raises(ValueError, match=r"expected shape \(3,\)"):
        tracker_update(s, np.ones(2), np.ones(2), cfg)


def test_state_size_is_seven_numbers_plus_bookkeeping():
    s = TrackerState.empty(1000)
    assert s.nbytes == 1000 * (7 + 2) * 8


# ---------------------------------------------------------------- section 3: confidence limits
def test_confidence_limits_against_integrated_paris_law():
    fhi, k = 0.6, 0.004
    dhi = k * fhi
    cfg = TrackerConfig(hi_sigma=0.03, load_factor=0.10, load_exponent=2.0)
    lo, hi = rul_confidence_limits(np.array([fhi]), np.array([dhi]), cfg)

    def time_to_one(h_start, rate):
        # integrate dHI/dt = rate HI until HI = 1 (event), independent of the closed form
        ev = lambda t, y: y[0] - 1.0  # noqa: E731
        ev.terminal = True
        sol = integrate.solve_ivp(lambda t, y: rate * y, (0, 1e5), [h_start], events=ev,
                                  rtol=1e-10, atol=1e-12)
        return sol.t_events[0][0]

    # high load: stress x 1.1 -> Paris rate x 1.1^2; HI one sigma higher
    assert lo[0] == pytest.approx(time_to_one(fhi + 0.03, k * 1.1**2), rel=1e-6)
    assert hi[0] == pytest.approx(time_to_one(fhi - 0.03, k * 0.9**2), rel=1e-6)
    rul = paris_rul(np.array([fhi]), np.array([dhi]))[0]
    assert lo[0] < rul < hi[0]
    # the seed's eq 29 (rate x 1.10) is load_exponent = 1
    seed = TrackerConfig(hi_sigma=0.03, load_factor=0.10, load_exponent=1.0)
    lo1, _ = rul_confidence_limits(np.array([fhi]), np.array([dhi]), seed)
    assert lo1[0] == pytest.approx(time_to_one(fhi + 0.03, k * 1.1), rel=1e-6)
    # no spread -> both limits equal the RUL; past the threshold everything is 0 and finite
    z = TrackerConfig(hi_sigma=0.0, load_factor=0.0)
    a, b = rul_confidence_limits(np.array([fhi, 1.2]), np.array([dhi, dhi]), z)
    assert a[0] == pytest.approx(rul) and b[0] == pytest.approx(rul)
    assert a[1] == 0.0 and b[1] == 0.0


def test_config_validation_and_round_trip():
    with pytest.raises(ValueError, match=r"TrackerConfig\.dt"):
        TrackerConfig(dt=0.0)
    with pytest.raises(ValueError, match="valid_drul"):
        TrackerConfig(valid_drul=(0.0, -2.0))
    with pytest.raises(ValueError, match="initiation"):
        TrackerConfig(initiation="zeros")
    with pytest.raises(ValueError, match="load_exponent"):
        TrackerConfig(load_exponent=float("nan"))
    cfg = TrackerConfig(dt=10.0, lambda_hi=3.0, warn_rul=30.0)
    assert TrackerConfig.from_dict(cfg.to_dict()) == cfg
    cfg2 = TrackerConfig(load_exponent=1.0, paris_exponent=3.0)
    assert TrackerConfig.from_dict(cfg2.to_dict()) == cfg2
    with pytest.raises(ValueError, match="unknown keys"):
        TrackerConfig.from_dict({"dt": 1.0, "bogus": 2})


def test_two_point_initiation():
    cfg = TrackerConfig(dt=2.0, lambda_hi=0.5, lambda_rul=0.5, design_life=1e3,
                        initiation="two-point")
    t = np.array([0.0, 2.0, 4.0, 6.0])
    z = np.array([0.30, 0.34, 0.37, 0.41])
    h = track_series(t, z[:, None], cfg)
    # 1st: slope unknown -> floor 1/design_life; RUL tracker starts at the raw RUL
    assert h["fhi"][0, 0] == 0.30 and h["dhi"][0, 0] == 1e-3
    # 2nd: two-point slope, RUL tracker restarts
    assert h["fhi"][1, 0] == 0.34 and h["dhi"][1, 0] == pytest.approx(0.02)
    rul1 = -0.34 * math.log(0.34) / 0.02
    assert h["rul"][1, 0] == pytest.approx(rul1) and h["frul"][1, 0] == pytest.approx(rul1)
    assert h["drul"][1, 0] == 0.0
    # 3rd: RUL two-point slope from the two RULs that rest on measured slopes
    assert h["drul"][2, 0] == pytest.approx((h["rul"][2, 0] - rul1) / 2.0)
    assert h["frul"][2, 0] == h["rul"][2, 0] and h["d2rul"][2, 0] == 0.0
    assert not h["valid"][:3, 0].any()


@pytest.mark.parametrize("m", [2.0, 2.8, 4.0])
def test_paris_rul_and_limits_general_exponent_against_ode(m):
    p = m / 2
    h0, c = 0.6, 0.003
    dhi = c * h0**p  # current slope of dHI/dt = c HI^p

    def time_to_one(h_start, rate):
        ev = lambda t, y: y[0] - 1.0  # noqa: E731
        ev.terminal = True
        sol = integrate.solve_ivp(lambda t, y: rate * y**p, (0, 1e6), [h_start], events=ev,
                                  rtol=1e-11, atol=1e-13)
        return sol.t_events[0][0]

    rul = paris_rul(np.array([h0]), np.array([dhi]), exponent=m)[0]
    assert rul == pytest.approx(time_to_one(h0, c), rel=1e-6)
    # the load exponent defaults to the Paris exponent (the rate goes with stress^m), so
    # setting m alone (as `rulkit track --paris-exponent` does) keeps the limits consistent
    for cfg in (TrackerConfig(hi_sigma=0.02, load_factor=0.1, load_exponent=m, paris_exponent=m),
                TrackerConfig(hi_sigma=0.02, load_factor=0.1, paris_exponent=m)):
        lo, hi = rul_confidence_limits(np.array([h0]), np.array([dhi]), cfg)
        assert lo[0] == pytest.approx(time_to_one(h0 + 0.02, c * 1.1**m), rel=1e-6)
        assert hi[0] == pytest.approx(time_to_one(h0 - 0.02, c * 0.9**m), rel=1e-6)


def test_vectorised_chain_equals_loop_with_general_exponent():
    rng = np.random.default_rng(11)
    b = 20
    cfg = TrackerConfig(dt=1.0, lambda_hi=0.4, lambda_rul=0.2, paris_exponent=3.0,
                        initiation="two-point")
    t = np.arange(1.0, 16.0)
    hi = exponential_hi(t[:, None], rng.uniform(0.2, 0.5, b), 0.03) + rng.normal(0, 0.01, (15, b))
    vec, ref = TrackerState.empty(b), TrackerState.empty(b)
    for k in range(t.size):
        vec, _ = tracker_update(vec, np.full(b, t[k]), hi[k], cfg)
        ref = tracker_update_loop(ref, np.full(b, t[k]), hi[k], cfg)
    for name, col in vec.columns().items():
        np.testing.assert_allclose(col, ref.columns()[name], rtol=1e-12, atol=1e-12)


def test_floor_initiation_is_quiet_on_noisy_healthy_components():
    # i.i.d. noisy HI around 0.3 (healthy): no slope exists, so no alert may appear
    rng = np.random.default_rng(12)
    b, steps = 2000, 40
    hi = rng.uniform(0.1, 0.5, size=(steps, b))
    t = np.arange(float(steps))
    floor = track_series(t, hi, TrackerConfig(lambda_hi=0.01, lambda_rul=0.01))
    assert floor["level"].max() == 0
    assert np.all(floor["fhi"] < 0.75)
    # the two-point start takes its slope from two noisy acquisitions: spurious alerts
    two = track_series(t, hi, TrackerConfig(lambda_hi=0.01, lambda_rul=0.01,
                                            initiation="two-point"))
    assert two["level"].max() == 2


@pytest.mark.parametrize("m", [2.0, 3.0, 1.0])
def test_tracker_interval_around_its_own_rul(m):
    """The limits taken from the filtered RUL (seed eq 27) bracket it, are never negative,
    and equal the limits from (fHI, dHI) when the RUL is the Paris-law RUL of that state."""
    rng = np.random.default_rng(3)
    cfg = TrackerConfig(hi_sigma=0.03, paris_exponent=m)
    fhi = rng.uniform(0.0, 1.2, 500)
    dhi = rng.uniform(1e-4, 0.05, 500)
    frul = rng.normal(50.0, 80.0, 500)  # the seed's unclipped filter goes negative
    rul, low, high = tracker_rul_interval(fhi, frul, cfg)
    assert np.all(rul == np.maximum(frul, 0.0)) and np.all(low >= 0.0)
    assert np.all(low <= rul) and np.all(rul <= high)
    paris = paris_rul(fhi, dhi, cfg.hi_floor, m)
    ok = fhi < 1.0
    _, low2, high2 = tracker_rul_interval(fhi[ok], paris[ok], cfg)
    ref_low, ref_high = rul_confidence_limits(fhi[ok], dhi[ok], cfg)
    np.testing.assert_allclose(low2, ref_low, rtol=1e-10)
    np.testing.assert_allclose(high2, ref_high, rtol=1e-10)
