"""The Ithaco wheel (docs/systems/reaction-wheel.md §1) compiled with numba, one particle or
one filter state at a time: the derivatives written branch-free, classical RK4, the 2x2
Jacobian and the tangent-linear RK4 step. The step-1 kernels (particle filters, RBPF) call
these; they are tested equal to the numpy model of :mod:`rulkit.systems.reaction_wheel.wheel`.

Parameter vector ``P`` (float64): G_d, w_d, K_t, K_e, K_s, w_s, tau_c, J, R_in, K_f, theta_a,
w_a, V_bus, R_B, P_q, friction law (0 spec, 1 seed literal, 2 linear), b_v at 0 C, d b_v / dT
(the linear law's); see :func:`pack_params`.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from rulkit.systems.reaction_wheel.wheel import FRICTION_LAWS, IthacoParams


def pack_params(p: IthacoParams) -> np.ndarray:
    """Pack :class:`IthacoParams` into the kernel's float64 parameter vector."""
    if p.B != 0.0 or p.C != 0.0:
        raise ValueError("the step-1 kernels model no ripple "
                         "(B = C = 0, docs/systems/reaction-wheel.md §1.2)")
    return np.array(
        [p.G_d, p.w_d, p.K_t, p.K_e, p.K_s, p.w_s, p.tau_c, p.J, p.R_in, p.K_f, p.theta_a,
         p.w_a, p.V_bus, p.R_B, p.P_q, float(FRICTION_LAWS.index(p.friction_law)),
         p.viscous_at_0C, p.viscous_per_C],
        dtype=np.float64,
    )


@nb.njit(cache=True, inline="always")
def derivatives(I, w, V, b, tn, C):  # type: ignore[no-untyped-def]
    """Wheel derivatives for one particle: the algebra of ``wheel_derivatives`` written
    branch-free (comparisons as 0/1 factors, docs/systems/reaction-wheel.md §1: Heavisides are exact
    steps) so the particle loop vectorises. ``C`` is the tuple from :func:`wheel_constants`
    (inverses
    precomputed)."""
    G_d, w_d, K_t, K_e, K_s, w_s, tau_c, inv_J, R_in, K_f, V_bus, R_B, P_q, inv_Vbus = C
    aI = abs(I)
    aw = abs(w)
    sw = (1.0 if w > 0.0 else 0.0) - (1.0 if w < 0.0 else 0.0)
    I_bus = (R_B * I * I + 0.04 * aI * V_bus + P_q + K_e * w * I) * inv_Vbus
    V_h = K_f * (V_bus - 6.0 - (1.0 + R_in * I_bus) * (1.0 if I_bus > 0.0 else 0.0) - K_e * aw)
    f3 = min(V_h, 0.0)
    f5 = sw * K_s * (aw - w_s) * (1.0 if aw >= w_s else 0.0)
    dI = w_d * (G_d * (V + f3 - f5) - I)
    dw = (K_t * I - b * w - tau_c * sw + tn) * inv_J
    return dI, dw


@nb.njit(cache=True)
def wheel_constants(P):  # type: ignore[no-untyped-def]
    """The tuple of constants :func:`derivatives` takes, from the parameter vector ``P``
    (inverses of J and V_bus precomputed)."""
    return (P[0], P[1], P[2], P[3], P[4], P[5], P[6], 1.0 / P[7], P[8], P[9], P[12], P[13],
            P[14], 1.0 / P[12])


@nb.njit(cache=True, inline="always")
def rk4(I, w, V, b, tn0, tn1, tn2, dt, C):  # type: ignore[no-untyped-def]
    """Classical RK4 step; tn0/tn1/tn2: torque noise at t, t + dt/2, t + dt."""
    k1I, k1w = derivatives(I, w, V, b, tn0, C)
    k2I, k2w = derivatives(I + 0.5 * dt * k1I, w + 0.5 * dt * k1w, V, b, tn1, C)
    k3I, k3w = derivatives(I + 0.5 * dt * k2I, w + 0.5 * dt * k2w, V, b, tn1, C)
    k4I, k4w = derivatives(I + dt * k3I, w + dt * k3w, V, b, tn2, C)
    return (I + dt / 6.0 * (k1I + 2.0 * k2I + 2.0 * k3I + k4I),
            w + dt / 6.0 * (k1w + 2.0 * k2w + 2.0 * k3w + k4w))


