"""Reaction-wheel BLDC/DC motor with a degrading viscous damping coefficient (seed 002).

Physics (seed 002 eq. 1): ``T_gen = K I = J dw/dt + c w + T_L`` with torque constant ``K``,
rotor inertia ``J``, viscous damping ``c`` (the health parameter, growing over cycles) and a
constant load torque ``T_L``. In a pull-up test the drive applies maximum voltage and the
(current-limited) driver delivers a current with an initial spike that settles to a steady
value; we model it as ``I(t) = I_s + I_p exp(-t / tau_I)`` (docs/systems/motor-damping.md §5 [R]).

Contents
--------
- :class:`MotorConstants`: the synthetic motor's constants (documented,
docs/systems/motor-damping.md §5).
- :func:`speed_derivative`, :func:`pullup_speed_exact`: eq. 1 and its closed-form solution
  under the exponential current (the oracle for every integrator here).
- :func:`rk4_step_with_jacobian`, :func:`euler_step_with_jacobian`, :func:`measurement`,
  :func:`measurement_seed_lagged`: the micro-EKF transition and measurement functions with
  their analytic Jacobians (seed eqs. 2-3), for a batch of units with state ``[w, c]``.
- :class:`DCMotor`: the same physics as a :class:`~rulkit.model.StateSpaceModel`.
- :class:`VoltageDCMotor`: the motor with its electrical circuit under an applied voltage
  (states ``[i, w]``), used to check the physics against the closed-form steady state.
- :func:`failure_damping`, :func:`failure_damping_from_curves`,
  :func:`characteristic_curve_slope`: the failure threshold from the torque-speed curve and the
  design point (seed section 4.2).
- :func:`simulate_life_test`: the seeded synthetic life-test generator (pull-up cycles).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from rulkit.model import GaussianNoise, StateSpaceModel, as_batch

FloatArray = NDArray[np.float64]

__all__ = [
    "DCMotor",
    "LifeTest",
    "LifeTestConfig",
    "MotorConstants",
    "VoltageDCMotor",
    "characteristic_curve_slope",
    "damping_trend",
    "euler_step_with_jacobian",
    "failure_cycle",
    "failure_damping",
    "failure_damping_from_curves",
    "measurement",
    "measurement_seed_lagged",
    "pullup_speed_exact",
    "rk4_step_with_jacobian",
    "simulate_life_test",
    "speed_derivative",
]


@dataclass(frozen=True)
class MotorConstants:
    """Constants of the synthetic reaction-wheel motor (docs/systems/motor-damping.md §5 [R]).

    The seed's SRB-361-1103 data are not public; these constants are physically sensible for a
    small reaction-wheel motor and make the seed's failure threshold come out by algebra:
    at the design point (300 rad/s, 16 mN m) under the steady current,
    ``c_fail = (K I_s - T_L - 0.016) / 300 = 1.47e-4 N m s`` (the seed's 0.000147).

    Attributes
    ----------
    K : torque constant [N m / A] (0.030).
    J : rotor + wheel inertia [kg m^2] (3.0e-3).
    T_L : constant load (friction) torque [N m] (1.4e-3).
    I_s : steady pull-up current [A] (2.05).
    I_p : initial current spike above the steady value [A] (1.95; 4 A peak).
    tau_I : decay time of the spike [s] (1.0).
    """

    K: float = 0.030
    J: float = 3.0e-3
    T_L: float = 1.4e-3
    I_s: float = 2.05
    I_p: float = 1.95
    tau_I: float = 1.0

    def __post_init__(self) -> None:
        for name in ("K", "J", "tau_I"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"MotorConstants.{name}: expected positive and finite, got {v}")
        for name in ("T_L", "I_s", "I_p"):
            v = getattr(self, name)
            if not np.isfinite(v):
                raise ValueError(f"MotorConstants.{name}: expected a finite value, got {v}")

    def current(self, t: np.ndarray | float) -> FloatArray:
        """Pull-up current ``I(t) = I_s + I_p exp(-t / tau_I)`` [A]."""
        t = np.asarray(t, dtype=np.float64)
        return self.I_s + self.I_p * np.exp(-t / self.tau_I)

    def scaled(self, K: float = 1.0, J: float = 1.0, T_L: float = 1.0) -> MotorConstants:
        """The same motor with K, J, T_L multiplied by the given factors (constants known with
        error, docs/systems/motor-damping.md §5)."""
        return replace(self, K=self.K * K, J=self.J * J, T_L=self.T_L * T_L)


# ---------------------------------------------------------------------------------------------
# Physics: eq. 1 and its closed form
# ---------------------------------------------------------------------------------------------


def speed_derivative(
    w: np.ndarray, c: np.ndarray, current: np.ndarray, consts: MotorConstants
) -> FloatArray:
    """Angular acceleration from seed eq. 1: ``dw/dt = (K I - T_L - c w) / J`` (broadcasts)."""
    return (consts.K * np.asarray(current) - consts.T_L - np.asarray(c) * np.asarray(w)) / consts.J


def pullup_speed_exact(
    t: np.ndarray, c: np.ndarray, consts: MotorConstants, w0: np.ndarray | float = 0.0
) -> FloatArray:
    """Closed-form speed of eq. 1 under ``I(t) = I_s + I_p exp(-t/tau_I)`` from ``w(0) = w0``.

    With ``lam = c / J`` and ``mu = 1 / tau_I``:
    ``w(t) = w0 e^{-lam t} + (K I_s - T_L)/c (1 - e^{-lam t})
             + (K I_p / J) (e^{-mu t} - e^{-lam t}) / (lam - mu)``,
    with the limits ``c -> 0`` (``(K I_s - T_L) t / J``) and ``lam -> mu``
    (``(K I_p / J) t e^{-mu t}``) handled. ``c`` has shape (B,) (or scalar), ``t`` (T,);
    the result has shape (B, T) (or (T,) for scalar ``c``).
    """
    t = np.asarray(t, dtype=np.float64)
    c_arr = np.asarray(c, dtype=np.float64)
    scalar = c_arr.ndim == 0
    c2 = np.atleast_1d(c_arr)[:, None]
    w0a = np.atleast_1d(np.asarray(w0, dtype=np.float64))[:, None]
    lam = c2 / consts.J
    mu = 1.0 / consts.tau_I
    e_lam = np.exp(-lam * t)
    drive = consts.K * consts.I_s - consts.T_L
    # (1 - e^{-lam t}) / lam, stable for small lam via expm1
    small = np.abs(lam) < 1e-300
    lam_safe = np.where(small, 1.0, lam)
    one_minus = np.where(small, t, -np.expm1(-lam * t) / lam_safe)
    steady_part = drive / consts.J * one_minus
    d = lam - mu
    near = np.abs(d) < 1e-9 * mu
    d_safe = np.where(near, 1.0, d)
    spike = np.where(near, t * np.exp(-mu * t), (np.exp(-mu * t) - e_lam) / d_safe)
    w = w0a * e_lam + steady_part + consts.K * consts.I_p / consts.J * spike
    return w[0] if scalar else w


# ---------------------------------------------------------------------------------------------
# Micro-EKF transition and measurement functions with analytic Jacobians (seed eqs. 2-3)
# ---------------------------------------------------------------------------------------------


def _f(w: FloatArray, c: FloatArray, i: FloatArray, consts: MotorConstants) -> FloatArray:
    return (consts.K * i - consts.T_L - c * w) / consts.J


def rk4_step_with_jacobian(
    x: FloatArray,
    i0: FloatArray,
    i1: FloatArray,
    dt: FloatArray | float,
    consts: MotorConstants,
) -> tuple[FloatArray, FloatArray]:
    """One classical RK4 step of eq. 1 for states ``x = [w, c]`` (B, 2), and its Jacobian.

    The current is linear between the samples ``i0`` (start) and ``i1`` (end) of the step
    (midpoint value ``(i0 + i1)/2`` for the stages k2, k3); ``c`` is constant over the step
    (seed eq. 3, second row). ``dt`` is a scalar or (B,). The Jacobian ``F = d x_next / d x``
    (B, 2, 2) is the exact derivative of the RK4 map, obtained by differentiating the four
    stages (forward sensitivities) - the default micro-EKF discretisation
    (docs/systems/motor-damping.md §2: "discretise exactly or with RK4").
    """
    w = x[:, 0]
    c = x[:, 1]
    dt = np.asarray(dt, dtype=np.float64)
    h2 = 0.5 * dt
    im = 0.5 * (i0 + i1)
    a = -c / consts.J  # df/dw
    k1 = _f(w, c, i0, consts)
    dk1_w = a
    dk1_c = -w / consts.J
    w2 = w + h2 * k1
    k2 = _f(w2, c, im, consts)
    dk2_w = a * (1.0 + h2 * dk1_w)
    dk2_c = -w2 / consts.J + a * h2 * dk1_c
    w3 = w + h2 * k2
    k3 = _f(w3, c, im, consts)
    dk3_w = a * (1.0 + h2 * dk2_w)
    dk3_c = -w3 / consts.J + a * h2 * dk2_c
    w4 = w + dt * k3
    k4 = _f(w4, c, i1, consts)
    dk4_w = a * (1.0 + dt * dk3_w)
    dk4_c = -w4 / consts.J + a * dt * dk3_c
    s6 = dt / 6.0
    w_next = w + s6 * (k1 + 2.0 * (k2 + k3) + k4)
    dw_w = 1.0 + s6 * (dk1_w + 2.0 * (dk2_w + dk3_w) + dk4_w)
    dw_c = s6 * (dk1_c + 2.0 * (dk2_c + dk3_c) + dk4_c)
    x_next = np.stack([w_next, c], axis=1)
    F = np.zeros((x.shape[0], 2, 2))
    F[:, 0, 0] = dw_w
    F[:, 0, 1] = dw_c
    F[:, 1, 1] = 1.0
    return x_next, F


def euler_step_with_jacobian(
    x: FloatArray, i0: FloatArray, dt: FloatArray | float, consts: MotorConstants
) -> tuple[FloatArray, FloatArray]:
    """Seed eq. 3, first block (explicit Euler with the lagged current ``I_{k-1}``), and its
    Jacobian: ``w_k = w_{k-1} + (-c w_{k-1} - T_L + K I_{k-1}) dt / J``, ``c_k = c_{k-1}``;
    ``F = [[1 - c dt/J, -w dt/J], [0, 1]]``."""
    w = x[:, 0]
    c = x[:, 1]
    dt = np.asarray(dt, dtype=np.float64)
    w_next = w + dt * _f(w, c, i0, consts)
    F = np.zeros((x.shape[0], 2, 2))
    F[:, 0, 0] = 1.0 - c * dt / consts.J
    F[:, 0, 1] = -w * dt / consts.J
    F[:, 1, 1] = 1.0
    return np.stack([w_next, c], axis=1), F


def measurement(
    x: FloatArray, i: FloatArray, consts: MotorConstants
) -> tuple[FloatArray, FloatArray]:
    """Measurement ``z = [w, dw/dt]`` taken at the current state and current (default form):
    ``h(x) = [w, (K I - T_L - c w)/J]``, ``H = [[1, 0], [-c/J, -w/J]]``; shapes (B, 2), (B, 2, 2).
    """
    w = x[:, 0]
    c = x[:, 1]
    z = np.stack([w, _f(w, c, i, consts)], axis=1)
    H = np.zeros((x.shape[0], 2, 2))
    H[:, 0, 0] = 1.0
    H[:, 1, 0] = -c / consts.J
    H[:, 1, 1] = -w / consts.J
    return z, H


def measurement_seed_lagged(
    x: FloatArray, i_prev: FloatArray, dt: FloatArray | float, consts: MotorConstants
) -> tuple[FloatArray, FloatArray]:
    """Seed eq. 3's measurement: the acceleration is predicted from the *previous* state and
    current, ``(-c_{k-1} w_{k-1} - T_L + K I_{k-1}) / J``, written as a function of the
    current (Euler-predicted) state so an EKF can linearise it.

    With ``c_k = c_{k-1}`` and the Euler step, ``w_{k-1} = (w_k - b dt) / (1 - c dt / J)`` with
    ``b = (K I_{k-1} - T_L) / J``; so ``h_2(x) = b - c (w - b dt) / (J s)``, ``s = 1 - c dt/J``,
    ``dh_2/dw = -c / (J s)``, ``dh_2/dc = -(w - b dt) / (J s^2)``.
    """
    w = x[:, 0]
    c = x[:, 1]
    dt = np.asarray(dt, dtype=np.float64)
    b = (consts.K * i_prev - consts.T_L) / consts.J
    u = w - b * dt
    s = 1.0 - c * dt / consts.J
    z = np.stack([w, b - c * u / (consts.J * s)], axis=1)
    H = np.zeros((x.shape[0], 2, 2))
    H[:, 0, 0] = 1.0
    H[:, 1, 0] = -c / (consts.J * s)
    H[:, 1, 1] = -u / (consts.J * s * s)
    return z, H


# ---------------------------------------------------------------------------------------------
# State-space model classes
# ---------------------------------------------------------------------------------------------


class DCMotor(StateSpaceModel):
    """Eq. 1 as a state-space model: state ``[w, c]``, input current, output ``[w, dw/dt]``.

    ``step`` integrates one RK4 step with the current held (u of shape (N, 1) or (1,)) or
    linear between the step's end points (u of shape (N, 2): ``[I_k, I_{k+1}]``); ``c`` is a
    random walk with per-step variance ``q_c``. Failure when ``c >= c_fail``.
    """

    state_names = ("speed", "damping")
    input_names = ("current",)
    output_names = ("speed", "acceleration")

    def __init__(
        self,
        consts: MotorConstants | None = None,
        *,
        q_w: float = 1e-6,
        q_c: float = 0.0,
        sigma_w: float = 0.05,
        sigma_dw: float = 0.5,
        c_fail: float | None = None,
    ) -> None:
        self.consts = consts or MotorConstants()
        self._noise = GaussianNoise(Q=np.diag([q_w, q_c]), R=np.diag([sigma_w**2, sigma_dw**2]))
        self.threshold = failure_damping(self.consts) if c_fail is None else float(c_fail)

    @property
    def noise(self) -> GaussianNoise:
        """The Gaussian process and measurement noise (model contract, docs/engine.md)."""
        return self._noise

    def _currents(self, u: FloatArray | None, n: int) -> tuple[FloatArray, FloatArray]:
        if u is None:
            raise ValueError("u: the motor needs the current as input, got None")
        arr = np.asarray(u, dtype=np.float64)
        if arr.ndim == 1:
            arr = np.broadcast_to(arr, (n, arr.shape[0]))
        if arr.ndim != 2 or arr.shape[0] != n or arr.shape[1] not in (1, 2):
            raise ValueError(f"u: expected shape (N, 1), (N, 2), (1,) or (2,), got {np.shape(u)}")
        return arr[:, 0], arr[:, -1]

    def step(
        self,
        x: FloatArray,
        u: FloatArray | None,
        t: float,
        dt: float,
        rng: np.random.Generator | None = None,
    ) -> FloatArray:
        """One RK4 step of the batch of states [speed, damping] (N, 2) over ``dt`` under the
        current ``u``, plus process noise when ``rng`` is given (model contract)."""
        x = as_batch(x, 2)
        i0, i1 = self._currents(u, x.shape[0])
        x_next, _ = rk4_step_with_jacobian(x, i0, i1, dt, self.consts)
        if rng is not None:
            x_next = x_next + self._noise.sample_process(x.shape[0], rng)
        return x_next

    def output(self, x: FloatArray, u: FloatArray | None = None) -> FloatArray:
        """The measured speed (and acceleration) of each state in the batch."""
        x = as_batch(x, 2)
        i0, _ = self._currents(u, x.shape[0])
        return measurement(x, i0, self.consts)[0]

    def health(self, x: FloatArray) -> FloatArray:
        """The damping coefficient c of each state, shape (N,) (rises towards c_fail)."""
        return as_batch(x, 2)[:, 1]


class VoltageDCMotor:
    """The motor with its armature circuit under an applied voltage ``V`` (states ``[i, w]``):

    ``L di/dt = V - R i - K w``, ``J dw/dt = K i - c w - T_L`` (eq. 1 plus the circuit; the
    back-EMF constant equals the torque constant in SI units). Steady state (closed form):
    ``w_ss = (K V - R T_L) / (K^2 + R c)``, ``i_ss = (c w_ss + T_L) / K``.
    """

    def __init__(
        self,
        consts: MotorConstants | None = None,
        *,
        R: float = 1.5,
        L: float = 1.0e-3,
        c: float = 1.0e-5,
    ) -> None:
        self.consts = consts or MotorConstants()
        if not (R > 0 and L > 0 and c >= 0):
            raise ValueError(f"VoltageDCMotor: expected R > 0, L > 0, c >= 0; got {R}, {L}, {c}")
        self.R, self.L, self.c = float(R), float(L), float(c)

    def rhs(self, x: FloatArray, t: float, u: FloatArray | None) -> FloatArray:
        """``f(x (N, 2), t, u (N, 1) = V) -> dx/dt`` (the :mod:`rulkit.integrate` convention)."""
        if u is None:
            raise ValueError("u: the voltage motor needs the voltage as input, got None")
        v = np.asarray(u)[:, 0]
        i = x[:, 0]
        w = x[:, 1]
        k = self.consts.K
        di = (v - self.R * i - k * w) / self.L
        dw = (k * i - self.c * w - self.consts.T_L) / self.consts.J
        return np.stack([di, dw], axis=1)

    def steady_state(self, voltage: float) -> tuple[float, float]:
        """Closed-form ``(i_ss, w_ss)`` under a constant voltage."""
        k = self.consts.K
        w_ss = (k * voltage - self.R * self.consts.T_L) / (k * k + self.R * self.c)
        i_ss = (self.c * w_ss + self.consts.T_L) / k
        return i_ss, w_ss


# ---------------------------------------------------------------------------------------------
# Failure threshold from the torque-speed characteristic curve (seed section 4.2)
# ---------------------------------------------------------------------------------------------


def failure_damping(
    consts: MotorConstants,
    design_speed: float = 300.0,
    design_torque: float = 16e-3,
    steady_current: float | None = None,
) -> float:
    """Damping at which the characteristic curve passes through the design point.

    Under the steady current the curve is ``T_out = J dw/dt = K I_s - T_L - c w`` (eq. 1), a line
    of slope ``-c``; it falls below the design point ``(w_d, T_d)`` when
    ``c > c_fail = (K I_s - T_L - T_d) / w_d`` (docs/systems/motor-damping.md §4).
    With the default constants: (0.0615 - 0.0014 - 0.016) / 300 = 1.47e-4.
    """
    i_s = consts.I_s if steady_current is None else float(steady_current)
    if not (design_speed > 0):
        raise ValueError(f"design_speed: expected > 0, got {design_speed}")
    c_fail = (consts.K * i_s - consts.T_L - design_torque) / design_speed
    if not c_fail > 0:
        raise ValueError(
            f"failure_damping: the design point ({design_speed} rad/s, {design_torque} N m) is "
            f"above the undamped curve (K I_s - T_L = {consts.K * i_s - consts.T_L:.4g} N m)"
        )
    return float(c_fail)


def characteristic_curve_slope(
    speed: np.ndarray, torque: np.ndarray, mask: np.ndarray | None = None
) -> FloatArray:
    """Least-squares slope ``dT_out/dw`` of each curve (rows of ``speed``/``torque``, (B, T)),
    over the samples selected by ``mask`` (e.g. the steady-current part). Seed Fig. 11.

    ``ValueError`` (naming the curve) for non-finite selected samples or fewer than two
    distinct selected speeds (the slope would be NaN)."""
    w = np.atleast_2d(np.asarray(speed, dtype=np.float64))
    tq = np.atleast_2d(np.asarray(torque, dtype=np.float64))
    if w.shape != tq.shape or w.ndim != 2:
        raise ValueError(f"speed and torque: expected equal (B, T) shapes, got {w.shape}, "
                         f"{tq.shape}")
    m = np.ones_like(w, dtype=bool) if mask is None else np.broadcast_to(mask, w.shape)
    bad = m & ~(np.isfinite(w) & np.isfinite(tq))
    if bad.any():
        b, k = np.argwhere(bad)[0]
        raise ValueError(f"curve {b}: non-finite speed or torque at selected sample {k}")
    n = m.sum(axis=1)
    wm = np.where(m, w, 0.0).sum(axis=1) / np.maximum(n, 1)
    tm = np.where(m, tq, 0.0).sum(axis=1) / np.maximum(n, 1)
    dw = np.where(m, w - wm[:, None], 0.0)
    dtq = np.where(m, tq - tm[:, None], 0.0)
    sxx = (dw * dw).sum(axis=1)
    if np.any(sxx <= 0):
        b = int(np.flatnonzero(sxx <= 0)[0])
        raise ValueError(
            f"curve {b}: {int(n[b])} selected sample(s) with no spread in speed; a slope needs "
            f"at least two distinct speeds"
        )
    return (dw * dtq).sum(axis=1) / sxx


def failure_damping_from_curves(
    speed: np.ndarray,
    torque: np.ndarray,
    damping: np.ndarray,
    design_speed: float = 300.0,
    design_torque: float = 16e-3,
    mask: np.ndarray | None = None,
) -> float:
    """``c_fail`` from a family of characteristic curves (seed section 4.2, Figs. 10-12).

    For each curve (row) fit ``T_out = T0 + s w`` over the masked samples and evaluate it at the
    design speed; then interpolate the per-curve damping values (e.g. micro-EKF estimates)
    against those torques to the design torque (linear fit of damping vs torque at the design
    speed, which is exact when ``T_out(w_d) = K I_s - T_L - c w_d``). No motor constant is used.
    """
    w = np.atleast_2d(np.asarray(speed, dtype=np.float64))
    tq = np.atleast_2d(np.asarray(torque, dtype=np.float64))
    c = np.asarray(damping, dtype=np.float64).ravel()
    if w.shape != tq.shape or w.shape[0] != c.shape[0] or w.shape[0] < 2:
        raise ValueError(
            f"failure_damping_from_curves: expected speed/torque (B, T) and damping (B,) with "
            f"B >= 2, got {w.shape}, {tq.shape}, {c.shape}"
        )
    m = np.ones_like(w, dtype=bool) if mask is None else np.broadcast_to(mask, w.shape)
    slope = characteristic_curve_slope(w, tq, m)
    n = m.sum(axis=1)
    wm = np.where(m, w, 0.0).sum(axis=1) / n
    tm = np.where(m, tq, 0.0).sum(axis=1) / n
    torque_at_design = tm + slope * (design_speed - wm)
    coef = np.polyfit(torque_at_design, c, 1)
    return float(np.polyval(coef, design_torque))


# ---------------------------------------------------------------------------------------------
# Synthetic life test (docs/systems/motor-damping.md §5)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LifeTestConfig:
    """Settings of the synthetic life test (docs/systems/motor-damping.md §5 [R]).

    Damping trend over cycles ``n = 1..n_cycles``: ``c_trend(n) = c0 + a n + b n^2`` (``b`` =
    ``curvature``, 0 for the seed's linear law eq. 4; > 0 for an accelerating law); each cycle's
    true damping is ``c_n = c_trend(n) + e_n`` with ``e_n ~ N(0, scatter_sd^2)`` (clipped at a
    small positive floor). Each cycle is a pull-up from rest of ``duration`` seconds sampled
    every ``dt`` (``t_k = k dt``, k = 0..T-1) with noisy speed, acceleration and current.
    ``acceleration = "measured"`` adds independent noise of sd ``sigma_dw``; ``"differenced"``
    derives it from the noisy speed by central differences (correlated noise).
    """

    consts: MotorConstants = field(default_factory=MotorConstants)
    n_cycles: int = 68
    c0: float = 1.0e-5
    slope: float = 2.0e-6
    curvature: float = 0.0
    scatter_sd: float = 2.0e-6
    duration: float = 35.0
    dt: float = 0.05
    sigma_w: float = 0.05
    sigma_dw: float = 0.5
    sigma_i: float = 0.0
    acceleration: str = "measured"

    def __post_init__(self) -> None:
        if int(self.n_cycles) != self.n_cycles or self.n_cycles < 1:
            raise ValueError(f"n_cycles: expected a positive integer, got {self.n_cycles}")
        if not (self.dt > 0 and self.duration >= 2 * self.dt):
            raise ValueError(f"dt/duration: expected 0 < 2 dt <= duration, got {self.dt}, "
                             f"{self.duration}")
        for name in ("scatter_sd", "sigma_w", "sigma_dw", "sigma_i", "curvature"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name}: expected >= 0, got {getattr(self, name)}")
        if self.acceleration not in ("measured", "differenced"):
            raise ValueError(
                f"acceleration: expected 'measured' or 'differenced', got {self.acceleration!r}"
            )

    @property
    def time(self) -> FloatArray:
        """Sample times of one pull-up cycle, 0 to ``duration`` in steps of ``dt``."""
        n = round(self.duration / self.dt) + 1
        return self.dt * np.arange(n, dtype=np.float64)


def damping_trend(n: np.ndarray | float, c0: float, slope: float, curvature: float = 0.0):
    """``c_trend(n) = c0 + a n + b n^2`` (seed eq. 4 for b = 0)."""
    n = np.asarray(n, dtype=np.float64)
    return c0 + slope * n + curvature * n * n


def failure_cycle(c_fail: float, c0: float, slope: float, curvature: float = 0.0) -> float:
    """Cycle (real number) at which the trend crosses ``c_fail``: root of
    ``c0 + a n + b n^2 = c_fail`` (the true end of life used for RUL truth)."""
    d = c_fail - c0
    if curvature == 0.0:
        return d / slope if slope > 0 else np.inf
    return float((-slope + np.sqrt(slope * slope + 4.0 * curvature * d)) / (2.0 * curvature))


@dataclass(frozen=True)
class LifeTest:
    """One synthetic life test: ``n`` cycles of ``T`` samples each.

    ``cycle`` (n,) cycle numbers 1..n; ``time`` (T,); ``current``, ``speed``, ``acceleration``
    (n, T) measured; ``damping`` (n,) each cycle's true damping; ``trend`` (n,) the noise-free
    trend; ``c_fail`` the failure damping; ``eol`` the cycle at which the trend crosses it.
    """

    config: LifeTestConfig
    cycle: FloatArray
    time: FloatArray
    current: FloatArray
    speed: FloatArray
    acceleration: FloatArray
    damping: FloatArray
    trend: FloatArray
    c_fail: float
    eol: float


def simulate_life_test(
    config: LifeTestConfig, rng: np.random.Generator, c_fail: float | None = None
) -> LifeTest:
    """Seeded synthetic pull-up life test (docs/systems/motor-damping.md §5); all cycles at once.

    Speeds come from the closed form :func:`pullup_speed_exact` (no integration error), so the
    only errors in the data are the stated noises. Reproducible from ``rng``'s seed.
    """
    cfg = config
    consts = cfg.consts
    c_fail = failure_damping(consts) if c_fail is None else float(c_fail)
    t = cfg.time
    n = np.arange(1, cfg.n_cycles + 1, dtype=np.float64)
    trend = damping_trend(n, cfg.c0, cfg.slope, cfg.curvature)
    damping = np.maximum(trend + cfg.scatter_sd * rng.standard_normal(n.shape), 1e-9)
    w_true = pullup_speed_exact(t, damping, consts)
    i_true = np.broadcast_to(consts.current(t), w_true.shape)
    dw_true = speed_derivative(w_true, damping[:, None], i_true, consts)
    speed = w_true + cfg.sigma_w * rng.standard_normal(w_true.shape)
    current = i_true + cfg.sigma_i * rng.standard_normal(w_true.shape)
    if cfg.acceleration == "measured":
        accel = dw_true + cfg.sigma_dw * rng.standard_normal(w_true.shape)
    else:
        accel = np.gradient(speed, cfg.dt, axis=1)
    return LifeTest(
        config=cfg,
        cycle=n,
        time=t,
        current=np.ascontiguousarray(current),
        speed=speed,
        acceleration=accel,
        damping=damping,
        trend=trend,
        c_fail=c_fail,
        eol=failure_cycle(c_fail, cfg.c0, cfg.slope, cfg.curvature),
    )
