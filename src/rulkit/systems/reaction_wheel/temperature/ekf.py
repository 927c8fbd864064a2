"""Extended Kalman filters of step 1 on [I, w, T] (docs/systems/reaction-wheel.md §3.3).

- :func:`run_ekf`: the reference, batched over units on the engine's
  :class:`rulkit.estimation.ekf.ExtendedKalmanFilter` with the tangent-linear RK4 Jacobian.
- :func:`ekf_steps`: the same filter compiled (sequential scalar updates, tested equal to the
  reference), made for a user's record (docs/systems/reaction-wheel.md §3.4): time since the
  record's start (never epoch seconds) in the torque disturbance, any step between rows (a gap
  is predicted over in sub-steps of about ``dt``), missing cells (the update of that channel is
  skipped, a missing command holds the last one), an outlier gate per channel (a sample whose
  normalised innovation exceeds ``gate`` sigmas is not used), stuck sensors (a value repeated
  ``stuck_samples`` times is not used), one-sample command spikes (replaced by the previous
  command when both neighbours agree), and a re-anchoring of [I, w] at the measurement after a
  long gap or after ``reanchor_after`` rejected speed samples in a row. The state is carried
  between calls, so a record filtered in chunks gives the numbers of one pass.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numba as nb
import numpy as np

from rulkit.systems.reaction_wheel.wheel import (
    NOISE_LEVELS,
    IthacoParams,
    rk4_wheel_step,
    rk4_wheel_step_jacobian,
)
from rulkit.systems.reaction_wheel.wheel_kernels import (
    rk4_tangent_linear3,
    viscous_law,
    wheel_constants,
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
    the mean and variance of U(T_prior). Uses :class:`rulkit.estimation.ekf.ExtendedKalmanFilter`
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
    from rulkit.estimation.ekf import ExtendedKalmanFilter

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


# --------------------------------------------------------------------------------------------
# the compiled EKF for a user's record (docs/systems/reaction-wheel.md §3.4)

#: Bits of the ``flags`` the compiled EKF returns per row.
FLAG_SPEED_UNUSED = 1  # the speed sample was not used (missing, stuck or gated)
FLAG_CURRENT_UNUSED = 2  # the current sample was not used (missing, stuck or gated)
FLAG_GATED = 4  # a sample was refused by the outlier gate
FLAG_COMMAND = 8  # the command of the step was missing or a one-sample spike (replaced)
FLAG_REANCHORED = 16  # [I, w] restarted at the measurement (a long gap, or speed lost)
FLAG_GAP = 32  # the step from the previous row was longer than 1.5 dt (predicted over)


class EKFSettings(NamedTuple):
    """Scalar settings of :func:`ekf_steps` (types fixed: numba compiles one signature).

    ``dt`` the nominal sampling step (s); ``q_I``, ``q_w`` the random-walk steps of I and w per
    ``dt`` (the T steps, one per model, are an argument of :func:`ekf_steps`; a step of length
    h gets variance q^2 h / dt); ``r_w``, ``r_I`` the measurement variances; ``T_mean0``,
    ``T_var0`` the prior of T; ``p_stay`` the probability that the interacting models keep
    their model over a step (1 with one model); ``gate2`` the squared outlier gate in sigmas
    (inf: none); ``reanchor_after`` rejected speed samples in a row before [I, w] restart at
    the measurement (0: never); ``reanchor_gap`` (s) a gap after which they do;
    ``stuck_samples`` (0: off) how many equal values in a row make a sensor stuck;
    ``spike_V`` (0: off) the size of a one-sample command spike."""

    dt: float
    q_I: float
    q_w: float
    r_w: float
    r_I: float
    T_mean0: float
    T_var0: float
    p_stay: float
    gate2: float
    reanchor_after: int
    reanchor_gap: float
    stuck_samples: int
    spike_V: float


class EKFState(NamedTuple):
    """The filter between two calls of :func:`ekf_steps` (updated in place): per model the mean
    ``X`` (M, 3) of [I, w, T] and covariance ``P`` (M, 3, 3), the model probabilities ``mu``
    (M,), and ``mem`` the record's memory (its first time, the previous row, the run lengths of
    the stuck detector and of the rejected speed samples, the rows seen)."""

    X: FloatArray
    P: FloatArray
    mu: FloatArray
    mem: FloatArray


def q_ladder(low: float, high: float, n: int) -> tuple[float, ...]:
    """``n`` random-walk steps in geometric progression from ``low`` to ``high`` (the IMM's
    models; ``n = 1``: ``(low,)``)."""
    if n < 1 or not 0 < low <= high:
        raise ValueError(f"q_ladder: expected n >= 1 and 0 < low <= high, got {n}, {low}, {high}")
    return tuple(low * (high / low) ** (i / (n - 1)) for i in range(n)) if n > 1 else (low,)


@dataclass(frozen=True)
class EKFConfig:
    """Settings of the compiled EKF on a user's record (docs/systems/reaction-wheel.md §3.4); all
    [R] (the seeds have no such filter).

    ``q_T``: the random-walk step of T per sample (C) of each interacting model: one value is
    a plain EKF, several an interacting multiple-model filter (Blom and Bar-Shalom 1988) whose
    models switch with probability 1 - ``p_stay`` per step; ``q_I``, ``q_w`` the (tiny)
    process noise of [I, w]; ``T_prior`` the uniform prior of T (C), taken by its mean and
    variance; ``gate`` the outlier gate (sigmas; inf: none); ``reanchor_after`` (samples),
    ``reanchor_gap_s`` (s), ``stuck_samples`` (0: off) and ``spike_V`` (V, 0: off) as in
    :class:`EKFSettings`; ``interval_scale`` multiplies the standard deviation of the printed
    interval (mean +- z scale sd): the mixture's spread is wider than its errors, and the
    default is measured on a battery of simulated records (``benchmarks/rw_step1_accuracy.py``,
    ``--calibrate``), then checked on other seeds.
    """

    q_T: tuple[float, ...] = q_ladder(0.003, 0.1, 4)
    p_stay: float = 0.99
    q_I: float = 1e-6
    q_w: float = 1e-6
    T_prior: tuple[float, float] = (15.0, 45.0)
    gate: float = 5.0
    reanchor_after: int = 20
    reanchor_gap_s: float = 10.0
    stuck_samples: int = 10
    spike_V: float = 0.5
    interval_scale: float = 0.387

    def __post_init__(self) -> None:
        if not self.q_T or not all(q > 0 and math.isfinite(q) for q in self.q_T):
            raise ValueError(f"q_T: expected one or more positive steps (C), got {self.q_T}")
        if len(self.q_T) > 1 and not 0 < self.p_stay < 1:
            raise ValueError(f"p_stay: expected 0 < p_stay < 1 with several models, got "
                             f"{self.p_stay}")
        lo, hi = self.T_prior
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(f"T_prior: expected finite (lo, hi) with lo < hi, got {self.T_prior}")
        if not (self.gate > 0 and self.interval_scale > 0 and self.q_I >= 0 and self.q_w >= 0
                and self.reanchor_gap_s > 0 and self.spike_V >= 0):
            raise ValueError("gate, interval_scale and reanchor_gap_s must be > 0; q_I, q_w and "
                             "spike_V >= 0")
        if self.reanchor_after < 0 or self.stuck_samples < 0 or self.stuck_samples == 1:
            raise ValueError("reanchor_after must be >= 0 and stuck_samples 0 (off) or >= 2")

    def settings(self, dt: float, sigma: tuple[float, float]) -> EKFSettings:
        """The kernel's settings for sampling step ``dt`` and noise ``(sigma_w, sigma_I)``."""
        lo, hi = self.T_prior
        return EKFSettings(float(dt), float(self.q_I), float(self.q_w), float(sigma[0]) ** 2,
                           float(sigma[1]) ** 2, 0.5 * (lo + hi), (hi - lo) ** 2 / 12.0,
                           float(self.p_stay) if len(self.q_T) > 1 else 1.0,
                           float(self.gate) ** 2, int(self.reanchor_after),
                           float(self.reanchor_gap_s), int(self.stuck_samples),
                           float(self.spike_V))


