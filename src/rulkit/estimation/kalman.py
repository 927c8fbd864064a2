"""Kalman filter family batched over B units: KF, EKF, UKF (engine-api.md, estimation.kalman).

This module holds the validation, the functional core (``kf_predict``, ``kf_update``) and the
linear :class:`KalmanFilter`; the EKF is in :mod:`rulkit.estimation.ekf` and the UKF in
:mod:`rulkit.estimation.ukf` (both with ``from_model``), on the shared loop
:class:`NonlinearKalmanFilter` defined here. Every filter here is an
:class:`~rulkit.estimation.base.Estimator`: ``filter`` returns a :class:`KalmanResult` whose
``posterior(k, unit)`` is a Gaussian :class:`~rulkit.estimation.base.Posterior`, and a prior may
be given as a ``Posterior`` instead of ``x0, P0``.

Conventions (all arrays float64; a single unit is B = 1):

* States ``x`` have shape (B, n), covariances ``P`` (B, n, n), measurements ``y`` (B, m).
* Model matrices ``F``, ``Q``, ``H``, ``R`` are shared ``(n, n)`` / ``(m, n)`` / ``(m, m)`` or
  per unit ``(B, n, n)`` / ``(B, m, n)`` / ``(B, m, m)``. In the filter classes they may also
  be callables of the step index ``k`` returning such an array (time-varying models). Stacked
  ``(T, ...)`` arrays are *not* accepted because ``(T, n, n)`` and ``(B, n, n)`` would be
  ambiguous; wrap them as ``lambda k: F_seq[k]``.
* Step order (same as the particle filter): ``x0, P0`` describe the state one step *before*
  ``ys[0]``; step ``k`` predicts (applies the transition) and then assimilates ``ys[k]``.
  The results hold the filtered (posterior) moments after each ``ys[k]``, and the predicted
  ones in ``x_pred``/``P_pred``.
* Update (Bar-Shalom et al. 2001, eqs 5.2.3-12..17): innovation ``nu = y - h(x)``,
  ``S = H P H^T + R``, gain from a linear solve ``K^T = S^{-1} H P`` (no explicit inverse),
  covariance in Joseph form ``P+ = (I - K H) P (I - K H)^T + K R K^T``.
  ``nis = nu^T S^{-1} nu`` (normalised innovation squared; chi-square with m degrees of
  freedom when the filter is consistent) and ``loglik = log N(nu; 0, S)`` (log|S| from a
  Cholesky factor, which also rejects an S that is not positive definite).
* Missing data: a measurement row of unit b containing any NaN skips the update of that unit at
  that step (its state and covariance stay at the prediction); its ``nu`` and ``nis`` are NaN,
  its ``loglik`` increment is 0 and ``skipped`` is True. Infinite measurements are an error.
  (Partially observed rows are treated as missing as a whole: simple and never biased.)
* Bad input raises ``ValueError`` naming the argument (and the unit, where relevant): wrong
  shapes, non-finite values, non-symmetric or not positive semi-definite covariances (the
  engine's one state check :func:`rulkit.model.as_batch` and covariance check
  :func:`rulkit.model.check_covariance`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Self, cast

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from rulkit.estimation.base import (
    Estimator,
    EstimatorState,
    FilterResult,
    Posterior,
    refuse_model,
)
from rulkit.model import StateSpaceModel, as_batch, check_covariance, plain

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
MatrixLike = np.ndarray | Callable[[int], np.ndarray]

_LOG_2PI = float(np.log(2.0 * np.pi))

__all__ = [
    "FilterStepError",
    "Innovation",
    "KalmanFilter",
    "KalmanResult",
    "KalmanState",
    "NonlinearKalmanFilter",
    "discretise",
    "kf_predict",
    "kf_update",
    "numerical_jacobian",
]


class FilterStepError(ValueError):
    """A filter's ``filter`` loop failed at step ``step`` (the index into ``ys``): the
    message is ``"step k: <what failed>"``, so a caller that knows which record row step
    k is (a file reader) can name it."""

    def __init__(self, step: int, err: Exception) -> None:
        super().__init__(f"step {step}: {err}")
        self.step = step


# ----------------------------------------------------------------------------------------------
# result types
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Innovation:
    """Innovation of one update for B units.

    ``nu`` (B, m) innovation, ``S`` (B, m, m) its covariance, ``nis`` (B,) normalised innovation
    squared ``nu^T S^-1 nu``, ``loglik`` (B,) ``log N(nu; 0, S)``, ``skipped`` (B,) True where the
    measurement was missing (NaN): then ``nu``/``nis`` are NaN and ``loglik`` is 0.
    """

    nu: FloatArray
    S: FloatArray
    nis: FloatArray
    loglik: FloatArray
    skipped: BoolArray


@dataclass(frozen=True)
class KalmanResult(FilterResult):
    """Output of ``filter``: per step k (T steps) and unit b (B units).

    ``x`` (T, B, n) / ``P`` (T, B, n, n) filtered moments after ``ys[k]``; ``x_pred`` /
    ``P_pred`` the predicted ones before it; ``innovations`` (T, B, m), ``S`` (T, B, m, m),
    ``nis`` (T, B), ``loglik_increments`` (T, B), ``skipped`` (T, B) and ``loglik`` (B,), the
    sum of the increments (the log marginal likelihood of the observed data).
    ``posterior(k, unit)`` is step k's Gaussian :class:`Posterior` of one unit.
    """

    x: FloatArray
    P: FloatArray
    x_pred: FloatArray
    P_pred: FloatArray
    innovations: FloatArray
    S: FloatArray
    nis: FloatArray
    loglik_increments: FloatArray
    skipped: BoolArray
    loglik: FloatArray

    @property
    def n_steps(self) -> int:
        """Number of steps ``T``."""
        return int(self.x.shape[0])

    def _unit(self, unit: int) -> int:
        b = self.x.shape[1]
        if not -b <= unit < b:
            raise ValueError(f"unit: expected a unit in [0, {b - 1}], got {unit}")
        return unit % b

    def posterior(self, k: int | None = None, unit: int = 0) -> Posterior:
        """``N(x[k, unit], P[k, unit])`` (k None: the last step)."""
        t = self.n_steps
        kk = t - 1 if k is None else k
        if not -t <= kk < t:
            raise ValueError(f"k: expected a step in [{-t}, {t - 1}], got {k}")
        b = self._unit(unit)
        return Posterior(self.x[kk, b], self.P[kk, b])

    def moments(self, unit: int = 0) -> tuple[FloatArray, FloatArray]:
        """``(x[:, unit] (T, n), P[:, unit] (T, n, n))``."""
        b = self._unit(unit)
        return self.x[:, b], self.P[:, b]


# ----------------------------------------------------------------------------------------------
# validation helpers
# ----------------------------------------------------------------------------------------------
def _T(a: np.ndarray) -> np.ndarray:
    return np.swapaxes(a, -1, -2)


def _sym(a: np.ndarray) -> np.ndarray:
    return 0.5 * (a + _T(a))


def _check_finite(a: np.ndarray, name: str) -> None:
    if not np.all(np.isfinite(a)):
        idx = np.argwhere(~np.isfinite(a))[0]
        raise ValueError(f"{name}: non-finite value at index {tuple(int(i) for i in idx)}")


def _as_state(x: Any, name: str = "x") -> FloatArray:
    return as_batch(x, None, name, single=False, batch="B")


def _as_matrix(a: Any, rows: int, cols: int, batch: int | None, name: str) -> FloatArray:
    """A shared (rows, cols) or per-unit (B, rows, cols) matrix, finite."""
    arr = np.asarray(a, dtype=np.float64)
    if rows == 1 and cols == 1 and arr.ndim == 0:
        arr = arr.reshape(1, 1)
    ok = arr.shape == (rows, cols) or (
        arr.ndim == 3 and arr.shape[1:] == (rows, cols) and (batch is None or arr.shape[0] == batch)
    )
    if not ok:
        b = "B" if batch is None else str(batch)
        raise ValueError(
            f"{name}: expected shape ({rows}, {cols}) or ({b}, {rows}, {cols}), got {arr.shape}"
        )
    _check_finite(arr, name)
    return arr


def _as_cov(c: Any, n: int, batch: int | None, name: str, definite: bool = False) -> FloatArray:
    """A shared (n, n) or per-unit (B, n, n) covariance (B = ``batch`` when known)."""
    return check_covariance(c, n, name, units=True if batch is None else batch,
                            definite=definite)


def _as_measurements(y: Any, batch: int, m: int, name: str = "y") -> FloatArray:
    arr = np.asarray(y, dtype=np.float64)
    if arr.shape != (batch, m):
        raise ValueError(f"{name}: expected shape ({batch}, {m}), got {arr.shape}")
    if np.any(np.isinf(arr)):
        idx = np.argwhere(np.isinf(arr))[0]
        raise ValueError(
            f"{name}: infinite value at unit {idx[0]}, component {idx[1]} (use NaN for missing)"
        )
    return arr


def _matvec(M: np.ndarray, x: np.ndarray) -> np.ndarray:
    """M (r, c) or (B, r, c) times x (B, c) -> (B, r)."""
    if M.ndim == 2:
        return x @ M.T
    return np.einsum("bij,bj->bi", M, x)


# ----------------------------------------------------------------------------------------------
# core (unchecked) predict / update
# ----------------------------------------------------------------------------------------------
def _predict(
    x: FloatArray, P: FloatArray, F: FloatArray, Q: FloatArray, Bu: FloatArray | None
) -> tuple[FloatArray, FloatArray]:
    xn = _matvec(F, x)
    if Bu is not None:
        xn = xn + Bu
    Pn = _sym(F @ P @ _T(F) + Q)
    return xn, Pn


def _chol_S(S: FloatArray) -> FloatArray:
    try:
        return cast(FloatArray, np.linalg.cholesky(S))
    except np.linalg.LinAlgError:
        lo = np.linalg.eigvalsh(S)[..., 0]
        b = int(np.argmin(lo))  # Cholesky may fail on a tiny positive eigenvalue too
        raise ValueError(
            f"innovation covariance S = H P H^T + R is not positive definite for unit {b} "
            f"(smallest eigenvalue {lo[b]:.3g}); check R and P"
        ) from None


def _finish_innovation(
    nu: FloatArray, S: FloatArray, Sinv_nu: FloatArray, L: FloatArray, skipped: BoolArray
) -> Innovation:
    m = nu.shape[1]
    nis = np.einsum("bi,bi->b", nu, Sinv_nu)
    logdet = 2.0 * np.log(np.diagonal(L, axis1=-2, axis2=-1)).sum(axis=-1)
    loglik = -0.5 * (nis + logdet + m * _LOG_2PI)
    if skipped.any():
        nu = nu.copy()
        nu[skipped] = np.nan
        nis = np.where(skipped, np.nan, nis)
        loglik = np.where(skipped, 0.0, loglik)
    return Innovation(nu=nu, S=S, nis=nis, loglik=loglik, skipped=skipped)


def _update(
    x: FloatArray,
    P: FloatArray,
    y: FloatArray,
    H: FloatArray,
    R: FloatArray,
    yhat: FloatArray | None,
) -> tuple[FloatArray, FloatArray, Innovation]:
    B, n = x.shape
    skipped = cast(BoolArray, np.isnan(y).any(axis=1))
    if yhat is None:
        yhat = _matvec(H, x)
    nu = y - yhat
    nu0 = np.where(skipped[:, None], 0.0, nu) if skipped.any() else nu
    HP = H @ P  # (B, m, n)
    S = _sym(HP @ _T(H) + R)
    if S.ndim == 2:  # P shared (n, n) and H shared: give every unit its own copy
        S = np.broadcast_to(S, (B, *S.shape)).copy()
    L = _chol_S(S)
    rhs = np.concatenate([nu0[:, :, None], np.broadcast_to(HP, (B, *HP.shape[-2:]))], axis=2)
    sol = np.linalg.solve(S, rhs)  # S^-1 [nu, H P]
    Sinv_nu = sol[:, :, 0]
    K = _T(sol[:, :, 1:])  # (B, n, m) = P H^T S^-1
    xn = x + np.einsum("bij,bj->bi", K, nu0)
    IKH = np.eye(n) - K @ H
    Pn = _sym(IKH @ P @ _T(IKH) + K @ R @ _T(K))
    if skipped.any():
        Pn = np.where(skipped[:, None, None], np.broadcast_to(P, Pn.shape), Pn)
    return xn, Pn, _finish_innovation(nu, S, Sinv_nu, L, skipped)


# ----------------------------------------------------------------------------------------------
# public functional core
# ----------------------------------------------------------------------------------------------
def kf_predict(
    x: np.ndarray,
    P: np.ndarray,
    F: np.ndarray,
    Q: np.ndarray,
    Bu: np.ndarray | None = None,
    *,
    check: bool = True,
) -> tuple[FloatArray, FloatArray]:
    """Kalman prediction ``x <- F x + Bu``, ``P <- F P F^T + Q`` for B units.

    ``x`` (B, n), ``P`` (B, n, n) (or shared (n, n)), ``F`` and ``Q`` (n, n) or (B, n, n), ``Bu``
    an optional control contribution (n,) or (B, n). Validates shapes, finiteness and (unless
    ``check=False``, for tight loops with already validated matrices) that ``P`` and ``Q`` are
    symmetric positive semi-definite; errors name the argument.
    """
    x = _as_state(x)
    B, n = x.shape
    P = _as_cov(P, n, B, "P") if check else _as_matrix(P, n, n, B, "P")
    F = _as_matrix(F, n, n, B, "F")
    Q = _as_cov(Q, n, B, "Q") if check else _as_matrix(Q, n, n, B, "Q")
    bu = None
    if Bu is not None:
        bu = np.asarray(Bu, dtype=np.float64)
        if bu.shape not in ((n,), (B, n)):
            raise ValueError(f"Bu: expected shape ({n},) or ({B}, {n}), got {bu.shape}")
        _check_finite(bu, "Bu")
    xn, Pn = _predict(x, P, F, Q, bu)
    if Pn.ndim == 2:
        Pn = np.broadcast_to(Pn, (B, n, n)).copy()
    return xn, Pn


def kf_update(
    x: np.ndarray,
    P: np.ndarray,
    y: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    h_of_x: np.ndarray | Callable[[FloatArray], np.ndarray] | None = None,
    *,
    check: bool = True,
) -> tuple[FloatArray, FloatArray, Innovation]:
    """Kalman measurement update for B units (Joseph form, linear solves).

    ``y`` (B, m) with NaN rows meaning "missing" (the update of that unit is skipped);
    ``H`` (m, n) or (B, m, n); ``R`` (m, m) or (B, m, m). ``h_of_x``: predicted measurement
    (B, m) (or a callable of ``x``) replacing ``H x`` (EKF use, with ``H`` the Jacobian).
    ``check=False`` skips the symmetry / semi-definiteness checks of ``P`` and ``R`` (shapes and
    finiteness are always checked; an S that is not positive definite still raises).
    Returns ``(x, P, Innovation)``.
    """
    x = _as_state(x)
    B, n = x.shape
    P = _as_cov(P, n, B, "P") if check else _as_matrix(P, n, n, B, "P")
    Rm = np.asarray(R, dtype=np.float64)
    m = 1 if Rm.ndim == 0 else Rm.shape[-1]
    y = _as_measurements(y, B, m)
    H = _as_matrix(H, m, n, B, "H")
    R = _as_cov(R, m, B, "R") if check else _as_matrix(R, m, m, B, "R")
    yhat = None
    if h_of_x is not None:
        yhat = np.asarray(h_of_x(x) if callable(h_of_x) else h_of_x, dtype=np.float64)
        if yhat.shape != (B, m):
            raise ValueError(f"h_of_x: expected shape ({B}, {m}), got {yhat.shape}")
        _check_finite(yhat, "h_of_x")
    if P.ndim == 2:
        P = np.broadcast_to(P, (B, n, n))
    return _update(x, P, y, H, R, yhat)


def numerical_jacobian(
    fun: Callable[..., np.ndarray], x: np.ndarray, *args: Any, eps: float | None = None
) -> FloatArray:
    """Central-difference Jacobian of a batched function, ``(B, m, n)``.

    ``fun(x (B, n), *args) -> (B, m)`` (or (B,), taken as m = 1). Column j uses the step
    ``h_bj = eps * max(1, |x_bj|)`` (``eps`` defaults to cbrt(machine epsilon) ~ 6e-6, the
    optimum for central differences), rounded so that ``x + h`` is exact. Truncation error
    O(h^2); 2 n calls of ``fun``, each vectorised over B.
    """
    x = _as_state(x)
    B, n = x.shape
    rel = float(np.cbrt(np.finfo(np.float64).eps)) if eps is None else float(eps)
    if not (np.isfinite(rel) and rel > 0):
        raise ValueError(f"eps: expected a positive finite step, got {plain(eps)}")
    h = rel * np.maximum(1.0, np.abs(x))
    h = (x + h) - x  # representable steps
    cols = []
    for j in range(n):
        xp = x.copy()
        xm = x.copy()
        xp[:, j] += h[:, j]
        xm[:, j] -= h[:, j]
        fp = np.asarray(fun(xp, *args), dtype=np.float64)
        fm = np.asarray(fun(xm, *args), dtype=np.float64)
        if fp.ndim == 1:
            fp, fm = fp[:, None], fm[:, None]
        if fp.ndim != 2 or fp.shape[0] != B:
            raise ValueError(f"fun: expected an output of shape ({B}, m), got {fp.shape}")
        cols.append((fp - fm) / (h[:, j, None] + h[:, j, None]))
    return np.stack(cols, axis=-1)


def discretise(A: np.ndarray, Qc: np.ndarray, dt: float) -> tuple[FloatArray, FloatArray]:
    """Discretise ``dx = A x dt + dw`` (spectral density ``Qc``) over ``dt`` by Van Loan (1978).

    ``Phi = expm(A dt)``, ``Qd = int_0^dt expm(A s) Qc expm(A s)^T ds``, both from one matrix
    exponential of ``M = [[-A, Qc], [0, A^T]] dt``: ``expm(M) = [[., Phi^-1 Qd], [0, Phi^T]]``.
    ``A``, ``Qc``: (n, n) or (B, n, n) (broadcast together).
    """
    A = np.asarray(A, dtype=np.float64)
    if A.ndim not in (2, 3) or A.shape[-1] != A.shape[-2]:
        raise ValueError(f"A: expected shape (n, n) or (B, n, n), got {A.shape}")
    _check_finite(A, "A")
    n = A.shape[-1]
    Qc = _as_cov(Qc, n, A.shape[0] if A.ndim == 3 else None, "Qc")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: expected a positive finite step, got {plain(dt)}")
    return _van_loan(A, Qc, float(dt))


def _van_loan(A: FloatArray, Qc: FloatArray, dt: float) -> tuple[FloatArray, FloatArray]:
    """Unchecked core of :func:`discretise`."""
    n = A.shape[-1]
    lead = np.broadcast_shapes(A.shape[:-2], Qc.shape[:-2])
    M = np.zeros((*lead, 2 * n, 2 * n))
    M[..., :n, :n] = -A * dt
    M[..., :n, n:] = Qc * dt
    M[..., n:, n:] = _T(A) * dt
    E = scipy.linalg.expm(M)
    Phi = _T(E[..., n:, n:])
    Qd = _sym(Phi @ E[..., :n, n:])
    return np.ascontiguousarray(Phi), Qd


# ----------------------------------------------------------------------------------------------
# filter classes
# ----------------------------------------------------------------------------------------------
def _check_x0_P0(x0: Any, P0: Any, n_x: int | None = None) -> tuple[FloatArray, FloatArray]:
    """The prior as (B, n) means and (B, n, n) covariances: ``x0`` (B, n), one unit (n,), or a
    :class:`Posterior` (then ``P0`` is its covariance and must not be given)."""
    if isinstance(x0, Posterior):
        if P0 is not None:
            raise ValueError("P0: the prior posterior carries its own covariance")
        x0, P0 = x0.mean, x0.cov
    elif P0 is None:
        raise ValueError("P0: the prior covariance is required (or give a Posterior as prior)")
    if n_x is not None and np.shape(x0)[-1:] != (n_x,):
        raise ValueError(f"x0: expected {n_x} states (the model's), got shape {np.shape(x0)}")
    if np.ndim(x0) == 1:  # one unit needs no batch axis: (n,) is (1, n)
        x0 = np.asarray(x0, dtype=np.float64)[None, :]
    x0 = _as_state(x0, "x0")
    B, n = x0.shape
    P0 = _as_cov(P0, n, B, "P0")
    if P0.ndim == 2:
        P0 = np.broadcast_to(P0, (B, n, n)).copy()
    return x0, P0


def _one_unit_ys(ys: Any, B: int) -> FloatArray:
    """``ys`` as (T, B, m): for one unit (B = 1) a (T, m) or (T,) array gains the unit axis."""
    arr = np.asarray(ys, dtype=np.float64)
    if B == 1 and arr.ndim in (1, 2):
        arr = arr.reshape(arr.shape[0], 1, -1)
    return arr


def _check_ys(ys: Any, B: int, m: int) -> FloatArray:
    arr = _one_unit_ys(ys, B)
    if arr.ndim != 3 or arr.shape[1:] != (B, m):
        one = f" or (T, {m})" if B == 1 else ""
        raise ValueError(f"ys: expected shape (T, {B}, {m}){one}, got {np.shape(ys)}")
    if np.any(np.isinf(arr)):
        idx = np.argwhere(np.isinf(arr))[0]
        raise ValueError(
            f"ys: infinite value at step {idx[0]}, unit {idx[1]}, component {idx[2]} "
            "(use NaN for missing)"
        )
    return arr


def _input_at(us: Any, k: int, T: int) -> Any:
    """Input of step k: ``us`` may be None, a (T, ...) array or a callable of k."""
    if us is None:
        return None
    if callable(us):
        return us(k)
    return us[k]


class _Stacker:
    """Preallocated (T, B, ...) result buffers."""

    def __init__(self, T: int, B: int, n: int, m: int) -> None:
        self.x = np.empty((T, B, n))
        self.P = np.empty((T, B, n, n))
        self.xp = np.empty((T, B, n))
        self.Pp = np.empty((T, B, n, n))
        self.nu = np.empty((T, B, m))
        self.S = np.empty((T, B, m, m))
        self.nis = np.empty((T, B))
        self.ll = np.empty((T, B))
        self.sk = np.empty((T, B), dtype=bool)

    def put(
        self, k: int, xp: FloatArray, Pp: FloatArray, x: FloatArray, P: FloatArray, inn: Innovation
    ) -> None:
        self.xp[k], self.Pp[k], self.x[k], self.P[k] = xp, Pp, x, P
        self.nu[k], self.S[k], self.nis[k] = inn.nu, inn.S, inn.nis
        self.ll[k], self.sk[k] = inn.loglik, inn.skipped

    def result(self) -> KalmanResult:
        return KalmanResult(
            x=self.x,
            P=self.P,
            x_pred=self.xp,
            P_pred=self.Pp,
            innovations=self.nu,
            S=self.S,
            nis=self.nis,
            loglik_increments=self.ll,
            skipped=self.sk,
            loglik=self.ll.sum(axis=0),
        )


class _MatrixSource:
    """A constant matrix (validated once) or a callable of k (shape-checked each step)."""

    def __init__(
        self, a: MatrixLike, rows: int | None, cols: int | None, name: str, cov: bool
    ) -> None:
        self.name, self.cov, self.fn = name, cov, None
        if callable(a):
            self.fn = a
            self.rows, self.cols, self.value = rows, cols, None
        else:
            arr = np.asarray(a, dtype=np.float64)
            if arr.ndim == 0:
                arr = arr.reshape(1, 1)
            if arr.ndim not in (2, 3):
                raise ValueError(f"{name}: expected a 2-D or 3-D array, got shape {arr.shape}")
            self.rows, self.cols = arr.shape[-2], arr.shape[-1]
            _check_finite(arr, name)
            if cov:
                check_covariance(arr, arr.shape[-1], name, units=True)
            self.value = arr

    def validate(self, B: int, rows: int, cols: int) -> None:
        if self.value is not None:
            self.value = (check_covariance(self.value, rows, self.name, units=B) if self.cov
                          else _as_matrix(self.value, rows, cols, B, self.name))
        self.rows, self.cols = rows, cols

    def at(self, k: int, B: int) -> FloatArray:
        if self.fn is None:
            assert self.value is not None
            return self.value
        val = _as_matrix(self.fn(k), self.rows, self.cols, B, f"{self.name}({k})")  # type: ignore[arg-type]
        return val


@dataclass
class KalmanState(EstimatorState):
    """Running state of the per-step API of the Kalman family: ``x`` (B, n), ``P`` (B, n, n)
    after step ``k`` (-1 after ``initialise``: the prior), ``loglik`` (B,) the running log
    marginal likelihood, ``innovation`` the last step's (None before the first)."""

    x: FloatArray
    P: FloatArray
    m: int
    k: int = -1
    loglik: FloatArray = field(default_factory=lambda: np.zeros(0))
    innovation: Innovation | None = None

    def posterior(self, unit: int = 0) -> Posterior:
        """``N(x[unit], P[unit])``."""
        b = self.x.shape[0]
        if not -b <= unit < b:
            raise ValueError(f"unit: expected a unit in [0, {b - 1}], got {unit}")
        return Posterior(self.x[unit], self.P[unit])


