"""Rao-Blackwellised PF for step 1 of the reaction wheel (spec rw-lubrication.md section 3,
beyond the seeds): compiled kernel equals the numpy reference; with T known each particle's
Kalman filter is the engine's EKF on [I, w] (finite-difference Jacobians); posterior vs the EKF
on [I, w, T] in the nearly linear regime; calibration of the 90 % interval on data drawn from
the filter's own model; Table 5 / telemetry entry points."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rulkit.estimation.ekf import ExtendedKalmanFilter
from rulkit.systems.reaction_wheel.telemetry import table3_telemetry
from rulkit.systems.reaction_wheel.temperature.ekf import run_ekf
from rulkit.systems.reaction_wheel.temperature.estimator import estimate_temperature
from rulkit.systems.reaction_wheel.temperature.rbpf import RBPF_DESIGNS, RBPFConfig, run_rbpf
from rulkit.systems.reaction_wheel.temperature.study import format_table5, run_table5
from rulkit.systems.reaction_wheel.wheel import IthacoParams, rk4_wheel_step, simulate_table3


@pytest.fixture(scope="module")
def short_run():
    return simulate_table3(np.random.default_rng(21), "low", t_end=20.0)


def _model_draw(rng: np.random.Generator, M: int, K: int, q_T: float,
                sigma: tuple[float, float]):
    """M truths drawn from the filter's own model: T_0 ~ U(15, 45), Gaussian random walk,
    wheel from rest at 1 V, measurement noise (the posterior is calibrated by construction)."""
    p = IthacoParams()
    T = rng.uniform(15.0, 45.0, M)[:, None] + np.concatenate(
        [np.zeros((M, 1)), np.cumsum(q_T * rng.standard_normal((M, K - 1)), axis=1)], axis=1)
    x = np.zeros((M, K, 2))
    for k in range(1, K):  # batched over the M runs
        x[:, k] = rk4_wheel_step(x[:, k - 1], 1.0, T[:, k], (k - 1) * 0.05, 0.05, p)
    y = x[:, :, ::-1] + rng.standard_normal((M, K, 2)) * np.array(sigma)
    return y, np.ones(K), T


@pytest.mark.parametrize(("p_jump", "propose"), [(0.0, 0.0), (0.02, 0.0), (1e-3, 0.05)])
def test_kernel_equals_numpy_reference(short_run, p_jump: float, propose: float) -> None:
    """Same seed -> same numbers from the numba kernel and the numpy path (which uses the
    model's rk4_wheel_step / rk4_wheel_step_jacobian and the engine's systematic resampler),
    also with the reweighted jump proposal."""
    cfg = RBPFConfig(n_particles=40, p_jump=p_jump, jump_sd=2.0, jump_propose=propose)
    y, V = short_run.y[:300], short_run.V[:300]
    a = run_rbpf(y, V, np.random.default_rng(5), cfg)
    b = run_rbpf(y, V, np.random.default_rng(5), cfg, backend="numpy")
    assert a.action.sum() > 3  # resampling exercised
    np.testing.assert_allclose(a.T_mean, b.T_mean, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.T_std, b.T_std, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.T_lo, b.T_lo, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.T_hi, b.T_hi, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.Iw_mean, b.Iw_mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.loglik, b.loglik, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(a.ess, b.ess, rtol=1e-9)
    assert np.array_equal(a.action, b.action)


def test_known_temperature_particle_kf_equals_engine_ekf(short_run) -> None:
    """With the temperature path given, every particle runs the same Kalman filter on [I, w]:
    its mean and innovation log-likelihood equal those of the engine's ExtendedKalmanFilter with
    T as an input and central finite-difference Jacobians (an independent linearisation)."""
    d = short_run
    K = 200
    y, V, T = d.y[:K], d.V[:K], d.T[:K] + 1.5  # a wrong-but-known T: innovations are not tiny
    q = (1e-4, 1e-4)
    cfg = RBPFConfig(n_particles=3, q_I=q[0], q_w=q[1])
    r = run_rbpf(y, V, np.random.default_rng(0), cfg, backend="numpy", T_path=T)
    p = IthacoParams()

    def f(x, u, j):
        return rk4_wheel_step(x, u, T[j + 1], j * d.dt, d.dt, p)

    def h(x, u, j):
        return x[:, ::-1]

    R = np.diag([d.sigma_w**2, d.sigma_I**2])  # output order [w, I]
    ekf = ExtendedKalmanFilter(f, h, np.diag(np.square(q)), R)
    x0 = np.array([[y[0, 1], y[0, 0]]])
    P0 = np.diag([d.sigma_I**2, d.sigma_w**2])[None]
    res = ekf.filter(y[1:, None, :], x0, P0, us=V[:-1])
    np.testing.assert_allclose(r.Iw_mean[1:], res.x[:, 0, :], rtol=0, atol=1e-9)
    np.testing.assert_allclose(r.loglik[1:], res.loglik_increments[:, 0], rtol=1e-7, atol=1e-7)


def test_posterior_matches_ekf_in_nearly_linear_regime() -> None:
    """From equilibrium at constant 23 C the model is nearly linear-Gaussian: after 30 s the
    RBPF's posterior mean and sd of T agree with the EKF on [I, w, T] (same q_T and prior)."""
    d = simulate_table3(np.random.default_rng(3), "low", t_end=45.0, initial="equilibrium")
    r = run_rbpf(d.y, d.V, np.random.default_rng(4), RBPFConfig(n_particles=400))
    e = run_ekf(d.y, d.V, sigma=(d.sigma_w, d.sigma_I), dt=d.dt)
    late = d.t >= 30.0
    m_e, s_e = e.T_mean[late, 0], e.T_std[late, 0]
    assert np.max(np.abs(r.T_mean[late] - m_e)) < 0.5 * np.mean(s_e)
    ratio = np.mean(r.T_std[late]) / np.mean(s_e)
    assert 0.7 < ratio < 1.4, ratio


