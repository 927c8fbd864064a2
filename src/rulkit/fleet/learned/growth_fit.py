"""Maximum-likelihood fits of the growth laws of eq. (7)-(9), with the fit's own diagnostics.

docs/fleet-models.md sections 4 and 6. :func:`minimize_bounded` runs L-BFGS-B on a negative
log-likelihood whose value and gradient come from one compiled call (central differences inside
numba: one Python round trip per gradient instead of one per parameter) and reports what a user
must hear about: the optimiser stopping without converging, and parameters at a bound.
:func:`fit_growth` learns the prior (mean, covariance), the noise variances, the random walk and,
with an onset grid, the onset prior, for one Box-Cox shape; :func:`profile_shape` chooses the
shape (the Paris exponent m = 2 (1 - lam)) by profile likelihood, coarse (m = 0, 1, ..., 8) then
fine (steps of 0.25 around the best), or locally from a previous fit's shape (a warm start,
used by the held-out folds).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from rulkit.fleet.learned.growth_filter import THETA, boxcox
from rulkit.fleet.learned.histories import Histories

FloatArray = NDArray[np.float64]
M_MAX = 8.0
"""Largest Paris exponent of the shape profile (m in [0, M_MAX])."""


@dataclass(frozen=True)
class OptimResult:
    """An optimiser's outcome: the parameters, the minimum, and what went wrong (if anything):
    ``stalled`` holds the optimiser's message when it stopped without converging, ``at_bound``
    the parameters within 0.1 % of the width of their bounds, as ``name:low`` or
    ``name:high``."""

    x: FloatArray
    fun: float
    stalled: str = ""
    at_bound: tuple[str, ...] = ()


def minimize_bounded(fun_grad: Callable[[FloatArray], tuple[float, FloatArray]], x0: FloatArray,
                     bounds: list[tuple[float, float]], names: list[str],
                     maxiter: int = 400, tol_nats: float = 1e-5) -> OptimResult:
    """L-BFGS-B from ``x0`` (clipped into ``bounds``) on ``fun_grad(x) -> (f, gradient)``.

    Stops when an iteration gains less than about ``tol_nats`` of log-likelihood (the relative
    tolerance is set from the value at ``x0``; differences that small change no RUL). BLAS is
    held to one thread (the tiny dense algebra of L-BFGS-B is far slower threaded on a shared
    machine)."""
    from scipy.optimize import minimize
    from threadpoolctl import threadpool_limits

    lo = np.array([b[0] for b in bounds])
    hi = np.array([b[1] for b in bounds])
    x0 = np.clip(np.asarray(x0, dtype=np.float64), lo, hi)
    f0 = abs(fun_grad(x0)[0])
    ftol = max(tol_nats / max(f0 if f0 < 1e299 else 1.0, 1.0), 2.2e-9)
    with threadpool_limits(limits=1, user_api="blas"):
        res = minimize(fun_grad, x0, jac=True, method="L-BFGS-B",
                       bounds=[(a if np.isfinite(a) else None, b if np.isfinite(b) else None)
                               for a, b in bounds],
                       options={"maxiter": maxiter, "maxfun": 5 * maxiter, "ftol": ftol})
    width = hi - lo
    low = np.isfinite(width) & (res.x - lo <= 1e-3 * width)
    high = np.isfinite(width) & (hi - res.x <= 1e-3 * width)
    stalled = "" if res.success else str(res.message)
    at = [f"{n}:low" for n, b in zip(names, low, strict=True) if b]
    at += [f"{n}:high" for n, b in zip(names, high, strict=True) if b]
    return OptimResult(x=np.asarray(res.x, dtype=np.float64), fun=float(res.fun),
                       stalled=stalled, at_bound=tuple(at))


@dataclass(frozen=True)
class FitDiagnostics:
    """What a fit's optimiser reported (read by :mod:`rulkit.fleet.learned.checks`): its
    :class:`OptimResult`, whether the shape sits at an end of its range, and, for the onset
    model, the onset grid's quadrature error (nats) when its refinement stopped at the largest
    grid before converging (0: converged)."""

    optim: OptimResult
    shape_at_edge: bool = False
    grid_error: float = 0.0


@dataclass(frozen=True)
class GrowthSpec:
    """Which parameters a growth model learns: ``noise`` "additive" (HI scale), "multiplicative"
    (log scale) or "mixed" (both); ``walk`` the Brownian random walk (False: independent
    errors only); ``onset_grid`` the onset values in scaled age (one value 0: no onset)."""

    noise: str = "additive"
    walk: bool = True
    onset_grid: tuple[float, ...] = (0.0,)

    def __post_init__(self) -> None:
        if self.noise not in ("additive", "multiplicative", "mixed"):
            raise ValueError(f"noise: expected additive, multiplicative or mixed, got "
                             f"{self.noise!r}")

    def free(self) -> list[int]:
        """Indices into :data:`THETA` that are learned."""
        idx = [0, 1, 2, 3, 4]
        if self.noise in ("multiplicative", "mixed"):
            idx.append(5)
        if self.noise in ("additive", "mixed"):
            idx.append(6)
        if self.walk:
            idx.append(7)
        if len(self.onset_grid) > 1:
            idx += [8, 9]
        return idx


@dataclass(frozen=True)
class GrowthFit:
    """A fitted shape: Box-Cox ``lam``, the full parameter vector ``theta`` (fixed zeros at
    -inf), the log-likelihood of the HI, and the optimiser's diagnostics."""

    lam: float
    theta: FloatArray
    log_likelihood: float
    optim: OptimResult = field(default_factory=lambda: OptimResult(np.zeros(0), math.nan))


