"""Unscented Kalman filter batched over B units.

Same conventions as the KF/EKF of :mod:`rulkit.estimation.kalman` (states (B, n), step order,
missing data, errors naming the argument).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from rulkit.estimation.kalman import (
    _T,
    FloatArray,
    Innovation,
    MatrixLike,
    NonlinearKalmanFilter,
    _as_measurements,
    _check_finite,
    _chol_S,
    _finish_innovation,
    _sym,
)
from rulkit.model import (
    InputLike,
    StateSpaceModel,
    check_covariance,
    kalman_functions_from_model,
    plain,
)

__all__ = ["UnscentedKalmanFilter"]


class UnscentedKalmanFilter(NonlinearKalmanFilter):
    """Unscented Kalman filter for B units, additive noise (Wan & van der Merwe 2000).

    Model ``x_k = f(x_{k-1}, u_k, k) + w`` (``Q`` per step), ``y_k = h(x_k, u_k, k) + v``.
    Scaled sigma points ``x, x +/- sqrt(n + lam) L_i`` (``L L^T = P``, ``lam = alpha^2 (n +
    kappa) - n``), mean weights ``Wm0 = lam / (n + lam)``, ``Wc0 = Wm0 + 1 - alpha^2 + beta``,
    ``Wi = 1 / (2 (n + lam))``. ``f``/``h`` are called once per step on all B (2n + 1) sigma
    points stacked as (B (2n+1), n); a per-unit input ``u`` of shape (B, n_u) is repeated
    to match (a 1-D input is shared and passed unchanged). Means are accumulated as deviations
    from the central sigma point, which keeps the large negative ``Wm0`` of a small ``alpha``
    from cancelling catastrophically.
    Covariance update ``P - K S K^T`` (the UKF has no explicit H for the Joseph form).
    Same ``predict`` / ``update`` / ``filter`` interface as :class:`ExtendedKalmanFilter`
    (discrete models only).
    """

    def __init__(
        self,
        f: Callable[..., np.ndarray],
        h: Callable[..., np.ndarray],
        Q: MatrixLike,
        R: MatrixLike,
        alpha: float = 1e-3,
        beta: float = 2.0,
        kappa: float = 0.0,
    ) -> None:
        if not (np.isfinite(alpha) and alpha > 0):
            raise ValueError(f"alpha: expected a positive finite value, got {plain(alpha)}")
        if not np.isfinite(beta) or not np.isfinite(kappa):
            raise ValueError("beta, kappa: expected finite values")
        self._set_functions(f, h, Q, R)
        self.alpha, self.beta, self.kappa = float(alpha), float(beta), float(kappa)

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
        alpha: float = 1e-3,
        beta: float = 2.0,
        kappa: float = 0.0,
    ) -> UnscentedKalmanFilter:
        """A UKF for ``model`` (docs/engine-api.md, "from_model"): the sigma points go through
        the noise-free ``model.step(x, u(t_k), t_k, dt, None)`` (``t_k = t0 + k dt``, ``dt``
        defaulting to ``model.dt``) and ``model.output``; ``Q``, ``R`` default to
        ``model.noise``. Shapes as for :meth:`ExtendedKalmanFilter.from_model`."""
        fn = kalman_functions_from_model(model, dt, t0, u, Q, R, "numerical")
        return cls(fn.f, fn.h, fn.Q, fn.R, alpha=alpha, beta=beta, kappa=kappa)._sized_for(model)

    def _weights(self, n: int) -> tuple[float, float, float, float]:
        lam = self.alpha**2 * (n + self.kappa) - n
        if n + lam <= 0:
            raise ValueError(f"alpha, kappa: n + lambda = {n + lam:.3g} must be positive")
        wm0 = lam / (n + lam)
        wc0 = wm0 + 1.0 - self.alpha**2 + self.beta
        wi = 0.5 / (n + lam)
        return float(np.sqrt(n + lam)), wm0, wc0, wi

    @staticmethod
    def _sqrt(P: FloatArray) -> FloatArray:
        try:
            return cast(FloatArray, np.linalg.cholesky(P))
        except np.linalg.LinAlgError:  # semi-definite P: symmetric square root
            check_covariance(P, P.shape[-1], "P", units=True, rtol=1e-9)
            w, V = np.linalg.eigh(P)
            return V * np.sqrt(np.clip(w, 0.0, None))[..., None, :]

    def _sigma(self, x: FloatArray, P: FloatArray, c: float) -> FloatArray:
        B, n = x.shape
        L = self._sqrt(P)
        d = c * _T(L)  # rows are the columns of L
        sig = np.empty((B, 2 * n + 1, n))
        sig[:, 0] = x
        sig[:, 1 : n + 1] = x[:, None, :] + d
        sig[:, n + 1 :] = x[:, None, :] - d
        return sig

    @staticmethod
    def _eval(
        fun: Callable[..., np.ndarray], sig: FloatArray, u: Any, k: Any, name: str
    ) -> FloatArray:
        B, p, n = sig.shape
        uu = u
        if u is not None:
            ua = np.asarray(u)
            if ua.ndim >= 2 and ua.shape[0] == B:  # per-unit input: one row per sigma point
                uu = np.repeat(ua, p, axis=0)
        val = np.asarray(fun(sig.reshape(B * p, n), uu, k), dtype=np.float64)
        if val.ndim == 1:
            val = val[:, None]
        if val.ndim != 2 or val.shape[0] != B * p:
            raise ValueError(f"{name}: expected an output of shape ({B * p}, ...), got {val.shape}")
        _check_finite(val, f"{name} (at the sigma points of step {k})")
        return val.reshape(B, p, val.shape[1])

    def _moments(
        self, Y: FloatArray, wm0: float, wc0: float, wi: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        mean = Y[:, 0] + wi * (Y[:, 1:] - Y[:, :1]).sum(axis=1)
        D = Y - mean[:, None, :]
        cov = wc0 * np.einsum("bi,bj->bij", D[:, 0], D[:, 0]) + wi * np.einsum(
            "bpi,bpj->bij", D[:, 1:], D[:, 1:]
        )
        return mean, _sym(cov), D

    def predict(
        self, x: FloatArray, P: FloatArray, k: int, u: Any = None
    ) -> tuple[FloatArray, FloatArray]:
        """Unscented transform of ``N(x, P)`` through ``f``, plus ``Q``."""
        B, n = x.shape
        c, wm0, wc0, wi = self._weights(n)
        Y = self._eval(self.f, self._sigma(x, P, c), u, k, "f")
        if Y.shape[2] != n:
            raise ValueError(f"f: expected {n} output columns, got {Y.shape[2]}")
        xn, Pn, _ = self._moments(Y, wm0, wc0, wi)
        return xn, _sym(Pn + self.Q.at(k, B))

    def update(
        self, x: FloatArray, P: FloatArray, y: FloatArray, k: int, u: Any = None
    ) -> tuple[FloatArray, FloatArray, Innovation]:
        """Assimilate ``y`` (B, m) with sigma points redrawn from ``N(x, P)``."""
        B, n = x.shape
        c, wm0, wc0, wi = self._weights(n)
        sig = self._sigma(x, P, c)
        Z = self._eval(self.h, sig, u, k, "h")
        zhat, Pzz, Dz = self._moments(Z, wm0, wc0, wi)
        m = zhat.shape[1]
        R = self.R.at(k, B)
        Dx = sig[:, 1:] - x[:, None, :]
        Pxz = wi * np.einsum("bpi,bpj->bij", Dx, Dz[:, 1:])  # central point has Dx = 0
        S = _sym(Pzz + R)
        y = _as_measurements(y, B, m)
        skipped = cast(NDArray[np.bool_], np.isnan(y).any(axis=1))
        nu = y - zhat
        nu0 = np.where(skipped[:, None], 0.0, nu) if skipped.any() else nu
        L = _chol_S(S)
        sol = np.linalg.solve(S, np.concatenate([nu0[:, :, None], _T(Pxz)], axis=2))
        Sinv_nu = sol[:, :, 0]
        K = _T(sol[:, :, 1:])
        xn = x + np.einsum("bij,bj->bi", K, nu0)
        Pn = _sym(P - K @ S @ _T(K))
        if skipped.any():
            Pn = np.where(skipped[:, None, None], P, Pn)
        return xn, Pn, _finish_innovation(nu, S, Sinv_nu, L, skipped)