def test_interval_coverage_on_data_from_the_model() -> None:
    """Over 60 seeded runs drawn from the model, the 90 % interval holds the true final T in
    46..60 of them (binomial(60, 0.9): mean 54, sd 2.3) and the errors are unbiased."""
    sigma = (3e-3, 3e-2)
    rng = np.random.default_rng(77)
    ys, V, Ts = _model_draw(rng, 60, 400, 0.02, sigma)
    hits, errs = 0, []
    for y, T in zip(ys, Ts, strict=True):
        r = run_rbpf(y, V, rng, RBPFConfig(n_particles=300), sigma=sigma)
        hits += int(r.T_lo[-1] <= T[-1] <= r.T_hi[-1])
        errs.append((r.T_mean[-1] - T[-1]) / r.T_std[-1])
    assert 46 <= hits <= 60, hits
    assert abs(np.mean(errs)) < 3.5 / math.sqrt(60), np.mean(errs)


def test_bad_input_is_refused(short_run) -> None:
    y, V = short_run.y[:50], short_run.V[:50]
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="n_particles"):
        RBPFConfig(n_particles=1)
    with pytest.raises(ValueError, match="p_jump"):
        RBPFConfig(p_jump=1.0)
    with pytest.raises(ValueError, match="q_w"):
        RBPFConfig(q_w=-1.0)
    with pytest.raises(ValueError, match="y: expected shape"):
        run_rbpf(y[:, :1], V, rng)
    with pytest.raises(ValueError, match="V: expected shape"):
        run_rbpf(y, V[:-1], rng)
    bad = y.copy()
    bad[7, 0] = np.nan
    with pytest.raises(ValueError, match="row 7"):
        run_rbpf(bad, V, rng)
    with pytest.raises(ValueError, match="sigma"):
        run_rbpf(y, V, rng, sigma=(0.0, 1.0))
    with pytest.raises(ValueError, match="backend"):
        run_rbpf(y, V, rng, backend="cuda")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="T_path"):
        run_rbpf(y, V, rng, T_path=np.ones(3), backend="numpy")


