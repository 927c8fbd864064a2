"""The reference estimator of step 1 that is not a particle filter: an extended Kalman filter
on [I, w, T] (docs/systems/reaction-wheel.md §3), batched over units on the engine's
:class:`rulkit.estimation.kalman.ExtendedKalmanFilter` with the tangent-linear RK4 Jacobian.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rulkit.systems.reaction_wheel.wheel import (
    NOISE_LEVELS,
    IthacoParams,
    rk4_wheel_step,
    rk4_wheel_step_jacobian,
)

FloatArray = np.ndarray


@dataclass(frozen=True)
class EKFResult:
    """EKF estimates of T for B units: ``T_mean``/``T_std`` (K, B); row 0 is the prior."""

    t: FloatArray
    T_mean: FloatArray
    T_std: FloatArray


def run_ekf(
    ys: FloatArray,
    V: FloatArray,
    *,
    sigma: Any = NOISE_LEVELS["low"],
    dt: float = 0.05,
    t0: float = 0.0,
    q_T: float = 0.02,
    q_Iw: tuple[float, float] = (1e-6, 1e-6),
    T_prior: tuple[float, float] = (15.0, 45.0),
    params: IthacoParams | None = None,
    analytic_jacobian: bool = True,
) -> EKFResult:
    """Extended Kalman filter on [I, w, T] (docs/systems/reaction-wheel.md §3 reference), batched
    over B units.

    ``ys`` (K, 2) or (K, B, 2) = [w, I_m] sharing the voltage ``V`` (K,); ``sigma`` is
    ``(sigma_w, sigma_I)`` or per unit (B, 2). Discrete model: one
    RK4 step of the wheel with T held, T a random walk of step ``q_T``; tiny process noise
    ``q_Iw`` on [I, w] keeps P well conditioned. Prior: [I, w] = y_0 with covariance R, T with
    the mean and variance of U(T_prior). Uses :class:`rulkit.estimation.kalman.ExtendedKalmanFilter`
    with the tangent-linear RK4 Jacobian (:func:`rk4_wheel_step_jacobian`; finite differences
    when ``analytic_jacobian=False``).
    """
    Y = np.asarray(ys, dtype=np.float64)
    if Y.ndim == 2:
        Y = Y[:, None, :]
    if Y.ndim != 3 or Y.shape[2] != 2 or Y.shape[0] < 2:
        raise ValueError(f"ys: expected shape (K, 2) or (K, B, 2), got {np.shape(ys)}")
    V = np.asarray(V, dtype=np.float64)
    K = Y.shape[0]
    if V.shape != (K,):
        raise ValueError(f"V: expected shape ({K},), got {V.shape}")
    ekf, x0, P0, clock = ekf_setup(Y[0], sigma, params, q_T=q_T, q_Iw=q_Iw, T_prior=T_prior,
                                   analytic_jacobian=analytic_jacobian)
    clock.t0, clock.dt = t0, dt
    res = ekf.filter(Y[1:], x0, P0, us=V[:-1])
    T_mean = np.vstack([x0[None, :, 2], res.x[:, :, 2]])
    T_std = np.vstack([np.sqrt(P0[None, :, 2, 2]), np.sqrt(res.P[:, :, 2, 2])])
    return EKFResult(t0 + dt * np.arange(K), T_mean, T_std)


@dataclass
class StepClock:
    """Time of step ``j`` of an EKF run: ``t0 + j dt`` (mutable, so one filter object can
    continue a record chunk after chunk)."""

    t0: float = 0.0
    dt: float = 0.05


def ekf_setup(
    y0: FloatArray,
    sigma: tuple[float, float] | FloatArray,
    params: IthacoParams | None = None,
    *,
    q_T: float = 0.02,
    q_Iw: tuple[float, float] = (1e-6, 1e-6),
    T_prior: tuple[float, float] = (15.0, 45.0),
    analytic_jacobian: bool = True,
) -> tuple[Any, FloatArray, FloatArray, StepClock]:
    """The wheel EKF of :func:`run_ekf` for B units whose first sample is ``y0`` (B, 2) =
    [w, I_m]: (filter, prior mean x0 (B, 3), prior covariance P0 (B, 3, 3), its
    :class:`StepClock`)."""
    from rulkit.estimation.kalman import ExtendedKalmanFilter

    p = params or IthacoParams()
    y0 = np.asarray(y0, dtype=np.float64)
    B = y0.shape[0]
    clock = StepClock()

    def f(x: FloatArray, u: float, j: int) -> FloatArray:
        X = rk4_wheel_step(x[:, :2], u, x[:, 2], clock.t0 + j * clock.dt, clock.dt, p)
        return np.column_stack([X, x[:, 2]])

    def jac_f(x: FloatArray, u: float, j: int) -> FloatArray:
        return rk4_wheel_step_jacobian(x, u, x[:, 2], clock.t0 + j * clock.dt, clock.dt, p)

    def h(x: FloatArray, u: float, j: int) -> FloatArray:
        return np.column_stack([x[:, 1], x[:, 0]])

    H = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])

    sg = np.broadcast_to(np.asarray(sigma, dtype=np.float64), (B, 2))  # per unit [sw, sI]
    if not np.all(sg > 0):
        raise ValueError(f"sigma: expected positive (sigma_w, sigma_I), got {sigma}")
    sw, sI = sg[:, 0], sg[:, 1]
    Q = np.diag([q_Iw[0] ** 2, q_Iw[1] ** 2, q_T**2])
    R = np.zeros((B, 2, 2))
    R[:, 0, 0], R[:, 1, 1] = sw**2, sI**2
    ekf = ExtendedKalmanFilter(f, h, Q, R, jac_f=jac_f if analytic_jacobian else None,
                               jac_h=lambda x, u, j: H)
    lo, hi = T_prior
    x0 = np.column_stack([y0[:, 1], y0[:, 0], np.full(B, 0.5 * (lo + hi))])
    P0 = np.zeros((B, 3, 3))
    P0[:, 0, 0], P0[:, 1, 1], P0[:, 2, 2] = sI**2, sw**2, (hi - lo) ** 2 / 12.0
    return ekf, x0, P0, clock
