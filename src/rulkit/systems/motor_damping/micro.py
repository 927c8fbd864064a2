"""Micro EKF: the damping coefficient of each pull-up cycle (seed 002 eqs. 2-3, section 3.1).

State ``x_k = [w_k, c_k]`` per cycle, input the current, measurement ``z_k = [w_k, dw/dt_k]``
(or the speed alone). All cycles (and all Monte Carlo runs) are filtered together as a batch of
B units: the loop is over the samples of a cycle, never over cycles or runs. Cycles of different
lengths are padded with NaN; a unit whose samples have run out keeps its last posterior.

Two discretisations (docs/systems/motor-damping.md §2):
- ``"rk4"`` (default): one RK4 step of eq. 1 with the current linear between samples, exact
  Jacobian of the RK4 map; measurement taken at the current state and current.
- ``"seed-euler"``: the seed's eq. 3 as printed - explicit Euler with the lagged current, and
  the acceleration predicted from the previous state (:func:`measurement_seed_lagged`).

The prediction step uses the model's analytic Jacobian (``P <- F P F^T + Q``); the update is the
engine's Joseph-form :func:`~rulkit.estimation.kalman.kf_update` with the nonlinear predicted
measurement, called with ``check=False`` (shapes and finiteness still checked; the symmetry and
definiteness checks per call were a large share of the cost at 700 steps per cycle, and the
inputs are validated once here).

Bad input: non-finite current at a sample of a cycle, infinite speed or acceleration, NaN
padding that is not a tail, or a time that does not increase raise ``ValueError`` naming the
unit (row) and sample. A NaN speed or acceleration at a valid sample is a missing measurement:
that unit's update is skipped at that sample (prediction only), as in the engine's filters.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rulkit.systems.motor_damping.motor import (
    MotorConstants,
    euler_step_with_jacobian,
    measurement,
    measurement_seed_lagged,
    rk4_step_with_jacobian,
)

FloatArray = NDArray[np.float64]

__all__ = ["MicroEKFResult", "MicroEKFSettings", "micro_ekf"]


@dataclass(frozen=True)
class MicroEKFSettings:
    """Tuning of the micro EKF.

    ``c_prior``, ``c_prior_sd``: prior on the damping at the start of each cycle (wide: the sd
    covers the whole life, 1e-5 .. 1.5e-4). ``q_w`` per-step process variance of the speed
    (model error, e.g. current interpolation), ``q_c`` per-step random-walk variance of ``c``
    (0: ``c`` constant within a cycle, as in the generator). ``sigma_w``, ``sigma_dw``:
    measurement noise sds. ``use_acceleration``: False filters the speed channel alone (used
    when the acceleration was derived from the speed, whose noise it shares). ``gate``: a
    sample whose normalised innovation squared exceeds it is not used for ``c``: the speed is
    reset to its measurement (variance ``sigma_w^2``, no correlation with ``c``), so a spike in
    a channel or a glitch of the current costs a sample, not the cycle's damping (0: off, as in
    the seed and the reproduction; ``rulkit motor damping`` uses 100, a 10-sigma innovation).
    """

    scheme: str = "rk4"
    c_prior: float = 5.0e-5
    c_prior_sd: float = 2.0e-4
    q_w: float = 1.0e-10
    q_c: float = 0.0
    sigma_w: float = 0.05
    sigma_dw: float = 0.5
    use_acceleration: bool = True
    gate: float = 0.0

    def __post_init__(self) -> None:
        if self.scheme not in ("rk4", "seed-euler"):
            raise ValueError(f"scheme: expected 'rk4' or 'seed-euler', got {self.scheme!r}")
        for name in ("c_prior_sd", "sigma_w", "sigma_dw"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: expected > 0, got {getattr(self, name)}")
        for name in ("q_w", "q_c", "gate"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name}: expected >= 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class MicroEKFResult:
    """Per-unit end-of-cycle posterior: ``c`` (B,), ``c_var`` (B,), ``speed`` (B,) and
    ``mean_nis`` (B,) (average normalised innovation squared over the cycle, ~ m for a
    consistent filter), ``n_gated`` (B,) samples outside the gate. With ``keep_history``:
    ``x_hist`` (T, B, 2) and ``p_hist`` (T, B, 2, 2).
    """

    c: FloatArray
    c_var: FloatArray
    speed: FloatArray
    mean_nis: FloatArray
    x_hist: FloatArray | None = None
    p_hist: FloatArray | None = None
    n_gated: NDArray[np.int64] | None = None


def _check_inputs(
    t: FloatArray, valid: NDArray[np.bool_], current: FloatArray, speed: FloatArray,
    acc: FloatArray | None,
) -> None:
    """Refuse inputs that would silently turn the filter's state into NaN (module docstring)."""
    if not valid[:, 0].all():
        u = int(np.flatnonzero(~valid[:, 0])[0])
        raise ValueError(f"micro_ekf: time of unit {u} is NaN at sample 0 (empty cycle)")
    gap = ~valid[:, :-1] & valid[:, 1:]
    if gap.any():
        u, k = np.argwhere(gap)[0]
        raise ValueError(
            f"micro_ekf: time of unit {u} is valid again at sample {k + 1} after NaN; NaN "
            f"padding must be a tail (samples after the cycle's last one)"
        )
    with np.errstate(invalid="ignore"):
        back = valid[:, 1:] & ~(np.diff(t, axis=1) > 0)
    if back.any():
        u, k = np.argwhere(back)[0]
        raise ValueError(
            f"micro_ekf: time of unit {u} does not increase at sample {k + 1} "
            f"({float(t[u, k])!r} -> {float(t[u, k + 1])!r})"
        )
    bad_i = valid & ~np.isfinite(current)
    if bad_i.any():
        u, k = np.argwhere(bad_i)[0]
        raise ValueError(
            f"micro_ekf: current of unit {u} is {float(current[u, k])!r} at sample {k} (the "
            f"prediction needs a finite current at every sample)"
        )
    if not np.isfinite(speed[:, 0]).all():
        u = int(np.flatnonzero(~np.isfinite(speed[:, 0]))[0])
        raise ValueError(
            f"micro_ekf: speed of unit {u} is {float(speed[u, 0])!r} at sample 0 (the filter "
            f"starts from the first measured speed)"
        )
    for name, a in (("speed", speed), ("acceleration", acc)):
        if a is not None and np.isinf(a).any():
            u, k = np.argwhere(np.isinf(a))[0]
            raise ValueError(
                f"micro_ekf: {name} of unit {u} is infinite at sample {k} (NaN = missing)"
            )


