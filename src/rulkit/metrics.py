"""Prognostic performance metrics (engine-api.md, ``rulkit.metrics``).

Definitions follow Saxena, Celaya, Saha, Saha & Goebel, "Metrics for offline evaluation of
prognostic performance", Int. J. PHM 1 (2010) (below: [S2010]) and, for CRPS, Gneiting &
Raftery, "Strictly proper scoring rules, prediction, and estimation", JASA 102 (2007) ([GR2007]).

Notation: predictions are made at times ``t_i`` (i = P .. EoP) for a unit whose end of life is
``t_EoL``; the true RUL is ``r*(i) = t_EoL - t_i`` and ``r(i)`` the predicted RUL (a point value,
or the median of a predicted distribution). The error is ``Delta(i) = r*(i) - r(i)`` (positive:
the prediction is early, i.e. conservative).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rulkit.model import plain
from rulkit.prognosis.rul import RULDistribution

FloatArray = NDArray[np.float64]


class UninformativeForecastWarning(UserWarning):
    """A forecast carries no information a metric could score (e.g. every sample censored):
    the metric is NaN, never a perfect score."""


def _first(mask: np.ndarray) -> tuple[int, ...] | None:
    """Index of the first True entry of ``mask`` (``()`` for a true 0-d mask), else None.

    ``np.argwhere`` of a 0-d array has no columns, so a scalar NaN or zero went unnoticed.
    """
    if mask.ndim == 0:
        return () if bool(mask) else None
    hit = np.argwhere(mask)
    return tuple(int(i) for i in hit[0]) if hit.size else None


def _arr(x: ArrayLike, name: str) -> FloatArray:
    a = np.asarray(x, dtype=np.float64)
    if a.size == 0:
        raise ValueError(f"{name}: empty")
    bad = _first(~np.isfinite(a))
    if bad is not None:
        raise ValueError(f"{name}: non-finite value at index {bad}")
    return a


def _same_shape(a: FloatArray, b: FloatArray, na: str, nb: str) -> None:
    if a.shape != b.shape:
        raise ValueError(f"{na} and {nb}: shapes differ, {a.shape} vs {b.shape}")


def _nonzero_truth(truth: FloatArray, name: str) -> None:
    z = _first(truth == 0)
    if z is not None:
        raise ValueError(
            f"{name}: zero at index {z}; a relative error is "
            "undefined there (drop the end-of-life point)"
        )


# ---------------------------------------------------------------------------- point errors
def rul_percentage_error(rul_pred: ArrayLike, rul_true: ArrayLike) -> FloatArray:
    """RUL percentage error ``100 (r* - r) / r*`` elementwise ([S2010], "error" and
    "relative error"); positive means an early (conservative) prediction.

    Raises ``ValueError`` where ``r* = 0`` (undefined), on NaN/inf or on a shape mismatch.
    """
    r = _arr(rul_pred, "rul_pred")
    rt = _arr(rul_true, "rul_true")
    _same_shape(r, rt, "rul_pred", "rul_true")
    _nonzero_truth(rt, "rul_true")
    return 100.0 * (rt - r) / rt


def rmspe(estimate: ArrayLike, truth: ArrayLike, axis: int | None = None) -> float | FloatArray:
    """Root mean squared percentage error ``100 sqrt(mean(((x_hat - x) / x)^2))``.

    The definition of docs/systems/reaction-wheel.md §6 (and the RMSPE of [S2010]'s accuracy metrics
    with ``x = r*``). ``axis`` as in :func:`numpy.mean`; ``None`` averages over all entries.
    """
    e = _arr(estimate, "estimate")
    x = _arr(truth, "truth")
    _same_shape(e, x, "estimate", "truth")
    _nonzero_truth(x, "truth")
    out = 100.0 * np.sqrt(np.mean(((e - x) / x) ** 2, axis=axis))
    return float(out) if np.ndim(out) == 0 else out


def relative_accuracy(rul_pred: ArrayLike, rul_true: ArrayLike) -> float | FloatArray:
    """Relative accuracy ``RA = 1 - |r* - r| / r*`` ([S2010], RA at a time t_lambda).

    Elementwise; 1 is perfect, it can be negative for errors larger than r*. Defined before
    end of life only: ``r* <= 0`` raises ``ValueError`` (a negative r* gave RA > 1, i.e. "better
    than perfect", silently).
    """
    r = _arr(rul_pred, "rul_pred")
    rt = _arr(rul_true, "rul_true")
    _same_shape(r, rt, "rul_pred", "rul_true")
    _nonzero_truth(rt, "rul_true")
    neg = _first(rt < 0)
    if neg is not None:
        raise ValueError(f"rul_true: negative at index {neg} (a prediction after end of "
                         "life); RA is defined for r* > 0")
    out = 1.0 - np.abs(rt - r) / rt
    return float(out) if np.ndim(out) == 0 else out


def cumulative_relative_accuracy(
    rul_pred: ArrayLike, rul_true: ArrayLike, weights: ArrayLike | None = None
) -> float:
    """Cumulative relative accuracy ``CRA = sum_i w_i RA(i)`` with ``sum_i w_i = 1``.

    [S2010]: CRA = (1/|l|) sum_{i in l} w(r(i)) RA(i) over the prediction times l; equal weights
    (the default) give the plain mean of RA. Weights are normalised to sum 1 here so that CRA
    stays on RA's scale whatever weighting is chosen (e.g. more weight near end of life).
    """
    ra = np.atleast_1d(np.asarray(relative_accuracy(rul_pred, rul_true)))
    if weights is None:
        w = np.full(ra.shape, 1.0 / ra.size)
    else:
        w = _arr(weights, "weights")
        _same_shape(w, ra, "weights", "rul_pred")
        if np.any(w < 0) or not w.sum() > 0:
            raise ValueError("weights: must be non-negative and not all zero")
        w = w / w.sum()
    return float(np.sum(w * ra))


# ---------------------------------------------------------------------------- alpha-lambda / PH
def _point(pred: ArrayLike | Sequence[RULDistribution]) -> tuple[FloatArray, list | None]:
    """Point predictions (medians for distributions) and the distributions, if any."""
    if isinstance(pred, Sequence) and len(pred) > 0 and isinstance(pred[0], RULDistribution):
        dists = list(pred)
        if not all(isinstance(d, RULDistribution) for d in dists):
            raise ValueError("rul_pred: mix of RULDistribution and numbers")
        return np.array([d.median for d in dists], dtype=np.float64), dists
    return _arr(cast(ArrayLike, pred), "rul_pred"), None


def _prediction_series(
    times: ArrayLike,
    rul_pred: ArrayLike | Sequence[RULDistribution],
    t_eol: float,
    alpha: float,
    beta: float,
) -> tuple[FloatArray, FloatArray, list | None]:
    """Validated (times, point predictions, distributions or None) of alpha-lambda and PH.

    Checks equal 1-D shapes, strictly increasing finite times, a finite ``t_eol``,
    ``alpha > 0`` and ``0 < beta <= 1`` (a NaN in any of them would make every comparison
    False and the metric fail or pass silently).
    """
    t = _arr(times, "times")
    r, dists = _point(rul_pred)
    if t.ndim != 1 or r.shape != t.shape:
        raise ValueError(f"times and rul_pred: expected equal 1-D shapes, got {t.shape}, {r.shape}")
    if np.any(np.diff(t) <= 0):
        i = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise ValueError(f"times: not strictly increasing at index {i + 1}")
    if not math.isfinite(t_eol):
        raise ValueError(f"t_eol: expected a finite end-of-life time, got {plain(t_eol)}")
    if not alpha > 0 or not math.isfinite(alpha):
        raise ValueError(f"alpha: expected a finite positive value, got {plain(alpha)}")
    if not 0 < beta <= 1:
        raise ValueError(f"beta: expected a probability in (0, 1], got {plain(beta)}")
    return t, r, dists


def mass_inside(dist: RULDistribution, lo: float, hi: float) -> float:
    """Probability mass of ``dist`` in [lo, hi].

    A censored sample is only known to exceed its bound, so it counts as inside only when
    ``hi`` is infinite and its bound is >= lo; otherwise as outside (conservative).
    """
    s, w, c = dist.samples, dist.weights, dist.censored
    inside = ~c & (s >= lo) & (s <= hi)
    m = float(w[inside].sum())
    if math.isinf(hi):
        m += float(w[c & (s >= lo)].sum())
    return m


@dataclass(frozen=True)
class AlphaLambdaResult:
    """Outcome of :func:`alpha_lambda` at ``t_lambda``."""

    t_lambda: float
    t_pred: float  # time of the prediction used (latest at or before t_lambda)
    rul_pred: float  # point prediction (median for distributions)
    rul_true: float
    lower: float  # (1 - alpha) r*
    upper: float  # (1 + alpha) r*
    prob_mass: float  # mass of the predicted distribution inside [lower, upper] (nan for points)
    passed: bool


def alpha_lambda(
    times: ArrayLike,
    rul_pred: ArrayLike | Sequence[RULDistribution],
    t_eol: float,
    *,
    alpha: float = 0.2,
    lam: float = 0.5,
    t_p: float | None = None,
    beta: float = 0.5,
) -> AlphaLambdaResult:
    """Alpha-lambda accuracy ([S2010]): is the prediction at ``t_lambda`` within alpha of r*?

    ``t_lambda = t_P + lam (t_EoL - t_P)`` (``t_P`` defaults to the first prediction time):
    ``lam`` is a *fraction* of the time from the first prediction to end of life, as in
    [S2010]; NASA ProgPy's ``alpha_lambda`` takes the time ``t_lambda`` itself (convert with
    ``lam = (t_lambda - t_P) / (t_EoL - t_P)``).
    The prediction used is the latest one made at or before ``t_lambda``. With point
    predictions it passes when ``(1 - alpha) r* <= r <= (1 + alpha) r*``; with a sequence of
    :class:`RULDistribution` it passes when the probability mass inside those bounds is
    ``>= beta`` (censored mass counts as outside unless the upper bound is infinite).
    """
    t, r, dists = _prediction_series(times, rul_pred, t_eol, alpha, beta)
    if not 0 <= lam <= 1:
        raise ValueError(f"lam: expected a value in [0, 1], got {plain(lam)}")
    tp = float(t[0]) if t_p is None else float(t_p)
    if not math.isfinite(tp):
        raise ValueError(f"t_p: expected a finite time, got {plain(t_p)}")
    if not t_eol > tp:
        raise ValueError(f"t_eol: must exceed t_p ({plain(tp)}), got {plain(t_eol)}")
    t_lam = tp + lam * (t_eol - tp)
    tol = 1e-12 * max(1.0, abs(t_lam))  # t_lambda equal to a prediction time up to round-off
    idx = int(np.searchsorted(t, t_lam + tol, side="right")) - 1
    if idx < 0:
        raise ValueError(f"no prediction at or before t_lambda = {plain(t_lam)}")
    rt = t_eol - float(t[idx])
    lo, hi = (1 - alpha) * rt, (1 + alpha) * rt
    rp = float(r[idx])
    if dists is None:
        mass = math.nan
        ok = lo <= rp <= hi
    else:
        mass = mass_inside(dists[idx], lo, hi)
        ok = mass >= beta
    return AlphaLambdaResult(t_lam, float(t[idx]), rp, rt, lo, hi, mass, bool(ok))


@dataclass(frozen=True)
class PrognosticHorizonResult:
    """Outcome of :func:`prognostic_horizon`."""

    horizon: float  # t_EoL - t_i at the qualifying time (nan if none qualifies)
    t_first: float  # the qualifying prediction time (nan if none)
    index: int  # its index (-1 if none)
    inside: NDArray[np.bool_]  # per prediction time: criterion met


def prognostic_horizon(
    times: ArrayLike,
    rul_pred: ArrayLike | Sequence[RULDistribution],
    t_eol: float,
    *,
    alpha: float = 0.05,
    beta: float = 0.5,
    bounds: Literal["absolute", "relative"] = "absolute",
    stay: bool = False,
) -> PrognosticHorizonResult:
    """Prognostic horizon ``PH = t_EoL - t_i`` ([S2010]).

    ``i = min{j : pi[r(j)] >= beta}`` where ``pi`` is the probability mass of the prediction
    inside the alpha-bounds (for point predictions: 1 if inside, else 0). Bounds are
    ``r* +- alpha t_EoL`` (``bounds="absolute"``, [S2010]'s PH cone of constant width) or
    ``(1 -+ alpha) r*`` (``"relative"``, the alpha-lambda cone). With ``stay=True`` the
    criterion must also hold at every later prediction time (a stricter variant used in
    later literature). Only prediction times before ``t_eol`` are considered.
    Returns ``horizon = nan`` and ``index = -1`` when no time qualifies.
    """
    t, r, dists = _prediction_series(times, rul_pred, t_eol, alpha, beta)
    if bounds not in ("absolute", "relative"):
        raise ValueError(f"bounds: expected 'absolute' or 'relative', got {bounds!r}")
    rt = t_eol - t
    if bounds == "absolute":
        lo, hi = rt - alpha * t_eol, rt + alpha * t_eol
    else:
        lo, hi = (1 - alpha) * rt, (1 + alpha) * rt
    if dists is None:
        inside = (r >= lo) & (r <= hi)
    else:
        inside = np.array([mass_inside(d, a, b) >= beta for d, a, b in zip(dists, lo, hi,
                                                                          strict=True)])
    inside = inside & (t < t_eol)
    if stay:
        # suffix-all: criterion holds at j and every later time before t_eol
        valid = t < t_eol
        ok_or_after = inside | ~valid
        suffix = np.flip(np.logical_and.accumulate(np.flip(ok_or_after)))
        cand = suffix & inside
    else:
        cand = inside
    hits = np.flatnonzero(cand)
    if hits.size == 0:
        return PrognosticHorizonResult(math.nan, math.nan, -1, inside)
    i = int(hits[0])
    return PrognosticHorizonResult(float(t_eol - t[i]), float(t[i]), i, inside)


def convergence(times: ArrayLike, metric: ArrayLike, t_p: float | None = None) -> float:
    """Convergence of a metric curve ``M(t_i)`` ([S2010]): distance from ``(t_P, 0)`` to the
    centroid of the area under the piecewise-constant curve (``M(i)`` held on
    ``[t_i, t_{i+1})``, i = P .. EoUP - 1; the last value is not used):

        x_c = sum_i (t_{i+1}^2 - t_i^2) M(i) / (2 sum_i (t_{i+1} - t_i) M(i))
        y_c = sum_i (t_{i+1} - t_i) M(i)^2 / (2 sum_i (t_{i+1} - t_i) M(i))
        C_M = sqrt((x_c - t_P)^2 + y_c^2)

    Smaller is faster convergence. ``M`` is a non-negative error measure (e.g. |Delta|).
    ``t_p`` defaults to ``times[0]``.
    """
    t = _arr(times, "times")
    m = _arr(metric, "metric")
    if t.ndim != 1 or m.shape != t.shape or t.size < 2:
        raise ValueError(f"times and metric: need equal 1-D shapes of length >= 2, got "
                         f"{t.shape}, {m.shape}")
    if np.any(np.diff(t) <= 0):
        raise ValueError("times: not strictly increasing")
    if np.any(m < 0):
        raise ValueError("metric: must be non-negative (an error measure)")
    dtv = np.diff(t)
    mi = m[:-1]
    area = float(np.sum(dtv * mi))
    if area <= 0:
        raise ValueError("metric: zero area under the curve; convergence is undefined")
    xc = float(np.sum((t[1:] ** 2 - t[:-1] ** 2) * mi)) / (2 * area)
    yc = float(np.sum(dtv * mi**2)) / (2 * area)
    tp = float(t[0]) if t_p is None else float(t_p)
    if not math.isfinite(tp):
        raise ValueError(f"t_p: expected a finite time, got {plain(t_p)}")
    return math.hypot(xc - tp, yc)


# ---------------------------------------------------------------------------- probabilistic
def interval_coverage(lower: ArrayLike, upper: ArrayLike, truth: ArrayLike) -> float:
    """Fraction of ``truth`` values inside their closed interval ``[lower, upper]``.

    Infinite bounds are allowed (e.g. an upper quantile falling in censored mass); NaN is not.
    """
    lo = np.asarray(lower, dtype=np.float64)
    hi = np.asarray(upper, dtype=np.float64)
    y = _arr(truth, "truth")
    if lo.shape != y.shape or hi.shape != y.shape:
        raise ValueError(f"lower, upper, truth: shapes differ {lo.shape}, {hi.shape}, {y.shape}")
    if np.isnan(lo).any() or np.isnan(hi).any():
        raise ValueError("lower/upper: NaN bound")
    bad = np.flatnonzero(np.ravel(lo > hi))
    if bad.size:
        raise ValueError(f"lower > upper at index {bad[0]}")
    return float(np.mean((y >= lo) & (y <= hi)))


def crps_samples(
    samples: ArrayLike, y: ArrayLike, weights: ArrayLike | None = None
) -> float | FloatArray:
    """CRPS of the weighted empirical distribution of ``samples`` at observation(s) ``y``.

    [GR2007] eq. (21): ``CRPS(F, y) = E|X - y| - 1/2 E|X - X'|`` with X, X' independent draws
    from F = sum_j w_j delta_{x_j}; this equals ``int (F(z) - 1{z >= y})^2 dz`` exactly.
    ``E|X - X'| = 2 sum_k w_(k) (x_(k) W_(k) - S_(k))`` over the sorted samples, where
    ``W_(k)``/``S_(k)`` are the sums of w and w x over samples ranked below k: O(N log N).

    ``samples`` is (N,) with scalar ``y``, or (..., N) with ``y`` of shape (...) (one forecast
    per observation). ``weights`` like ``samples`` (normalised along the last axis).
    Lower is better; 0 only for a point mass at y.
    """
    x = _arr(samples, "samples")
    yy = _arr(y, "y")
    if x.shape[:-1] != yy.shape:
        raise ValueError(f"samples (..., N) and y (...): shapes {x.shape} and {yy.shape} "
                         "do not match")
    if weights is None:
        w = np.full(x.shape, 1.0 / x.shape[-1])
    else:
        w = _arr(weights, "weights")
        _same_shape(w, x, "weights", "samples")
        if np.any(w < 0):
            raise ValueError("weights: negative weight")
        tot = w.sum(axis=-1, keepdims=True)
        if np.any(tot <= 0):
            raise ValueError("weights: all zero for some forecast")
        w = w / tot
    term1 = np.sum(w * np.abs(x - yy[..., None]), axis=-1)
    order = np.argsort(x, axis=-1, kind="stable")
    xs = np.take_along_axis(x, order, axis=-1)
    ws = np.take_along_axis(w, order, axis=-1)
    w_below = np.cumsum(ws, axis=-1) - ws
    s_below = np.cumsum(ws * xs, axis=-1) - ws * xs
    e_abs = 2.0 * np.sum(ws * (xs * w_below - s_below), axis=-1)
    out = term1 - 0.5 * e_abs
    return float(out) if np.ndim(out) == 0 else out


def crps_normal(mu: ArrayLike, sigma: ArrayLike, y: ArrayLike) -> float | FloatArray:
    """CRPS of a normal forecast N(mu, sigma^2) at ``y`` ([GR2007] eq. (5)):

        CRPS = sigma [ z (2 Phi(z) - 1) + 2 phi(z) - 1/sqrt(pi) ],   z = (y - mu) / sigma.

    Broadcasts; ``sigma`` must be positive.
    """
    from scipy.special import ndtr

    m = _arr(mu, "mu")
    s = _arr(sigma, "sigma")
    yy = _arr(y, "y")
    if np.any(s <= 0):
        raise ValueError("sigma: must be positive")
    z = (yy - m) / s
    pdf = np.exp(-0.5 * z * z) / math.sqrt(2 * math.pi)
    out = s * (z * (2 * ndtr(z) - 1) + 2 * pdf - 1 / math.sqrt(math.pi))
    return float(out) if np.ndim(out) == 0 else out


def crps_rul(dist: RULDistribution, rul_true: float, *, truth_censored: bool = False) -> float:
    """CRPS of a (possibly censored) RUL distribution, against a possibly censored truth.

    ``int_{-inf}^{U} (F(z) - 1{z >= y})^2 dz`` with ``F`` the weighted CDF of the uncensored
    samples and ``U = min(horizon, c)``: the forecast's CDF is known only below its horizon,
    and a truth censored at ``c`` (``truth_censored=True``: the unit was still running, its RUL
    exceeds ``c = rul_true``) only says ``1{z >= y} = 0`` below ``c``. This is the CRPS with
    the threshold weight ``1{z < U}`` ([GR2007] section 4.2), a proper score for censored data;
    with nothing censored and an infinite horizon it is the ordinary CRPS
    (:func:`crps_samples`). Computed exactly from the step CDF, O(N log N).

    A forecast whose every sample is censored says only "beyond the horizon": it scores NaN
    with a :class:`UninformativeForecastWarning` (extend the horizon), never a perfect 0.
    """
    y = float(rul_true)
    if not math.isfinite(y):
        raise ValueError(f"rul_true: expected a finite value, got {plain(rul_true)}")
    if not np.any(dist.weights[~dist.censored] > 0):  # every (weighted) sample censored
        warnings.warn(UninformativeForecastWarning(
            f"crps_rul: every sample of the forecast is censored at the horizon "
            f"{dist.horizon:g}: it only says RUL > {dist.horizon:g}, so no score is given "
            "(NaN); predict with a longer horizon"), stacklevel=2)
        return math.nan
    upper = min(dist.horizon, y if truth_censored else math.inf)
    y_ind = math.inf if truth_censored else y
    keep = ~dist.censored
    vals = dist.samples[keep]
    pts = vals[vals < upper]
    extra = [y_ind] if y_ind < upper else []
    if math.isfinite(upper):
        extra.append(upper)
    pts = np.unique(np.concatenate([pts, np.asarray(extra, dtype=np.float64)]))
    if pts.size < 2:
        return 0.0
    F = np.asarray(dist.cdf(pts[:-1]), dtype=np.float64)
    ind = (pts[:-1] >= y_ind).astype(np.float64)
    return float(np.sum((F - ind) ** 2 * np.diff(pts)))
