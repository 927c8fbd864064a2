"""Physics of the reaction-wheel motor (seed 002 eq. 1) against independent oracles."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from rulkit.estimation.kalman import numerical_jacobian
from rulkit.integrate import integrate, rk4_step
from rulkit.systems.motor_damping.motor import (
    DCMotor,
    LifeTestConfig,
    MotorConstants,
    VoltageDCMotor,
    characteristic_curve_slope,
    euler_step_with_jacobian,
    failure_cycle,
    failure_damping,
    failure_damping_from_curves,
    measurement,
    measurement_seed_lagged,
    pullup_speed_exact,
    rk4_step_with_jacobian,
    simulate_life_test,
    speed_derivative,
)

M = MotorConstants()


@pytest.mark.parametrize("c", [1e-5, 1.47e-4, 3.0e-3, 1e-12])  # 3e-3: lam = 1/tau_I (limit)
def test_closed_form_speed_matches_solve_ivp(c: float) -> None:
    t = np.linspace(0.0, 35.0, 351)
    sol = solve_ivp(
        lambda tt, y: [(M.K * M.current(tt) - M.T_L - c * y[0]) / M.J],
        (0.0, 35.0), [2.0], t_eval=t, rtol=1e-11, atol=1e-10,
    )
    w = pullup_speed_exact(t, c, M, w0=2.0)
    np.testing.assert_allclose(w, sol.y[0], rtol=1e-8, atol=1e-7)


def test_steady_state_under_constant_current() -> None:
    # constant current (no spike): w -> (K I - T_L) / c; integrate the model itself
    consts = MotorConstants(I_p=0.0)
    c = 5e-4  # time constant J / c = 6 s
    model = DCMotor(consts)
    _, X = integrate(
        lambda x, t, u: np.stack([speed_derivative(x[:, 0], x[:, 1], u[:, 0], consts),
                                  np.zeros(len(x))], axis=1),
        np.array([0.0, c]), 0.0, 0.05, 2000, u=np.array([consts.I_s]), store=False,
    )
    w_ss = (consts.K * consts.I_s - consts.T_L) / c
    assert X[-1, 0, 0] == pytest.approx(w_ss, rel=1e-6)
    # the model's own step reaches the same point
    x = np.array([[0.0, c]])
    for _ in range(2000):
        x = model.step(x, np.array([consts.I_s]), 0.0, 0.05)
    assert x[0, 0] == pytest.approx(w_ss, rel=1e-6)


def test_steady_state_under_constant_voltage() -> None:
    motor = VoltageDCMotor(M, R=1.5, L=0.05, c=1e-3)  # time constants 33 ms and 1.9 s
    v = 12.0
    _, X = integrate(motor.rhs, np.array([0.0, 0.0]), 0.0, 4e-3, 15000, u=np.array([v]),
                     store=False)
    i_ss, w_ss = motor.steady_state(v)
    # closed form by hand: w = (K V - R T_L) / (K^2 + R c)
    assert w_ss == pytest.approx((0.03 * 12 - 1.5 * 1.4e-3) / (0.03**2 + 1.5 * 1e-3))
    np.testing.assert_allclose(X[-1, 0], [i_ss, w_ss], rtol=1e-8)
    # torque balance at steady state: K i = c w + T_L
    assert M.K * i_ss == pytest.approx(1e-3 * w_ss + M.T_L)


def _batch(rng: np.random.Generator, b: int = 6) -> tuple[np.ndarray, ...]:
    x = np.column_stack([rng.uniform(0, 600, b), rng.uniform(1e-5, 2e-4, b)])
    i0 = rng.uniform(2.0, 4.0, b)
    i1 = rng.uniform(2.0, 4.0, b)
    return x, i0, i1


def test_rk4_step_matches_engine_rk4_with_interpolated_current() -> None:
    x, i0, i1 = _batch(np.random.default_rng(0))
    dt, t0 = 0.05, 3.0

    def f(xx, t, u):
        return np.stack([speed_derivative(xx[:, 0], xx[:, 1], u[:, 0], M), np.zeros(len(xx))], 1)

    def cur(t):
        return (i0 + (i1 - i0) * (t - t0) / dt)[:, None]

    ref = rk4_step(f, x, t0, dt, u=cur)
    got, _ = rk4_step_with_jacobian(x, i0, i1, dt, M)
    np.testing.assert_allclose(got, ref, rtol=1e-13, atol=1e-12)


def test_rk4_with_sampled_current_converges_to_closed_form() -> None:
    c = np.array([1e-5, 1.47e-4])
    errs = []
    for dt in (0.1, 0.05):
        t = np.arange(0.0, 35.0 + dt / 2, dt)
        x = np.column_stack([np.zeros(2), c])
        cur = M.current(t)
        for k in range(1, t.size):
            x, _ = rk4_step_with_jacobian(x, np.full(2, cur[k - 1]), np.full(2, cur[k]), dt, M)
        errs.append(np.abs(x[:, 0] - pullup_speed_exact(t[-1:], c, M)[:, 0]).max())
    # linear current interpolation is second order, so the whole scheme is O(dt^2);
    # at the data's dt = 0.05 s the error is far below the speed noise (0.05 rad/s)
    assert errs[1] < errs[0] / 3.5
    assert errs[1] < 5e-3


@pytest.mark.parametrize("dt", [0.05, np.array([0.01, 0.05, 0.1, 0.02, 0.05, 0.2])])
def test_jacobians_against_finite_differences(dt) -> None:
    x, i0, i1 = _batch(np.random.default_rng(1))
    # scale c so that central differences see both components at a similar relative size
    scale = np.array([1.0, 1e-4])

    def fd(fun):
        def g(xs):
            return fun(xs * scale)[0] if isinstance(fun(xs * scale), tuple) else fun(xs * scale)
        J = numerical_jacobian(g, x / scale)
        return J / scale[None, None, :]

    for fun in (
        lambda xx: rk4_step_with_jacobian(xx, i0, i1, dt, M),
        lambda xx: euler_step_with_jacobian(xx, i0, dt, M),
        lambda xx: measurement(xx, i1, M),
        lambda xx: measurement_seed_lagged(xx, i0, dt, M),
    ):
        _, J_analytic = fun(x)
        J_fd = fd(fun)
        np.testing.assert_allclose(J_analytic, J_fd, rtol=1e-6, atol=1e-9)


def test_seed_lagged_measurement_is_the_previous_state_acceleration() -> None:
    x_prev, i0, _ = _batch(np.random.default_rng(2))
    dt = 0.05
    x_k, _ = euler_step_with_jacobian(x_prev, i0, dt, M)
    z, _ = measurement_seed_lagged(x_k, i0, dt, M)
    expected = (-x_prev[:, 1] * x_prev[:, 0] - M.T_L + M.K * i0) / M.J  # seed eq. 3, row 2
    np.testing.assert_allclose(z[:, 1], expected, rtol=1e-10)
    np.testing.assert_array_equal(z[:, 0], x_k[:, 0])


def test_failure_damping_by_hand() -> None:
    # (K I_s - T_L - T_d) / w_d = (0.0615 - 0.0014 - 0.016) / 300 = 0.0441 / 300
    assert failure_damping(M) == pytest.approx(1.47e-4, rel=1e-12)
    assert failure_damping(M, 250.0, 20e-3, steady_current=2.0) == pytest.approx(
        (0.06 - 0.0014 - 0.02) / 250.0
    )
    with pytest.raises(ValueError, match="above the undamped curve"):
        failure_damping(M, 300.0, 0.07)


def test_failure_damping_from_a_family_of_curves() -> None:
    t = np.arange(0.0, 35.0, 0.05)
    c = np.linspace(2e-5, 1.4e-4, 12)
    w = pullup_speed_exact(t, c, M)
    torque = M.J * speed_derivative(w, c[:, None], M.current(t), M)
    steady = t >= 10.0  # spike decayed to 1.95 exp(-10) = 9e-5 A
    slopes = characteristic_curve_slope(w, torque, steady)
    # at steady current the curve is a line of slope -c (seed Fig. 12 = identity)
    np.testing.assert_allclose(slopes, -c, rtol=2e-3)
    c_fail = failure_damping_from_curves(w, torque, c, mask=steady)
    assert c_fail == pytest.approx(failure_damping(M), rel=2e-3)
    # a mask that selects one sample of curve 3, or a NaN sample: named, not a NaN slope
    one = np.broadcast_to(steady, w.shape).copy()
    one[3] = False
    one[3, 300] = True
    with pytest.raises(ValueError, match="curve 3: 1 selected sample"):
        characteristic_curve_slope(w, torque, one)
    w_nan = w.copy()
    w_nan[5, 400] = np.nan
    with pytest.raises(ValueError, match="curve 5: non-finite speed or torque at selected sample"):
        characteristic_curve_slope(w_nan, torque, steady)


def test_failure_cycle_by_hand() -> None:
    assert failure_cycle(1.47e-4, 1e-5, 2e-6) == pytest.approx(68.5)
    # 2e-8 n^2 + 2e-6 n - 1.37e-4 = 0
    n = failure_cycle(1.47e-4, 1e-5, 2e-6, 2e-8)
    assert 2e-8 * n * n + 2e-6 * n + 1e-5 == pytest.approx(1.47e-4, rel=1e-12)


def test_generator_reproducible_and_noise_as_stated() -> None:
    cfg = LifeTestConfig(n_cycles=10)
    a = simulate_life_test(cfg, np.random.default_rng(7))
    b = simulate_life_test(cfg, np.random.default_rng(7))
    c = simulate_life_test(cfg, np.random.default_rng(8))
    for name in ("speed", "acceleration", "current", "damping"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.speed, c.speed)
    w_true = pullup_speed_exact(a.time, a.damping, cfg.consts)
    assert np.std(a.speed - w_true) == pytest.approx(cfg.sigma_w, rel=0.03)
    dw_true = speed_derivative(w_true, a.damping[:, None], cfg.consts.current(a.time), cfg.consts)
    assert np.std(a.acceleration - dw_true) == pytest.approx(cfg.sigma_dw, rel=0.03)
    np.testing.assert_allclose(a.trend, 1e-5 + 2e-6 * np.arange(1, 11))
    assert a.eol == pytest.approx(68.5)
    # the wheel passes the design speed within a cycle even at c_fail
    assert pullup_speed_exact(a.time, failure_damping(cfg.consts), cfg.consts).max() > 300.0


def test_generator_differenced_acceleration_and_validation() -> None:
    cfg = LifeTestConfig(n_cycles=3, acceleration="differenced")
    lt = simulate_life_test(cfg, np.random.default_rng(0))
    np.testing.assert_allclose(lt.acceleration, np.gradient(lt.speed, cfg.dt, axis=1))
    with pytest.raises(ValueError, match="acceleration"):
        LifeTestConfig(acceleration="guess")
    with pytest.raises(ValueError, match="n_cycles"):
        LifeTestConfig(n_cycles=0)
    with pytest.raises(ValueError, match=r"MotorConstants\.J"):
        MotorConstants(J=-1.0)


def test_state_space_model_contract() -> None:
    model = DCMotor(M)
    x = np.array([[100.0, 5e-5], [200.0, 1e-4]])
    u = np.array([[3.0], [2.5]])
    y = model.output(x, u)
    np.testing.assert_allclose(y[:, 1], (M.K * u[:, 0] - M.T_L - x[:, 1] * x[:, 0]) / M.J)
    x1 = model.step(x, u, 0.0, 0.05)
    x1n = model.step(x, u, 0.0, 0.05, rng=np.random.default_rng(0))
    assert x1.shape == x1n.shape == (2, 2)
    assert not np.array_equal(x1, x1n)
    np.testing.assert_array_equal(model.health(x), x[:, 1])
    assert model.threshold == pytest.approx(1.47e-4)
    with pytest.raises(ValueError, match="current"):
        model.step(x, None, 0.0, 0.05)
