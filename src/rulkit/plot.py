"""Figures for prognostics: the alpha-lambda cone, RUL distributions over time, state estimates
with bands, and NIS/NEES against their chi-square bounds.

Every function draws on an :class:`~matplotlib.axes.Axes` you pass (``ax=``) or on a new
:class:`~matplotlib.figure.Figure` it creates, and returns what it drew on, so figures compose::

    from rulkit import plot
    ax = plot.alpha_lambda_cone(times, dists, t_eol=120.0, alpha=0.2)
    ax.figure.savefig("cone.png")

No function touches :mod:`matplotlib.pyplot` or its global state: figures are built with the
object API (``matplotlib.figure.Figure``), so they render with the Agg backend in a headless
process, a worker thread or a test, and nothing stays open after saving. Colours come from the
active matplotlib style.

What is drawn (the metrics are in :mod:`rulkit.metrics`, following Saxena et al. 2010):

- :func:`alpha_lambda_cone`: the true RUL ``r*(t) = t_EoL - t``, the accuracy cone
  ``(1 -+ alpha) r*(t)`` from the first prediction time to end of life (a triangle), and each
  prediction's median with its equal-tailed interval. An interval reaching into censored mass
  (infinite upper quantile) is drawn up to the top of the axes and marked with a ``^``.
  ``lam`` adds the vertical line at ``t_lambda = t_P + lam (t_EoL - t_P)``: here lambda is a
  *fraction* of the time from the first prediction to end of life, where NASA ProgPy's
  ``alpha_lambda`` takes a time.
- :func:`rul_distributions`: one density per prediction time (a half-violin standing on the
  time axis, scaled to the spacing of the times), its median, and the true RUL if known.
- :func:`state_estimates`: one panel per state component: estimate, a band (``mean +- k std``
  or given quantiles), truth and the measurements where they belong (on the panel of the state
  they measure, found from the measurement function, or on a panel of their own).
- :func:`consistency`: per-step NIS or NEES (averaged over units when given ``(T, B)``), the
  per-step two-sided chi-square acceptance interval and the time-averaged statistic with its
  own (much narrower) interval, from :func:`rulkit.estimation.consistency.chi2_interval`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from rulkit.estimation.base import FilterResult, Posterior
from rulkit.estimation.consistency import chi2_interval
from rulkit.model import plain
from rulkit.prognosis.rul import RULDistribution

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = [
    "alpha_lambda_cone",
    "consistency",
    "new_axes",
    "plot_profile",
    "rul_distributions",
    "state_estimates",
]

FloatArray = np.ndarray


def new_axes(figsize: tuple[float, float] = (6.4, 4.0)) -> Axes:
    """A fresh Axes on a new pyplot-free :class:`~matplotlib.figure.Figure`."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout="constrained")
    return fig.add_subplot()


