"""The compiled wheel of wheel_kernels against the numpy model of wheel.py (the oracle): the
simulation loop, the tangent-linear RK4 Jacobian on [I, w, T], and another wheel's linear
viscous law."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rulkit.systems.reaction_wheel.wheel import (
    IthacoParams,
    rk4_wheel_step,
    rk4_wheel_step_jacobian,
    table3_trajectory,
    viscous_coefficient,
)
from rulkit.systems.reaction_wheel.wheel_kernels import (
    pack_params,
    rk4_tangent_linear3,
    simulate_states,
    viscous_law,
    wheel_constants,
)

OTHER = replace(IthacoParams(), J=0.011, K_t=0.033, K_e=0.033, friction_law="linear",
                viscous_at_0C=5.5e-5, viscous_per_C=-3e-7)


def test_compiled_simulation_equals_the_numpy_model() -> None:
    _, V, T, x = table3_trajectory()
    xs = simulate_states(np.zeros(2), np.asarray(V), np.asarray(T), 0.0, 0.05,
                         pack_params(IthacoParams()))
    np.testing.assert_allclose(xs, x, rtol=1e-13, atol=1e-12)


@pytest.mark.parametrize("p", [IthacoParams(), OTHER, IthacoParams(friction_law="seed_literal")],
                         ids=["seed", "other", "literal"])
def test_tangent_linear_step_equals_the_numpy_jacobian(p: IthacoParams) -> None:
    P = pack_params(p)
    b0, b1 = viscous_law(P)
    assert b0 + b1 * 27.0 == pytest.approx(float(viscous_coefficient(27.0, p.friction_law, p)),
                                           rel=1e-12)
    amp = p.J * p.theta_a * p.w_a**2
    t, dt = 12.3, 0.05
    tn = [amp * np.sin(p.w_a * s) for s in (t, t + dt / 2, t + dt)]
    x = np.array([[0.3, 150.0, 27.0]])
    I1, w1, F = rk4_tangent_linear3(0.3, 150.0, 2.0, b0, b1, 27.0, *tn, dt, wheel_constants(P))
    ref_x = rk4_wheel_step(x[:, :2], 2.0, 27.0, t, dt, p)[0]
    ref_F = rk4_wheel_step_jacobian(x, 2.0, x[:, 2], t, dt, p)[0]
    np.testing.assert_allclose([I1, w1], ref_x, rtol=1e-13)
    np.testing.assert_allclose(np.array(F).reshape(2, 3), ref_F[:2], rtol=1e-12, atol=1e-15)
    # and the Jacobian itself against central differences of the numpy step
    h = np.array([1e-6, 1e-4, 1e-4])
    for j in range(3):
        e = np.zeros((1, 3))
        e[0, j] = h[j]
        up = rk4_wheel_step((x + e)[:, :2], 2.0, (x + e)[0, 2], t, dt, p)[0]
        dn = rk4_wheel_step((x - e)[:, :2], 2.0, (x - e)[0, 2], t, dt, p)[0]
        np.testing.assert_allclose((up - dn) / (2 * h[j]), np.array(F).reshape(2, 3)[:, j],
                                   rtol=1e-5, atol=1e-9)