@nb.njit(cache=True)
def viscous_law(P):  # type: ignore[no-untyped-def]
    """(b0, b1) of b_v(T) = b0 + b1 T (docs/systems/reaction-wheel.md §1, (RW-7))."""
    if P[15] > 1.5:  # another wheel's linear law
        return P[16], P[17]
    if P[15] > 0.5:  # seed literal viscous law b = 0.0049 - 0.0002 (T + 30)
        return 0.0049 - 0.0002 * 30.0, -0.0002
    return 1e-3 * (0.049 - 0.0002 * 30.0), -1e-3 * 0.0002  # b = 1e-3 (0.049 - 0.0002 (T + 30))


@nb.njit(cache=True, inline="always")
def jacobian(I, w, b, C):  # type: ignore[no-untyped-def]
    """2x2 Jacobian of the wheel derivatives w.r.t. [I, w] (T held), as
    :func:`rulkit.systems.reaction_wheel.wheel.wheel_jacobian` (one-sided at the kinks)."""
    G_d, w_d, K_t, K_e, K_s, w_s, _tau_c, inv_J, R_in, K_f, V_bus, R_B, P_q, inv_Vbus = C
    sI = (1.0 if I > 0.0 else 0.0) - (1.0 if I < 0.0 else 0.0)
    sw = (1.0 if w > 0.0 else 0.0) - (1.0 if w < 0.0 else 0.0)
    I_bus = (R_B * I * I + 0.04 * abs(I) * V_bus + P_q + K_e * w * I) * inv_Vbus
    on = 1.0 if I_bus > 0.0 else 0.0
    dbI = (2.0 * R_B * I + 0.04 * sI * V_bus + K_e * w) * inv_Vbus
    dbw = K_e * I * inv_Vbus
    V_h = K_f * (V_bus - 6.0 - (1.0 + R_in * I_bus) * on - K_e * abs(w))
    neg = 1.0 if V_h < 0.0 else 0.0
    df3_dI = neg * (-K_f * R_in * dbI * on)
    df3_dw = neg * K_f * (-R_in * dbw * on - K_e * sw)
    df5_dw = K_s * (1.0 if abs(w) >= w_s else 0.0)
    return (w_d * (G_d * df3_dI - 1.0), w_d * G_d * (df3_dw - df5_dw), K_t * inv_J, -b * inv_J)


@nb.njit(cache=True, inline="always")
def mul2(a, b):  # type: ignore[no-untyped-def]
    """Product of two 2x2 matrices given as row-major 4-tuples."""
    return (a[0] * b[0] + a[1] * b[2], a[0] * b[1] + a[1] * b[3],
            a[2] * b[0] + a[3] * b[2], a[2] * b[1] + a[3] * b[3])


@nb.njit(cache=True)
def rk4_tangent_linear(I, w, V, b, tn0, tn1, tn2, dt, C):  # type: ignore[no-untyped-def]
    """RK4 step of [I, w] and its tangent-linear Jacobian F (row-major 2x2 tuple), as
    :func:`rulkit.systems.reaction_wheel.wheel.rk4_wheel_step_jacobian` restricted to [I, w]."""
    h = 0.5 * dt
    k1I, k1w = derivatives(I, w, V, b, tn0, C)
    A1 = jacobian(I, w, b, C)
    I2, w2 = I + h * k1I, w + h * k1w
    k2I, k2w = derivatives(I2, w2, V, b, tn1, C)
    A2 = mul2(jacobian(I2, w2, b, C), (1.0 + h * A1[0], h * A1[1], h * A1[2], 1.0 + h * A1[3]))
    I3, w3 = I + h * k2I, w + h * k2w
    k3I, k3w = derivatives(I3, w3, V, b, tn1, C)
    A3 = mul2(jacobian(I3, w3, b, C), (1.0 + h * A2[0], h * A2[1], h * A2[2], 1.0 + h * A2[3]))
    I4, w4 = I + dt * k3I, w + dt * k3w
    k4I, k4w = derivatives(I4, w4, V, b, tn2, C)
    A4 = mul2(jacobian(I4, w4, b, C), (1.0 + dt * A3[0], dt * A3[1], dt * A3[2],
                                    1.0 + dt * A3[3]))
    c = dt / 6.0
    F = (1.0 + c * (A1[0] + 2.0 * (A2[0] + A3[0]) + A4[0]),
         c * (A1[1] + 2.0 * (A2[1] + A3[1]) + A4[1]),
         c * (A1[2] + 2.0 * (A2[2] + A3[2]) + A4[2]),
         1.0 + c * (A1[3] + 2.0 * (A2[3] + A3[3]) + A4[3]))
    return (I + c * (k1I + 2.0 * k2I + 2.0 * k3I + k4I),
            w + c * (k1w + 2.0 * k2w + 2.0 * k3w + k4w), F)


