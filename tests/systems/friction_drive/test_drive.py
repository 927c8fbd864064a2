"""Tests of the friction-drive model (seed 003 eq. 1-19; spec friction-drive.md)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp
from scipy.linalg import expm

from rulkit.estimation.kalman import discretise, numerical_jacobian
from rulkit.systems.friction_drive import drive as fd

P = fd.DEFAULT_PARAMS


def _rhs_matrix_form(x: np.ndarray, cur: float) -> np.ndarray:
    """Seed eq. (3)-(4) written as A(alpha) x + B u, plus eq. (7): an independent formulation."""
    w, a, m = x[:2], x[2], x[3]
    A = np.array([
        [(-a * P.r1**2 - P.B1) / P.J1, a * P.r1 * P.r2 / P.J1],
        [a * P.r2 * P.r1 / P.J2, (-a * P.r2**2 - P.B2) / P.J2],
    ])
    Bm = np.array([P.Km / P.J1, 0.0])
    p = (P.r1 * w[0] - P.r2 * w[1]) ** 2
    return np.concatenate([A @ w + Bm * cur, [-m * p * a, 0.0]])


def _states(rng: np.random.Generator, n: int = 6) -> np.ndarray:
    return np.column_stack([
        rng.uniform(0, 160, n), rng.uniform(0, 15, n), rng.uniform(0.1, 11, n),
        rng.uniform(0, 0.03, n),
    ])


def test_drift_matches_matrix_form_of_seed_equations():
    rng = np.random.default_rng(1)
    X = _states(rng)
    cur = rng.uniform(0, 20, X.shape[0])
    got = fd.drift(X, cur)
    want = np.stack([_rhs_matrix_form(x, c) for x, c in zip(X, cur, strict=True)])
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-12)


def test_analytic_jacobian_matches_finite_differences():
    rng = np.random.default_rng(2)
    X = _states(rng, 8)
    J = fd.jacobian(X)
    Jn = numerical_jacobian(lambda x: fd.drift(x, 20.0), X)
    scale = np.maximum(np.abs(J), 1e-3)
    assert np.max(np.abs(J - Jn) / scale) < 1e-6


def test_f44_changes_only_the_m_m_entry():
    X = _states(np.random.default_rng(3), 3)
    J0, J1 = fd.jacobian(X), fd.jacobian(X, f44=-100.0)
    diff = J1 - J0
    assert np.all(diff[:, 3, 3] == -100.0)
    diff[:, 3, 3] = 0
    assert np.all(diff == 0)


def test_expm_discretisation_of_the_jacobian_matches_scipy_and_quadrature():
    x = np.array([[120.0, 10.0, 9.0, 0.01]])
    A = fd.jacobian(x)[0]
    Qc = np.diag([0.0, 0.0, 0.0, 3e-7])
    dt = 1e-3
    Phi, Qd = discretise(A, Qc, dt)
    np.testing.assert_allclose(Phi, expm(A * dt), rtol=1e-12, atol=1e-15)
    # Qd = int_0^dt e^{As} Qc e^{A^T s} ds, entrywise quadrature
    for i, j in [(3, 3), (2, 3), (2, 2), (0, 3)]:
        val, _ = quad(lambda s, i=i, j=j: (expm(A * s) @ Qc @ expm(A * s).T)[i, j], 0, dt,
                      epsabs=1e-22, epsrel=1e-10)
        assert Qd[i, j] == pytest.approx(val, rel=1e-7, abs=1e-22)


def test_integrate_path_matches_solve_ivp_under_a_square_wave():
    dt = 1e-3
    K = 2500
    t = np.arange(K) * dt
    cur = fd.square_wave_current(t)
    x0 = np.array([[0.0, 0.0, 10.0, 0.01]])
    X = fd.integrate_path(x0, cur, dt, n_sub=2)
    # reference: adaptive DOP853 over each constant-current segment (tight tolerances)
    y = x0[0].copy()
    edges = [0.0, 1.0, 2.0, 2.5]
    for a, b in itertools.pairwise(edges):
        c = 20.0 if int(a) % 2 == 0 else 0.0
        sol = solve_ivp(lambda _t, z, c=c: _rhs_matrix_form(z, c), (a, b), y, method="DOP853",
                        rtol=1e-12, atol=1e-12)
        y = sol.y[:, -1]
    np.testing.assert_allclose(X[-1, 0], y, rtol=1e-8, atol=1e-8)


def test_numba_kernel_equals_numpy_reference():
    rng = np.random.default_rng(4)
    X0 = _states(rng, 5)
    cur = rng.uniform(0, 20, 300)
    mp = rng.uniform(0.0, 0.02, 300)
    a = fd.integrate_path(X0, cur, 1e-3, n_sub=3, m_path=mp)
    b = fd.integrate_path_numpy(X0, cur, 1e-3, n_sub=3, m_path=mp)
    np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-12)
    c = fd.integrate_path(X0, cur, 1e-3, n_sub=3, m_path=mp, store=False)
    np.testing.assert_array_equal(c, a[-1])


def test_quasi_steady_slip_is_the_equilibrium_of_the_full_model():
    alphas = np.array([0.1, 1.0, 10.0])
    x0 = np.column_stack([np.zeros(3), np.zeros(3), alphas, np.zeros(3)])  # m = 0: alpha frozen
    # the slow time constant at alpha = 0.1 is ~14 s: integrate 300 s
    xT = fd.integrate_path(x0, np.full(30000, 20.0), 1e-2, store=False)
    np.testing.assert_allclose(fd.slip(xT), fd.quasi_steady_slip(alphas, 20.0), rtol=1e-8)
    np.testing.assert_allclose(xT[:, :2], fd.steady_state_speeds(alphas, 20.0), rtol=1e-8)


def test_quasi_steady_time_matches_quadrature_and_inverse():
    m, cur = 0.01, 20.0
    G2 = P.gain(cur) ** 2
    c = P.c
    val, _ = quad(lambda a: (1 + c * a) ** 2 / (m * G2 * a), 0.1, 10.0, epsrel=1e-12)
    assert fd.quasi_steady_time(np.array([10.0]), 0.1, m, cur)[0] == pytest.approx(val, rel=1e-10)
    t = np.array([0.0, 1e4, 5e5, 1.0e6])
    a = fd.quasi_steady_alpha(10.0, m, cur, t)
    back = fd.quasi_steady_time(np.full(t.shape, 10.0), a, m, cur)
    np.testing.assert_allclose(back[1:], t[1:], rtol=1e-9)
    assert a[0] == pytest.approx(10.0)
    assert np.all(np.diff(a) < 0)


def test_quasi_steady_time_never_fails_for_nonpositive_m_and_zero_below_threshold():
    out = fd.quasi_steady_time(np.array([5.0, 5.0, 0.05]), 0.1, np.array([0.0, -0.01, 0.01]), 20.0)
    assert np.isinf(out[0]) and np.isinf(out[1]) and out[2] == 0.0


def test_square_wave_is_on_during_the_first_half_of_each_period():
    t = np.arange(0, 4, 1e-3)
    u = fd.square_wave_current(t)
    assert u[0] == 20.0 and u[999] == 20.0 and u[1000] == 0.0 and u[1999] == 0.0
    assert u[2000] == 20.0 and u.mean() == pytest.approx(10.0)


def test_model_contract_step_output_health_and_noise():
    model = fd.FrictionDriveModel(q_rate=np.diag([0, 0, 0, 1e-4]), dt=1e-3)
    x = np.array([[100.0, 8.0, 9.0, 0.01]])
    np.testing.assert_array_equal(model.step(x, np.array([20.0]), 0.0, 1e-3),
                                  fd.rk4_step(x, 20.0, 1e-3))
    assert model.output(x).shape == (1, 2)
    assert model.health(x)[0] == pytest.approx(0.1)
    assert model.threshold == 0.99
    rng = np.random.default_rng(5)
    xs = np.repeat(x, 20000, axis=0)
    noisy = model.step(xs, np.array([20.0]), 0.0, 2e-3, rng)
    dm = noisy[:, 3] - fd.rk4_step(xs[:1], 20.0, 2e-3)[0, 3]
    assert dm.var() == pytest.approx(1e-4 * 2e-3, rel=0.05)
    assert np.all(noisy[:, 0] == noisy[0, 0])  # no noise on the speeds
    with pytest.raises(ValueError, match="current"):
        model.step(x, None, 0.0, 1e-3)


def test_bad_inputs_raise_specific_errors():
    with pytest.raises(ValueError, match="J1"):
        fd.FrictionDriveParams(J1=-1.0)
    with pytest.raises(ValueError, match="failure_level"):
        fd.FrictionDriveParams(failure_level=1.0)
    with pytest.raises(ValueError, match="x0"):
        fd.integrate_path(np.array([[0.0, np.nan, 10.0, 0.01]]), np.ones(3), 1e-3)
    with pytest.raises(ValueError, match="m_path"):
        fd.integrate_path(np.zeros(4), np.ones(3), 1e-3, m_path=np.ones(2))
    with pytest.raises(ValueError, match="current"):
        fd.drift(np.zeros((3, 4)), np.ones(2))
    with pytest.raises(ValueError, match="dt"):
        fd.integrate_path(np.zeros(4), np.ones(3), 0.0)
    # the numpy reference path refuses the same input (it raised IndexError or ran on NaN)
    for integrate in (fd.integrate_path, fd.integrate_path_numpy):
        with pytest.raises(ValueError, match="m_path: expected shape"):
            integrate(np.zeros(4), np.ones(3), 1e-3, m_path=np.ones(2))
        with pytest.raises(ValueError, match="m_path: contains NaN"):
            integrate(np.zeros(4), np.ones(3), 1e-3, m_path=np.array([0.01, np.nan, 0.01]))
        with pytest.raises(ValueError, match="currents"):
            integrate(np.zeros(4), np.array([1.0, np.inf]), 1e-3)


def test_time_to_alpha_matches_the_stored_path():
    x0 = np.array([[0.0, 0.0, 10.0, 0.5], [0.0, 0.0, 10.0, 0.0], [0.0, 0.0, 0.05, 0.01]])
    t, xe = fd.time_to_alpha(x0, 20.0, 9.0, 1e-3, 3.0)
    path = fd.integrate_path(x0, np.full(3000, 20.0), 1e-3)[:, :, 2]
    k = int(np.flatnonzero(path[:, 0] <= 9.0)[0])
    lin = (k - 1 + (path[k - 1, 0] - 9.0) / (path[k - 1, 0] - path[k, 0])) * 1e-3
    assert t[0] == pytest.approx(lin, rel=1e-12)
    assert xe[0, 2] == pytest.approx(path[k, 0], rel=1e-12)
    assert np.isinf(t[1]) and xe[1, 2] == 10.0  # m = 0: never
    assert t[2] == 0.0


def test_nan_inputs_are_refused_not_read_as_never_failing():
    # m = NaN failed the "m > 0" test and came back as +inf ("never fails") before
    with pytest.raises(ValueError, match="m: non-finite"):
        fd.quasi_steady_time(np.array([5.0, 5.0]), 0.1, np.array([0.01, np.nan]), 20.0)
    with pytest.raises(ValueError, match="alpha_start"):
        fd.quasi_steady_time(np.array([-1.0]), 0.1, 0.01, 20.0)
    with pytest.raises(ValueError, match="alpha_end"):
        fd.quasi_steady_time(np.array([5.0]), np.nan, 0.01, 20.0)
    with pytest.raises(ValueError, match="current"):
        fd.quasi_steady_alpha(5.0, 0.01, np.nan, 10.0)
    with pytest.raises(ValueError, match="t: expected"):
        fd.quasi_steady_alpha(5.0, 0.01, 20.0, -1.0)
    with pytest.raises(ValueError, match="alpha_level"):
        fd.time_to_alpha(np.array([[0.0, 0.0, 10.0, 0.01]]), 20.0, np.nan, 1e-3, 1.0)
    with pytest.raises(ValueError, match="current"):
        fd.time_to_alpha(np.array([[0.0, 0.0, 10.0, 0.01]]), np.nan, 9.0, 1e-3, 1.0)
    with pytest.raises(ValueError, match="n_sub"):
        fd.FrictionDriveModel(n_sub=0)
    with pytest.raises(ValueError, match="dt"):
        fd.FrictionDriveModel(dt=np.nan)
