"""Extended Kalman filter batched over B units.

Same conventions as the KF of :mod:`rulkit.estimation.kalman` (states (B, n), step order,
Joseph-form update, missing data, errors naming the argument).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from rulkit.estimation.kalman import (
    _T,
    FloatArray,
    Innovation,
    MatrixLike,
    NonlinearKalmanFilter,
    _apply,
    _check_finite,
    _sym,
    _update,
    _van_loan,
    numerical_jacobian,
)
from rulkit.integrate import rk4_step
from rulkit.model import InputLike, StateSpaceModel, kalman_functions_from_model, plain

__all__ = ["ExtendedKalmanFilter"]


def _check_jacobian_at(where: str | np.ndarray, continuous: bool) -> str | np.ndarray:
    """``"start"``, ``"midpoint"`` or a 1-D boolean mask (continuous models only)."""
    if isinstance(where, str):
        if where not in ("start", "midpoint"):
            raise ValueError(f"jacobian_at: expected 'start', 'midpoint' or a boolean mask, "
                             f"got {where!r}")
        if where == "midpoint" and not continuous:
            raise ValueError("jacobian_at='midpoint' applies to continuous models only")
        return where
    mask = np.asarray(where)
    if mask.dtype != np.bool_ or mask.ndim != 1:
        raise ValueError("jacobian_at: a mask must be a 1-D boolean array (one entry per unit)")
    if not continuous and mask.any():
        raise ValueError("jacobian_at: the midpoint applies to continuous models only")
    return mask.copy()


class ExtendedKalmanFilter(NonlinearKalmanFilter):
    """Extended Kalman filter for B units (first-order linearisation at the current estimate).

    Discrete model (default): ``x_k = f(x_{k-1}, u_k, k) + w``, ``Q`` the per-step covariance.
    Continuous model (``continuous=True``, ``dt`` required): ``dx/dt = f(x, u, t) + w(t)`` with
    ``Q`` the spectral density of ``w``; the mean is advanced by RK4 (``substeps`` steps of
    ``dt/substeps``) and the covariance with ``Phi = expm(J dt)``, ``Qd`` by Van Loan
    (:func:`discretise`), ``J`` the Jacobian at the prior mean. Measurement
    ``y_k = h(x_k, u_k, k) + v`` (for continuous models the third argument is the time
    ``t0 + (k + 1) dt`` of ``ys[k]``, and ``f`` gets the start time ``t0 + k dt`` of the step).
    ``jacobian_at`` (continuous models): where ``J`` of ``Phi = expm(J dt)`` is evaluated:
    ``"start"`` (the prior mean, as above: ``Phi`` first order in ``dt``), ``"midpoint"`` (the
    mean after half an RK4 step, at ``t + dt/2``: ``Phi`` second order, which matters when the
    Jacobian changes within a step, e.g. right after an input switch), or a (B,) boolean mask
    choosing the midpoint per unit. The mean prediction is the same either way.

    Jacobians: ``jac_f(x, u, k) -> (B, n, n)``, ``jac_h(x, u, k) -> (B, m, n)``; central finite
    differences (:func:`numerical_jacobian`) when not given. ``Q``, ``R`` may be shared, per
    unit or callables of k.
    """

    def __init__(
        self,
        f: Callable[..., np.ndarray],
        h: Callable[..., np.ndarray],
        Q: MatrixLike,
        R: MatrixLike,
        *,
        jac_f: Callable[..., np.ndarray] | None = None,
        jac_h: Callable[..., np.ndarray] | None = None,
        continuous: bool = False,
        dt: float | None = None,
        t0: float = 0.0,
        substeps: int = 1,
        jacobian_at: str | np.ndarray = "start",
    ) -> None:
        self._set_functions(f, h, Q, R)
        self.jac_f, self.jac_h = jac_f, jac_h
        self.continuous = bool(continuous)
        if self.continuous:
            if dt is None or not (np.isfinite(dt) and dt > 0):
                raise ValueError(f"dt: a continuous model needs a positive finite dt, got "
                                 f"{plain(dt)}")
            if int(substeps) != substeps or substeps < 1:
                raise ValueError(f"substeps: expected a positive integer, got {plain(substeps)}")
        self.dt = None if dt is None else float(dt)
        self.t0 = float(t0)
        self.substeps = int(substeps)
        self.jacobian_at = _check_jacobian_at(jacobian_at, self.continuous)

    @classmethod
    def from_model(
        cls,
        model: StateSpaceModel,
        *,
        dt: float | None = None,
        t0: float = 0.0,
        u: InputLike = None,
        Q: np.ndarray | None = None,
        R: np.ndarray | None = None,
        jacobian: str = "auto",
    ) -> ExtendedKalmanFilter:
        """A discrete-time EKF for ``model`` (docs/engine-api.md, "from_model").

        Prediction k is the noise-free ``model.step(x, u(t_k), t_k, dt, None)`` with ``t_k =
        t0 + k dt`` (``dt`` defaults to ``model.dt``), linearised by the model's analytic
        ``step_jacobian`` when it defines one (``jacobian="auto"``) or central differences
        (``"numerical"``, or no analytic one); measurement ``model.output(x, u)`` likewise.
        ``Q``, ``R`` default to ``model.noise``. ``filter`` accepts one unit without a unit
        axis (``x0`` (n_x,), ``ys`` (T, n_y) or (T,) for one output); wrong shapes are a
        ``ValueError`` before any model code runs. Results keep the unit axis (B = 1).
        """
        fn = kalman_functions_from_model(model, dt, t0, u, Q, R, jacobian)
        return cls(fn.f, fn.h, fn.Q, fn.R, jac_f=fn.jac_f, jac_h=fn.jac_h)._sized_for(model)

    # -- time arguments -------------------------------------------------------------------
    def _tf(self, k: int) -> float | int:
        return self.t0 + k * self.dt if self.continuous else k  # type: ignore[operator]

    def _th(self, k: int) -> float | int:
        return self.t0 + (k + 1) * self.dt if self.continuous else k  # type: ignore[operator]

    def _jacobian(
        self,
        fun: Callable[..., np.ndarray],
        jac: Callable[..., np.ndarray] | None,
        x: FloatArray,
        u: Any,
        targ: Any,
        rows: int,
        name: str,
    ) -> FloatArray:
        B, n = x.shape
        if jac is None:
            J = numerical_jacobian(lambda xx: fun(xx, u, targ), x)
        else:
            J = np.asarray(jac(x, u, targ), dtype=np.float64)
            if J.ndim == 2 and J.shape == (rows, n):
                J = np.broadcast_to(J, (B, rows, n))
        if J.shape != (B, rows, n):
            raise ValueError(
                f"{name}: expected a Jacobian of shape ({B}, {rows}, {n}), got {J.shape}"
            )
        _check_finite(J, name)
        return J

    def predict(
        self, x: FloatArray, P: FloatArray, k: int, u: Any = None
    ) -> tuple[FloatArray, FloatArray]:
        """Predict step k (from ``ys[k-1]`` to ``ys[k]``); returns ``(x_pred, P_pred)``."""
        B, n = x.shape
        targ = self._tf(k)
        if self.continuous:
            dt = self.dt
            assert dt is not None
            J = self._continuous_jacobian(x, u, targ, dt)
            h = dt / self.substeps
            xn = x
            for i in range(self.substeps):
                xn = rk4_step(lambda xx, tt, uu: self.f(xx, uu, tt), xn, targ + i * h, h, u)
            Phi, Qd = _van_loan(J, self.Q.at(k, B), dt)
            Pn = _sym(Phi @ P @ _T(Phi) + Qd)
        else:
            xn = _apply(self.f, x, u, targ, B, "f")
            self._check_prediction(xn, B, n, k)  # before the Jacobian, so the error names f
            J = self._jacobian(self.f, self.jac_f, x, u, targ, n, "jac_f")
            Pn = _sym(J @ P @ _T(J) + self.Q.at(k, B))
            return xn, Pn
        self._check_prediction(xn, B, n, k)
        return xn, Pn

    def _continuous_jacobian(self, x: FloatArray, u: Any, t: float, dt: float) -> FloatArray:
        """J for ``Phi = expm(J dt)`` at the prior mean or, per ``jacobian_at``, at the mean
        after half an RK4 step (time ``t + dt/2``)."""
        B, n = x.shape
        where = self.jacobian_at
        if isinstance(where, str) and where == "start":
            return self._jacobian(self.f, self.jac_f, x, u, t, n, "jac_f")
        x_mid = rk4_step(lambda xx, tt, uu: self.f(xx, uu, tt), x, t, 0.5 * dt, u)
        _check_finite(x_mid, "f (half-step state for the midpoint Jacobian)")
        J_mid = self._jacobian(self.f, self.jac_f, x_mid, u, t + 0.5 * dt, n, "jac_f")
        if isinstance(where, str):
            return J_mid
        if where.shape != (B,):
            raise ValueError(f"jacobian_at: a mask needs shape ({B},), got {where.shape}")
        if where.all():
            return J_mid
        J_start = self._jacobian(self.f, self.jac_f, x, u, t, n, "jac_f")
        return np.where(where[:, None, None], J_mid, J_start)

    @staticmethod
    def _check_prediction(xn: FloatArray, B: int, n: int, k: int) -> None:
        """The predicted state must be (B, n) and finite (checked before its Jacobian is used)."""
        if xn.shape != (B, n):
            raise ValueError(f"f: expected an output of shape ({B}, {n}), got {xn.shape}")
        _check_finite(xn, f"f (predicted state at step {k})")

    def update(
        self, x: FloatArray, P: FloatArray, y: FloatArray, k: int, u: Any = None
    ) -> tuple[FloatArray, FloatArray, Innovation]:
        """Assimilate ``y`` (B, m) (= ``ys[k]``); returns ``(x, P, Innovation)``."""
        B = x.shape[0]
        targ = self._th(k)
        yhat = _apply(self.h, x, u, targ, B, "h")
        m = yhat.shape[1]
        H = self._jacobian(self.h, self.jac_h, x, u, targ, m, "jac_h")
        return _update(x, P, y, H, self.R.at(k, B), yhat)