#: The plain EKF of ``method="ekf"``: one model, the q_T of the reference :func:`run_ekf`, its
#: own interval (no scale), and the same handling of a record's defects.
PLAIN_EKF = EKFConfig(q_T=(0.02,), interval_scale=1.0)


#: Slots of :attr:`EKFState.mem`.
_T_FIRST, _T_PREV, _V1, _V2, _V_HOLD, _YW, _YI, _STUCK_W, _STUCK_I, _REJ_W, _ROWS = range(11)


def ekf_start(n_models: int = 1) -> EKFState:
    """An empty filter of ``n_models`` interacting models: :func:`ekf_steps` initialises it
    at the record's first row."""
    return EKFState(np.zeros((n_models, 3)), np.zeros((n_models, 3, 3)),
                    np.full(n_models, 1.0 / n_models), np.zeros(11))


@nb.njit(cache=True)
def _predict(x, P, V, h, tn0, tn1, tn2, q2, C, b0, b1):  # type: ignore[no-untyped-def]
    """One RK4 step of length ``h`` (torque disturbance ``tn0``, ``tn1``, ``tn2`` at its
    start, middle and end) with the covariance propagated by the tangent-linear Jacobian and
    the random-walk variances ``q2`` = (I, w, T) added, in place."""
    I1, w1, F = rk4_tangent_linear3(x[0], x[1], V, b0, b1, x[2], tn0, tn1, tn2, h, C)
    x[0], x[1] = I1, w1
    # P <- F P F^T with F = [[F0 F1 F2], [F3 F4 F5], [0 0 1]]
    a0 = (F[0] * P[0, 0] + F[1] * P[1, 0] + F[2] * P[2, 0],
          F[0] * P[0, 1] + F[1] * P[1, 1] + F[2] * P[2, 1],
          F[0] * P[0, 2] + F[1] * P[1, 2] + F[2] * P[2, 2])
    a1 = (F[3] * P[0, 0] + F[4] * P[1, 0] + F[5] * P[2, 0],
          F[3] * P[0, 1] + F[4] * P[1, 1] + F[5] * P[2, 1],
          F[3] * P[0, 2] + F[4] * P[1, 2] + F[5] * P[2, 2])
    p00 = a0[0] * F[0] + a0[1] * F[1] + a0[2] * F[2]
    p01 = a0[0] * F[3] + a0[1] * F[4] + a0[2] * F[5]
    p11 = a1[0] * F[3] + a1[1] * F[4] + a1[2] * F[5]
    P[0, 0] = p00 + q2[0]
    P[1, 1] = p11 + q2[1]
    P[2, 2] += q2[2]
    P[0, 1] = P[1, 0] = p01
    P[0, 2] = P[2, 0] = a0[2]
    P[1, 2] = P[2, 1] = a1[2]


