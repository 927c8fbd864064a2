"""Ithaco wheel model (spec rw-lubrication.md sections 1-2): physics the spec states, checked
against independent oracles (scipy root finding and solve_ivp), and the seed-literal runaway."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import fsolve

from rulkit.systems.reaction_wheel.wheel import (
    IthacoParams,
    ReactionWheel,
    rk4_wheel_step,
    simulate_table3,
    table3_temperature,
    table3_voltage,
    viscous_coefficient,
    wheel_derivatives,
)

QUIET = IthacoParams(theta_a=0.0)  # torque noise off: a true equilibrium exists


def _equilibrium(V: float, T: float, p: IthacoParams = QUIET) -> np.ndarray:
    def g(x: np.ndarray) -> np.ndarray:
        return wheel_derivatives(x[None], V, T, 0.0, p)[0]

    x = fsolve(g, np.array([0.2 * V, 100.0 * V]), xtol=1e-12)
    assert np.abs(g(x)).max() < 1e-9
    return x


@pytest.mark.parametrize(("V", "I_spec", "w_spec"), [(1.0, 0.190, 91.4), (3.0, 0.570, 378.4)])
def test_steady_state_matches_spec(V: float, I_spec: float, w_spec: float) -> None:
    I, w = _equilibrium(V, 23.0)
    assert I == pytest.approx(I_spec, abs=5e-4)
    assert w == pytest.approx(w_spec, abs=0.05)
    # the closed form used by the filters agrees with the root
    assert ReactionWheel(QUIET).steady_state(V, 23.0) == pytest.approx([I, w], rel=1e-9)


def test_rk4_matches_solve_ivp_and_relaxes_with_200s_time_constant() -> None:
    """RK4 at dt = 0.05 s tracks an adaptive LSODA solution (rtol 1e-10) with the torque noise
    on, and the wheel relaxes to the 1 V equilibrium with tau = J / b_v ~ 200 s. Starts at
    I = 0.19 A, w = 1 rad/s: from rest the Coulomb term sign(w) chatters while K_t I < tau_c,
    which stalls adaptive solvers (fixed-step RK4 passes through it)."""
    p = IthacoParams()
    dt, n = 0.05, 2000  # 100 s
    x0 = np.array([[0.19, 1.0]])
    x = x0.copy()
    for k in range(n):
        x = rk4_wheel_step(x, 1.0, 23.0, k * dt, dt, p)
    sol = solve_ivp(lambda t, z: wheel_derivatives(z[None], 1.0, 23.0, t, p)[0], (0, n * dt),
                    x0[0], method="LSODA", rtol=1e-10, atol=1e-12)
    assert sol.success
    assert x[0] == pytest.approx(sol.y[:, -1], abs=2e-5)
    tau = p.J / float(viscous_coefficient(23.0))
    assert tau == pytest.approx(200.0, rel=0.05)
    w_inf = _equilibrium(1.0, 23.0)[1]
    assert x[0, 1] == pytest.approx(w_inf + (1.0 - w_inf) * np.exp(-100.0 / tau), abs=0.1)


def test_temperature_sensitivity_at_1V() -> None:
    dwdT = (_equilibrium(1.0, 24.0)[1] - _equilibrium(1.0, 22.0)[1]) / 2.0
    assert dwdT == pytest.approx(0.48, abs=0.01)
    # the current carries no temperature information
    assert _equilibrium(1.0, 40.0)[0] == pytest.approx(_equilibrium(1.0, 10.0)[0], abs=1e-12)


def test_viscous_law_positive_over_spec_range_and_literal_negative() -> None:
    T = np.linspace(-30, 214.9, 50)  # b_v reaches 0 at 215 C
    assert np.all(viscous_coefficient(T) > 0)
    assert viscous_coefficient(-5.0, "seed_literal") < 0 < viscous_coefficient(-6.0, "seed_literal")
    with pytest.raises(ValueError, match="friction_law"):
        viscous_coefficient(20.0, "bogus")  # type: ignore[arg-type]


def test_seed_literal_friction_runs_away_default_stays_bounded() -> None:
    """The printed viscous law makes RK4 produce NaN within 10 s (spec section 1); the default
    stays finite and below the overspeed threshold for 200 s."""
    dt = 0.05
    lit = IthacoParams(friction_law="seed_literal")
    x = np.zeros((1, 2))
    first_bad = None
    with np.errstate(all="ignore"):
        for k in range(400):
            x = rk4_wheel_step(x, 1.0, 23.0, k * dt, dt, lit)
            if not np.all(np.isfinite(x)):
                first_bad = (k + 1) * dt
                break
    assert first_bad is not None and first_bad <= 10.0
    x = np.zeros((1, 2))
    p = IthacoParams()
    for k in range(4000):
        x = rk4_wheel_step(x, 1.0, 23.0, k * dt, dt, p)
    assert np.all(np.isfinite(x)) and 0 < x[0, 1] < p.w_s


def test_speed_limiter_and_emf_limiter_are_exact_steps() -> None:
    p = IthacoParams(theta_a=0.0)
    below = wheel_derivatives(np.array([[0.0, 689.999]]), 0.0, 23.0, 0.0, p)[0, 0]
    at = wheel_derivatives(np.array([[0.0, 700.0]]), 0.0, 23.0, 0.0, p)[0, 0]
    # below w_s no limiter; at 700 rad/s: dI/dt = w_d G_d (-K_s (700 - 690)) plus the EMF limiter
    assert below == pytest.approx(0.0, abs=1e-12)
    I_bus = p.P_q / p.V_bus
    V_h = p.K_f * (p.V_bus - 6 - (1 + p.R_in * I_bus) - p.K_e * 700.0)
    expected = p.w_d * p.G_d * (min(V_h, 0.0) - p.K_s * 10.0)
    assert at == pytest.approx(expected, rel=1e-12)
    # EMF torque limiting engages when V_h < 0 (low bus voltage)
    low_bus = replace(p, V_bus=8.0)
    d = wheel_derivatives(np.array([[0.0, 100.0]]), 1.0, 23.0, 0.0, low_bus)[0, 0]
    I_bus = low_bus.P_q / 8.0
    V_h = 0.5 * (8.0 - 6 - (1 + 2 * I_bus) - 0.029 * 100)
    assert V_h < 0 and d == pytest.approx(9 * 0.19 * (1.0 + V_h), rel=1e-12)


def test_table3_path() -> None:
    assert table3_temperature(49.99) == 23.0
    assert table3_temperature(50.0) == pytest.approx(31.0)
    assert table3_temperature(300.0) == pytest.approx(33.41, abs=0.005)
    assert table3_temperature(500.0) == pytest.approx(31.47, abs=0.005)
    assert table3_voltage(249.99) == 1.0 and table3_voltage(250.0) == 3.0


def test_simulate_table3_noise_and_determinism() -> None:
    a = simulate_table3(np.random.default_rng(5), "high", t_end=20.0)
    b = simulate_table3(np.random.default_rng(5), "high", t_end=20.0)
    assert np.array_equal(a.y, b.y) and a.y.shape == (401, 2)
    resid = a.y - np.column_stack([a.x[:, 1], a.x[:, 0]])
    assert resid[:, 0].std() == pytest.approx(3e-3, rel=0.15)
    assert resid[:, 1].std() == pytest.approx(1.3e-1, rel=0.15)
    eq = simulate_table3(np.random.default_rng(0), t_end=1.0, initial="equilibrium")
    assert eq.x[0, 1] == pytest.approx(91.4, abs=0.05)


def test_state_space_model_contract() -> None:
    m = ReactionWheel(noise="low")
    x = np.array([[0.19, 91.4], [0.0, 0.0], [0.57, 378.0]])
    u = np.array([[1.0, 23.0], [3.0, 30.0], [3.0, 40.0]])
    batch = m.step(x, u, 0.0, 0.05)
    rows = np.vstack([m.step(x[i], u[i], 0.0, 0.05) for i in range(3)])
    assert np.array_equal(batch, rows)
    assert m.output(x).tolist() == x[:, ::-1].tolist()
    assert m.noise.R == pytest.approx(np.diag([9e-6, 9e-4]))
    with pytest.raises(ValueError, match="u: expected shape"):
        m.step(x, np.ones(3), 0.0, 0.05)
    with pytest.raises(ValueError, match="non-finite"):
        m.step(x, np.array([np.nan, 23.0]), 0.0, 0.05)
    with pytest.raises(ValueError, match="noise"):
        ReactionWheel(noise="medium")
    ripple = ReactionWheel(ripple=True)
    assert ripple.n_x == 3 and ripple.params.B == 0.22


def test_rk4_step_jacobian_matches_finite_differences() -> None:
    """Tangent-linear RK4 Jacobian of [I, w, T] vs the engine's central differences, including
    the speed limiter (w > w_s) and the EMF limiter (V_bus = 8 V)."""
    from rulkit.estimation.kalman import numerical_jacobian
    from rulkit.systems.reaction_wheel.wheel import rk4_wheel_step_jacobian

    x = np.array([[0.19, 91.4, 23.0], [0.57, 300.0, 33.0], [0.05, 2.0, 40.0], [0.1, 700.0, 30.0]])
    for p in (IthacoParams(), IthacoParams(V_bus=8.0)):
        def step(xx: np.ndarray, p: IthacoParams = p) -> np.ndarray:
            X = rk4_wheel_step(xx[:, :2], 1.0, xx[:, 2], 3.0, 0.05, p)
            return np.column_stack([X, xx[:, 2]])

        J = rk4_wheel_step_jacobian(x, 1.0, x[:, 2], 3.0, 0.05, p)
        np.testing.assert_allclose(J, numerical_jacobian(step, x), rtol=1e-6, atol=1e-7)


def test_check_measurements_names_the_argument_and_row():
    from rulkit.systems.reaction_wheel.wheel import check_measurements

    y = np.zeros((5, 2))
    V = np.ones(5)
    y_ok, V_ok, sw, sI = check_measurements(y, V, (3e-3, 3e-2), 0.05)
    assert y_ok.dtype == V_ok.dtype == np.float64 and (sw, sI) == (3e-3, 3e-2)
    bad = y.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="row 3"):
        check_measurements(bad, V, (3e-3, 3e-2), 0.05)
    with pytest.raises(ValueError, match=r"^V: expected shape \(5,\)"):
        check_measurements(y, V[:4], (3e-3, 3e-2), 0.05)
    with pytest.raises(ValueError, match=r"^y: expected shape"):
        check_measurements(y[:1], V[:1], (3e-3, 3e-2), 0.05)
    with pytest.raises(ValueError, match=r"^sigma"):
        check_measurements(y, V, (0.0, 3e-2), 0.05)
    with pytest.raises(ValueError, match=r"^dt"):
        check_measurements(y, V, (3e-3, 3e-2), np.inf)
