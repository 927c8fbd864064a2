"""Steady-state alpha-beta and alpha-beta-gamma trackers (docs/systems/embedded-rul.md §2, seed 004
section 4, Kalata 1984 / Bar-Shalom 1992).

Noise convention that defines the tracking index (docs/systems/embedded-rul.md §2, seed eq 12)
    ``lambda = sigma_w dt^2 / sigma_v``. The trackers are the steady-state Kalman filters of

    * constant velocity, state (x, v): ``F = [[1, dt], [0, 1]]``, process noise ``G w`` with
      ``G = [dt^2/2, dt]``, ``w ~ N(0, sigma_w^2)`` (a piecewise-constant acceleration per step);
    * constant acceleration, state (x, v, a): ``F = [[1, dt, dt^2/2], [0, 1, dt], [0, 0, 1]]``,
      ``G = [dt^2/2, dt, 1]``, ``w ~ N(0, sigma_w^2)`` (a per-step acceleration increment),

    measured through ``H = [1, 0(, 0)]`` with variance ``sigma_v^2``. The steady-state gain is
    ``K = [alpha, beta/dt]`` resp. ``[alpha, beta/dt, gamma/dt^2]`` and depends on lambda only.
    tests/estimation/test_trackers.py checks both gain sets against
    ``scipy.linalg.solve_discrete_are`` to 1e-12 (relative) for lambda in [1e-4, 1e3].

Update conventions
    ``alpha_beta_update``: ``x += v dt; r = z - x; x += alpha r; v += beta r / dt`` (seed
    pseudo-code). ``alpha_beta_gamma_update`` uses the full constant-acceleration prediction
    ``x += v dt + a dt^2/2; v += a dt`` and the correction ``a += gamma r / dt^2`` with
    ``gamma = beta^2 / (2 alpha)``: this is the steady-state Kalman update. The seed's
    pseudo-code differs in two places: it divides the acceleration correction by ``2 dt^2``
    (half the Kalman gain, docs/systems/embedded-rul.md §2) and it does not predict ``v += a dt``;
    both are Kalman-inconsistent and not reproduced here.

Missing data: a NaN measurement skips the correction for that unit (prediction only), like the
Kalman filters; an infinite measurement raises ``ValueError``. The state itself is not scanned
(the per-update path stays at the seed's operation count): a NaN state row stays NaN for that
unit only, which :func:`rulkit.fleet.tracking.tracker_chain.tracker_update` uses for components
without an acquisition yet (it overwrites those rows at their first one).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
# A scalar or one value per unit (B,).
ScalarOrUnits = float | np.ndarray

__all__ = [
    "alpha_beta_gains",
    "alpha_beta_gamma_gains",
    "alpha_beta_gamma_update",
    "alpha_beta_update",
    "tracking_index",
]


def _positive(a: ArrayLike, name: str) -> FloatArray:
    arr = np.asarray(a, dtype=np.float64)
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        bad = np.flatnonzero(~(np.isfinite(arr) & (arr > 0)).ravel())[0]
        raise ValueError(
            f"{name}: expected positive finite values, got {arr.ravel()[bad]!r} at index {bad}"
        )
    return arr


def _out(a: FloatArray) -> FloatArray | float:
    return float(a) if a.ndim == 0 else a


def tracking_index(sigma_w: ArrayLike, sigma_v: ArrayLike, dt: ArrayLike) -> FloatArray | float:
    """Tracking index ``lambda = sigma_w dt^2 / sigma_v`` (seed eq 12, docs/systems/embedded-rul.md
    §2).

    ``sigma_w``: process-noise standard deviation (the per-step acceleration, resp. acceleration
    increment, of the module docstring); ``sigma_v``: measurement-noise standard deviation;
    ``dt``: update interval. All positive; broadcast together; a scalar in gives a float out.
    """
    w = _positive(sigma_w, "sigma_w")
    v = _positive(sigma_v, "sigma_v")
    d = _positive(dt, "dt")
    return _out(w * d * d / v)


def alpha_beta_gains(lam: ArrayLike) -> tuple[FloatArray | float, FloatArray | float]:
    """Steady-state alpha-beta gains from the tracking index (seed eqs 13-15,
    docs/systems/embedded-rul.md §2).

    ``r = (4 + lam - sqrt(8 lam + lam^2)) / 4``, ``alpha = 1 - r^2``,
    ``beta = 2 (2 - alpha) - 4 sqrt(1 - alpha) = 2 (1 - r)^2``. Evaluated without cancellation
    as ``1 - r = (lam + sqrt(lam^2 + 8 lam)) / (4 + lam + sqrt(lam^2 + 8 lam))``,
    ``alpha = (1 - r)(1 + r)``. Vectorised: scalar or array ``lam`` (> 0).
    """
    lam = _positive(lam, "lam")
    sq = np.sqrt(lam * (lam + 8.0))
    den = 4.0 + lam + sq
    u = (lam + sq) / den  # 1 - r
    r = 4.0 / den
    alpha = u * (1.0 + r)
    beta = 2.0 * u * u
    return _out(alpha), _out(beta)


def _abg_root(lam: FloatArray) -> FloatArray:
    """``u = 1 - s`` for the root s in (0, 1) of ``s^3 + b s^2 + c s - 1 = 0``
    (docs/systems/embedded-rul.md §2).

    With ``s = 1 - u`` the cubic becomes ``g(u) = u^3 - (lam/2) u^2 + (3 lam/2) u - lam = 0``;
    ``g(0) = -lam < 0 < 1 = g(1)`` and the product of its roots is lam, so exactly one root lies
    in (0, 1) for every lam > 0 (for lam < 18 g is monotone; for larger lam the other two roots
    are real but their product lam / u > 1 keeps them outside). Solved by safeguarded Newton
    iteration (bisection fallback) on the bracket [0, 1], vectorised and at full precision,
    which avoids Cardano's formula (the seed's eqs 17-23, which are misprinted and need the
    square root of a negative number once the cubic has three real roots, lam > ~20).
    """
    lam = np.asarray(lam, dtype=np.float64)
    half = 0.5 * lam
    lo = np.zeros_like(lam)
    hi = np.ones_like(lam)
    # start: u ~ lam^(1/3) for small lam (u^3 ~ lam), u -> 1 for large lam
    u = np.minimum(np.cbrt(lam), 0.5 + 0.5 * lam / (1.0 + lam))
    eps = np.finfo(np.float64).eps
    done = np.zeros(lam.shape, dtype=bool)
    for _ in range(60):
        g = ((u - half) * u + 3.0 * half) * u - lam
        lo = np.where(g < 0, u, lo)
        hi = np.where(g > 0, u, hi)
        dg = (3.0 * u - lam) * u + 3.0 * half
        with np.errstate(divide="ignore", invalid="ignore"):
            un = u - g / dg
        bad = ~((un >= lo) & (un <= hi))  # also catches NaN from dg = 0
        un = np.where(bad, 0.5 * (lo + hi), un)
        un = np.where((g == 0) | done, u, un)
        done |= np.abs(un - u) <= 8 * eps * un  # g carries rounding noise of a few ulp
        u = un
        if done.all():
            break
    return u


def alpha_beta_gamma_gains(
    lam: ArrayLike,
) -> tuple[FloatArray | float, FloatArray | float, FloatArray | float]:
    """Steady-state alpha-beta-gamma gains from the tracking index (seed eqs 16-26,
    docs/systems/embedded-rul.md §2).

    ``s`` is the root in (0, 1) of ``s^3 + b s^2 + c s - 1 = 0``, ``b = lam/2 - 3``,
    ``c = lam/2 + 3``; ``alpha = 1 - s^2``, ``beta = 2 (1 - s)^2``, ``gamma = beta^2 / (2
    alpha)`` (so the acceleration gain is ``gamma / dt^2``, the Kalman-consistent convention).
    Computed through ``u = 1 - s`` (see :func:`_abg_root`): ``alpha = u (2 - u)``,
    ``beta = 2 u^2``, ``gamma = 2 u^3 / (2 - u)``. Vectorised: scalar or array ``lam`` (> 0).
    """
    lam = _positive(lam, "lam")
    u = _abg_root(lam)
    alpha = u * (2.0 - u)
    beta = 2.0 * u * u
    gamma = 2.0 * u**3 / (2.0 - u)
    return _out(alpha), _out(beta), _out(gamma)


def _check_state(state: np.ndarray, n: int) -> FloatArray:
    s = np.asarray(state, dtype=np.float64)
    if s.ndim != 2 or s.shape[1] != n:
        raise ValueError(f"state: expected shape (B, {n}), got {s.shape}")
    return s


def _check_z(z: ArrayLike, B: int) -> tuple[FloatArray, FloatArray | None]:
    """Measurements (B,) and the mask of missing (NaN) ones (None when none is missing)."""
    zz = np.asarray(z, dtype=np.float64)
    if zz.shape != (B,):
        raise ValueError(f"z: expected shape ({B},), got {zz.shape}")
    fin = np.isfinite(zz)
    if fin.all():
        return zz, None
    if np.any(np.isinf(zz)):
        raise ValueError(f"z: infinite value at unit {int(np.flatnonzero(np.isinf(zz))[0])}")
    return zz, ~fin


def _check_step_and_gains(dt: ArrayLike, B: int, **gains: ArrayLike) -> None:
    """``dt`` must be finite and > 0 and the gains finite, each a scalar or (B,) (a Python
    float is checked without numpy: the trackers' rank steps pass their gains so, per call)."""
    for name, val in (("dt", dt), *gains.items()):
        if type(val) is float:
            if not math.isfinite(val):
                raise ValueError(f"{name}: must be finite")
            continue
        arr = np.asarray(val, dtype=np.float64)
        if arr.ndim > 1 or (arr.ndim == 1 and arr.shape != (B,)):
            raise ValueError(f"{name}: expected a scalar or shape ({B},), got {arr.shape}")
        if not np.isfinite(arr).all():
            raise ValueError(f"{name}: must be finite")
    if not (np.asarray(dt) > 0.0).all():
        raise ValueError("dt: must be > 0 (time must advance between acquisitions)")


def alpha_beta_update(
    state: np.ndarray, z: ArrayLike, dt: ScalarOrUnits, alpha: ScalarOrUnits,
    beta: ScalarOrUnits,
) -> FloatArray:
    """One alpha-beta step for B units at once (seed section 4 pseudo-code,
    docs/systems/embedded-rul.md §2).

    ``state`` (B, 2) = (x, dx/dt); ``z`` (B,); ``dt``, ``alpha``, ``beta`` scalars or (B,).
    ``x_p = x + v dt; r = z - x_p; x = x_p + alpha r; v = v + beta r / dt``. Returns a new
    (B, 2) array (the input is not modified). NaN in ``z``: that unit is only predicted.
    """
    s = _check_state(state, 2)
    zz, missing = _check_z(z, s.shape[0])
    _check_step_and_gains(dt, s.shape[0], alpha=alpha, beta=beta)
    x = s[:, 0]
    v = s[:, 1]
    xp = x + v * dt
    r = zz - xp
    if missing is not None:
        r[missing] = 0.0
    out = np.empty_like(s)
    out[:, 0] = xp + alpha * r
    out[:, 1] = v + beta * r / dt
    return out


def alpha_beta_gamma_update(
    state: np.ndarray,
    z: ArrayLike,
    dt: ScalarOrUnits,
    alpha: ScalarOrUnits,
    beta: ScalarOrUnits,
    gamma: ScalarOrUnits,
) -> FloatArray:
    """One alpha-beta-gamma step for B units at once (docs/systems/embedded-rul.md §2; see module
    docstring).

    ``state`` (B, 3) = (x, dx/dt, d2x/dt2); ``z`` (B,); ``dt`` and gains scalars or (B,).
    ``x_p = x + v dt + a dt^2/2; v_p = v + a dt; r = z - x_p;``
    ``x = x_p + alpha r; v = v_p + beta r / dt; a = a + gamma r / dt^2`` (the steady-state
    Kalman update of the constant-acceleration model). Returns a new (B, 3) array. NaN in
    ``z``: that unit is only predicted.
    """
    s = _check_state(state, 3)
    zz, missing = _check_z(z, s.shape[0])
    _check_step_and_gains(dt, s.shape[0], alpha=alpha, beta=beta, gamma=gamma)
    x = s[:, 0]
    v = s[:, 1]
    a = s[:, 2]
    adt = a * dt
    xp = x + (v + 0.5 * adt) * dt
    r = zz - xp
    if missing is not None:
        r[missing] = 0.0
    rdt = r / dt
    out = np.empty_like(s)
    out[:, 0] = xp + alpha * r
    out[:, 1] = v + adt + beta * rdt
    out[:, 2] = a + gamma * rdt / dt
    return out