class _KalmanLoop(Estimator):
    """The one loop of the Kalman family, shared by ``filter`` and the per-step API: a
    subclass validates the prior and its matrices (``_start``) and advances one step
    (``_advance``: predict, then update with ``ys[k]``)."""

    n_y: int | None = None

    def _start(self, prior: Any, P0: Any) -> tuple[FloatArray, FloatArray, int]:
        raise NotImplementedError  # pragma: no cover - overridden

    def _advance(
        self, x: FloatArray, P: FloatArray, y: FloatArray, k: int, u: Any
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, Innovation]:
        raise NotImplementedError  # pragma: no cover - overridden

    def _check_inputs(self, us: Any, name: str = "us") -> None:
        """Refuse inputs the filter would ignore, or missing ones it needs."""

    def _guarded(
        self, x: FloatArray, P: FloatArray, y: FloatArray, k: int, u: Any
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, Innovation]:
        try:
            return self._advance(x, P, y, k, u)
        except (ValueError, np.linalg.LinAlgError) as err:
            raise FilterStepError(k, err) from err

    def initialise(self, prior: Any, rng: np.random.Generator | None = None, *,
                   P0: Any = None) -> KalmanState:
        """Start from ``prior``: a :class:`Posterior`, or means ``x0`` (B, n) / (n,) with
        ``P0``. ``rng`` is unused (the Kalman filters are deterministic): it is accepted so
        every estimator starts as ``initialise(prior, rng)``."""
        x, P, m = self._start(prior, P0)
        return KalmanState(x, P, m, loglik=np.zeros(x.shape[0]))

    def step(self, state: KalmanState, y: Any, u: Any = None) -> KalmanState:
        """Predict step ``k = state.k + 1`` and assimilate ``y`` (B, m) (one unit: (m,) or a
        scalar); ``u`` the step's input. Mutates and returns ``state``; an error leaves it
        as it was and names the step."""
        B, m = state.x.shape[0], state.m
        k = state.k + 1
        arr = np.asarray(y, dtype=np.float64)
        if arr.size != B * m or arr.ndim > 2 or (arr.ndim == 2 and arr.shape != (B, m)):
            raise ValueError(f"y: expected shape ({B}, {m}), got {arr.shape}")
        yk = _check_ys(arr.reshape(1, B, m), B, m)[0]
        self._check_inputs(u, "u")
        _, _, x, P, inn = self._guarded(state.x, state.P, yk, k, u)
        state.x, state.P, state.k, state.innovation = x, P, k, inn
        state.loglik = state.loglik + inn.loglik
        return state

    def filter(
        self,
        ys: np.ndarray,
        prior: Any,
        P0: Any = None,
        us: np.ndarray | Callable[[int], Any] | None = None,
    ) -> KalmanResult:
        """Run over ``ys`` (T, B, m) (one unit: (T, m) or (T,)) from the prior one step before
        ``ys[0]``: a :class:`Posterior`, or ``x0`` (B, n) with ``P0`` (n, n) or (B, n, n).
        ``us[k]`` (or ``us(k)``) is step k's input."""
        x, P, m = self._start(prior, P0)
        B, n = x.shape
        ys_arr = self._measurements(ys, B, m)
        self._check_inputs(us)
        T = ys_arr.shape[0]
        out = _Stacker(T, B, n, m)
        for k in range(T):
            xp, Pp, x, P, inn = self._guarded(x, P, ys_arr[k], k, _input_at(us, k, T))
            out.put(k, xp, Pp, x, P, inn)
        return out.result()

    def _measurements(self, ys: Any, B: int, m: int) -> FloatArray:
        arr = _one_unit_ys(ys, B)
        if arr.ndim != 3 or arr.shape[1:] != (B, m):
            one = f" (or (T, {m}) for one unit)" if B == 1 else ""
            raise ValueError(f"ys: expected shape (T, {B}, {m}){one}, got {np.shape(ys)}")
        return _check_ys(arr, B, m)