def micro_ekf(
    time: np.ndarray,
    current: np.ndarray,
    speed: np.ndarray,
    acceleration: np.ndarray | None,
    consts: MotorConstants,
    settings: MicroEKFSettings | None = None,
    *,
    keep_history: bool = False,
) -> MicroEKFResult:
    """Run the micro EKF over a batch of cycles (seed eqs. 2-3; docs/systems/motor-damping.md §2).

    ``time`` (T,) shared or (B, T); ``current``, ``speed``, ``acceleration`` (B, T). NaN-padded
    tails (time NaN) mark cycles shorter than T; a NaN speed/acceleration inside a cycle is a
    missing measurement (skipped); other bad input raises ``ValueError`` (module docstring).
    ``acceleration=None`` (or
    ``settings.use_acceleration=False``) uses the speed channel only.
    """
    from rulkit.estimation.kalman import kf_update

    s = settings or MicroEKFSettings()
    speed = np.atleast_2d(np.asarray(speed, dtype=np.float64))
    current = np.atleast_2d(np.asarray(current, dtype=np.float64))
    b, n_t = speed.shape
    t = np.asarray(time, dtype=np.float64)
    t = np.broadcast_to(t, (b, n_t)) if t.ndim == 1 else t
    use_acc = acceleration is not None and s.use_acceleration
    acc = np.atleast_2d(np.asarray(acceleration, dtype=np.float64)) if use_acc else None
    bad_acc = acc is not None and acc.shape != (b, n_t)
    if current.shape != (b, n_t) or t.shape != (b, n_t) or bad_acc:
        raise ValueError("micro_ekf: time/current/speed/acceleration must share shape (B, T)")
    valid = np.isfinite(t)
    _check_inputs(t, valid, current, speed, acc)

    x = np.empty((b, 2))
    x[:, 0] = speed[:, 0]
    x[:, 1] = s.c_prior
    P = np.zeros((b, 2, 2))
    P[:, 0, 0] = s.sigma_w**2
    P[:, 1, 1] = s.c_prior_sd**2
    Q = np.diag([s.q_w, s.q_c])
    m = 2 if use_acc else 1
    R = np.diag([s.sigma_w**2, s.sigma_dw**2])[:m, :m]
    nis_sum = np.zeros(b)
    n_upd = np.zeros(b)
    n_gated = np.zeros(b, dtype=np.int64)
    n_hist = n_t if keep_history else 0
    x_hist = np.empty((n_hist, b, 2))
    p_hist = np.empty((n_hist, b, 2, 2))
    if keep_history:
        x_hist[0] = x
        p_hist[0] = P
    for k in range(1, n_t):
        ok = valid[:, k]
        dt = np.where(ok, t[:, k] - t[:, k - 1], 1.0)
        i0 = np.where(ok, current[:, k - 1], 0.0)
        i1 = np.where(ok, current[:, k], 0.0)
        if s.scheme == "rk4":
            xp, F = rk4_step_with_jacobian(x, i0, i1, dt, consts)
            zp, H = measurement(xp, i1, consts)
        else:
            xp, F = euler_step_with_jacobian(x, i0, dt, consts)
            zp, H = measurement_seed_lagged(xp, i0, dt, consts)
        Pp = F @ P @ F.transpose(0, 2, 1) + Q
        y = np.empty((b, m))
        y[:, 0] = speed[:, k]
        if acc is not None:  # use_acc
            y[:, 1] = acc[:, k]
        y = np.where(ok[:, None], y, zp[:, :m])  # padded samples: no innovation
        gated = ok & _outside_gate(y, zp[:, :m], Pp, H[:, :m, :], R, s.gate)
        y = np.where(gated[:, None], np.nan, y)  # not used for c
        xu, Pu, inn = kf_update(xp, Pp, y, H[:, :m, :], R, h_of_x=zp[:, :m], check=False)
        if gated.any():  # the speed restarts from its measurement (class docstring)
            xu[gated, 0] = speed[gated, k]
            Pu[gated, 0, :] = 0.0
            Pu[gated, :, 0] = 0.0
            Pu[gated, 0, 0] = s.sigma_w**2
            n_gated += gated
        x = np.where(ok[:, None], xu, x)
        P = np.where(ok[:, None, None], Pu, P)
        upd = ok & ~inn.skipped  # a NaN measurement is skipped (prediction only)
        nis_sum += np.where(upd, inn.nis, 0.0)
        n_upd += upd
        if keep_history:
            x_hist[k] = x
            p_hist[k] = P
    return MicroEKFResult(
        c=x[:, 1].copy(),
        c_var=P[:, 1, 1].copy(),
        speed=x[:, 0].copy(),
        mean_nis=nis_sum / np.maximum(n_upd, 1),
        x_hist=x_hist if keep_history else None,
        p_hist=p_hist if keep_history else None,
        n_gated=n_gated,
    )


def _outside_gate(y: FloatArray, zp: FloatArray, P: FloatArray, H: FloatArray, R: FloatArray,
                  gate: float) -> NDArray[np.bool_]:
    """Units (B,) whose measurement ``y`` (B, m) lies beyond ``gate`` in normalised innovation
    squared (never when ``gate`` is 0 or a channel is missing)."""
    if gate <= 0:
        return np.zeros(y.shape[0], bool)
    nu = y - zp
    S = H @ P @ np.swapaxes(H, 1, 2) + R
    with np.errstate(invalid="ignore"):
        nis = np.einsum("bi,bi->b", nu, np.linalg.solve(S, nu[..., None])[..., 0])
    return np.isfinite(nis) & (nis > gate)