def _stat_rows(x: FloatArray, z: FloatArray) -> FloatArray:
    return np.stack([np.ones_like(x), x, x * x, z, x * z, z * z], axis=-1)


def two_stage_start(x: FloatArray, z: FloatArray, hist: Histories) -> FloatArray:
    """Starting point: per-unit least squares (units with >= 2 points), their mean and cov
    (the two-stage estimate of docs/fleet-models.md section 4)."""
    s = np.zeros((hist.n_units, 6))
    np.add.at(s, hist.unit, _stat_rows(x, z))
    n, sx, sxx, sz, sxz, szz = s.T
    det = n * sxx - sx * sx
    ok = (n >= 2) & (det > 1e-12 * np.maximum(n * sxx, 1e-300))
    if ok.sum() >= 1:
        b = (n[ok] * sxz[ok] - sx[ok] * sz[ok]) / det[ok]
        a = (sz[ok] - b * sx[ok]) / n[ok]
        res = szz[ok] - a * sz[ok] - b * sxz[ok]
        dof = np.maximum(n[ok] - 2, 0).sum()
        v = max(float(res.sum() / dof) if dof > 0 else 1e-4, 1e-10)
        ma, mb = float(a.mean()), float(b.mean())
        saa = max(float(a.var()), 1e-4 * v)
        sbb = max(float(b.var()), 1e-4 * v)
    else:
        ma, mb, saa, sbb, v = float(z.mean()), 0.0, float(z.var()) + 1e-6, 1.0, 1e-2
    return np.array([ma, mb, 0.5 * math.log(saa), 0.0, 0.5 * math.log(sbb), math.log(v),
                     math.log(v) - 4.0])


def _floor_hi(hi: FloatArray) -> float:
    """HI floor for the starting values' transform (a lone 0 must not dominate them)."""
    pos = hi[hi > 0]
    return max(0.5 * float(np.quantile(pos, 0.05)), 1e-4) if pos.size else 1e-4


def _start(hist: Histories, x: FloatArray, lam: float, setup: GrowthSpec) -> FloatArray:
    """Starting values: the two-stage estimate on the transformed HI (growth scale)."""
    z = boxcox(np.maximum(hist.hi, _floor_hi(hist.hi)), lam)
    t7 = two_stage_start(x, z, hist)  # m_a, m_b, log l11, l21, log l22, log r, log q
    th = np.full(len(THETA), -np.inf)
    th[:5] = t7[:5]
    r = math.exp(t7[5])  # residual variance on the growth scale
    h = np.clip(hist.hi, _floor_hi(hist.hi), None)
    to_hi = float(np.median(h ** (2.0 * (1.0 - lam))))  # (dhi/dz)^2 at the data
    to_log = float(np.median(h ** (-2.0 * lam)))  # (dlog hi/dz)^2 at the data
    half = 0.7 if setup.noise == "mixed" else 0.0  # each term half the residual at the start
    if setup.noise in ("multiplicative", "mixed"):
        th[5] = math.log(max(r * to_log, 1e-12)) - half
    if setup.noise in ("additive", "mixed"):
        th[6] = math.log(max(r * to_hi, 1e-12)) - half
    if setup.walk:
        th[7] = math.log(r) - 4.0
    grid = np.asarray(setup.onset_grid)
    th[8] = float(np.median(grid)) if grid.size > 1 else 0.0
    th[9] = math.log(max(float(grid.max() - grid.min()) / 2.0, 1e-6)) if grid.size > 1 else 0.0
    return th