class KalmanFilter(_KalmanLoop):
    """Linear Kalman filter ``x_k = F x_{k-1} + G u_k + w``, ``y_k = H x_k + v`` for B units.

    ``F``, ``H``, ``Q``, ``R`` (and the optional control matrix ``G`` (n, n_u)) are shared arrays,
    per-unit (B, ...) arrays or callables of the step index k. Constant ``Q``/``R`` are checked
    symmetric PSD once; time-varying ones are shape- and finiteness-checked per step.
    """

    def __init__(
        self,
        F: MatrixLike,
        H: MatrixLike,
        Q: MatrixLike,
        R: MatrixLike,
        G: MatrixLike | None = None,
    ) -> None:
        self.F = _MatrixSource(F, None, None, "F", cov=False)
        self.H = _MatrixSource(H, None, None, "H", cov=False)
        self.Q = _MatrixSource(Q, None, None, "Q", cov=True)
        self.R = _MatrixSource(R, None, None, "R", cov=True)
        self.G = None if G is None else _MatrixSource(G, None, None, "G", cov=False)
        if G is not None and callable(G):
            raise ValueError("G: a callable control matrix is not supported; pass an array")

    def _start(self, prior: Any, P0: Any) -> tuple[FloatArray, FloatArray, int]:
        x, P = _check_x0_P0(prior, P0)
        B, n = x.shape
        m = self.R.rows if self.R.value is not None else self.H.rows
        if m is None:  # both callables: ask R for its size
            m = np.atleast_2d(np.asarray(self.R.fn(0))).shape[-1]  # type: ignore[misc]
        self.F.validate(B, n, n)
        self.Q.validate(B, n, n)
        self.H.validate(B, m, n)
        self.R.validate(B, m, m)
        if self.G is not None:
            self.G.validate(B, n, cast(FloatArray, self.G.value).shape[-1])
        return x, P, m

    def _measurements(self, ys: Any, B: int, m: int) -> FloatArray:
        arr = _one_unit_ys(ys, B)
        if arr.ndim != 3 or arr.shape[1:] != (B, m):
            one = f" or (T, {m})" if B == 1 else ""
            raise ValueError(f"ys: expected shape (T, {B}, {m}){one}, got {np.shape(ys)}")
        return _check_ys(arr, B, m)

    def _check_inputs(self, us: Any, name: str = "us") -> None:
        if us is None and self.G is not None:
            raise ValueError(f"{name}: the filter has a control matrix G but no inputs were "
                             "given")
        if us is not None and self.G is None:
            raise ValueError(f"{name}: inputs were given but the filter has no control matrix G "
                             "(pass G=... to KalmanFilter); they would be ignored")

    def _advance(
        self, x: FloatArray, P: FloatArray, y: FloatArray, k: int, u: Any
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, Innovation]:
        B = x.shape[0]
        bu = None
        if self.G is not None:
            ua = np.asarray(u, dtype=np.float64)
            _check_finite(ua, f"us[{k}]")
            bu = _matvec(cast(FloatArray, self.G.value),  # G is constant
                         np.broadcast_to(ua, (B, ua.shape[-1])))
        xp, Pp = _predict(x, P, self.F.at(k, B), self.Q.at(k, B), bu)
        xn, Pn, inn = _update(xp, Pp, y, self.H.at(k, B), self.R.at(k, B), None)
        return xp, Pp, xn, Pn, inn