def test_table5_rows_and_telemetry_entry_point() -> None:
    """The RBPF designs appear as Table 5 rows (method "rbpf") with coverage columns, and
    through estimate_temperature(method="rbpf")."""
    df = run_table5(runs=1, designs=("RB05",), n_particles=(30,), coverage=True, ekf=False)
    rb = df[df["method"] == "rbpf"]
    assert set(rb["noise"]) == {"low", "high"} and set(rb["design"]) == {"RB05"}
    assert np.all((df["cover_mean"] >= 0) & (df["cover_mean"] <= 1))
    assert "rbpf" in format_table5(df) and "coverage" in format_table5(df, "cover_late_mean")
    with pytest.raises(ValueError, match="not a known"):
        run_table5(runs=1, methods=[("rbpf", "F2")], n_particles=(30,), ekf=False)
    tel = table3_telemetry(np.random.default_rng(1), "low", t_end=10.0)
    out = estimate_temperature(tel, "rbpf", n_particles=30, rng=np.random.default_rng(2),
                               level=0.9)
    assert list(out.columns) == ["time_s", "T_mean", "T_lo", "T_hi", "untrusted", "flags"]
    assert "not calibrated" in out.attrs["note"]
    assert np.all(out["T_lo"] <= out["T_hi"])
    with pytest.raises(ValueError, match="design"):
        estimate_temperature(tel, "rbpf", rng=np.random.default_rng(2), design="F1")
    assert set(RBPF_DESIGNS) >= {"RB", "RB05", "RBJ", "RBJ0"}


def test_plot_includes_rbpf_variant(tmp_path) -> None:
    from rulkit.systems.reaction_wheel.temperature.study import plot_temperature_estimates

    paths = plot_temperature_estimates(tmp_path, n_particles=30, variants=("rbpf",),
                                       with_ekf=False, t_end=5.0)
    assert paths[0].name == "rw_step1_rbpf_RBJ.png" and paths[0].stat().st_size > 10_000


def test_jump_proposal_reweighting_targets_the_prior_model(short_run) -> None:
    """Proposing jumps 20x more often than the prior and reweighting gives the same posterior
    as proposing from the prior (N = 2000, within Monte-Carlo error); without the reweighting
    (a prior with that jump rate) the posterior is visibly wider: the check has power."""
    from rulkit.systems.reaction_wheel.temperature.rbpf import _log_mix

    d = np.linspace(-12, 12, 101)
    from scipy.stats import norm

    ref = np.log(0.01 * norm.pdf(d, scale=5.0) + 0.99 * norm.pdf(d, scale=0.02))
    np.testing.assert_allclose(_log_mix(d, 0.01, 5.0, 0.02), ref, rtol=1e-12)
    y, V = short_run.y[:300], short_run.V[:300]
    base = {"n_particles": 2000, "q_T": 0.02, "jump_sd": 2.0}
    a = run_rbpf(y, V, np.random.default_rng(1), RBPFConfig(p_jump=0.01, **base))
    b = run_rbpf(y, V, np.random.default_rng(2),
                 RBPFConfig(p_jump=0.01, jump_propose=0.2, **base))
    c = run_rbpf(y, V, np.random.default_rng(3), RBPFConfig(p_jump=0.2, **base))
    tail = slice(200, 300)
    sa, sb, sc = (float(np.mean(r.T_std[tail])) for r in (a, b, c))
    assert np.max(np.abs(a.T_mean[tail] - b.T_mean[tail])) < 0.25 * sa
    assert 0.8 < sb / sa < 1.25, (sa, sb)
    assert sc / sa > 1.5, (sa, sc)
