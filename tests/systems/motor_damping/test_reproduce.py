"""Multi-scale EKF of seed 002: micro EKF consistency, macro EKF vs least squares, RUL."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rulkit.estimation.kalman import discretise, kf_predict
from rulkit.systems.motor_damping.macro import (
    MacroSettings,
    estimate_scatter_var,
    macro_filter,
    macro_track,
    predicted_damping,
    rul_covariance_quantiles,
    rul_monte_carlo,
)
from rulkit.systems.motor_damping.micro import MicroEKFSettings, micro_ekf
from rulkit.systems.motor_damping.motor import LifeTestConfig, simulate_life_test


@pytest.fixture(scope="module")
def life():
    # 120 cycles spanning c = 1.2e-5 .. 2.5e-4: one batch of 120 units
    cfg = LifeTestConfig(n_cycles=120)
    return simulate_life_test(cfg, np.random.default_rng(11))


def test_micro_ekf_recovers_damping_within_stated_uncertainty(life) -> None:
    res = micro_ekf(life.time, life.current, life.speed, life.acceleration,
                    life.config.consts, MicroEKFSettings())
    e = res.c - life.damping
    nees = e**2 / res.c_var
    # NEES of a consistent filter is chi2(1) per cycle: mean 1 +- sqrt(2/120) = 0.13
    assert 0.65 < nees.mean() < 1.4
    assert np.mean(np.abs(e) <= 1.96 * np.sqrt(res.c_var)) >= 0.88
    # and the error is tiny against one cycle's increase of the damping (2e-6)
    assert np.sqrt(np.mean(e**2)) < 0.01 * life.config.slope
    # innovations consistent: mean NIS ~ m = 2 measurements
    assert 1.8 < res.mean_nis.mean() < 2.2


def test_seed_lagged_euler_form_is_biased(life) -> None:
    sub = slice(0, 40)
    ok = micro_ekf(life.time, life.current[sub], life.speed[sub], life.acceleration[sub],
                   life.config.consts, MicroEKFSettings())
    seed = micro_ekf(life.time, life.current[sub], life.speed[sub], life.acceleration[sub],
                     life.config.consts, MicroEKFSettings(scheme="seed-euler"))
    bias_ok = np.mean(ok.c - life.damping[sub])
    bias_seed = np.mean(seed.c - life.damping[sub])
    sd = np.sqrt(seed.c_var).mean()
    assert abs(bias_seed) > 10 * sd  # far outside its own stated uncertainty
    assert abs(bias_seed) > 20 * abs(bias_ok)


def test_micro_ekf_padded_short_cycle_equals_running_it_alone(life) -> None:
    n_short = 300
    t = np.tile(life.time, (2, 1))
    cur = life.current[:2].copy()
    sp = life.speed[:2].copy()
    acc = life.acceleration[:2].copy()
    t[1, n_short:] = np.nan
    cur[1, n_short:] = sp[1, n_short:] = acc[1, n_short:] = np.nan
    both = micro_ekf(t, cur, sp, acc, life.config.consts)
    alone = micro_ekf(life.time[:n_short], life.current[1:2, :n_short],
                      life.speed[1:2, :n_short], life.acceleration[1:2, :n_short],
                      life.config.consts)
    full = micro_ekf(life.time, life.current[:1], life.speed[:1], life.acceleration[:1],
                     life.config.consts)
    np.testing.assert_allclose(both.c[1], alone.c[0], rtol=1e-12)
    np.testing.assert_allclose(both.c_var[1], alone.c_var[0], rtol=1e-10)
    np.testing.assert_allclose(both.c[0], full.c[0], rtol=1e-12)


def test_micro_ekf_speed_only_channel(life) -> None:
    res = micro_ekf(life.time, life.current[:30], life.speed[:30], None, life.config.consts)
    e = res.c - life.damping[:30]
    assert np.mean(e**2 / res.c_var) < 2.0
    assert 0.8 < res.mean_nis.mean() < 1.2  # one measurement
    with pytest.raises(ValueError, match="scheme"):
        MicroEKFSettings(scheme="euler")


def _linear_data(rng, b: int, n: int, c0=1e-5, a=2e-6, s=2e-6, r=4e-18):
    cyc = np.arange(1.0, n + 1)
    z = c0 + a * cyc + np.sqrt(s * s + r) * rng.standard_normal((b, n))
    return cyc, z, np.full((b, n), r)


def test_macro_filter_equals_weighted_least_squares() -> None:
    rng = np.random.default_rng(0)
    cyc, z, _ = _linear_data(rng, 3, 25)
    rv = rng.uniform(1e-12, 9e-12, (3, 25))
    st = MacroSettings(c_prior_sd=1.0, a_prior_sd=1.0)  # diffuse prior
    x, P, _ = macro_filter(cyc, z, rv, st)
    for u in range(3):
        # state at the last cycle: c_n = beta0 + beta1 n, a = beta1
        X = np.column_stack([np.ones(25), cyc - cyc[-1]])
        W = 1.0 / rv[u]
        cov = np.linalg.inv(X.T @ (W[:, None] * X))
        beta = cov @ X.T @ (W * z[u])
        np.testing.assert_allclose(x[u], beta, rtol=1e-6)
        np.testing.assert_allclose(P[u], cov, rtol=1e-5)


def test_macro_track_equals_rerunning_every_prefix() -> None:
    rng = np.random.default_rng(1)
    cyc, z, r = _linear_data(rng, 4, 20)
    for st in (MacroSettings(), MacroSettings(q_a_grid=(0.0, 1e-14, 1e-13)),
               MacroSettings(model="quadratic", q_a_grid=(0.0, 1e-18))):
        tr = macro_track(cyc, z, r, st)
        for k in (2, 9, 19):
            s2 = estimate_scatter_var(cyc[: k + 1], z[:, : k + 1], r[:, : k + 1], st)
            lls = []
            xs = []
            for qa in st.q_a_grid or (st.q_a,):
                x, P, ll = macro_filter(cyc[: k + 1], z[:, : k + 1], r[:, : k + 1] + s2[:, None],
                                        st, q_a=qa)
                lls.append(ll)
                xs.append((x, P))
            best = np.argmax(np.stack(lls), axis=0)
            for u in range(4):
                np.testing.assert_allclose(tr.x[k, u], xs[best[u]][0][u], rtol=1e-10)
                np.testing.assert_allclose(tr.P[k, u], xs[best[u]][1][u], rtol=1e-10)


def test_macro_slope_recovery_and_coverage() -> None:
    rng = np.random.default_rng(2)
    cyc, z, r = _linear_data(rng, 200, 58)
    tr = macro_track(cyc, z, r, MacroSettings())
    a = tr.x[-1, :, 1]
    sd = np.sqrt(tr.P[-1, :, 1, 1])
    se_true = 2e-6 / np.sqrt(np.sum((cyc - cyc.mean()) ** 2))
    assert abs(a.mean() - 2e-6) < 4 * se_true / np.sqrt(200)
    assert sd.mean() == pytest.approx(se_true, rel=0.1)
    assert 0.91 <= np.mean(np.abs(a - 2e-6) <= 1.96 * sd) <= 0.985
    # scatter estimate: unbiased for the variance
    assert np.sqrt(tr.scatter_var[-1].mean()) == pytest.approx(2e-6, rel=0.05)


def _assert_predictions_are_the_kalman_filter(x: np.ndarray, P: np.ndarray, F: np.ndarray,
                                              Q: np.ndarray, q: float, cycles: int) -> None:
    """predicted_damping m cycles ahead equals m Kalman predictions with (F, Q), m = 1..cycles."""
    xm, Pm = x, P
    for m in range(1, cycles + 1):
        xm, Pm = kf_predict(xm, Pm, F, Q)
        mu, v = predicted_damping(x, P, np.array([float(m)]), q)
        np.testing.assert_allclose(mu[:, 0], xm[:, 0], rtol=1e-12)
        np.testing.assert_allclose(v[:, 0], Pm[:, 0, 0], rtol=1e-10)


def test_predicted_variance_matches_iterated_kalman_prediction() -> None:
    x = np.array([[5e-5, 2e-6], [6e-5, 1e-6]])
    P = np.array([[[4e-12, -1e-13], [-1e-13, 1e-14]], [[1e-12, 0.0], [0.0, 4e-14]]])
    q_a = 1e-14
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    F, Q = discretise(A, np.diag([0.0, q_a]), 1.0)  # Van Loan oracle for the model's Q
    np.testing.assert_allclose(Q, q_a * np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]]), rtol=1e-12)
    _assert_predictions_are_the_kalman_filter(x, P, F, Q, q_a, cycles=10)


def test_rul_quantiles_covariance_vs_exact_crossing_and_monte_carlo() -> None:
    rng = np.random.default_rng(3)
    x = np.array([[6e-5, 2e-6]])
    P = np.array([[[2e-12, -3e-14], [-3e-14, 4e-15]]])
    c_fail = 1.47e-4
    levels = np.array([0.05, 0.5, 0.95])
    q_cov = rul_covariance_quantiles(x, P, c_fail, levels, step=0.01)[0]
    # exact for q_a = 0: T = (c_fail - c)/a with (c, a) ~ N(x, P)
    d = rng.multivariate_normal(x[0], P[0], 400_000)
    t = (c_fail - d[:, 0]) / d[:, 1]
    t = np.where(d[:, 1] > 0, t, np.inf)
    np.testing.assert_allclose(q_cov, np.quantile(t, levels), rtol=5e-3)
    smp, cen = rul_monte_carlo(x, P, c_fail, rng, n_samples=20_000, horizon=500.0)
    q_mc = np.quantile(np.where(cen[0], np.inf, smp[0]), levels)
    np.testing.assert_allclose(q_mc, q_cov, rtol=0.02)
    # median by hand: (c_fail - c)/a at the mean is the median of the crossing for q_a = 0
    # when mu(m) = c_fail (z_0.5 = 0)
    assert q_cov[1] == pytest.approx((c_fail - 6e-5) / 2e-6, abs=0.02)


def test_rul_interval_coverage_over_units_and_first_crossing() -> None:
    # data from the macro model itself; truth = trend crossing
    rng = np.random.default_rng(4)
    cyc, z, r = _linear_data(rng, 400, 30)
    tr = macro_track(cyc, z, r, MacroSettings())
    c_fail = 1.47e-4
    q = rul_covariance_quantiles(tr.x[-1], tr.P[-1], c_fail, np.array([0.05, 0.95]))
    truth = 68.5 - 30
    cover = np.mean((q[:, 0] <= truth) & (truth <= q[:, 1]))
    assert 0.86 <= cover <= 0.94  # 90 % nominal, binomial sd 1.5 %
    smp, cen = rul_monte_carlo(tr.x[-1, :5], tr.P[-1, :5], c_fail, rng, n_samples=50,
                               scatter_var=tr.scatter_var[-1, :5], t0=30.0)
    assert np.all(smp[~cen] == np.round(smp[~cen]))  # whole cycles for the first crossing


def test_rul_with_slope_noise_is_wider() -> None:
    x = np.array([[6e-5, 2e-6]])
    P = np.array([[[2e-12, 0.0], [0.0, 4e-15]]])
    lv = np.array([0.05, 0.95])
    q0 = rul_covariance_quantiles(x, P, 1.47e-4, lv)[0]
    q1 = rul_covariance_quantiles(x, P, 1.47e-4, lv, q_a=(2e-7) ** 2)[0]
    assert q1[0] < q0[0] and q1[1] > q0[1]
    with pytest.raises(ValueError, match="q_a"):
        MacroSettings(q_a=-1.0)


def test_tiny_experiment_end_to_end(tmp_path) -> None:
    from rulkit.systems.motor_damping.report import write_outputs, write_report
    from rulkit.systems.motor_damping.reproduce import MotorDampingConfig, run

    life = LifeTestConfig(n_cycles=30, duration=15.0)
    cfg = MotorDampingConfig(
        runs=2, life=life, mc_samples=40, variant_runs=1, qa_sweep_sd=(0.0,),
        q_a_grid=(0.0, 1e-14), prediction_cycles=(10, 20, 30), j_prior_sweep_sd=(1e-7,),
    )
    cfg = replace(cfg, micro=MicroEKFSettings())
    res = run(cfg)
    assert set(res.tables) >= {"micro_main", "micro_variants", "slope", "rul_metrics",
                               "qa_sweep", "threshold"}
    assert res.c_fail == pytest.approx(1.47e-4)
    met = res.tables["rul_metrics"]
    assert set(met["scenario"]) >= {"linear", "accelerating", "accelerating-qa-ml"}
    # the macro-law comparison: both laws on both truths; the linear law's rows are the
    # scenarios above (reused, same numbers), the quadratic law's are extra scenarios
    mm = res.tables["macro_models"]
    assert len(mm) == 8
    assert set(zip(mm["truth"], mm["macro_model"], strict=True)) == {
        (t, m) for t in ("linear", "accelerating") for m in ("linear", "quadratic")}
    for truth in ("linear", "accelerating"):
        row = mm[(mm["truth"] == truth) & (mm["macro_model"] == "linear")
                 & (mm["method"] == "covariance")].iloc[0]
        ref = met[(met["scenario"] == truth) & (met["method"] == "covariance")].iloc[0]
        assert row["coverage_90"] == ref["coverage_90"]
        assert res.scenarios[f"{truth}-quadratic-macro"].track.x.shape[-1] == 3
    assert (mm["median_width"] > 0).all()
    # the sweep's row at the default prior is the comparison's quadratic covariance row
    sw = res.tables["macro_j_prior_sweep"]
    assert set(sw["truth"]) == {"linear", "accelerating"}
    for truth in ("linear", "accelerating"):
        a = sw[sw["truth"] == truth].iloc[0]
        b = mm[(mm["truth"] == truth) & (mm["macro_model"] == "quadratic")
               & (mm["method"] == "covariance")].iloc[0]
        assert a["coverage_90"] == b["coverage_90"]
    paths = write_outputs(res, tmp_path, "test")
    names = {p.name for p in paths}
    assert "report.md" in names and "fig17_rul.png" in names
    assert "fig_macro_models_rul.png" in names
    text = (tmp_path / "report.md").read_text()
    assert "2.67e-6" in text and "0.000147" in text
    assert write_report(res, tmp_path / "again", "test") == tmp_path / "again" / "report.md"
    assert (tmp_path / "again" / "report.md").read_text() == text


def test_runs_reproducible_from_seed_and_independent_of_chunking() -> None:
    from rulkit.systems.motor_damping.reproduce import _simulate_and_estimate

    life = LifeTestConfig(n_cycles=4, duration=5.0)
    a = _simulate_and_estimate(life, 3, 5, MicroEKFSettings(), chunk=3)
    b = _simulate_and_estimate(life, 3, 5, MicroEKFSettings(), chunk=1)
    c = _simulate_and_estimate(life, 3, 6, MicroEKFSettings(), chunk=3)
    np.testing.assert_allclose(a[1], b[1], rtol=1e-12)
    np.testing.assert_array_equal(a[3], b[3])
    assert not np.allclose(a[1], c[1], rtol=1e-6)


@pytest.mark.parametrize("missing", [False, True])
def test_micro_ekf_matches_engine_extended_kalman_filter(life, missing) -> None:
    """Oracle: the engine's EKF class with finite-difference Jacobians on the same model; with
    ``missing``, NaN measurements inside a cycle are skipped by both (not NaN-poisoned)."""
    from rulkit.estimation.ekf import ExtendedKalmanFilter
    from rulkit.systems.motor_damping.motor import measurement, rk4_step_with_jacobian

    consts = life.config.consts
    s = MicroEKFSettings()
    sl = slice(60, 63)
    cur, sp, acc = life.current[sl], life.speed[sl].copy(), life.acceleration[sl].copy()
    if missing:
        sp[0, 100] = np.nan
        acc[1, 200:205] = np.nan
        sp[2, -1] = np.nan
    dt = life.config.dt
    ekf = ExtendedKalmanFilter(
        lambda x, u, k: rk4_step_with_jacobian(x, u[:, 0], u[:, 1], dt, consts)[0],
        lambda x, u, k: measurement(x, u[:, 1], consts)[0],
        np.diag([s.q_w, s.q_c]), np.diag([s.sigma_w**2, s.sigma_dw**2]),
    )
    ys = np.stack([sp[:, 1:], acc[:, 1:]], axis=2).transpose(1, 0, 2)  # (T-1, B, 2)
    us = np.stack([cur[:, :-1], cur[:, 1:]], axis=2).transpose(1, 0, 2)
    x0 = np.column_stack([sp[:, 0], np.full(3, s.c_prior)])
    P0 = np.diag([s.sigma_w**2, s.c_prior_sd**2])
    ref = ekf.filter(ys, x0, np.broadcast_to(P0, (3, 2, 2)), us=us)
    ours = micro_ekf(life.time, cur, sp, acc, consts, s)
    np.testing.assert_allclose(ours.c, ref.x[-1, :, 1], rtol=1e-6)
    np.testing.assert_allclose(ours.c_var, ref.P[-1, :, 1, 1], rtol=1e-3)
    np.testing.assert_allclose(ours.mean_nis, np.nanmean(ref.nis, axis=0), rtol=1e-4)
    assert ref.skipped.sum() == (7 if missing else 0)


def test_micro_ekf_refuses_input_that_would_poison_the_state(life) -> None:
    consts = life.config.consts
    t = np.tile(life.time, (2, 1))
    cur, sp, acc = life.current[:2].copy(), life.speed[:2].copy(), life.acceleration[:2].copy()

    clean = {"t": t, "current": cur, "speed": sp, "acceleration": acc}

    def refused(name: str, unit: int, k: int, value: float, message: str) -> None:
        """micro_ekf with one cell of input ``name`` set to ``value`` raises ``message``."""
        args = {key: a.copy() for key, a in clean.items()}
        args[name][unit, k] = value
        with pytest.raises(ValueError, match=message):
            micro_ekf(args["t"], args["current"], args["speed"], args["acceleration"], consts)

    refused("t", 1, 50, t[1, 49], r"unit 1 does not increase at sample 50")
    refused("t", 0, 10, np.nan, r"unit 0 is valid again at sample 11")
    refused("current", 1, 7, np.nan, r"current of unit 1 is nan at sample 7")
    refused("acceleration", 0, 3, np.inf, r"acceleration of unit 0 is infinite at sample 3")
    refused("speed", 1, 0, np.nan, r"speed of unit 1 is nan at sample 0")


def test_macro_refuses_unsorted_or_repeated_cycles_and_bad_estimates() -> None:
    cyc, z, r = _linear_data(np.random.default_rng(0), 2, 6)
    s = MacroSettings()
    for bad in (cyc[[0, 2, 1, 3, 4, 5]], np.r_[cyc[:3], cyc[2:5]], cyc - 2.0):
        with pytest.raises(ValueError, match="strictly increasing"):
            macro_track(bad, z, r, s)
        with pytest.raises(ValueError, match="strictly increasing"):
            macro_filter(bad, z, r, s)
    z_nan = z.copy()
    z_nan[1, 3] = np.nan
    with pytest.raises(ValueError, match="z: non-finite value at unit 1, cycle 4"):
        macro_track(cyc, z_nan, r, s)
    r_neg = r.copy()
    r_neg[0, 2] = -1e-18
    with pytest.raises(ValueError, match=r"negative variance .* at unit 0, cycle 3"):
        macro_filter(cyc, z, r_neg, s)


# ---------------------------------------------------------------------------------------------
# quadratic (constant-acceleration) macro law
# ---------------------------------------------------------------------------------------------


def _accel_data(rng, b: int, n: int, c0=1e-5, a=2e-6, bq=2e-8, s=0.0, r=1e-20):
    # c(n) = c0 + a n + bq n^2: curvature j = dc^2/dn^2 = 2 bq
    cyc = np.arange(1.0, n + 1)
    z = c0 + a * cyc + bq * cyc**2 + np.sqrt(s * s + r) * rng.standard_normal((b, n))
    return cyc, z, np.full((b, n), r)


def test_quadratic_macro_filter_equals_weighted_least_squares_quadratic_fit() -> None:
    rng = np.random.default_rng(20)
    cyc, z, _ = _accel_data(rng, 3, 30, s=1e-9)
    rv = rng.uniform(0.5e-18, 2e-18, (3, 30))
    # diffuse against the data: the prior's information is < 1e-6 of the data's
    st = MacroSettings(model="quadratic", c_prior_sd=1e-3, a_prior_sd=1e-4, j_prior_sd=1e-5)
    x, P, _ = macro_filter(cyc, z, rv, st)
    assert x.shape == (3, 3) and P.shape == (3, 3, 3)
    for u in range(3):
        # oracle: WLS fit c_N + a_N (n - N) + j (n - N)^2 / 2 -> state at the last cycle N
        d = cyc - cyc[-1]
        X = np.column_stack([np.ones(30), d, 0.5 * d * d])
        W = 1.0 / rv[u]
        cov = np.linalg.inv(X.T @ (W[:, None] * X))
        beta = cov @ X.T @ (W * z[u])
        np.testing.assert_allclose(x[u], beta, rtol=1e-5)
        np.testing.assert_allclose(P[u], cov, rtol=1e-3)
        # and the fit recovers the true curvature 2 bq = 4e-8 and the slope at cycle 30
        assert x[u, 2] == pytest.approx(4e-8, abs=5 * np.sqrt(cov[2, 2]))
        assert x[u, 1] == pytest.approx(2e-6 + 4e-8 * 30, abs=5 * np.sqrt(cov[1, 1]))
    # noise-free data: exact to rounding with the default (informative) priors as well
    cyc, z, r = _accel_data(rng, 2, 40)
    tr = macro_track(cyc, z, r, MacroSettings(model="quadratic"))
    np.testing.assert_allclose(tr.x[-1, :, 2], 4e-8, rtol=1e-4)
    np.testing.assert_allclose(tr.x[-1, :, 0], 1e-5 + 2e-6 * 40 + 2e-8 * 1600, rtol=1e-6)
    assert np.all(tr.scatter_var[-1] < 1e-18)  # quadratic residuals vanish
    # the linear law on the same data: slope biased, scatter inflated by the curvature
    tl = macro_track(cyc, z, r, MacroSettings())
    assert np.all(np.sqrt(tl.scatter_var[-1]) > 1e-6)


def test_quadratic_with_zero_curvature_prior_is_the_linear_filter() -> None:
    rng = np.random.default_rng(21)
    cyc, z, r = _linear_data(rng, 4, 25)
    rv = r + 4e-12
    lin = macro_filter(cyc, z, rv, MacroSettings())
    quad = macro_filter(cyc, z, rv, MacroSettings(model="quadratic", j_prior_sd=0.0))
    np.testing.assert_allclose(quad[0][:, :2], lin[0], rtol=1e-9)
    np.testing.assert_allclose(quad[1][:, :2, :2], lin[1], rtol=1e-9, atol=1e-30)
    np.testing.assert_allclose(quad[0][:, 2], 0.0, atol=1e-30)
    np.testing.assert_allclose(quad[2], lin[2], rtol=1e-12)
    # predictions and RUL quantiles agree as well
    lv = np.array([0.05, 0.5, 0.95])
    np.testing.assert_allclose(
        rul_covariance_quantiles(quad[0], quad[1], 1.47e-4, lv),
        rul_covariance_quantiles(lin[0], lin[1], 1.47e-4, lv), rtol=1e-9,
    )
    with pytest.raises(ValueError, match="model"):
        MacroSettings(model="cubic")
    with pytest.raises(ValueError, match="j_prior_sd"):
        MacroSettings(model="quadratic", j_prior_sd=-1.0)


def test_quadratic_predicted_variance_matches_iterated_kalman_prediction() -> None:
    x = np.array([[5e-5, 2e-6, 4e-8], [6e-5, 1e-6, -1e-8]])
    P = np.array([
        [[4e-12, -1e-13, 1e-15], [-1e-13, 1e-14, -2e-16], [1e-15, -2e-16, 1e-17]],
        [[1e-12, 0.0, 0.0], [0.0, 4e-14, 0.0], [0.0, 0.0, 4e-18]],
    ])
    q = 1e-18
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    F, Q = discretise(A, np.diag([0.0, 0.0, q]), 1.0)  # Van Loan oracle for F and Q
    from rulkit.systems.motor_damping.macro import _transition

    F_m, Q_m = _transition(1.0, q, 3)
    np.testing.assert_allclose(F_m, F, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(Q_m, Q, rtol=1e-10)
    _assert_predictions_are_the_kalman_filter(x, P, F, Q, q, cycles=12)


def test_quadratic_crossing_against_hand_computed_roots() -> None:
    import math

    from rulkit.systems.motor_damping.macro import quadratic_crossing

    cf = 1.47e-4
    # 1e-4 + 2e-6 m + 2e-8 m^2 = 1.47e-4  <=>  2 m^2 + 200 m - 4700 = 0 (units of 1e-8)
    assert quadratic_crossing(1e-4, 2e-6, 4e-8, cf) == pytest.approx(
        (-200 + math.sqrt(200**2 + 8 * 4700)) / 4, rel=1e-12)  # 19.6419...
    # decelerating but still crossing: -1 m^2 + 200 m - 4700 = 0, smaller root
    assert quadratic_crossing(1e-4, 2e-6, -2e-8, cf) == pytest.approx(
        (200 - math.sqrt(200**2 - 4 * 4700)) / 2, rel=1e-12)  # 27.198...
    # linear law, already failed, never crossing (maximum below c_fail; falling trend)
    assert quadratic_crossing(1e-4, 2e-6, 0.0, cf) == pytest.approx(23.5, rel=1e-12)
    assert quadratic_crossing(1.5e-4, 2e-6, 4e-8, cf) == 0.0
    assert quadratic_crossing(1e-4, 2e-6, -1e-7, cf) == np.inf  # max 1.2e-4 at m = 20
    assert quadratic_crossing(1e-4, -1e-6, 0.0, cf) == np.inf
    # j > 0 rescues a falling trend: 5 m^2 - 100 m - 4700 = 0
    assert quadratic_crossing(1e-4, -1e-6, 1e-7, cf) == pytest.approx(
        (100 + math.sqrt(100**2 + 20 * 4700)) / 10, rel=1e-12)
    # tiny curvature: no cancellation (the textbook form loses all digits here)
    assert quadratic_crossing(1e-4, 2e-6, 1e-20, cf) == pytest.approx(23.5, rel=1e-9)


def test_quadratic_rul_covariance_and_monte_carlo_vs_analytic_crossing() -> None:
    from rulkit.systems.motor_damping.macro import quadratic_crossing

    rng = np.random.default_rng(22)
    x = np.array([[8e-5, 2.5e-6, 4e-8]])
    P = np.diag([1e-12, 1e-14, 1e-17])[None]
    cf = 1.47e-4
    lv = np.array([0.05, 0.5, 0.95])
    # oracle: crossing of each drawn trend, by the analytic root
    d = rng.multivariate_normal(x[0], P[0], 200_000)
    t = quadratic_crossing(d[:, 0], d[:, 1], d[:, 2], cf)
    exact = np.quantile(t, lv)
    q_cov = rul_covariance_quantiles(x, P, cf, lv, step=0.01)[0]
    # the trend is increasing over the range (P(j < 0) ~ 0): the band crossing is exact
    np.testing.assert_allclose(q_cov, exact, rtol=5e-3)
    smp, cen = rul_monte_carlo(x, P, cf, rng, n_samples=20_000, horizon=300.0)
    q_mc = np.quantile(np.where(cen[0], np.inf, smp[0]), lv)
    # within-cycle linear interpolation of a convex trend: < 0.01 cycle early
    np.testing.assert_allclose(q_mc, exact, rtol=0.01)
    # median at the mean trend's crossing
    assert q_cov[1] == pytest.approx(quadratic_crossing(8e-5, 2.5e-6, 4e-8, cf), abs=0.05)
    # a (nearly) known state: every Monte Carlo path is the mean trend, crossing at the root
    # (linear interpolation within the crossing cycle: j / (8 a') ~ 0.002 cycle early)
    P0 = P * 1e-8
    smp0, _ = rul_monte_carlo(x, P0, cf, rng, n_samples=200, horizon=300.0)
    np.testing.assert_allclose(smp0[0], quadratic_crossing(8e-5, 2.5e-6, 4e-8, cf), atol=0.005)
    # process noise on the curvature alone: Monte Carlo spread = covariance quantiles
    q_cov_n = rul_covariance_quantiles(x, P0, cf, lv, q_a=1e-17, step=0.01)[0]
    smp_n, cen_n = rul_monte_carlo(x, P0, cf, rng, n_samples=20_000, q_a=1e-17, horizon=300.0)
    q_mc_n = np.quantile(np.where(cen_n[0], np.inf, smp_n[0]), lv)
    np.testing.assert_allclose(q_mc_n, q_cov_n, rtol=0.005)
    np.testing.assert_allclose(q_mc_n[2] - q_mc_n[0], q_cov_n[2] - q_cov_n[0], rtol=0.03)
    assert q_cov_n[2] - q_cov_n[0] > 1.5  # cycles: the noise matters at this q
    # first-crossing truth: whole cycles, later than or equal to the trend's crossing on
    # average minus the scatter's head start (scatter can only bring the first crossing on)
    smp_f, cen_f = rul_monte_carlo(x, P0, cf, rng, n_samples=2000, horizon=300.0,
                                   scatter_var=np.array([(2e-6) ** 2]), t0=10.0)
    assert not cen_f.any() and np.all(smp_f == np.round(smp_f))
    assert np.median(smp_f) <= np.ceil(q_cov[1]) and np.median(smp_f) >= q_cov[1] - 3


def test_study_for_another_motor_keeps_the_crossing_cycle() -> None:
    from rulkit.systems.motor_damping.micro import micro_ekf
    from rulkit.systems.motor_damping.motor import (
        LifeTestConfig,
        MotorConstants,
        failure_damping,
        simulate_life_test,
    )
    from rulkit.systems.motor_damping.report import _motor_lines
    from rulkit.systems.motor_damping.reproduce import MotorDampingConfig, study_for_motor

    other = MotorConstants(K=0.05, J=4e-3, T_L=2e-3)
    kw = study_for_motor(other, LifeTestConfig(n_cycles=12, duration=20.0))
    ratio = failure_damping(other) / failure_damping(MotorConstants())
    assert kw["life"].slope == pytest.approx(2e-6 * ratio) and kw["life"].consts == other
    lt = simulate_life_test(kw["life"], np.random.default_rng(0))
    assert lt.c_fail == pytest.approx(failure_damping(other))
    assert lt.eol == pytest.approx(68.5)  # the synthetic motor's crossing cycle
    est = micro_ekf(lt.time, lt.current, lt.speed, lt.acceleration, other)
    assert np.all(np.abs(est.c - lt.damping) < 5 * np.sqrt(est.c_var) + 1e-9)
    cfg = MotorDampingConfig.quick(**kw)
    assert "not the synthetic one" in _motor_lines(cfg)[0]
    assert _motor_lines(MotorDampingConfig.quick()) == []