@nb.njit(cache=True)
def _update(x, P, i, y, r):  # type: ignore[no-untyped-def]
    """Scalar Kalman update of state ``i`` measured as ``y`` with variance ``r``, in place;
    returns the log-likelihood of the innovation."""
    e = y - x[i]
    S = P[i, i] + r
    k0, k1, k2 = P[0, i] / S, P[1, i] / S, P[2, i] / S
    x[0] += k0 * e
    x[1] += k1 * e
    x[2] += k2 * e
    K = (k0, k1, k2)
    for a in range(3):
        for b in range(a, 3):
            v = P[a, b] - K[a] * K[b] * S
            P[a, b] = v
            P[b, a] = v
    return -0.5 * (e * e / S + math.log(2.0 * math.pi * S))


@nb.njit(cache=True)
def _explained(X, P, i, y, r, gate2):  # type: ignore[no-untyped-def]
    """Whether some model predicts ``y`` (state ``i``) within the gate."""
    for j in range(X.shape[0]):
        e = y - X[j, i]
        if e * e <= gate2 * (P[j, i, i] + r):
            return True
    return False


@nb.njit(cache=True)
def _mix(X, P, mu, p_stay, X0, P0, c):  # type: ignore[no-untyped-def]
    """The interacting-multiple-model mixing step (Blom and Bar-Shalom 1988): each model's
    start is the mixture of all models' posteriors weighted by the chance it came from them
    (switching probability (1 - p_stay) / (M - 1)); returns the predicted model
    probabilities (into ``c``)."""
    M = X.shape[0]
    off = (1.0 - p_stay) / (M - 1) if M > 1 else 0.0
    for j in range(M):
        cj = 0.0
        for i in range(M):
            cj += (p_stay if i == j else off) * mu[i]
        c[j] = cj
    for j in range(M):
        for a in range(3):
            X0[j, a] = 0.0
            for b in range(3):
                P0[j, a, b] = 0.0
        for i in range(M):
            wij = (p_stay if i == j else off) * mu[i] / c[j]
            for a in range(3):
                X0[j, a] += wij * X[i, a]
        for i in range(M):
            wij = (p_stay if i == j else off) * mu[i] / c[j]
            d0, d1, d2 = X[i, 0] - X0[j, 0], X[i, 1] - X0[j, 1], X[i, 2] - X0[j, 2]
            for a in range(3):
                da = d0 if a == 0 else (d1 if a == 1 else d2)
                P0[j, a, 0] += wij * (P[i, a, 0] + da * d0)
                P0[j, a, 1] += wij * (P[i, a, 1] + da * d1)
                P0[j, a, 2] += wij * (P[i, a, 2] + da * d2)
    X[:, :] = X0
    P[:, :, :] = P0


