"""Fixed-step ODE integrators over a batch of states (docs/engine-api.md; docs/guide.md).

A batch of states is an ``(N, n)`` float64 array (N particles, Monte Carlo samples or fleet
units). The right-hand side is vectorised over the batch: ``f(x (N, n), t, u) -> dxdt (N, n)``.
One call of :func:`euler_step` or :func:`rk4_step` advances every row by the same ``dt``.

Inputs ``u``
    ``None`` (passed to ``f`` as ``None``), a constant array, or a callable ``u(t)``. A 1-D
    input ``(n_u,)`` is broadcast (read-only view) to ``(N, n_u)`` before it reaches ``f``, so
    ``f`` may always index ``u[:, j]``. RK4 evaluates a callable input at ``t``, ``t + dt/2``
    and ``t + dt`` (classical RK4 on the non-autonomous system).

Accuracy: Euler has global error O(dt), classical RK4 O(dt^4) (tested against closed forms
and ``scipy.integrate.solve_ivp`` in tests/test_integrate.py).

The model contract (:mod:`rulkit.model`) advances states by ``step(x, u, t, dt, rng)``;
:func:`ode_step` turns a right-hand side written in the contract's argument order,
``rhs(x, u, t) -> dxdt``, into such a step (what a continuous-time model's ``step`` returns,
and what the EKF's continuous mode integrates). The functions above keep their older
low-level form ``f(x, t, u)``, on which :func:`ode_step` builds.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rulkit.model import plain

FloatArray = NDArray[np.float64]
RHS = Callable[[FloatArray, float, Any], FloatArray]
InputLike = None | np.ndarray | Callable[[float], Any]

__all__ = ["euler_step", "integrate", "ode_step", "rk4_step"]


def _input_at(u: InputLike, t: float, n_rows: int) -> FloatArray | None:
    """Evaluate the input at time ``t`` and return it as ``(N, n_u)`` (or None)."""
    if u is None:
        return None
    val = u(t) if callable(u) else u
    arr = np.asarray(val, dtype=np.float64)
    if arr.ndim == 0:
        arr = arr.reshape(1)
    if arr.ndim == 1:
        return np.broadcast_to(arr, (n_rows, arr.shape[0]))
    if arr.ndim != 2 or arr.shape[0] != n_rows:
        raise ValueError(f"u: expected shape (n_u,) or ({n_rows}, n_u) at t={plain(t)}, got "
                         f"{arr.shape}")
    return arr


def euler_step(f: RHS, x: FloatArray, t: float, dt: float, u: InputLike = None) -> FloatArray:
    """One explicit Euler step ``x + dt f(x, t, u(t))`` for a batch ``x`` of shape (N, n)."""
    x = np.asarray(x, dtype=np.float64)
    return x + dt * f(x, t, _input_at(u, t, x.shape[0]))


def rk4_step(f: RHS, x: FloatArray, t: float, dt: float, u: InputLike = None) -> FloatArray:
    """One classical 4th-order Runge-Kutta step for a batch ``x`` of shape (N, n).

    k1 = f(x, t), k2 = f(x + dt/2 k1, t + dt/2), k3 = f(x + dt/2 k2, t + dt/2),
    k4 = f(x + dt k3, t + dt); x_next = x + dt/6 (k1 + 2 k2 + 2 k3 + k4).
    A constant input is evaluated once; a callable one at t, t + dt/2 (shared by k2, k3), t + dt.
    """
    x = np.asarray(x, dtype=np.float64)
    n_rows = x.shape[0]
    h2 = 0.5 * dt
    if callable(u):
        u0 = _input_at(u, t, n_rows)
        um = _input_at(u, t + h2, n_rows)
        u1 = _input_at(u, t + dt, n_rows)
    else:
        u0 = um = u1 = _input_at(u, t, n_rows)
    k1 = f(x, t, u0)
    k2 = f(x + h2 * k1, t + h2, um)
    k3 = f(x + h2 * k2, t + h2, um)
    k4 = f(x + dt * k3, t + dt, u1)
    return x + (dt / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)


_STEPPERS: dict[str, Callable[..., FloatArray]] = {"euler": euler_step, "rk4": rk4_step}


def integrate(
    f: RHS,
    x0: np.ndarray,
    t0: float,
    dt: float,
    n_steps: int,
    u: InputLike = None,
    method: str = "rk4",
    store: bool = True,
) -> tuple[FloatArray, FloatArray]:
    """Integrate ``dx/dt = f(x, t, u)`` with a fixed step from ``t0`` for ``n_steps`` steps.

    Parameters
    ----------
    f : callable ``f(x (N, n), t, u) -> (N, n)``.
    x0 : initial states, shape (N, n) or a single state (n,) (treated as N = 1).
    t0, dt : start time and (positive, finite) step.
    n_steps : number of steps (>= 0).
    u : None, a constant array ``(n_u,)`` / ``(N, n_u)`` or a callable ``u(t)``.
    method : ``"rk4"`` (default) or ``"euler"``.
    store : when True return every state; when False only the final one (saves memory).

    Returns
    -------
    ``(t, X)``: with ``store=True`` ``t`` has shape (n_steps + 1,) and ``X`` (n_steps + 1, N, n)
    with ``X[0] == x0``; with ``store=False`` ``t`` is ``[t0 + n_steps dt]`` (shape (1,)) and
    ``X`` has shape (1, N, n). Raises ``ValueError`` on bad arguments, or when ``f`` returns a
    wrong shape or the state becomes non-finite (naming the step).
    """
    try:
        stepper = _STEPPERS[method]
    except KeyError:
        raise ValueError(f"method: expected one of {sorted(_STEPPERS)}, got {method!r}") from None
    x = np.array(x0, dtype=np.float64)  # copy: never alias the caller's array
    if x.ndim == 1:
        x = x[None, :]
    if x.ndim != 2 or x.shape[1] == 0:
        raise ValueError(f"x0: expected shape (N, n) or (n,), got {np.shape(x0)}")
    if not np.all(np.isfinite(x)):
        raise ValueError("x0: contains NaN or infinite values")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: expected a positive finite step, got {plain(dt)}")
    if not np.isfinite(t0):
        raise ValueError(f"t0: expected a finite time, got {plain(t0)}")
    if isinstance(n_steps, bool) or int(n_steps) != n_steps or n_steps < 0:
        raise ValueError(f"n_steps: expected a non-negative integer, got {plain(n_steps)}")
    n_steps = int(n_steps)
    t = t0 + dt * np.arange(n_steps + 1, dtype=np.float64)
    if store:
        out = np.empty((n_steps + 1, *x.shape), dtype=np.float64)
        out[0] = x
    shape = x.shape
    if n_steps > 0:  # one up-front evaluation so a wrong f fails with a clear message
        d0 = np.asarray(f(x, float(t0), _input_at(u, float(t0), shape[0])))
        if d0.shape != shape:
            raise ValueError(f"f: returned shape {d0.shape} at t0, expected {shape} (like x)")
    for k in range(n_steps):
        x = stepper(f, x, float(t[k]), dt, u)
        if x.shape != shape:
            raise ValueError(f"f: the step from t={t[k]} gave shape {x.shape}, expected {shape}")
        if not np.all(np.isfinite(x)):
            raise ValueError(f"integrate: state became non-finite at step {k + 1} (t={t[k + 1]})")
        if store:
            out[k + 1] = x
    if store:
        return t, out
    return t[-1:], x[None]


def ode_step(
    rhs: Callable[[FloatArray, Any, float], FloatArray],
    method: str = "rk4",
    substeps: int = 1,
) -> Callable[..., FloatArray]:
    """The contract's ``step(x, u, t, dt, rng=None)`` for ``dx/dt = rhs(x, u, t)``.

    ``substeps`` fixed steps of ``dt / substeps`` by ``method`` (``"rk4"`` or ``"euler"``); ``u``
    is a constant or a callable ``u(t)`` (evaluated as in :func:`rk4_step`). ``rng`` is
    accepted and unused: the step is deterministic (a model adds its process noise on top).
    """
    try:
        stepper = _STEPPERS[method]
    except KeyError:
        raise ValueError(f"method: expected one of {sorted(_STEPPERS)}, got {method!r}") from None
    if isinstance(substeps, bool) or int(substeps) != substeps or substeps < 1:
        raise ValueError(f"substeps: expected a positive integer, got {plain(substeps)}")
    n_sub = int(substeps)

    def f(x: FloatArray, t: float, u: Any) -> FloatArray:
        return rhs(x, u, t)

    def step(x: FloatArray, u: Any, t: float, dt: float,
             rng: np.random.Generator | None = None) -> FloatArray:
        h = dt / n_sub
        for i in range(n_sub):
            x = stepper(f, x, t + i * h, h, u)
        return np.asarray(x, dtype=np.float64)

    return step
