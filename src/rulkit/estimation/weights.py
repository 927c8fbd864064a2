"""Weighted-particle utilities: log-sum-exp normalisation, effective sample size, weighted
mean, covariance and quantiles (docs/guide.md, "Log-weights"), shared by
:mod:`rulkit.estimation.particle` and its users. The row-wise numba/numpy kernels behind them
are in :mod:`rulkit.estimation.batched`.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from rulkit.estimation.base import weighted_moments
from rulkit.estimation.batched import ess_rows, normalise_weights
from rulkit.model import plain

FloatArray = NDArray[np.float64]

__all__ = [
    "DegenerateWeightsError",
    "effective_sample_size",
    "log_normalise",
    "weighted_cov",
    "weighted_mean",
    "weighted_quantile",
]


class DegenerateWeightsError(FloatingPointError):
    """Every particle weight is zero (all log-weights -inf) or some log-weight is NaN / +inf.

    ``step`` is the filter step at which it happened (``None`` outside a filter).
    """

    def __init__(self, message: str, step: int | None = None) -> None:
        super().__init__(message)
        self.step = step


# ---------------------------------------------------------------------------------------------
# Weight utilities
# ---------------------------------------------------------------------------------------------


def _describe_degenerate(logw: FloatArray) -> str:
    n_nan = int(np.isnan(logw).sum())
    n_pinf = int(np.isposinf(logw).sum())
    if n_nan:
        first = int(np.flatnonzero(np.isnan(logw))[0])
        return f"{n_nan} of {logw.size} log-weights are NaN (first at particle {first})"
    if n_pinf:
        first = int(np.flatnonzero(np.isposinf(logw))[0])
        return f"{n_pinf} of {logw.size} log-weights are +inf (first at particle {first})"
    return f"all {logw.size} weights are zero (every log-weight is -inf)"


def log_normalise(logw: FloatArray) -> tuple[FloatArray, float]:
    """Normalise log-weights by log-sum-exp: return ``(w, log_sum)`` with ``sum(w) == 1``.

    ``log_sum = log sum_i exp(logw_i)``, computed as ``m + log sum exp(logw - m)`` with
    ``m = max logw`` so nothing overflows (docs/guide.md, "Log-weights": normalise with
    log-sum-exp). Raises ``DegenerateWeightsError`` when every log-weight is -inf, or any is NaN or
    +inf.
    """
    logw = np.asarray(logw, dtype=np.float64)
    if logw.ndim != 1 or logw.size == 0:
        raise ValueError(f"logw: expected a non-empty 1-D array, got shape {logw.shape}")
    w, ls = normalise_weights(logw)
    if not math.isfinite(ls):  # NaN anywhere, +inf anywhere, or all -inf
        raise DegenerateWeightsError(_describe_degenerate(logw))
    return w, float(ls)


def effective_sample_size(w: FloatArray) -> float:
    """Effective sample size ``1 / sum_i w_i^2`` of normalised weights (seed 000 eq. 16)."""
    return float(ess_rows(np.asarray(w, dtype=np.float64)))


def weighted_mean(x: FloatArray, w: FloatArray) -> FloatArray:
    """Weighted mean ``sum_i w_i x_i`` of particles ``x`` (N, n_x) or (N,) with weights (N,)."""
    return np.asarray(w, dtype=np.float64) @ np.asarray(x, dtype=np.float64)


def weighted_cov(x: FloatArray, w: FloatArray, mean: FloatArray | None = None) -> FloatArray:
    """Weighted covariance ``sum_i w_i (x_i - m)(x_i - m)^T`` (n_x, n_x) of particles (N, n_x).

    The plug-in (posterior) second central moment of the weighted empirical measure, without a
    small-sample correction. ``mean`` may be passed when already computed.
    """
    x = np.asarray(x, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, None]
    if mean is None:
        return weighted_moments(x, w)[1]
    return _cov(x, w, np.asarray(mean, dtype=np.float64))


def _cov(x: FloatArray, w: FloatArray, m: FloatArray) -> FloatArray:
    """``sum_i w_i (x_i - m)(x_i - m)^T`` for particles (N, n_x), computed on the transpose.

    ``x - m`` on an (N, n_x) array with small ``n_x`` runs numpy's inner loop over ``n_x``
    elements N times; on the (n_x, N) transpose the inner loops run over N (several times
    faster at n_x = 2). Same products and BLAS reduction as ``((x - m).T * w) @ (x - m)``.
    """
    xc = x.T.copy()  # (n_x, N), C-contiguous
    xc -= m[:, None]
    return (xc * w) @ xc.T


def weighted_quantile(values: FloatArray, w: FloatArray, q: float | FloatArray) -> FloatArray:
    """Quantiles of the weighted empirical distribution (inverse of its CDF).

    ``values`` (N,) or (N, n) with weights ``w`` (N,) (need not be normalised, non-negative);
    ``q`` scalar or (n_q,) in [0, 1]. Returns shape ``q.shape + values.shape[1:]``. The
    ``q``-quantile is the smallest value ``v`` with ``F(v) >= q``, ``F`` the weighted CDF
    (zero-weight particles are never returned) — numpy's ``method="inverted_cdf"``, which for
    equal weights is the classical sample quantile without interpolation.
    """
    v = np.asarray(values, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)
    qa = np.asarray(q, dtype=np.float64)
    if v.ndim not in (1, 2) or v.shape[0] != w.shape[0] or w.ndim != 1:
        raise ValueError(
            f"weighted_quantile: values must be (N,) or (N, n) and weights (N,), "
            f"got {v.shape} and {w.shape}"
        )
    if qa.ndim > 1 or np.any((qa < 0) | (qa > 1)) or np.any(np.isnan(qa)):
        raise ValueError(f"weighted_quantile: q must be scalar or 1-D in [0, 1], got {plain(q)}")
    if v.shape[0] == 0 or not np.all(np.isfinite(w)) or np.any(w < 0) or not w.sum() > 0:
        raise ValueError(
            "weighted_quantile: weights must be finite, non-negative and not all zero "
            f"(N = {w.shape[0]})"
        )
    if np.isnan(v).any():
        raise ValueError("weighted_quantile: values contain NaN (no order is defined)")
    return _weighted_quantile(v, w, qa)


def _weighted_quantile(v: FloatArray, w: FloatArray, qa: FloatArray) -> FloatArray:
    one_d = v.ndim == 1
    v2 = v[:, None] if one_d else v
    n, n_col = v2.shape
    order = np.argsort(v2, axis=0)  # one sort per component
    cw = np.cumsum(w[order], axis=0)  # (N, n) cumulative weights in sorted order
    q1 = np.atleast_1d(qa)
    thr = q1[:, None] * cw[-1]  # (n_q, n)
    zero_q = q1 == 0
    idx = np.empty((q1.size, n_col), dtype=np.intp)
    for j in range(n_col):  # loop over state components (n_x), never over particles
        # first index with cumulative weight >= q * total ...
        idx[:, j] = np.searchsorted(cw[:, j], thr[:, j], side="left")
    if zero_q.any():  # ... and > 0 for q = 0, so a zero-weight particle is never returned
        for j in range(n_col):
            idx[zero_q, j] = np.searchsorted(cw[:, j], 0.0, side="right")
    np.minimum(idx, n - 1, out=idx)
    cols = np.arange(n_col)
    out = v2[order[idx, cols], cols]  # (n_q, n)
    if one_d:
        out = out[:, 0]
    return out[0] if qa.ndim == 0 else out
