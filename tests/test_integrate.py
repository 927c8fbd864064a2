"""Fixed-step integrators against closed forms and scipy.integrate.solve_ivp."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from rulkit.integrate import euler_step, integrate, rk4_step


def decay(rates):
    rates = np.asarray(rates, dtype=float)

    def f(x, t, u):
        return -rates[:, None] * x

    return f


def oscillator(x, t, u):
    # x'' = -omega^2 x with omega = 2: state (position, velocity)
    return np.column_stack([x[:, 1], -4.0 * x[:, 0]])


def oscillator_exact(x0, t):
    w = 2.0
    p0, v0 = x0[:, 0], x0[:, 1]
    return np.column_stack(
        [p0 * np.cos(w * t) + v0 / w * np.sin(w * t), -p0 * w * np.sin(w * t) + v0 * np.cos(w * t)]
    )


def test_exponential_decay_rk4_and_euler_against_closed_form():
    rates = np.array([0.5, 1.0, 2.0])
    x0 = np.array([[1.0], [2.0], [-3.0]])
    t, X = integrate(decay(rates), x0, 0.0, 0.01, 200, method="rk4")
    exact = x0[None, :, :] * np.exp(-rates[None, :, None] * t[:, None, None])
    assert t.shape == (201,) and X.shape == (201, 3, 1)
    # RK4 applied to x' = -k x multiplies by the degree-4 Taylor polynomial of exp(-k dt)
    z = -rates[:, None] * 0.01
    amp = 1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24
    np.testing.assert_allclose(X[-1], x0 * amp**200, rtol=1e-13)
    np.testing.assert_allclose(X, exact, rtol=1e-8, atol=0)
    _, Xe = integrate(decay(rates), x0, 0.0, 0.01, 200, method="euler")
    # Euler with one step: (1 - k dt)^n exactly (a discrete closed form)
    np.testing.assert_allclose(Xe[-1], x0 * (1 - rates[:, None] * 0.01) ** 200, rtol=1e-12)
    assert np.max(np.abs(Xe[-1] - exact[-1])) > 1e-4  # Euler is visibly first order here


@pytest.mark.parametrize(("method", "order"), [("rk4", 4.0), ("euler", 1.0)])
def test_global_convergence_order_on_harmonic_oscillator(method, order):
    x0 = np.array([[1.0, 0.0], [0.3, -1.2]])
    T = 5.0
    errs = []
    for n in (250, 500, 1000) if method == "rk4" else (2000, 4000, 8000):
        _, X = integrate(oscillator, x0, 0.0, T / n, n, method=method, store=False)
        errs.append(np.max(np.abs(X[0] - oscillator_exact(x0, T))))
    rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    np.testing.assert_allclose(rates, order, atol=0.1)


def test_rk4_matches_solve_ivp_on_van_der_pol_batch():
    mu = 1.5

    def f(x, t, u):
        return np.column_stack([x[:, 1], mu * (1 - x[:, 0] ** 2) * x[:, 1] - x[:, 0]])

    x0 = np.array([[2.0, 0.0], [0.5, 0.5], [-1.0, 1.0]])
    T, n = 4.0, 4000
    _, X = integrate(f, x0, 0.0, T / n, n, store=False)
    for i in range(3):
        ref = solve_ivp(
            lambda t, y: f(y[None, :], t, None)[0],
            (0, T),
            x0[i],
            method="DOP853",
            rtol=1e-12,
            atol=1e-12,
        )
        np.testing.assert_allclose(X[0, i], ref.y[:, -1], rtol=0, atol=1e-9)


def test_time_dependent_input_callable_and_constant():
    # x' = u(t) = cos(t): x(t) = sin(t); RK4 is Simpson's rule here (error O(dt^4))
    t, X = integrate(lambda x, t, u: u, np.zeros((2, 1)), 0.0, 0.01, 300, u=lambda t: [np.cos(t)])
    np.testing.assert_allclose(X[:, :, 0], np.sin(t)[:, None] * np.ones((1, 2)), atol=1e-11)
    # constant 1-D input broadcast to (N, n_u): x' = -x + u -> x = u + (x0 - u) e^-t
    x0 = np.array([[0.0], [4.0]])
    t, X = integrate(lambda x, t, u: -x + u[:, :1], x0, 0.0, 0.01, 100, u=np.array([2.0]))
    np.testing.assert_allclose(X[-1, :, 0], 2.0 + (x0[:, 0] - 2.0) * np.exp(-1.0), rtol=1e-10)
    # per-row input
    t, X = integrate(lambda x, t, u: -x + u, x0, 0.0, 0.01, 100, u=np.array([[1.0], [3.0]]))
    np.testing.assert_allclose(
        X[-1, :, 0], [1.0 + (0 - 1.0) * np.exp(-1.0), 3.0 + (4 - 3.0) * np.exp(-1.0)], rtol=1e-10
    )


def test_single_steps_and_store_false_agree():
    x0 = np.array([[1.0, 0.0]])
    x1 = rk4_step(oscillator, x0, 0.0, 0.1)
    _, X = integrate(oscillator, x0, 0.0, 0.1, 1)
    np.testing.assert_array_equal(X[1], x1)
    np.testing.assert_array_equal(euler_step(oscillator, x0, 0.0, 0.1), [[1.0, -0.4]])
    t_all, X_all = integrate(oscillator, x0, 1.0, 0.1, 7)
    t_end, X_end = integrate(oscillator, x0, 1.0, 0.1, 7, store=False)
    np.testing.assert_array_equal(X_all[-1], X_end[0])
    assert t_end.shape == (1,) and t_end[0] == pytest.approx(1.7)
    assert t_all[0] == 1.0


def test_single_state_and_x0_not_modified():
    x0 = np.array([1.0, 0.0])
    _, X = integrate(oscillator, x0, 0.0, 0.1, 3)
    assert X.shape == (4, 1, 2)
    np.testing.assert_array_equal(x0, [1.0, 0.0])
    _, X0 = integrate(oscillator, x0, 0.0, 0.1, 0)
    assert X0.shape == (1, 1, 2)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"method": "rk45"}, "method"),
        ({"dt": 0.0}, "dt"),
        ({"dt": np.nan}, "dt"),
        ({"n_steps": -1}, "n_steps"),
        ({"n_steps": 2.5}, "n_steps"),
        ({"x0": np.array([[np.nan, 0.0]])}, "x0"),
        ({"x0": np.zeros((2, 2, 2))}, "x0"),
        ({"t0": np.inf}, "t0"),
        ({"u": np.ones((3, 1))}, "u"),
    ],
)
def test_bad_arguments_raise_clear_errors(kwargs, match):
    args = {"x0": np.zeros((2, 2)), "t0": 0.0, "dt": 0.1, "n_steps": 3, "method": "rk4"}
    args.update(kwargs)
    u = args.pop("u", None)
    with pytest.raises(ValueError, match=match):
        integrate(
            oscillator,
            args["x0"],
            args["t0"],
            args["dt"],
            args["n_steps"],
            u=u,
            method=args["method"],
        )


def test_wrong_rhs_shape_and_blow_up_are_reported():
    with pytest.raises(ValueError, match="shape"):
        integrate(lambda x, t, u: x[:, :1], np.zeros((2, 2)), 0.0, 0.1, 2)
    with pytest.raises(ValueError, match="f: returned shape"):
        integrate(lambda x, t, u: np.zeros((2, 3)), np.zeros((2, 2)), 0.0, 0.1, 2)
    with pytest.raises(ValueError, match="non-finite at step"), np.errstate(over="ignore"):
        integrate(lambda x, t, u: x**2, np.ones((1, 1)), 0.0, 0.5, 50)


def test_ode_step_is_the_contract_step_of_rk4_and_euler() -> None:
    """ode_step(rhs(x, u, t)) gives step(x, u, t, dt, rng) equal to rk4_step/euler_step on the
    same right-hand side, and RK4 substeps converge to the closed form x0 exp(-a t) + u/a."""
    from rulkit.integrate import ode_step

    a = 0.7

    def rhs(x, u, t):
        return -a * x + u

    x0 = np.array([[1.0], [2.0]])
    step = ode_step(rhs)
    np.testing.assert_array_equal(step(x0, 0.5, 0.0, 0.1, None),
                                  rk4_step(lambda x, t, u: rhs(x, u, t), x0, 0.0, 0.1, 0.5))
    eul = ode_step(rhs, method="euler", substeps=4)
    np.testing.assert_allclose(eul(x0, 0.5, 0.0, 0.1), x0 + 0.1 * (-a * x0 + 0.5), rtol=1e-2)
    exact = x0 * np.exp(-a * 1.0) + 0.5 / a * (1 - np.exp(-a * 1.0))
    np.testing.assert_allclose(ode_step(rhs, substeps=10)(x0, 0.5, 0.0, 1.0), exact, rtol=1e-6)
    with pytest.raises(ValueError, match="substeps"):
        ode_step(rhs, substeps=0)