@nb.njit(cache=True, inline="always")
def _stage3(A, w, b1, inv_J, c, M):  # type: ignore[no-untyped-def]
    """One tangent-linear stage on the augmented state [I, w, T]: ``A`` the 2x2 Jacobian at the
    stage state, the T column d(dw/dt)/dT = -b1 w / J, ``M`` the previous stage's 2x3 block
    (row-major 6-tuple) advanced by ``c``; returns the stage's 2x3 block."""
    d00, d01, d02 = 1.0 + c * M[0], c * M[1], c * M[2]
    d10, d11, d12 = c * M[3], 1.0 + c * M[4], c * M[5]
    a12 = -b1 * w * inv_J
    return (A[0] * d00 + A[1] * d10, A[0] * d01 + A[1] * d11, A[0] * d02 + A[1] * d12,
            A[2] * d00 + A[3] * d10, A[2] * d01 + A[3] * d11, A[2] * d02 + A[3] * d12 + a12)


@nb.njit(cache=True)
def rk4_tangent_linear3(I, w, V, b0, b1, T, tn0, tn1, tn2, dt, C):  # type: ignore[no-untyped-def]
    """RK4 step of [I, w] with T held (b_v = b0 + b1 T) and the top two rows of its
    tangent-linear Jacobian w.r.t. [I, w, T] (row-major 6-tuple; the T row is [0, 0, 1]), as
    :func:`rulkit.systems.reaction_wheel.wheel.rk4_wheel_step_jacobian`."""
    b = b0 + b1 * T
    inv_J = C[7]
    h = 0.5 * dt
    zero = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    k1I, k1w = derivatives(I, w, V, b, tn0, C)
    M1 = _stage3(jacobian(I, w, b, C), w, b1, inv_J, 0.0, zero)
    I2, w2 = I + h * k1I, w + h * k1w
    k2I, k2w = derivatives(I2, w2, V, b, tn1, C)
    M2 = _stage3(jacobian(I2, w2, b, C), w2, b1, inv_J, h, M1)
    I3, w3 = I + h * k2I, w + h * k2w
    k3I, k3w = derivatives(I3, w3, V, b, tn1, C)
    M3 = _stage3(jacobian(I3, w3, b, C), w3, b1, inv_J, h, M2)
    I4, w4 = I + dt * k3I, w + dt * k3w
    k4I, k4w = derivatives(I4, w4, V, b, tn2, C)
    M4 = _stage3(jacobian(I4, w4, b, C), w4, b1, inv_J, dt, M3)
    c = dt / 6.0
    F = (1.0 + c * (M1[0] + 2.0 * (M2[0] + M3[0]) + M4[0]),
         c * (M1[1] + 2.0 * (M2[1] + M3[1]) + M4[1]),
         c * (M1[2] + 2.0 * (M2[2] + M3[2]) + M4[2]),
         c * (M1[3] + 2.0 * (M2[3] + M3[3]) + M4[3]),
         1.0 + c * (M1[4] + 2.0 * (M2[4] + M3[4]) + M4[4]),
         c * (M1[5] + 2.0 * (M2[5] + M3[5]) + M4[5]))
    return (I + c * (k1I + 2.0 * k2I + 2.0 * k3I + k4I),
            w + c * (k1w + 2.0 * k2w + 2.0 * k3w + k4w), F)


@nb.njit(cache=True)
def simulate_states(x0, V, T, t0, dt, P):  # type: ignore[no-untyped-def]
    """The noise-free wheel [I, w] (K, 2) from ``x0`` by RK4: step k -> k+1 holds ``V[k]`` and
    ``T[k]`` and starts at time ``t0 + k dt`` (as
    :func:`rulkit.systems.reaction_wheel.wheel.table3_trajectory`)."""
    K = V.shape[0]
    C = wheel_constants(P)
    b0, b1 = viscous_law(P)
    amp = P[7] * P[10] * P[11] * P[11]
    w_a = P[11]
    out = np.empty((K, 2))
    I, w = x0[0], x0[1]
    out[0, 0], out[0, 1] = I, w
    for k in range(K - 1):
        t = t0 + k * dt
        tn0 = amp * np.sin(w_a * t)
        tn1 = amp * np.sin(w_a * (t + 0.5 * dt))
        tn2 = amp * np.sin(w_a * (t + dt))
        I, w = rk4(I, w, V[k], b0 + b1 * T[k], tn0, tn1, tn2, dt, C)
        out[k + 1, 0], out[k + 1, 1] = I, w
    return out