def _bounds(hist: Histories, lam: float, setup: GrowthSpec) -> list[tuple[float, float]]:
    z = boxcox(np.maximum(hist.hi, _floor_hi(hist.hi)), lam)
    lz = math.log(max(float(np.std(z)), 1e-12))
    lh = math.log(max(float(np.std(hist.hi)), 1e-12))
    ll = math.log(max(float(np.std(np.log(np.maximum(hist.hi, _floor_hi(hist.hi))))), 1e-12))
    grid = np.asarray(setup.onset_grid)
    span = float(grid.max() - grid.min()) if grid.size > 1 else 1.0
    step = span / max(grid.size - 1, 1)
    inf = math.inf
    return [(-inf, inf), (-inf, inf), (lz - 9.2, lz + 9.2), (-inf, inf), (lz - 9.2, lz + 9.2),
            (2 * ll - 18.4, 2 * ll + 2.0), (2 * lh - 18.4, 2 * lh + 2.0),
            (2 * lz - 18.4, 2 * lz + 9.2),
            (float(grid.min()) - span, float(grid.max()) + span),
            (math.log(max(step / 2.0, 1e-9)), math.log(max(2.0 * span, 1e-9)))]


def fit_growth(hist: Histories, x: FloatArray, lam: float, setup: GrowthSpec,
               start: FloatArray | None = None) -> GrowthFit:
    """Maximise the likelihood of eq. (7)-(9) at Box-Cox shape ``lam`` (scaled age ``x``)."""
    grid = np.asarray(setup.onset_grid, dtype=np.float64)
    free = np.asarray(setup.free(), dtype=np.int64)
    th0 = _start(hist, x, lam, setup) if start is None else np.array(start, dtype=np.float64)
    for j in range(len(THETA)):  # a warm start from another setup: its fixed zeros stay fixed
        if j not in free and j < 8:
            th0[j] = -np.inf if j >= 5 else th0[j]
    if 5 in free and not np.isfinite(th0[5]):
        th0[5] = th0[6] - 2.0 if np.isfinite(th0[6]) else 0.0
    if 6 in free and not np.isfinite(th0[6]):
        th0[6] = th0[5] - 2.0 if np.isfinite(th0[5]) else 0.0
    if 7 in free and not np.isfinite(th0[7]):
        th0[7] = (th0[5] if np.isfinite(th0[5]) else 0.0) - 4.0
    bounds = _bounds(hist, lam, setup)
    y, start_idx = hist.hi, hist.start.astype(np.int64)
    from rulkit.fleet.learned.filter_kernels import growth_nll_grad as nll_grad

    steps = np.full(free.size, 1e-5)

    def fg(v: FloatArray) -> tuple[float, FloatArray]:
        th = th0.copy()
        th[free] = v
        f, g = nll_grad(th, free, steps, x, y, start_idx, lam, grid)
        return float(f), np.asarray(g)

    res = minimize_bounded(fg, th0[free], [bounds[j] for j in free],
                           [THETA[j] for j in free])
    th = th0.copy()
    th[free] = res.x
    return GrowthFit(lam=lam, theta=th, log_likelihood=-res.fun, optim=res)


def lam_of(m: float) -> float:
    """Box-Cox shape of a Paris exponent: lam = 1 - m/2."""
    return 1.0 - m / 2.0


def profile_shape(fit_at: Callable[[float], GrowthFit], start_m: float | None = None,
                  m_max: float = M_MAX) -> tuple[GrowthFit, bool]:
    """The best fit over the Paris exponent m in [0, m_max] (profile likelihood).

    Without ``start_m``: m = 0, 1, ..., m_max (stopping once two steps in a row lost
    likelihood and the last is 20 nats below the best: the profile is taken as unimodal), then
    m +- 0.5, +- 0.25 around the best. With
    ``start_m``: a hill climb in steps of 0.25 from it (held-out folds, warm started). Returns
    the best fit and whether m sits at an end of its range."""
    tried: dict[float, GrowthFit] = {}

    def at(m: float) -> GrowthFit:
        m = round(min(max(m, 0.0), m_max) * 4.0) / 4.0
        if m not in tried:
            tried[m] = fit_at(lam_of(m))
        return tried[m]

    def best_m() -> float:
        return max(tried, key=lambda k: tried[k].log_likelihood)

    if start_m is None:
        falling = 0
        for m in np.arange(0.0, m_max + 1e-9, 1.0):
            prev = tried[m - 1.0].log_likelihood if m >= 1.0 else -math.inf
            ll = at(float(m)).log_likelihood
            falling = falling + 1 if ll < prev else 0
            # past the peak by two steps and far below it: the rest of the range is worse
            if falling >= 2 and ll < tried[best_m()].log_likelihood - 20.0:
                break
        m0 = best_m()
        for d in (-0.5, 0.5, -0.25, 0.25):
            at(m0 + d)
    else:
        at(start_m)
        for _ in range(int(4 * m_max)):
            m0 = best_m()
            at(m0 - 0.25)
            at(m0 + 0.25)
            if best_m() == m0:
                break
    m_best = best_m()
    return tried[m_best], m_best in (0.0, m_max)


__all__ = ["M_MAX", "FitDiagnostics", "GrowthFit", "GrowthSpec", "OptimResult", "fit_growth",
           "lam_of", "minimize_bounded", "profile_shape", "two_stage_start"]