def _apply(
    fun: Callable[..., np.ndarray], x: FloatArray, u: Any, k: Any, rows: int, name: str
) -> FloatArray:
    """``fun(x, u, k)`` as a (rows, ...) array (a (rows,) output is one column)."""
    val = np.asarray(fun(x, u, k), dtype=np.float64)
    if val.ndim == 1 and rows == x.shape[0]:
        val = val[:, None]
    if val.ndim != 2 or val.shape[0] != rows:
        raise ValueError(f"{name}: expected an output of shape ({rows}, ...), got {val.shape}")
    return val


class NonlinearKalmanFilter(_KalmanLoop):
    """The shared loop of the EKF and UKF: a subclass defines ``Q``, ``R`` and the one-step
    ``predict(x, P, k, u)`` and ``update(x, P, y, k, u)``."""

    Q: _MatrixSource
    R: _MatrixSource
    n_x: int | None = None  # known when built from a model: shapes checked before any call
    n_y: int | None = None

    def _set_functions(self, f: Callable[..., np.ndarray], h: Callable[..., np.ndarray],
                       Q: MatrixLike, R: MatrixLike) -> None:
        """Keep the step ``f``, the output ``h`` and the covariances ``Q``, ``R`` (shared, per
        unit or callables of k); a model given as ``f`` is a ``TypeError`` naming ``from_model``."""
        refuse_model(f, type(self).__name__)
        self.f, self.h = f, h
        self.Q = _MatrixSource(Q, None, None, "Q", cov=True)
        self.R = _MatrixSource(R, None, None, "R", cov=True)

    def _sized_for(self, model: StateSpaceModel) -> Self:
        """This filter with ``model``'s state and output sizes, so that ``filter`` checks
        shapes before any model code runs (the end of each ``from_model``)."""
        self.n_x, self.n_y = model.n_x, model.n_y
        return self

    def predict(
        self, x: FloatArray, P: FloatArray, k: int, u: Any = None
    ) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - overridden
        """Predict step ``k``: ``(x_pred (B, n), P_pred (B, n, n))``."""
        raise NotImplementedError

    def update(
        self, x: FloatArray, P: FloatArray, y: FloatArray, k: int, u: Any = None
    ) -> tuple[FloatArray, FloatArray, Innovation]:  # pragma: no cover - overridden
        """Assimilate ``y`` (B, m) (= ``ys[k]``): ``(x, P, Innovation)``."""
        raise NotImplementedError

    def _start(self, prior: Any, P0: Any) -> tuple[FloatArray, FloatArray, int]:
        x, P = _check_x0_P0(prior, P0, self.n_x)
        B, n = x.shape
        self.Q.validate(B, n, n)
        if self.R.value is not None:
            m = self.R.value.shape[-1]
        elif self.n_y is not None:
            m = self.n_y
        else:  # a callable R: ask it for its size
            m = np.atleast_2d(np.asarray(self.R.fn(0))).shape[-1]  # type: ignore[misc]
        self.R.validate(B, m, m)
        return x, P, m

    def _measurements(self, ys: Any, B: int, m: int) -> FloatArray:
        arr = _one_unit_ys(ys, B)
        if arr.ndim != 3 or arr.shape[2] != m:
            one = f" (or (T, {m}) for one unit)" if B == 1 else ""
            raise ValueError(f"ys: expected shape (T, {B}, {m}){one}, got {np.shape(ys)}")
        return _check_ys(arr, B, m)

    def _advance(
        self, x: FloatArray, P: FloatArray, y: FloatArray, k: int, u: Any
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, Innovation]:
        xp, Pp = self.predict(x, P, k, u)
        xn, Pn, inn = self.update(xp, Pp, y, k, u)
        return xp, Pp, xn, Pn, inn