@nb.njit(cache=True)
def _anchor(X, P, yw, yI, s):  # type: ignore[no-untyped-def]
    """Restart [I, w] of every model at the measurement (finite channels) with the
    measurement variance, uncorrelated with T."""
    for j in range(X.shape[0]):
        if yI == yI:
            X[j, 0] = yI
        if yw == yw:
            X[j, 1] = yw
        P[j, 0, 1] = P[j, 1, 0] = P[j, 0, 2] = P[j, 2, 0] = P[j, 1, 2] = P[j, 2, 1] = 0.0
        P[j, 0, 0] = s.r_I if yI == yI else 1.0
        P[j, 1, 1] = s.r_w if yw == yw else 1e4


@nb.njit(cache=True)
def _command(v0, mem, s):  # type: ignore[no-untyped-def]
    """The command held over the step ending at a row whose own command is ``v0`` (``mem``
    holds the two before): the previous row's command, the last finite one if it is missing,
    or the one before when it is a one-sample spike both neighbours disagree with. Returns
    (command, replaced)."""
    v1, v2 = mem[_V1], mem[_V2]
    if v1 != v1:
        return mem[_V_HOLD], True
    if s.spike_V > 0.0 and v2 == v2 and v0 == v0:
        if abs(v1 - v2) > s.spike_V and abs(v1 - v0) > s.spike_V and abs(v0 - v2) <= s.spike_V:
            return v2, True
    return v1, False


@nb.njit(cache=True)
def _stuck(y, prev, count, s):  # type: ignore[no-untyped-def]
    """(new run count, stuck?) of a channel whose value ``y`` follows ``prev``."""
    if y == y and y == prev:
        count += 1.0
    else:
        count = 0.0
    return count, s.stuck_samples > 0 and count >= s.stuck_samples - 1


@nb.njit(cache=True)
def _first_row(X, P, mu, mem, t, V, yw, yI, s):  # type: ignore[no-untyped-def]
    """The prior at the record's first row: [I, w] measured, T from the prior."""
    M = X.shape[0]
    mem[_T_FIRST] = t
    for j in range(M):
        X[j, 0] = yI if yI == yI else 0.0
        X[j, 1] = yw if yw == yw else 0.0
        X[j, 2] = s.T_mean0
        P[j, :, :] = 0.0
        P[j, 0, 0] = s.r_I if yI == yI else 1.0
        P[j, 1, 1] = s.r_w if yw == yw else 1e4
        P[j, 2, 2] = s.T_var0
        mu[j] = 1.0 / M
    mem[_V_HOLD] = V if V == V else 0.0
    mem[_V2] = np.nan


@nb.njit(cache=True)
def _measure(X, P, c, i, y, r, unused, s, flag_unused):  # type: ignore[no-untyped-def]
    """Update every model with channel ``i`` unless the sample is ``unused`` (missing, stuck)
    or no model explains it; accumulates each model's log-likelihood into ``c`` (log scale).
    Returns (the row's flag bits, whether the sample was gated)."""
    if unused:
        return flag_unused, False
    if not _explained(X, P, i, y, r, s.gate2):
        return flag_unused | FLAG_GATED, True
    for j in range(X.shape[0]):
        c[j] += _update(X[j], P[j], i, y, r)
    return 0, False


