"""Ithaco type-A reaction wheel after Bialke (docs/systems/reaction-wheel.md §1; seed 000/001
eqs 1-6, Table 2), vectorised over a batch of states, and the Table 3 validation path
(docs/systems/reaction-wheel.md §2).

States ``x = [I_m (A), w (rad/s)]`` (plus the wheel angle ``theta (rad)`` when the motor ripple is
kept as unmodelled dynamics). Inputs ``u = [V_comm (V), T_lub (deg C)]``, held over a step.
Outputs ``y = [w, I_m]`` plus white noise (:data:`NOISE_LEVELS`, docs/systems/reaction-wheel.md
§1.2).

    I_bus = (R_B I^2 + 0.04 |I| V_bus + P_q + K_e w I) / V_bus                       (eq. 1)
    V_h   = K_f [V_bus - 6 - (1 + R_in I_bus) 1{I_bus > 0} - K_e |w|]                 (eq. 5)
    f3    = min(V_h, 0)                                   EMF torque limiting         (eqs 5-6)
    f5    = sign(w) K_s (|w| - w_s) 1{|w| >= w_s}          speed limiter              (eqs 5-6)
    dI/dt = w_d [G_d (V_comm + f3 - f5) - I]               driver low-pass            (eq. 4)
    dw/dt = [K_t I (1 + B sin 3N theta) + C sin(N theta / 2) - b_v(T) w - tau_c sign(w)
             + J theta_a w_a^2 sin(w_a t)] / J                                          (eqs 2-4)
    b_v(T) = 1e-3 [0.049 - 0.0002 (T + 30)]  N m s/rad                                  [R]

The seed's printed viscous law ``0.0049 - 0.0002 (T + 30)`` is negative above -5.5 C; it is kept
as ``friction_law="seed_literal"`` only to show the runaway it causes (tests).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from rulkit.integrate import rk4_step
from rulkit.model import FloatArray, GaussianNoise, StateSpaceModel, as_batch

FrictionLaw = Literal["spec", "seed_literal", "linear"]
#: The viscous friction laws :func:`viscous_coefficient` knows.
FRICTION_LAWS: tuple[str, ...] = ("spec", "seed_literal", "linear")

#: Measurement noise standard deviations of seed Table 5 (sigma_w rad/s, sigma_I A).
NOISE_LEVELS: dict[str, tuple[float, float]] = {
    "low": (3e-3, 3e-2),
    "high": (3e-3, 1.3e-1),
}


@dataclass(frozen=True)
class IthacoParams:
    """Parameters of the Ithaco type-A wheel (seed Table 2; ``[R]`` = our resolution,
    docs/systems/reaction-wheel.md §1.2)."""

    G_d: float = 0.19  # drive gain, A/V
    w_d: float = 9.0  # driver bandwidth, rad/s
    K_t: float = 0.029  # torque constant, N m/A
    K_e: float = 0.029  # back-EMF constant, V s/rad
    K_s: float = 95.0  # speed-limiter gain, V s/rad
    w_s: float = 690.0  # overspeed threshold, rad/s
    tau_c: float = 0.002  # Coulomb friction, N m
    J: float = 0.0077  # flywheel inertia, kg m^2
    N_poles: int = 36  # number of motor poles
    R_in: float = 2.0  # input resistance, ohm
    K_f: float = 0.5  # voltage feedback gain, V/V
    theta_a: float = 0.05  # torque-noise angle deviation, rad
    w_a: float = 0.2  # torque-noise frequency, rad/s
    B: float = 0.0  # torque ripple factor (Table 2: 0.22); 0 by default [R]
    C: float = 0.0  # cogging amplitude (Table 2: 0)
    V_bus: float = 28.0  # bus voltage, V [R]
    R_B: float = 2.0  # bus resistance, ohm [R]
    P_q: float = 3.0  # quiescent power, W [R]
    friction_law: FrictionLaw = "spec"
    #: b_v(T) = viscous_at_0C + viscous_per_C T for ``friction_law="linear"`` (another wheel);
    #: the defaults are the law (RW-7) of docs/systems/reaction-wheel.md written that way.
    viscous_at_0C: float = 1e-3 * (0.049 - 0.0002 * 30.0)  # N m s/rad
    viscous_per_C: float = -1e-3 * 0.0002  # N m s/rad per deg C

    def __post_init__(self) -> None:
        if self.friction_law not in FRICTION_LAWS:
            raise ValueError(f"friction_law: expected one of {FRICTION_LAWS}, got "
                             f"{self.friction_law!r}")
        if self.J <= 0 or self.V_bus <= 0:
            raise ValueError("J and V_bus must be positive")

    @property
    def viscous_slope(self) -> float:
        """d b_v / dT of the law in use, N m s/rad per deg C (docs/systems/reaction-wheel.md
        §1, (RW-7))."""
        if self.friction_law == "spec":
            return -1e-3 * 0.0002
        if self.friction_law == "seed_literal":
            return -0.0002
        return self.viscous_per_C


def check_measurements(
    y: FloatArray, V: FloatArray, sigma: tuple[float, float], dt: float, *, min_rows: int = 2
) -> tuple[FloatArray, FloatArray, float, float]:
    """Validate step-1 filter inputs (docs/systems/reaction-wheel.md §3): ``y`` (K >=
    ``min_rows``, 2) = [w (rad/s), I_m (A)], ``V`` (K,) commanded voltage, ``sigma`` =
    (sigma_w, sigma_I) > 0, ``dt`` > 0.

    Returns contiguous float64 ``y``, ``V`` and the two noise levels; raises ``ValueError``
    naming the argument (and the first non-finite row).
    """
    y = np.ascontiguousarray(y, dtype=np.float64)
    V = np.ascontiguousarray(V, dtype=np.float64)
    if y.ndim != 2 or y.shape[1] != 2 or y.shape[0] < min_rows:
        raise ValueError(f"y: expected shape (K >= {min_rows}, 2) holding [w, I_m], got "
                         f"{y.shape}")
    if V.shape != (y.shape[0],):
        raise ValueError(f"V: expected shape ({y.shape[0]},), got {V.shape}")
    finite = np.isfinite(y).all(axis=1) & np.isfinite(V)
    if not finite.all():
        bad = int(np.flatnonzero(~finite)[0])
        raise ValueError(f"y and V must be finite: row {bad} is not (validate telemetry with "
                         "rulkit.systems.reaction_wheel.telemetry)")
    sw, sI = (float(s) for s in sigma)
    if not (sw > 0 and sI > 0 and np.isfinite(sw) and np.isfinite(sI)):
        raise ValueError(f"sigma: expected positive finite (sigma_w, sigma_I), got {sigma}")
    if not (dt > 0 and np.isfinite(dt)):
        raise ValueError(f"dt: must be positive, got {dt}")
    return y, V, sw, sI


def viscous_coefficient(T: FloatArray | float, law: FrictionLaw = "spec",
                        params: IthacoParams | None = None) -> FloatArray:
    """Viscous friction coefficient b_v(T) in N m s/rad (docs/systems/reaction-wheel.md §1, seed eq.
    2).

    ``"spec"``: 1e-3 [0.049 - 0.0002 (T + 30)], positive from -30 to 215 C [R].
    ``"seed_literal"``: 0.0049 - 0.0002 (T + 30) as printed (negative above -5.5 C).
    ``"linear"``: ``params.viscous_at_0C + params.viscous_per_C T`` (another wheel's law).
    """
    T = np.asarray(T, dtype=np.float64)
    if law == "spec":
        return 1e-3 * (0.049 - 0.0002 * (T + 30.0))
    if law == "seed_literal":
        return 0.0049 - 0.0002 * (T + 30.0)
    if law == "linear":
        if params is None:
            raise ValueError("friction_law 'linear' needs the wheel's params (its coefficients)")
        return params.viscous_at_0C + params.viscous_per_C * T
    raise ValueError(f"friction_law: expected one of {FRICTION_LAWS}, got {law!r}")


def wheel_derivatives(
    x: FloatArray, V_comm: FloatArray | float, T: FloatArray | float, t: float, p: IthacoParams
) -> FloatArray:
    """Time derivative of a batch of wheel states ``x`` (N, 2) or (N, 3)
    (docs/systems/reaction-wheel.md §1).

    ``V_comm`` and ``T`` are scalars or (N,) arrays. The Heaviside functions of seed eq. 6 are
    exact comparisons (docs/systems/reaction-wheel.md §1.2: MATLAB's round(0.5) differs from
    numpy's).
    """
    I = x[:, 0]
    w = x[:, 1]
    aI = np.abs(I)
    aw = np.abs(w)
    I_bus = (p.R_B * I * I + 0.04 * aI * p.V_bus + p.P_q + p.K_e * w * I) / p.V_bus
    V_h = p.K_f * (p.V_bus - 6.0 - (1.0 + p.R_in * I_bus) * (I_bus > 0.0) - p.K_e * aw)
    f3 = np.minimum(V_h, 0.0)
    f5 = np.sign(w) * p.K_s * (aw - p.w_s) * (aw >= p.w_s)
    dI = p.w_d * (p.G_d * (V_comm + f3 - f5) - I)
    torque = p.K_t * I
    if x.shape[1] == 3:
        theta = x[:, 2]
        torque = p.K_t * I * (1.0 + p.B * np.sin(3 * p.N_poles * theta)) + p.C * np.sin(
            p.N_poles * theta / 2.0
        )
    tau_noise = p.J * p.theta_a * p.w_a**2 * np.sin(p.w_a * t)
    b = viscous_coefficient(T, p.friction_law, p)
    dw = (torque - b * w - p.tau_c * np.sign(w) + tau_noise) / p.J
    if x.shape[1] == 3:
        return np.stack([dI, dw, w], axis=1)
    return np.stack([dI, dw], axis=1)


def rk4_wheel_step(
    x: FloatArray, V_comm: FloatArray | float, T: FloatArray | float, t: float, dt: float,
    p: IthacoParams,
) -> FloatArray:
    """One classical RK4 step of :func:`wheel_derivatives`, inputs held over the step."""
    def f(xx: FloatArray, tt: float, u: object) -> FloatArray:
        return wheel_derivatives(xx, V_comm, T, tt, p)

    return rk4_step(f, x, t, dt)


def wheel_jacobian(
    x: FloatArray, V_comm: FloatArray | float, T: FloatArray | float, t: float, p: IthacoParams
) -> FloatArray:
    """Jacobian of :func:`wheel_derivatives` w.r.t. the augmented state [I, w, T], (N, 3, 3)
    (last row zero: T is held). Valid away from the kinks (|w| = w_s, V_h = 0, I_bus = 0,
    w = 0), where the one-sided derivative of the active branch is used; ripple not modelled.
    """
    I = x[:, 0]
    w = x[:, 1]
    n = I.shape[0]
    sI = np.sign(I)
    sw = np.sign(w)
    I_bus = (p.R_B * I * I + 0.04 * np.abs(I) * p.V_bus + p.P_q + p.K_e * w * I) / p.V_bus
    on = (I_bus > 0.0).astype(np.float64)
    dIbus_dI = (2 * p.R_B * I + 0.04 * sI * p.V_bus + p.K_e * w) / p.V_bus
    dIbus_dw = p.K_e * I / p.V_bus
    V_h = p.K_f * (p.V_bus - 6.0 - (1.0 + p.R_in * I_bus) * on - p.K_e * np.abs(w))
    neg = (V_h < 0.0).astype(np.float64)
    df3_dI = neg * (-p.K_f * p.R_in * dIbus_dI * on)
    df3_dw = neg * p.K_f * (-p.R_in * dIbus_dw * on - p.K_e * sw)
    df5_dw = p.K_s * (np.abs(w) >= p.w_s)
    b = viscous_coefficient(T, p.friction_law, p)
    db = p.viscous_slope
    Jm = np.zeros((n, 3, 3))
    Jm[:, 0, 0] = p.w_d * (p.G_d * df3_dI - 1.0)
    Jm[:, 0, 1] = p.w_d * p.G_d * (df3_dw - df5_dw)
    Jm[:, 1, 0] = p.K_t / p.J
    Jm[:, 1, 1] = -b / p.J
    Jm[:, 1, 2] = -db * w / p.J
    return Jm


def rk4_wheel_step_jacobian(
    x: FloatArray, V_comm: float, T: FloatArray, t: float, dt: float, p: IthacoParams
) -> FloatArray:
    """Jacobian (N, 3, 3) of one RK4 step of the augmented state [I, w, T] (T held) w.r.t. its
    start, by propagating the tangent-linear RK4 stages with :func:`wheel_jacobian`."""
    h = 0.5 * dt
    X = np.asarray(x, dtype=np.float64)[:, :2]
    T = np.broadcast_to(np.asarray(T, dtype=np.float64), (X.shape[0],))
    eye = np.broadcast_to(np.eye(3), (X.shape[0], 3, 3))
    k1 = wheel_derivatives(X, V_comm, T, t, p)
    A1 = wheel_jacobian(X, V_comm, T, t, p)
    X2 = X + h * k1
    k2 = wheel_derivatives(X2, V_comm, T, t + h, p)
    D2 = eye + h * A1
    A2 = wheel_jacobian(X2, V_comm, T, t + h, p) @ D2
    X3 = X + h * k2
    k3 = wheel_derivatives(X3, V_comm, T, t + h, p)
    D3 = eye + h * A2
    A3 = wheel_jacobian(X3, V_comm, T, t + h, p) @ D3
    X4 = X + dt * k3
    D4 = eye + dt * A3
    A4 = wheel_jacobian(X4, V_comm, T, t + dt, p) @ D4
    return eye + dt / 6.0 * (A1 + 2.0 * (A2 + A3) + A4)


class ReactionWheel(StateSpaceModel):
    """Ithaco type-A reaction wheel as a :class:`StateSpaceModel` (docs/systems/reaction-wheel.md
    §1).

    ``u`` is ``[V_comm, T_lub]`` (shape (2,) or (N, 2)). ``noise`` is the Table 5 level
    ``"low"`` or ``"high"`` (or explicit ``(sigma_w, sigma_I)``). ``ripple=True`` keeps the
    motor ripple (B = 0.22, Table 2) with the wheel angle as a third state;
    docs/systems/reaction-wheel.md §1.2 uses it in the truth model only, as unmodelled dynamics.
    There is no process noise (Q = 0): the wheel is deterministic given V_comm and T_lub.
    """

    input_names = ("V_comm", "T_lub")
    output_names = ("w", "I_m")

    def __init__(
        self,
        params: IthacoParams | None = None,
        noise: str | tuple[float, float] = "low",
        ripple: bool = False,
    ) -> None:
        p = params if params is not None else IthacoParams()
        if ripple and p.B == 0.0:
            p = replace(p, B=0.22)
        self.params = p
        self.ripple = ripple
        self.state_names = ("I_m", "w", "theta") if ripple else ("I_m", "w")
        if isinstance(noise, str):
            if noise not in NOISE_LEVELS:
                raise ValueError(f"noise: expected one of {sorted(NOISE_LEVELS)}, got {noise!r}")
            sw, sI = NOISE_LEVELS[noise]
        else:
            sw, sI = (float(v) for v in noise)
        if not (sw > 0 and sI > 0):
            raise ValueError("noise standard deviations must be positive")
        self.sigma_w, self.sigma_I = sw, sI
        self._noise = GaussianNoise(np.zeros((self.n_x, self.n_x)), np.diag([sw**2, sI**2]))

    @property
    def noise(self) -> GaussianNoise:
        return self._noise

    def _split_u(self, u: FloatArray | None, n: int) -> tuple[FloatArray, FloatArray]:
        if u is None:
            raise ValueError("u: the wheel needs [V_comm, T_lub]")
        uu = np.asarray(u, dtype=np.float64)
        if uu.ndim == 1:
            uu = np.broadcast_to(uu, (n, uu.shape[0]))
        if uu.shape != (n, 2):
            raise ValueError(f"u: expected shape (2,) or ({n}, 2), got {np.shape(u)}")
        if not np.all(np.isfinite(uu)):
            raise ValueError("u: non-finite V_comm or T_lub")
        return uu[:, 0], uu[:, 1]

    def step(
        self,
        x: FloatArray,
        u: FloatArray | None,
        t: float,
        dt: float,
        rng: np.random.Generator | None = None,
    ) -> FloatArray:
        """RK4 step of length ``dt`` with ``u = [V_comm, T_lub]`` held (no process noise)."""
        xb = as_batch(x, self.n_x)
        V, T = self._split_u(u, xb.shape[0])
        return rk4_wheel_step(xb, V, T, t, dt, self.params)

    def output(self, x: FloatArray, u: FloatArray | None = None) -> FloatArray:
        """Noise-free measurement ``[w, I_m]``, shape (N, 2)."""
        xb = as_batch(x, self.n_x)
        return np.stack([xb[:, 1], xb[:, 0]], axis=1)

    def steady_state(self, V_comm: float, T: float) -> FloatArray:
        """Equilibrium ``[I, w]`` for constant V_comm and T, ignoring the (zero-mean,
        0.2 rad/s) torque noise: I = G_d V, K_t I = b_v(T) w + tau_c (below w_s, limiter off)."""
        p = self.params
        I = p.G_d * V_comm
        w = (p.K_t * I - p.tau_c * np.sign(p.K_t * I)) / viscous_coefficient(T, p.friction_law, p)
        return np.array([I, float(w)])


# --------------------------------------------------------------------------------------------
# Table 3 validation path (docs/systems/reaction-wheel.md §2)


def table3_temperature(t: FloatArray | float) -> FloatArray:
    """Lubricant temperature of the Table 3 path read as a continuous rate
    (docs/systems/reaction-wheel.md §2).

    23 C for t < 50 s; 31 exp(3e-4 (t - 50)) for 50 <= t <= 300 s (33.41 C at 300 s);
    33.41.. exp(-3e-4 (t - 300)) after (31.47 C at 500 s).
    """
    t = np.asarray(t, dtype=np.float64)
    T300 = 31.0 * np.exp(3e-4 * 250.0)
    return np.where(
        t < 50.0,
        23.0,
        np.where(t <= 300.0, 31.0 * np.exp(3e-4 * (t - 50.0)), T300 * np.exp(-3e-4 * (t - 300.0))),
    )


def table3_voltage(t: FloatArray | float) -> FloatArray:
    """Commanded voltage of the Table 3 path: 1 V before 250 s, 3 V after
    (docs/systems/reaction-wheel.md §2)."""
    t = np.asarray(t, dtype=np.float64)
    return np.where(t < 250.0, 1.0, 3.0)


@dataclass(frozen=True)
class WheelRun:
    """A simulated wheel run on a fixed grid ``t`` (K,): inputs held over ``[t_k, t_{k+1})``.

    ``x`` (K, n_x) true states, ``y`` (K, 2) noisy ``[w, I_m]``, ``V`` and ``T`` (K,) inputs.
    """

    t: FloatArray
    V: FloatArray
    T: FloatArray
    x: FloatArray
    y: FloatArray
    sigma_w: float
    sigma_I: float
    dt: float


@functools.lru_cache(maxsize=8)
def table3_trajectory(
    dt: float = 0.05,
    t_end: float = 500.0,
    initial: Literal["rest", "equilibrium"] = "rest",
    ripple: bool = False,
    params: IthacoParams | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Noise-free Table 3 run ``(t, V, T, x)`` by RK4 (cached; arrays are read-only).

    Step k -> k+1 holds V(t_k) and T(t_k); ``initial`` "rest" (I = w = 0) [R] or
    "equilibrium" (1 V, 23 C steady state).
    """
    model = ReactionWheel(params, ripple=ripple)
    if not (dt > 0 and t_end > dt):
        raise ValueError(f"need 0 < dt < t_end, got dt={dt}, t_end={t_end}")
    n = round(t_end / dt) + 1
    t = np.arange(n, dtype=np.float64) * dt
    V = table3_voltage(t)
    T = table3_temperature(t)
    x = np.zeros((n, model.n_x))
    if initial == "equilibrium":
        x[0, :2] = model.steady_state(1.0, 23.0)
    elif initial != "rest":
        raise ValueError(f"initial: expected 'rest' or 'equilibrium', got {initial!r}")
    p = model.params
    for k in range(n - 1):
        x[k + 1] = rk4_wheel_step(x[k : k + 1], V[k], T[k], t[k], dt, p)[0]
    for a in (t, V, T, x):
        a.setflags(write=False)
    return t, V, T, x


def simulate_table3(
    rng: np.random.Generator,
    noise: str | tuple[float, float] = "low",
    *,
    dt: float = 0.05,
    t_end: float = 500.0,
    initial: Literal["rest", "equilibrium"] = "rest",
    ripple: bool = False,
    params: IthacoParams | None = None,
) -> WheelRun:
    """Simulate the Table 3 validation path (docs/systems/reaction-wheel.md §2) with RK4 at ``dt``.

    Step k -> k+1 holds V(t_k) and T(t_k). ``initial="rest"`` starts at I = w = 0 [R];
    ``"equilibrium"`` at the 1 V, 23 C steady state. Measurement noise ``[w, I_m]`` is drawn
    from ``rng`` in one call after the (deterministic) trajectory.
    """
    model = ReactionWheel(params, noise=noise, ripple=ripple)
    t, V, T, x = table3_trajectory(dt, t_end, initial, ripple, model.params)
    y = model.output(x) + model.noise.sample_measurement(t.size, rng)
    return WheelRun(t, V, T, x, y, model.sigma_w, model.sigma_I, dt)
