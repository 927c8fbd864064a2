"""Kalman family against independent oracles: brute-force Gaussian conditioning on the whole
trajectory, scipy.linalg.solve_discrete_are, scipy.linalg.expm / quadrature, finite differences,
chi-square statistics of the NIS, and the KF itself for EKF/UKF on linear models."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import quad_vec
from scipy.stats import multivariate_normal

from rulkit.estimation.ekf import ExtendedKalmanFilter
from rulkit.estimation.kalman import (
    KalmanFilter,
    discretise,
    kf_predict,
    kf_update,
    numerical_jacobian,
)
from rulkit.estimation.ukf import UnscentedKalmanFilter

DT = 0.5
F_CV = np.array([[1.0, DT], [0.0, 1.0]])
Q_CV = 0.3 * np.array([[DT**3 / 3, DT**2 / 2], [DT**2 / 2, DT]])
H_2 = np.array([[1.0, 0.0], [0.5, 1.0]])
R_2 = np.array([[0.4, 0.1], [0.1, 0.3]])


def simulate(rng, F, H, Q, R, x0, P0, T):
    """Sample one trajectory per unit (B = len(x0)) of the linear-Gaussian model."""
    B, n = x0.shape
    m = R.shape[0]
    x = x0 + rng.multivariate_normal(np.zeros(n), P0, size=B)
    ys = np.empty((T, B, m))
    for k in range(T):
        x = x @ F.T + rng.multivariate_normal(np.zeros(n), Q, size=B)
        ys[k] = x @ H.T + rng.multivariate_normal(np.zeros(m), R, size=B)
    return ys


def brute_force(Fs, Hs, Qs, Rs, m0, P0, ys, upto, bus=None):
    """Posterior of x_upto given the observed y_1..y_upto (one unit) by conditioning the joint
    Gaussian of (x_1..x_T, y_1..y_T) directly; NaN measurements are dropped. Also returns the
    log marginal likelihood of the observed measurements up to ``upto``.
    Time-varying lists Fs[k], Hs[k], Qs[k], Rs[k] (k = 0..T-1); bus[k] known input terms."""
    T = upto
    n = m0.shape[0]
    mus, Sig = [], []
    mu, S = m0, P0
    for k in range(T):
        mu = Fs[k] @ mu + (0.0 if bus is None else bus[k])
        S = Fs[k] @ S @ Fs[k].T + Qs[k]
        mus.append(mu)
        Sig.append(S)
    # Cov(x_j, x_i) for i <= j = Phi(j, i) Sig_i
    C = np.zeros((T * n, T * n))
    for i in range(T):
        block = Sig[i]
        for j in range(i, T):
            if j > i:
                block = Fs[j] @ block
            C[j * n : (j + 1) * n, i * n : (i + 1) * n] = block
            C[i * n : (i + 1) * n, j * n : (j + 1) * n] = block.T
    obs_rows, y_obs, y_mean, Hbig_rows = [], [], [], []
    for k in range(T):
        if np.any(np.isnan(ys[k])):
            continue
        Hk = np.zeros((Hs[k].shape[0], T * n))
        Hk[:, k * n : (k + 1) * n] = Hs[k]
        Hbig_rows.append(Hk)
        obs_rows.append(Rs[k])
        y_obs.append(ys[k])
        y_mean.append(Hs[k] @ mus[k])
    Hbig = np.vstack(Hbig_rows)
    Rbig = scipy.linalg.block_diag(*obs_rows)
    Cyy = Hbig @ C @ Hbig.T + Rbig
    Cxy = C[(T - 1) * n :, :] @ Hbig.T
    yv, ym = np.concatenate(y_obs), np.concatenate(y_mean)
    mean = mus[-1] + Cxy @ np.linalg.solve(Cyy, yv - ym)
    cov = Sig[-1] - Cxy @ np.linalg.solve(Cyy, Cxy.T)
    loglik = multivariate_normal(ym, Cyy).logpdf(yv)
    return mean, cov, loglik


def test_kf_equals_brute_force_conditioning_and_likelihood():
    rng = np.random.default_rng(1)
    T = 12
    x0 = np.array([[0.5, -0.2]])
    P0 = np.array([[1.0, 0.2], [0.2, 0.5]])
    ys = simulate(rng, F_CV, H_2, Q_CV, R_2, x0, P0, T)
    res = KalmanFilter(F_CV, H_2, Q_CV, R_2).filter(ys, x0, P0)
    for upto in (1, 5, T):
        mean, cov, ll = brute_force(
            [F_CV] * T, [H_2] * T, [Q_CV] * T, [R_2] * T, x0[0], P0, ys[:, 0], upto
        )
        np.testing.assert_allclose(res.x[upto - 1, 0], mean, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(res.P[upto - 1, 0], cov, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(res.loglik_increments[:upto, 0].sum(), ll, rtol=1e-10)
    np.testing.assert_allclose(res.loglik, res.loglik_increments.sum(axis=0))


def test_time_varying_callables_and_nan_skip_against_brute_force():
    rng = np.random.default_rng(2)
    T = 10
    Hs = [np.array([[1.0, 0.0]]) if k % 2 == 0 else np.array([[0.0, 1.0]]) for k in range(T)]
    Fs = [np.array([[1.0, DT * (1 + 0.1 * k)], [0.0, 0.95]]) for k in range(T)]
    Rs = [np.array([[0.2 + 0.05 * k]]) for k in range(T)]
    x0 = np.array([[1.0, 0.5], [0.0, 0.0]])
    P0 = np.eye(2)
    ys = rng.normal(size=(T, 2, 1))
    ys[3, 0, 0] = np.nan
    ys[7, 0, 0] = np.nan
    kf = KalmanFilter(lambda k: Fs[k], lambda k: Hs[k], Q_CV, lambda k: Rs[k])
    res = kf.filter(ys, x0, P0)
    assert res.skipped[3, 0] and res.skipped[7, 0] and not res.skipped[:, 1].any()
    assert np.isnan(res.nis[3, 0]) and np.isnan(res.innovations[3, 0]).all()
    assert res.loglik_increments[3, 0] == 0.0
    np.testing.assert_array_equal(res.x[3, 0], res.x_pred[3, 0])
    np.testing.assert_array_equal(res.P[3, 0], res.P_pred[3, 0])
    for b in range(2):
        for upto in (4, T):
            mean, cov, ll = brute_force(Fs, Hs, [Q_CV] * T, Rs, x0[b], P0, ys[:, b], upto)
            np.testing.assert_allclose(res.x[upto - 1, b], mean, rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(res.P[upto - 1, b], cov, rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(res.loglik_increments[:upto, b].sum(), ll, rtol=1e-10)


def test_steady_state_covariance_matches_solve_discrete_are():
    H = np.array([[1.0, 0.0]])
    R = np.array([[0.25]])
    ys = np.zeros((400, 1, 1))
    res = KalmanFilter(F_CV, H, Q_CV, R).filter(ys, np.zeros((1, 2)), 10.0 * np.eye(2))
    P_pred = scipy.linalg.solve_discrete_are(F_CV.T, H.T, Q_CV, R)
    np.testing.assert_allclose(res.P_pred[-1, 0], P_pred, rtol=1e-10)
    S = H @ P_pred @ H.T + R
    P_filt = P_pred - P_pred @ H.T @ np.linalg.solve(S, H @ P_pred)
    np.testing.assert_allclose(res.P[-1, 0], P_filt, rtol=1e-10)


def test_nis_is_chi_square_with_m_dof_on_model_data():
    rng = np.random.default_rng(3)
    B, T = 1000, 40
    x0 = np.zeros((B, 2))
    P0 = np.eye(2)
    ys = simulate(rng, F_CV, H_2, Q_CV, R_2, x0, P0, T)
    res = KalmanFilter(F_CV, H_2, Q_CV, R_2).filter(ys, x0, P0)
    nis = res.nis.ravel()
    m = 2
    # mean m, variance 2m; the innovations of a correct filter are independent
    assert abs(nis.mean() - m) < 4 * np.sqrt(2 * m / nis.size)
    assert abs(nis.var() - 2 * m) < 0.15 * 2 * m
    # one step's loglik against scipy's Gaussian density
    k, b = 5, 17
    ref = multivariate_normal(np.zeros(m), res.S[k, b]).logpdf(res.innovations[k, b])
    np.testing.assert_allclose(res.loglik_increments[k, b], ref, rtol=1e-12)


def test_batch_of_units_equals_separate_runs():
    rng = np.random.default_rng(4)
    B, T = 4, 15
    Fb = np.stack([F_CV * s for s in (1.0, 0.9, 1.05, 0.8)])
    Qb = np.stack([Q_CV * s for s in (1.0, 2.0, 0.5, 3.0)])
    Rb = np.stack([R_2 * s for s in (1.0, 0.2, 5.0, 1.5)])
    x0 = rng.normal(size=(B, 2))
    P0 = np.stack([np.eye(2) * s for s in (1.0, 2.0, 0.1, 4.0)])
    ys = rng.normal(size=(T, B, 2))
    ys[5, 2] = np.nan
    res = KalmanFilter(Fb, H_2, Qb, Rb).filter(ys, x0, P0)
    for b in range(B):
        one = KalmanFilter(Fb[b], H_2, Qb[b], Rb[b]).filter(ys[:, b : b + 1], x0[b : b + 1], P0[b])
        for name in ("x", "P", "nis", "loglik_increments", "S"):
            np.testing.assert_allclose(
                getattr(res, name)[:, b], getattr(one, name)[:, 0], rtol=1e-12, atol=1e-14
            )


def linear_fns(F, H):
    return (lambda x, u, k: x @ F.T), (lambda x, u, k: x @ H.T)


def _assert_same_filter(res, ref, tol):
    """Agreement relative to the scale of each quantity (x and innovations share x's scale)."""
    sx = np.abs(ref.x).max()
    sp = np.abs(ref.P).max()
    np.testing.assert_allclose(res.x, ref.x, rtol=0, atol=tol * sx)
    np.testing.assert_allclose(res.innovations, ref.innovations, rtol=0, atol=tol * sx)
    np.testing.assert_allclose(res.P, ref.P, rtol=0, atol=tol * sp)
    np.testing.assert_allclose(res.S, ref.S, rtol=0, atol=tol * sp)
    np.testing.assert_allclose(res.loglik, ref.loglik, rtol=tol * 100, atol=0)
    np.testing.assert_array_equal(res.skipped, ref.skipped)


@pytest.fixture(scope="module")
def linear_case():
    rng = np.random.default_rng(5)
    B, T = 3, 20
    x0 = rng.normal(size=(B, 2))
    P0 = np.diag([1.0, 0.5])
    ys = simulate(rng, F_CV, H_2, Q_CV, R_2, x0, P0, T)
    ys[4, 1] = np.nan
    ref = KalmanFilter(F_CV, H_2, Q_CV, R_2).filter(ys, x0, P0)
    return ys, x0, P0, ref


def test_ekf_equals_kf_on_linear_model(linear_case):
    ys, x0, P0, ref = linear_case
    f, h = linear_fns(F_CV, H_2)
    ekf = ExtendedKalmanFilter(
        f, h, Q_CV, R_2, jac_f=lambda x, u, k: F_CV, jac_h=lambda x, u, k: H_2
    ).filter(ys, x0, P0)
    _assert_same_filter(ekf, ref, 1e-12)
    # finite-difference Jacobians of a linear map: exact up to rounding / step (~1e-10)
    _assert_same_filter(ExtendedKalmanFilter(f, h, Q_CV, R_2).filter(ys, x0, P0), ref, 1e-9)


@pytest.mark.parametrize(("alpha", "tol"), [(1e-3, 2e-10), (0.1, 1e-12), (1.0, 1e-12)])
def test_ukf_equals_kf_on_linear_model(linear_case, alpha, tol):
    # The sigma-point mean carries rounding of order eps |x| / alpha^2 (weights ~ 1/alpha^2), so
    # the default alpha = 1e-3 agrees to ~1e-10 and larger alpha to ~1e-14; measured, not tuned.
    ys, x0, P0, ref = linear_case
    f, h = linear_fns(F_CV, H_2)
    ukf = UnscentedKalmanFilter(f, h, Q_CV, R_2, alpha=alpha).filter(ys, x0, P0)
    _assert_same_filter(ukf, ref, tol)


def test_continuous_ekf_equals_kf_with_closed_form_double_integrator():
    # dx/dt = [v, 0] + w, spectral density q on velocity. RK4 is exact (A^2 = 0) and the
    # closed forms are Phi = [[1, dt], [0, 1]], Qd = q [[dt^3/3, dt^2/2], [dt^2/2, dt]].
    q, dt = 0.7, 0.25
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    Qc = np.diag([0.0, q])
    Phi = np.array([[1.0, dt], [0.0, 1.0]])
    Qd = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    H = np.array([[1.0, 0.0]])
    R = np.array([[0.05]])
    rng = np.random.default_rng(6)
    x0 = np.array([[0.0, 1.0], [2.0, -0.5]])
    P0 = np.eye(2)
    ys = simulate(rng, Phi, H, Qd, R, x0, P0, 25)
    ref = KalmanFilter(Phi, H, Qd, R).filter(ys, x0, P0)
    for jac in (lambda x, u, t: A, None):
        ekf = ExtendedKalmanFilter(
            lambda x, u, t: x @ A.T,
            lambda x, u, t: x @ H.T,
            Qc,
            R,
            jac_f=jac,
            continuous=True,
            dt=dt,
        ).filter(ys, x0, P0)
        np.testing.assert_allclose(ekf.x, ref.x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(ekf.P, ref.P, rtol=1e-9, atol=1e-11)


def test_numerical_jacobian_matches_analytic():
    def fun(x, c):
        return np.column_stack(
            [
                np.sin(x[:, 0]) * x[:, 1],
                x[:, 0] ** 2 + np.exp(x[:, 2]),
                c * x[:, 0] * x[:, 1] * x[:, 2],
            ]
        )

    def jac(x, c):
        J = np.zeros((x.shape[0], 3, 3))
        J[:, 0, 0] = np.cos(x[:, 0]) * x[:, 1]
        J[:, 0, 1] = np.sin(x[:, 0])
        J[:, 1, 0] = 2 * x[:, 0]
        J[:, 1, 2] = np.exp(x[:, 2])
        J[:, 2, 0] = c * x[:, 1] * x[:, 2]
        J[:, 2, 1] = c * x[:, 0] * x[:, 2]
        J[:, 2, 2] = c * x[:, 0] * x[:, 1]
        return J

    x = np.random.default_rng(7).normal(size=(5, 3)) * [1.0, 10.0, 0.5]
    np.testing.assert_allclose(numerical_jacobian(fun, x, 1.5), jac(x, 1.5), rtol=1e-8, atol=1e-8)
    # scalar-valued function: (B,) output is taken as m = 1
    J1 = numerical_jacobian(lambda x: (x**2).sum(axis=1), x)
    np.testing.assert_allclose(J1[:, 0, :], 2 * x, rtol=1e-8, atol=1e-8)
    with pytest.raises(ValueError, match="eps"):
        numerical_jacobian(fun, x, 1.0, eps=-1.0)


def test_discretise_double_integrator_closed_form_and_batched():
    q, dt = 2.0, 0.3
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    Phi, Qd = discretise(A, np.diag([0.0, q]), dt)
    np.testing.assert_allclose(Phi, [[1.0, dt], [0.0, 1.0]], rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(
        Qd, q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]), rtol=1e-13
    )
    Ab = np.stack([A, 2 * A])
    Phib, Qdb = discretise(Ab, np.diag([0.0, q]), dt)
    np.testing.assert_allclose(Phib[1], [[1.0, 2 * dt], [0.0, 1.0]], rtol=1e-14)
    np.testing.assert_allclose(Qdb[0], Qd, rtol=1e-14)


def test_discretise_random_system_against_quadrature_of_expm():
    rng = np.random.default_rng(8)
    A = rng.normal(size=(3, 3))
    G = rng.normal(size=(3, 2))
    Qc = G @ G.T
    dt = 0.4
    Phi, Qd = discretise(A, Qc, dt)
    np.testing.assert_allclose(Phi, scipy.linalg.expm(A * dt), rtol=1e-13, atol=1e-14)
    ref, _ = quad_vec(
        lambda s: scipy.linalg.expm(A * s) @ Qc @ scipy.linalg.expm(A * s).T, 0, dt, epsabs=1e-14
    )
    np.testing.assert_allclose(Qd, ref, rtol=1e-11, atol=1e-13)


def test_ukf_unscented_transform_exact_for_quadratic_gaussian():
    # alpha=1, beta=0, kappa=2 (n=1): the 3-point Gauss-Hermite rule, exact for polynomials up to
    # degree 5, so E[x^2] = mu^2 + s^2 and Var[x^2] = 4 mu^2 s^2 + 2 s^4 come out exactly.
    mu = np.array([[0.7], [-1.3]])
    s2 = np.array([0.4, 2.0])
    ukf = UnscentedKalmanFilter(
        lambda x, u, k: x**2,
        lambda x, u, k: x,
        np.zeros((1, 1)),
        np.eye(1),
        alpha=1.0,
        beta=0.0,
        kappa=2.0,
    )
    xm, Pm = ukf.predict(mu, s2[:, None, None], 0)
    np.testing.assert_allclose(xm[:, 0], mu[:, 0] ** 2 + s2, rtol=1e-14)
    np.testing.assert_allclose(Pm[:, 0, 0], 4 * mu[:, 0] ** 2 * s2 + 2 * s2**2, rtol=1e-13)
    # default scaling (alpha=1e-3, beta=2) still gets the mean of a quadratic exactly
    xm2, _ = UnscentedKalmanFilter(
        lambda x, u, k: x**2, lambda x, u, k: x, np.zeros((1, 1)), np.eye(1)
    ).predict(mu, s2[:, None, None], 0)
    np.testing.assert_allclose(xm2[:, 0], mu[:, 0] ** 2 + s2, rtol=1e-9)


def test_nonlinear_ekf_fd_jacobians_match_analytic_and_inputs_reach_models():
    def f(x, u, k):
        return np.column_stack([x[:, 0] + DT * np.sin(x[:, 1]), 0.9 * x[:, 1] + u[:, 0]])

    def jf(x, u, k):
        J = np.zeros((x.shape[0], 2, 2))
        J[:, 0, 0] = 1.0
        J[:, 0, 1] = DT * np.cos(x[:, 1])
        J[:, 1, 1] = 0.9
        return J

    def h(x, u, k):
        return (x[:, 0] ** 2)[:, None]

    def jh(x, u, k):
        return np.stack([2 * x[:, 0], np.zeros(x.shape[0])], axis=1)[:, None, :]

    rng = np.random.default_rng(9)
    B, T = 3, 10
    us = rng.normal(size=(T, B, 1)) * 0.1
    ys = rng.normal(size=(T, B, 1)) + 2.0
    x0 = np.ones((B, 2))
    a = ExtendedKalmanFilter(f, h, Q_CV, [[0.1]], jac_f=jf, jac_h=jh).filter(ys, x0, np.eye(2), us)
    b = ExtendedKalmanFilter(f, h, Q_CV, [[0.1]]).filter(ys, x0, np.eye(2), us)
    np.testing.assert_allclose(b.x, a.x, rtol=1e-7, atol=1e-8)
    np.testing.assert_allclose(b.P, a.P, rtol=1e-7, atol=1e-8)
    # the UKF is told the per-unit input too (repeated over sigma points) and runs
    c = UnscentedKalmanFilter(f, h, Q_CV, [[0.1]], alpha=0.5).filter(ys, x0, np.eye(2), us)
    assert np.all(np.isfinite(c.x)) and c.x.shape == (T, B, 2)


def test_kf_predict_update_functions_match_hand_computation():
    x = np.array([[1.0, 2.0]])
    P = np.array([[[2.0, 0.5], [0.5, 1.0]]])
    xp, Pp = kf_predict(x, P, F_CV, Q_CV, Bu=np.array([0.1, 0.0]))
    np.testing.assert_allclose(xp, [[1.0 + DT * 2.0 + 0.1, 2.0]])
    np.testing.assert_allclose(Pp[0], F_CV @ P[0] @ F_CV.T + Q_CV)
    H = np.array([[1.0, 0.0]])
    R = np.array([[0.5]])
    xu, Pu, inn = kf_update(xp, Pp, np.array([[3.0]]), H, R)
    S = Pp[0, 0, 0] + 0.5
    K = Pp[0, :, 0] / S
    nu = 3.0 - xp[0, 0]
    np.testing.assert_allclose(xu[0], xp[0] + K * nu, rtol=1e-14)
    np.testing.assert_allclose(Pu[0], Pp[0] - np.outer(K, K) * S, rtol=1e-13)
    np.testing.assert_allclose(inn.nis, [nu**2 / S], rtol=1e-14)
    np.testing.assert_allclose(inn.loglik, [-0.5 * (np.log(2 * np.pi * S) + nu**2 / S)], rtol=1e-14)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: kf_predict(np.zeros((2, 2)), np.eye(2), F_CV, -np.eye(2)), "Q: not positive"),
        (lambda: kf_predict(np.zeros((2, 2)), np.eye(2), np.eye(3), Q_CV), "F: expected shape"),
        (lambda: kf_predict(np.zeros((2, 2)), [[1.0, 0.5], [0.0, 1.0]], F_CV, Q_CV), "P: not sym"),
        (lambda: kf_predict(np.array([[0.0, np.nan]]), np.eye(2), F_CV, Q_CV), "x: non-finite"),
        (lambda: kf_predict(np.zeros(2), np.eye(2), F_CV, Q_CV),
         r"x: expected shape \(B, n_x\), got \(2,\)$"),
        (lambda: kf_update(np.zeros((1, 2)), np.eye(2), np.zeros((1, 2)), H_2, [[1.0]]), "y: exp"),
        (lambda: kf_update(np.zeros((1, 2)), np.eye(2), [[np.inf]], [[1.0, 0]], [[1.0]]), "y: inf"),
        (lambda: kf_update(np.zeros((1, 2)), np.eye(2), [[1.0]], [[1.0, 0, 0]], [[1.0]]), "H: exp"),
        (
            lambda: kf_update(np.zeros((1, 2)), np.zeros((2, 2)), [[1.0]], [[1.0, 0]], [[0.0]]),
            "innovation covariance S",
        ),
        (
            lambda: KalmanFilter(F_CV, H_2, Q_CV, R_2).filter(
                np.zeros((3, 1, 1)), np.zeros((1, 2)), np.eye(2)
            ),
            "ys: expected shape",
        ),
        (
            lambda: KalmanFilter(F_CV, H_2, Q_CV, R_2).filter(
                np.zeros((3, 1, 2)), np.zeros((1, 2)), -np.eye(2)
            ),
            "P0: not positive",
        ),
        (
            lambda: KalmanFilter(F_CV, H_2, Q_CV, np.stack([R_2, -R_2])).filter(
                np.zeros((3, 2, 2)), np.zeros((2, 2)), np.eye(2)
            ),
            "R: not positive semi-definite for unit 1",
        ),
        (
            lambda: ExtendedKalmanFilter(*linear_fns(F_CV, H_2), Q_CV, R_2, continuous=True),
            "dt",
        ),
        (lambda: discretise(np.eye(2), np.eye(2), -1.0), "dt"),
        (  # tiny covariance (damping-like 1e-12 scale), asymmetric above the tolerance but
            # below numpy's default isclose one: used to die with IndexError, not naming the unit
            lambda: kf_predict(np.zeros((2, 2)),
                               np.stack([1e-12 * np.eye(2),
                                         np.array([[1e-12, 1e-12], [1.5e-12, 1e-11]])]),
                               np.eye(2), np.zeros((2, 2))),
            r"P: not symmetric \(unit 1\)",
        ),
    ],
)
def test_bad_input_errors_name_the_argument(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_inputs_not_modified_and_shared_P_accepted():
    x = np.zeros((3, 2))
    P = np.eye(2)
    y = np.array([[1.0, 2.0], [np.nan, 0.0], [0.5, 0.5]])
    y_copy = y.copy()
    xu, Pu, inn = kf_update(x, P, y, H_2, R_2)
    np.testing.assert_array_equal(y, y_copy)
    np.testing.assert_array_equal(P, np.eye(2))
    assert Pu.shape == (3, 2, 2) and inn.skipped.tolist() == [False, True, False]
    np.testing.assert_array_equal(xu[1], [0.0, 0.0])
    np.testing.assert_array_equal(Pu[1], np.eye(2))


def test_control_input_against_brute_force():
    rng = np.random.default_rng(13)
    T, B = 8, 2
    G = np.array([[0.5 * DT**2], [DT]])
    us = rng.normal(size=(T, B, 1))
    x0 = np.zeros((B, 2))
    P0 = np.eye(2)
    ys = rng.normal(size=(T, B, 2))
    res = KalmanFilter(F_CV, H_2, Q_CV, R_2, G=G).filter(ys, x0, P0, us=us)
    for b in range(B):
        bus = [G @ us[k, b] for k in range(T)]
        mean, cov, ll = brute_force(
            [F_CV] * T, [H_2] * T, [Q_CV] * T, [R_2] * T, x0[b], P0, ys[:, b], T, bus
        )
        np.testing.assert_allclose(res.x[-1, b], mean, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(res.P[-1, b], cov, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(res.loglik[b], ll, rtol=1e-10)
    # a shared (T, n_u) input sequence is broadcast to every unit
    shared = KalmanFilter(F_CV, H_2, Q_CV, R_2, G=G).filter(ys, x0, P0, us=us[:, 0])
    one = KalmanFilter(F_CV, H_2, Q_CV, R_2, G=G).filter(ys[:, :1], x0[:1], P0, us=us[:, :1])
    np.testing.assert_allclose(shared.x[:, 0], one.x[:, 0], rtol=1e-13, atol=1e-14)
    with pytest.raises(ValueError, match="us"):
        KalmanFilter(F_CV, H_2, Q_CV, R_2, G=G).filter(ys, x0, P0)
    with pytest.raises(ValueError, match="us: inputs were given but the filter has no control"):
        KalmanFilter(F_CV, H_2, Q_CV, R_2).filter(ys, x0, P0, us=us)


def test_time_varying_callable_with_wrong_shape_names_step():
    kf = KalmanFilter(lambda k: F_CV if k < 2 else np.eye(3), H_2, Q_CV, R_2)
    with pytest.raises(ValueError, match=r"F\(2\): expected shape"):
        kf.filter(np.zeros((4, 1, 2)), np.zeros((1, 2)), np.eye(2))


def test_continuous_ekf_nonlinear_predict_against_solve_ivp_and_expm():
    # pendulum with damping: the mean follows the ODE (RK4 substeps vs solve_ivp), and the
    # covariance is expm(J dt) P expm(J dt)^T + int expm(J s) Qc expm(J s)^T ds (quadrature)
    from scipy.integrate import solve_ivp

    def f(x, u, t):
        return np.column_stack([x[:, 1], -9.81 * np.sin(x[:, 0]) - 0.3 * x[:, 1]])

    def jac(x):
        J = np.zeros((x.shape[0], 2, 2))
        J[:, 0, 1] = 1.0
        J[:, 1, 0] = -9.81 * np.cos(x[:, 0])
        J[:, 1, 1] = -0.3
        return J

    dt = 0.2
    Qc = np.diag([0.0, 0.5])
    x = np.array([[0.4, 0.0], [1.2, -0.5]])
    P = np.stack([np.eye(2) * 0.1, np.array([[0.2, 0.05], [0.05, 0.3]])])
    ekf = ExtendedKalmanFilter(
        f, lambda x, u, t: x[:, :1], Qc, [[0.01]], continuous=True, dt=dt, t0=1.0, substeps=40
    )
    xp, Pp = ekf.predict(x, P, k=0)
    for b in range(2):
        ref = solve_ivp(
            lambda t, y: f(y[None], None, t)[0],
            (1.0, 1.0 + dt),
            x[b],
            method="DOP853",
            rtol=1e-12,
            atol=1e-12,
        )
        np.testing.assert_allclose(xp[b], ref.y[:, -1], rtol=0, atol=1e-9)
        J = jac(x[b : b + 1])[0]
        Phi = scipy.linalg.expm(J * dt)
        Qd, _ = quad_vec(
            lambda s, J=J: scipy.linalg.expm(J * s) @ Qc @ scipy.linalg.expm(J * s).T,
            0,
            dt,
            epsabs=1e-14,
        )
        # the Jacobian is taken by finite differences here: agreement to ~1e-8
        np.testing.assert_allclose(Pp[b], Phi @ P[b] @ Phi.T + Qd, rtol=1e-7, atol=1e-9)


def test_check_false_gives_identical_numbers_and_still_checks_shapes():
    rng = np.random.default_rng(14)
    x = rng.normal(size=(4, 2))
    P = np.stack([np.eye(2) * (1 + b) for b in range(4)])
    y = rng.normal(size=(4, 2))
    a = kf_update(*kf_predict(x, P, F_CV, Q_CV), y, H_2, R_2)
    b = kf_update(*kf_predict(x, P, F_CV, Q_CV, check=False), y, H_2, R_2, check=False)
    for u, v in zip(a[:2], b[:2], strict=True):
        np.testing.assert_array_equal(u, v)
    np.testing.assert_array_equal(a[2].loglik, b[2].loglik)
    with pytest.raises(ValueError, match="Q: expected shape"):
        kf_predict(x, P, F_CV, np.eye(3), check=False)


def test_ekf_error_names_f_when_prediction_is_nan():
    ekf = ExtendedKalmanFilter(
        lambda x, u, k: x * np.nan, lambda x, u, k: x[:, :1], np.eye(2) * 1e-3, np.eye(1)
    )
    with pytest.raises(ValueError, match=r"^step 0: f \(predicted state"):
        ekf.filter(np.zeros((5, 1, 1)), np.zeros((1, 2)), np.eye(2))


def test_filter_errors_name_the_step():
    """A failure inside the loop says which step of ys it was (FilterStepError.step)."""
    from rulkit.estimation.kalman import FilterStepError

    ekf = ExtendedKalmanFilter(lambda x, u, k: x * (np.nan if k == 3 else 1.0),
                               lambda x, u, k: x[:, :1], np.eye(2) * 1e-3, np.eye(1))
    with pytest.raises(FilterStepError, match=r"^step 3: f \(predicted state") as info:
        ekf.filter(np.zeros((5, 1, 1)), np.zeros((1, 2)), np.eye(2))
    assert info.value.step == 3
    kf = KalmanFilter(F_CV, H_2[:1], Q_CV * 0, lambda k: np.eye(1) * (-1.0 if k == 2 else 1.0))
    with pytest.raises(FilterStepError, match=r"^step 2: ") as info:
        kf.filter(np.zeros((4, 1, 1)), np.zeros((1, 2)), np.eye(2))
    assert info.value.step == 2


# -- continuous EKF: where the Jacobian of Phi = expm(J dt) is evaluated -----------------------
_G, _C = 9.81, 0.3


def _pendulum(x, u, t):
    return np.column_stack([x[:, 1], -_G * np.sin(x[:, 0]) - _C * x[:, 1]])


def _pendulum_jac(x, u, t):
    J = np.zeros((x.shape[0], 2, 2))
    J[:, 0, 1] = 1.0
    J[:, 1, 0] = -_G * np.cos(x[:, 0])
    J[:, 1, 1] = -_C
    return J


def _true_phi(x0, dt):
    """State-transition matrix over dt from the variational equations (solve_ivp oracle)."""
    from scipy.integrate import solve_ivp

    def rhs(t, z):
        x, phi = z[:2], z[2:].reshape(2, 2)
        J = _pendulum_jac(x[None], None, t)[0]
        return np.concatenate([_pendulum(x[None], None, t)[0], (J @ phi).ravel()])

    sol = solve_ivp(rhs, (0, dt), np.concatenate([x0, np.eye(2).ravel()]), method="DOP853",
                    rtol=1e-13, atol=1e-14)
    return sol.y[2:, -1].reshape(2, 2)


def _phi_phiT_error(where, x0, dt):
    ekf = ExtendedKalmanFilter(_pendulum, lambda x, u, t: x[:, :1], np.zeros((2, 2)),
                               np.eye(1), jac_f=_pendulum_jac, continuous=True, dt=dt,
                               jacobian_at=where)
    _, Pn = ekf.predict(x0[None], np.eye(2)[None], 0)
    phi = _true_phi(x0, dt)
    return np.abs(Pn[0] - phi @ phi.T).max()


def test_midpoint_jacobian_is_second_order_against_the_variational_equations():
    x0 = np.array([1.2, -0.8])
    start = [_phi_phiT_error("start", x0, dt) for dt in (0.02, 0.01)]
    mid = [_phi_phiT_error("midpoint", x0, dt) for dt in (0.02, 0.01)]
    # error of Phi Phi^T per step: O(dt^2) at the start of the step, O(dt^3) at the midpoint
    assert 3.0 < start[0] / start[1] < 5.0
    assert 6.0 < mid[0] / mid[1] < 10.0
    assert mid[1] < 0.1 * start[1]


def test_jacobian_at_mask_picks_per_unit_and_leaves_the_mean_alone():
    x = np.array([[1.2, -0.8], [0.3, 2.0], [-0.5, 0.1]])
    P = np.broadcast_to(np.eye(2), (3, 2, 2)).copy()

    def make(where):
        return ExtendedKalmanFilter(_pendulum, lambda x, u, t: x[:, :1], 0.01 * np.eye(2),
                                    np.eye(1), jac_f=_pendulum_jac, continuous=True, dt=0.05,
                                    jacobian_at=where)

    xs, Ps = make("start").predict(x, P, 0)
    xm, Pm = make("midpoint").predict(x, P, 0)
    xk, Pk = make(np.array([True, False, True])).predict(x, P, 0)
    np.testing.assert_array_equal(xs, xm)
    np.testing.assert_array_equal(xk, xs)
    np.testing.assert_allclose(Pk[[0, 2]], Pm[[0, 2]], rtol=0, atol=1e-15)
    np.testing.assert_allclose(Pk[1], Ps[1], rtol=0, atol=1e-15)
    assert np.abs(Pm - Ps).max() > 1e-6


@pytest.mark.parametrize(("where", "continuous", "match"), [
    ("end", True, "expected 'start', 'midpoint'"),
    ("midpoint", False, "continuous models only"),
    (np.array([1, 0]), True, "boolean"),
])
def test_jacobian_at_is_validated(where, continuous, match):
    with pytest.raises(ValueError, match=match):
        ExtendedKalmanFilter(_pendulum, lambda x, u, t: x[:, :1], np.eye(2), np.eye(1),
                             continuous=continuous, dt=0.1 if continuous else None,
                             jacobian_at=where)