def _vector(x: ArrayLike, name: str) -> FloatArray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 1:
        raise ValueError(f"{name}: expected a 1-D array, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        i = int(np.flatnonzero(~np.isfinite(a))[0])
        raise ValueError(f"{name}: non-finite value {float(a[i])!r} at index {i}")
    return a


def _predictions(
    rul: Sequence[RULDistribution] | ArrayLike, k: int, level: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Median, lower and upper interval bounds (K,) of distributions, or points (bounds NaN)."""
    if isinstance(rul, Sequence) and len(rul) and isinstance(rul[0], RULDistribution):
        if len(rul) != k:
            raise ValueError(f"rul: expected {k} distributions (one per time), got {len(rul)}")
        med = np.empty(k)
        lo = np.empty(k)
        hi = np.empty(k)
        for i, d in enumerate(rul):
            if not isinstance(d, RULDistribution):
                raise TypeError(f"rul[{i}]: expected a RULDistribution, got {type(d).__name__}")
            med[i] = d.median
            lo[i], hi[i] = d.interval(level)
        return med, lo, hi
    pts = np.asarray(rul, dtype=np.float64)
    if pts.shape != (k,):
        raise ValueError(
            f"rul: expected {k} RULDistribution objects or a point array of shape ({k},), "
            f"got shape {pts.shape}"
        )
    nan = np.full(k, np.nan)
    return pts, nan, nan.copy()


def alpha_lambda_cone(
    times: ArrayLike,
    rul: Sequence[RULDistribution] | ArrayLike,
    t_eol: float,
    *,
    alpha: float = 0.2,
    lam: float | None = 0.5,
    t_p: float | None = None,
    level: float = 0.9,
    ax: Axes | None = None,
) -> Axes:
    """RUL predictions over time inside the alpha-lambda accuracy cone.

    ``times`` (K,) are the prediction times; ``rul`` is a sequence of K
    :class:`~rulkit.prognosis.rul.RULDistribution` (median and ``level`` interval drawn) or K
    point predictions. The cone is the triangle with vertices ``(t_P, (1 + alpha) r*(t_P))``,
    ``(t_EoL, 0)`` and ``(t_P, (1 - alpha) r*(t_P))``, ``t_P`` the first prediction time unless
    given. Returns the Axes.
    """
    t = _vector(times, "times")
    if not 0 < alpha < 1:
        raise ValueError(f"alpha: expected a value in (0, 1), got {plain(alpha)}")
    tp = float(t[0]) if t_p is None else float(t_p)
    if not (math.isfinite(t_eol) and t_eol > tp):
        raise ValueError(f"t_eol: expected a finite time after t_p = {plain(tp)}, got "
                         f"{plain(t_eol)}")
    med, lo, hi = _predictions(rul, t.size, level)
    ax = new_axes() if ax is None else ax
    r0 = t_eol - tp
    from matplotlib.patches import Polygon

    cone = Polygon(
        [(tp, (1 + alpha) * r0), (t_eol, 0.0), (tp, (1 - alpha) * r0)],
        closed=True, alpha=0.2, color="C2", lw=0, label=f"alpha = {alpha:g} cone",
    )
    cone.set_gid("alpha-lambda-cone")
    ax.add_patch(cone)
    ax.plot([tp, t_eol], [r0, 0.0], "k--", lw=1, label="true RUL", gid="true-rul")
    finite = np.concatenate([v[np.isfinite(v)] for v in (med, lo, hi)])
    top = max(1.3 * (1 + alpha) * r0, 1.05 * float(finite.max()) if finite.size else 0.0)
    med_drawn = np.where(np.isfinite(med), med, top)  # a median inside censored mass: at the top
    if np.any(np.isfinite(lo)) or np.any(np.isfinite(hi)):
        lo_drawn = np.where(np.isfinite(lo), lo, top)
        hi_drawn = np.where(np.isfinite(hi), hi, top)
        yerr = np.vstack([med_drawn - lo_drawn, hi_drawn - med_drawn])
        ax.errorbar(t, med_drawn, yerr=yerr, fmt="o", color="C0", capsize=3, ms=4,
                    label=f"median, {100 * level:g} % interval", gid="predictions")
        open_top = ~np.isfinite(hi)
        if open_top.any():
            ax.plot(t[open_top], np.full(open_top.sum(), top), "^", color="C0", ms=6,
                    label="interval into censored mass", gid="censored-upper")
    else:
        ax.plot(t, med_drawn, "o", color="C0", ms=4, label="prediction", gid="predictions")
    if lam is not None:
        if not 0 <= lam <= 1:
            raise ValueError(f"lam: expected a fraction in [0, 1], got {plain(lam)}")
        t_lam = tp + lam * (t_eol - tp)
        ax.axvline(t_lam, color="0.4", lw=1, ls=":", label=f"t_lambda (lambda = {lam:g})",
                   gid="t-lambda")
    t_lo = min(tp, float(t.min()))
    ax.set_xlim(t_lo - 0.03 * (t_eol - t_lo), t_eol)
    ax.set_ylim(0.0, 1.04 * top)
    ax.set_xlabel("time")
    ax.set_ylabel("RUL")
    ax.set_title("alpha-lambda")
    ax.legend(loc="upper right", fontsize="small")
    return ax


def rul_distributions(
    times: ArrayLike,
    dists: Sequence[RULDistribution],
    *,
    t_eol: float | None = None,
    width: float | None = None,
    n_grid: int = 200,
    ax: Axes | None = None,
) -> Axes:
    """One RUL density per prediction time, drawn as a half-violin to the right of its time.

    The density is :meth:`RULDistribution.pdf` (a weighted KDE of the uncensored samples),
    each scaled to its own peak so that narrow late predictions and wide early ones are both
    visible: compare shapes and locations, not heights. A censored fraction is printed above
    its density. ``width`` is the horizontal size of each density's peak in time units
    (default 0.8 of the smallest spacing of ``times``). A distribution with fewer
    than two distinct uncensored samples is drawn as its median only. ``t_eol`` adds the true
    RUL line. Returns the Axes.
    """
    t = _vector(times, "times")
    if len(dists) != t.size:
        raise ValueError(f"dists: expected {t.size} distributions (one per time), got {len(dists)}")
    if width is None:
        gaps = np.diff(np.sort(t))
        gaps = gaps[gaps > 0]
        width = 0.8 * float(gaps.min()) if gaps.size else 1.0
    ax = new_axes() if ax is None else ax
    top = 0.0
    cens_text = False
    curves: list[tuple[float, FloatArray, FloatArray]] = []
    for ti, d in zip(t, dists, strict=True):
        unc = d.samples[~d.censored]
        hi = float(unc.max()) if unc.size else float(d.samples.max())
        top = max(top, hi)
        grid = np.linspace(0.0, 1.1 * hi if hi > 0 else 1.0, n_grid)
        try:
            dens = d.pdf(grid)
        except ValueError:
            dens = np.zeros(0)
        curves.append((float(ti), grid, dens))
    for k, ((ti, grid, dens), d) in enumerate(zip(curves, dists, strict=True)):
        peak = float(dens.max()) if dens.size else 0.0
        if peak > 0:
            poly = ax.fill_betweenx(grid, ti, ti + width * dens / peak, color="C0", alpha=0.4,
                                    lw=0.5, label="RUL density" if k == 0 else None)
            poly.set_gid(f"rul-density-{k}")
        ax.plot([ti], [d.median], "_", color="C3", ms=10, mew=2,
                label="median" if k == 0 else None, gid=f"rul-median-{k}")
        if d.fraction_censored > 0:
            pct = 100 * d.fraction_censored
            ax.annotate(f"{pct:.0f} % cens." if pct >= 1 else "<1 % cens.", (ti, 1.12 * top),
                        fontsize="x-small", ha="left", va="bottom", rotation=90)
            cens_text = True
    if t_eol is not None:
        ax.plot([t.min(), t_eol], [t_eol - t.min(), 0.0], "k--", lw=1, label="true RUL",
                gid="true-rul")
    ax.set_ylim(0.0, 1.45 * top if cens_text else None)
    ax.set_xlabel("time")
    ax.set_ylabel("RUL")
    ax.set_title("RUL distributions")
    ax.legend(loc="upper right", fontsize="small")
    return ax


def _columns(a: ArrayLike | None, T: int, name: str) -> FloatArray | None:
    if a is None:
        return None
    x = np.asarray(a, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2 or x.shape[0] != T:
        raise ValueError(f"{name}: expected shape ({T},) or ({T}, n), got {np.shape(a)}")
    return x


def _estimate_moments(estimate: Any, unit: int) -> tuple[FloatArray, FloatArray] | None:
    """(mean (T, n), std (T, n)) of a filter result (:class:`FilterResult`, unit ``unit``) or
    of a sequence of :class:`Posterior` (one per time); None for plain arrays."""
    if isinstance(estimate, FilterResult):
        m, c = estimate.moments(unit)
    elif (isinstance(estimate, Sequence) and len(estimate) > 0
          and all(isinstance(p, Posterior) for p in estimate)):
        m = np.stack([p.mean for p in estimate])
        c = np.stack([p.cov for p in estimate])
    else:
        return None
    return np.asarray(m), np.sqrt(np.einsum("tii->ti", np.asarray(c)))


def _measurement_panels(output: Any, mean: FloatArray, m: int, measured: Sequence[int] | None,
                        n: int) -> tuple[list[int | None], Any]:
    """For each of the ``m`` measured quantities, the state panel it belongs on (None: a panel
    of its own), and the measurement function ``h(x (N, n)) -> (N, m)`` (or None).

    ``measured`` places them explicitly. Otherwise, with ``output`` (a function or a model with
    ``output``), a measurement goes on state i's panel only when ``h_j(x) = x_i`` exactly for
    every state tried (it measures that state itself); anything else (``1 - x_0``, a sum of
    states, another unit) gets its own panel with the measurement function of the estimate.
    Without either, every measurement has a panel of its own."""
    if measured is not None:
        which = [int(i) for i in measured]
        if len(which) != m or any(not 0 <= i < n for i in which):
            raise ValueError(f"measured: expected {m} state indices in [0, {n - 1}], got "
                             f"{list(measured)}")
        return list(which), None
    if output is None:
        return [None] * m, None
    h = output.output if hasattr(output, "output") else output
    if not callable(h):
        raise TypeError(f"output: expected a measurement function h(x) or a model, got "
                        f"{type(output).__name__}")
    rng = np.random.default_rng(0)
    probe = mean[np.isfinite(mean).all(axis=1)][:3]
    probe = np.concatenate([probe, rng.standard_normal((3, n)) * (1 + np.abs(probe).max(
        initial=1.0))])
    hx = np.asarray(h(probe), dtype=np.float64).reshape(probe.shape[0], -1)
    if hx.shape[1] != m:
        raise ValueError(f"output: the measurement function gives {hx.shape[1]} outputs, the "
                         f"measurements have {m} columns")
    panels: list[int | None] = []
    for j in range(m):
        same = [i for i in range(n) if np.array_equal(hx[:, j], probe[:, i])]
        panels.append(same[0] if same else None)
    return panels, h


def state_estimates(
    t: ArrayLike,
    estimate: ArrayLike | Any,
    *,
    std: ArrayLike | None = None,
    n_sigma: float = 3.0,
    lower: ArrayLike | None = None,
    upper: ArrayLike | None = None,
    truth: ArrayLike | None = None,
    measurements: ArrayLike | None = None,
    output: Any = None,
    measured: Sequence[int] | None = None,
    names: Sequence[str] | None = None,
    unit: int = 0,
    fig: Figure | None = None,
) -> Figure:
    """State estimates over time with a band, the truth and the measurements.

    ``estimate`` (T, n) or (T,), a filter's result (:class:`FilterResult`: the posterior
    means and the square roots of the covariance diagonals, unit ``unit``), or a sequence of T
    :class:`Posterior` (e.g. a prognosis profile's ``estimate``); the last two bring their own
    band ``mean +- n_sigma * std``. Otherwise the band is ``mean +- n_sigma * std`` (``std``
    (T, n)) or ``[lower, upper]`` (e.g. particle-filter quantiles). ``truth`` (T, n) is drawn
    dashed. ``measurements`` (T, m) are drawn where they belong: on the panels of the states
    ``measured`` (indices) when given; else, with ``output`` (the measurement function
    ``h(x (N, n)) -> (N, m)`` or the model), a measurement of a state itself goes on that
    state's panel and any other quantity on a panel of its own, beside ``h`` of the estimate;
    with neither, each measured quantity gets a panel of its own. NaN points are gaps.
    Returns the Figure (``fig.axes``: one per state, then one per measurement panel).
    """
    tt = _vector(t, "t")
    T = tt.size
    moments = _estimate_moments(estimate, unit)
    if moments is not None:
        if std is not None or lower is not None or upper is not None:
            raise ValueError("estimate: a filter result or posteriors bring their own band; "
                             "give no std/lower/upper")
        estimate, std = moments
    m = _columns(estimate, T, "estimate")
    assert m is not None
    n = m.shape[1]
    lo, hi, band = _band(m, std, lower, upper, n_sigma, T)
    tr = _columns(truth, T, "truth")
    ys = _columns(measurements, T, "measurements")
    labels = _check_columns(n, names, lower=lo, upper=hi, truth=tr)
    panels, h = ([], None) if ys is None else _measurement_panels(output, m, ys.shape[1],
                                                                   measured, n)
    own = [j for j, pnl in enumerate(panels) if pnl is None]
    if fig is None:
        from matplotlib.figure import Figure

        fig = Figure(figsize=(6.4, 2.2 * (n + len(own)) + 0.4), layout="constrained")
    axes = fig.subplots(n + len(own), 1, sharex=True, squeeze=False)[:, 0]
    for i, ax in enumerate(axes[:n]):
        if lo is not None and hi is not None:
            ax.fill_between(tt, lo[:, i], hi[:, i], color="C0", alpha=0.25, lw=0, label=band)
        for j in (j for j, pnl in enumerate(panels) if pnl == i):
            _measured(ax, tt, ys, j)
        if tr is not None:
            ax.plot(tt, tr[:, i], "k--", lw=1, label="truth", gid="truth")
        ax.plot(tt, m[:, i], color="C0", lw=1.5, label="estimate", gid="estimate")
        ax.set_ylabel(labels[i])
        ax.legend(loc="best", fontsize="small")
    out_names = list(getattr(output, "output_names", ()) or [])
    for ax, j in zip(axes[n:], own, strict=True):
        _measured(ax, tt, ys, j)
        if h is not None:
            ax.plot(tt, np.asarray(h(m), dtype=np.float64).reshape(T, -1)[:, j], color="C0",
                    lw=1.5, label="h(estimate)", gid="predicted-measurement")
        ax.set_ylabel(out_names[j] if j < len(out_names) else f"y[{j}]")
        ax.legend(loc="best", fontsize="small")
    axes[-1].set_xlabel("time")
    return fig


def _measured(ax: Axes, t: FloatArray, ys: FloatArray | None, j: int) -> None:
    """Measurement column ``j`` as grey dots."""
    assert ys is not None
    ax.plot(t, ys[:, j], ".", color="0.5", ms=3, label="measured", gid="measurements")


def _check_columns(n: int, names: Sequence[str] | None, **arrays: FloatArray | None
                   ) -> list[str]:
    """The panel labels; every array given must have ``n`` columns like the estimate."""
    for nm, arr in arrays.items():
        if arr is not None and arr.shape[1] != n:
            raise ValueError(f"{nm}: expected {n} columns like the estimate, got {arr.shape[1]}")
    labels = list(names) if names is not None else [f"x[{i}]" for i in range(n)]
    if len(labels) != n:
        raise ValueError(f"names: expected {n} names, got {len(labels)}")
    return labels


def _band(m: FloatArray, std: ArrayLike | None, lower: ArrayLike | None,
          upper: ArrayLike | None, n_sigma: float, T: int
          ) -> tuple[FloatArray | None, FloatArray | None, str]:
    """The band of :func:`state_estimates`: ``m +- n_sigma std`` or ``[lower, upper]``."""
    if std is not None and (lower is not None or upper is not None):
        raise ValueError("give either std or lower/upper for the band, not both")
    if (lower is None) != (upper is None):
        raise ValueError("lower and upper: give both or neither")
    sd = _columns(std, T, "std")
    if sd is not None:
        if sd.shape[1] != m.shape[1]:
            raise ValueError(f"std: expected {m.shape[1]} columns like the estimate, got "
                             f"{sd.shape[1]}")
        return m - n_sigma * sd, m + n_sigma * sd, f"+-{n_sigma:g} sigma"
    return _columns(lower, T, "lower"), _columns(upper, T, "upper"), "interval"


def consistency(
    t: ArrayLike,
    values: ArrayLike,
    dof: int,
    *,
    kind: str = "NIS",
    level: float = 0.95,
    ax: Axes | None = None,
) -> Axes:
    """NIS or NEES over time against chi-square acceptance bounds.

    ``values`` (T,) for one unit or (T, B) for B units (the per-step average over units is
    drawn, whose bounds are those of a mean of B chi2_dof variables); NaN entries (skipped
    updates) are ignored. Drawn: the per-step statistic, its two-sided ``level`` interval
    (``chi2_interval(dof, B)``), and the time average over the T' valid steps with its own
    interval ``chi2_interval(dof, T' B)``. Returns the Axes; the numbers are in the legend.
    """
    tt = _vector(t, "t")
    v = np.asarray(values, dtype=np.float64)
    if v.ndim == 1:
        v = v[:, None]
    if v.ndim != 2 or v.shape[0] != tt.size:
        raise ValueError(f"values: expected shape ({tt.size},) or ({tt.size}, B), got "
                         f"{np.shape(values)}")
    if int(dof) != dof or dof < 1:
        raise ValueError(f"dof: expected a positive integer, got {plain(dof)}")
    B = v.shape[1]
    with np.errstate(invalid="ignore"):
        counts = np.sum(np.isfinite(v), axis=1)
        step_mean = np.where(counts > 0, np.nansum(v, axis=1) / np.maximum(counts, 1), np.nan)
    ok = np.isfinite(step_mean)
    if not ok.any():
        raise ValueError("values: no finite entry (every update skipped?)")
    lo, hi = chi2_interval(int(dof), B, level)
    n_total = int(counts.sum())
    avg = float(np.nansum(v) / n_total)
    alo, ahi = chi2_interval(int(dof), n_total, level)
    ax = new_axes() if ax is None else ax
    what = kind if B == 1 else f"{kind}, mean over {B} units"
    ax.plot(tt[ok], step_mean[ok], ".", ms=3, color="C0", label=what, gid="statistic")
    ax.axhline(lo, color="C3", lw=1, label=f"{100 * level:g} % bounds per step", gid="step-lo")
    ax.axhline(hi, color="C3", lw=1, gid="step-hi")
    ax.axhline(avg, color="k", lw=1.5,
               label=f"time average {avg:.3g} (bounds {alo:.3g}-{ahi:.3g})", gid="time-average")
    ax.axhspan(alo, ahi, color="0.5", alpha=0.25, lw=0, gid="average-bounds")
    ax.set_xlabel("time")
    ax.set_ylabel(kind)
    ax.set_title(f"{kind} ({dof} dof)")
    ax.legend(loc="upper right", fontsize="small")
    return ax


def plot_profile(profile: Any, *, t_eol: float | None = None, alpha: float | None = None,
                 lam: float | None = 0.5, level: float | None = None, fig: Figure | None = None
                 ) -> Figure:
    """Two panels for a prognosis profile: the alpha-lambda cone (:func:`alpha_lambda_cone`)
    and the RUL densities over time (:func:`rul_distributions`).

    ``profile`` is a :class:`rulkit.prognosis.profile.PrognosisProfile` or anything with
    ``times`` and ``distributions`` (or ``dists``); ``t_eol``, ``alpha`` and ``level`` default to
    the profile's own (``profile.t_eol`` must be the true end of life: a censored record,
    ``failed=False``, has no cone, only the densities). Returns the Figure.
    """
    times = getattr(profile, "times", None)
    dists = getattr(profile, "distributions", getattr(profile, "dists", None))
    if times is None or dists is None:
        raise TypeError("profile: expected an object with 'times' and 'distributions' "
                        f"attributes, got {type(profile).__name__}")
    failed = bool(getattr(profile, "failed", True))
    if t_eol is None and failed:
        t_eol = getattr(profile, "t_eol", None)
    alpha = float(getattr(profile, "alpha", 0.2)) if alpha is None else alpha
    level = float(getattr(profile, "level", 0.9)) if level is None else level
    dists = list(dists)
    if fig is None:
        from matplotlib.figure import Figure

        fig = Figure(figsize=(11.0, 4.0), layout="constrained")
    if t_eol is None or not math.isfinite(t_eol):
        rul_distributions(times, dists, ax=fig.subplots())
        return fig
    a1, a2 = fig.subplots(1, 2)
    alpha_lambda_cone(times, dists, t_eol, alpha=alpha, lam=lam, level=level, ax=a1)
    rul_distributions(times, dists, t_eol=t_eol, ax=a2)
    return fig