@nb.njit(cache=True)
def _step(X, P, mu, mem, work, t, v0, yw, yI, s, qT, Pp, C, b0, b1):  # type: ignore[no-untyped-def]
    """One row after the first: mix, predict over the step (sub-steps across a gap), update
    with the usable channels, re-anchor when needed; returns the row's flags. ``work`` holds
    scratch arrays (X0, P0, c, ll)."""
    X0, P0, c, ll = work
    fl = 0
    tr = t - mem[_T_FIRST]
    d = tr - mem[_T_PREV]
    Vu, replaced = _command(v0, mem, s)
    if replaced:
        fl |= FLAG_COMMAND
    n = max(1, round(d / s.dt))
    h = d / n
    if abs(h - s.dt) <= 1e-4 * s.dt:  # a regular step (its times rounded in the file)
        h = s.dt
    if d > 1.5 * s.dt:
        fl |= FLAG_GAP
    M = X.shape[0]
    if M > 1:
        _mix(X, P, mu, s.p_stay, X0, P0, c)
    f = h / s.dt
    amp = Pp[7] * Pp[10] * Pp[11] * Pp[11]
    w_a = Pp[11]
    for m in range(n):  # the torque disturbance runs on the time since the record's start
        t0 = mem[_T_PREV] + m * h
        tn0 = amp * math.sin(w_a * t0)
        tn1 = amp * math.sin(w_a * (t0 + 0.5 * h))
        tn2 = amp * math.sin(w_a * (t0 + h))
        for j in range(M):
            q2 = (s.q_I * s.q_I * f, s.q_w * s.q_w * f, qT[j] * qT[j] * f)
            _predict(X[j], P[j], Vu, h, tn0, tn1, tn2, q2, C, b0, b1)
    cw, stuck_w = _stuck(yw, mem[_YW], mem[_STUCK_W], s)
    cI, stuck_I = _stuck(yI, mem[_YI], mem[_STUCK_I], s)
    mem[_STUCK_W], mem[_STUCK_I] = cw, cI
    if d > s.reanchor_gap:
        _anchor(X, P, yw, yI, s)
        mem[_REJ_W] = 0.0
        return fl | FLAG_REANCHORED
    ll[:] = 0.0
    f1, gated = _measure(X, P, ll, 1, yw, s.r_w, yw != yw or stuck_w, s, FLAG_SPEED_UNUSED)
    mem[_REJ_W] = mem[_REJ_W] + 1.0 if gated else (0.0 if f1 == 0 else mem[_REJ_W])
    f2, _ = _measure(X, P, ll, 0, yI, s.r_I, yI != yI or stuck_I, s, FLAG_CURRENT_UNUSED)
    fl |= f1 | f2
    if M > 1:
        top = -np.inf
        for j in range(M):
            ll[j] += math.log(c[j])
            top = max(top, ll[j])
        tot = 0.0
        for j in range(M):
            mu[j] = math.exp(ll[j] - top)
            tot += mu[j]
        for j in range(M):
            mu[j] /= tot
    if s.reanchor_after > 0 and mem[_REJ_W] >= s.reanchor_after:
        _anchor(X, P, yw, yI, s)
        mem[_REJ_W] = 0.0
        fl |= FLAG_REANCHORED
    return fl


@nb.njit(cache=True)
def ekf_steps(t, V, y, st, s, qT, Pp):  # type: ignore[no-untyped-def]
    """Filter the rows ``t`` (K,) absolute times (s), ``V`` (K,) commands, ``y`` (K, 2) =
    [w, I_m] (NaN: missing) from the state ``st`` (:func:`ekf_start`, updated in place);
    ``s`` an :class:`EKFSettings`, ``qT`` (M,) the T random-walk step of each interacting
    model per ``dt``, ``Pp`` the wheel's parameter vector. Returns (T_mean, T_sd, flags) per
    row: the mixture's mean and standard deviation (the first row of a record holds the
    prior)."""
    K = t.shape[0]
    X, P, mu, mem = st
    M = X.shape[0]
    C = wheel_constants(Pp)
    b0, b1 = viscous_law(Pp)
    out_m = np.empty(K)
    out_s = np.empty(K)
    flags = np.zeros(K, dtype=np.int8)
    work = (np.empty((M, 3)), np.empty((M, 3, 3)), np.empty(M), np.empty(M))
    for k in range(K):
        yw, yI = y[k, 0], y[k, 1]
        if mem[_ROWS] == 0.0:
            _first_row(X, P, mu, mem, t[k], V[k], yw, yI, s)
        else:
            flags[k] = _step(X, P, mu, mem, work, t[k], V[k], yw, yI, s, qT, Pp, C, b0, b1)
        m = 0.0
        for j in range(M):
            m += mu[j] * X[j, 2]
        v = 0.0
        for j in range(M):
            v += mu[j] * (P[j, 2, 2] + (X[j, 2] - m) ** 2)
        out_m[k] = m
        out_s[k] = math.sqrt(max(v, 0.0))
        mem[_T_PREV] = t[k] - mem[_T_FIRST]
        mem[_V2] = mem[_V1]
        mem[_V1] = V[k]
        if V[k] == V[k]:
            mem[_V_HOLD] = V[k]
        mem[_YW], mem[_YI] = yw, yI
        mem[_ROWS] += 1.0
    return out_m, out_s, flags
