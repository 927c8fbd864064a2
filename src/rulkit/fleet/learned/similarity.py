"""Similarity (nearest-trajectory) RUL: how long did units that looked like this one last?

docs/fleet-models.md section 6, eq. (12); after Wang et al. (2008) and MATLAB's
``residualSimilarityModel``. No degradation law: each failed training unit j becomes a library
curve, a quadratic f_j(x) = c0 + c1 x + c2 x^2 of its HI on scaled age fitted by least squares,
with its failure age L_j. A unit at age x0 is compared with every curve by the weighted mean
squared residual of its own recent acquisitions (exponentially forgotten, weight rho^j for the
acquisition j back, rho = 1 - 1/W),

    d_j = sum_i w_i (hi_i - f_j(x_i))^2 / sum_i w_i,

which needs only nine forgotten sums of (1, x, ..., x^4, hi, hi x, hi x^2, hi^2) per unit (O(1)
state and update). Neighbour weights are v_j ~ exp(-n_eff d_j / (2 kappa sigma^2)) over the
curves whose unit was still running at x0 (n_eff = sum_i w_i, sigma^2 the library's pooled
residual variance, kappa a temperature); the RUL distribution is the mixture of log-normal
kernels around the neighbours' remaining lives r_j = (L_j - x0) tau with log-sd ``bandwidth``.
When every library unit had failed by x0, the RUL is that of the longest-lived one (a kernel
at a small remaining life).

:func:`fit_similarity` builds the library and chooses W, kappa and the bandwidth by leaving
each library unit out of the library in turn and scoring its replay (the score of
:mod:`rulkit.fleet.learned.scoring`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rulkit.fleet.learned.degradation import time_scale_of
from rulkit.fleet.learned.hi_noise import check_forward
from rulkit.fleet.learned.histories import Histories
from rulkit.fleet.learned.regression import SumsState, forgotten_sums

FloatArray = NDArray[np.float64]
SUM_COLUMNS = ("s_1", "s_x", "s_x2", "s_x3", "s_x4", "s_h", "s_hx", "s_hx2", "s_hh")
WINDOWS = (5.0, 20.0)
TEMPERATURES = (1.0, 10.0, 100.0)
BANDWIDTHS = (0.1, 0.2, 0.35)


class SimilarityState(SumsState):
    """Per unit: forgotten sums ``s (B, 9)`` (:data:`SUM_COLUMNS`), ``t``, ``hi``, ``n``."""

    NAMES = SUM_COLUMNS


@dataclass(frozen=True)
class SimilarityModel:
    """A library of failed units' curves and the matching settings (module docstring):
    ``coefs`` (J x 3, flattened) and ``lives`` (J, scaled age) of the library, ``noise_var``
    sigma^2, ``window`` W, ``temperature`` kappa, ``bandwidth`` (log-sd of the kernels)."""

    coefs: tuple[float, ...]
    lives: tuple[float, ...]
    noise_var: float
    time_scale: float
    window: float = 20.0
    temperature: float = 10.0
    bandwidth: float = 0.2
    time_unit: str = ""
    n_units: int = 0
    n_failed: int = 0
    log_likelihood: float = math.nan
    warnings: tuple[str, ...] = ()
    time_axis: dict[str, Any] | None = None

    state_columns = (*SUM_COLUMNS, "t", "hi", "n")

    @property
    def name(self) -> str:
        """The candidate's name, ``similarity``."""
        return "similarity"

    def empty_state(self, size: int) -> SimilarityState:
        """``size`` units without acquisitions."""
        return SimilarityState(s=np.zeros((size, 9)), t=np.full(size, np.nan),
                               hi=np.full(size, np.nan), n=np.zeros(size, dtype=np.int64))

    def state_from_columns(self, c: dict[str, Any]) -> SimilarityState:
        """A state from its stored columns."""
        f = lambda k: np.asarray(c[k], dtype=np.float64)  # noqa: E731
        return SimilarityState(s=np.column_stack([f(k) for k in SUM_COLUMNS]), t=f("t"),
                               hi=f("hi"), n=np.asarray(c["n"], dtype=np.int64))

    def _rows(self, t: FloatArray, hi: FloatArray) -> FloatArray:
        x = t / self.time_scale
        return np.stack([np.ones_like(x), x, x**2, x**3, x**4, hi, hi * x, hi * x * x, hi * hi],
                        axis=-1)

    def update(self, state: SimilarityState, t: np.ndarray, hi: np.ndarray) -> SimilarityState:
        """One acquisition per unit (NaN = none): S = rho S + row."""
        t = np.asarray(t, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        check_forward(np.where(state.n > 0, state.t, np.nan), t)
        have = np.isfinite(t) & np.isfinite(hi)
        rho = 1.0 - 1.0 / self.window
        rows = self._rows(np.where(have, t, 0.0), np.where(have, hi, 0.0))
        s = np.where(have[:, None], rho * state.s + rows, state.s)
        return SimilarityState(s=s, t=np.where(have, t, state.t),
                               hi=np.where(have, hi, state.hi), n=state.n + have)

    def replay(self, hist: Histories) -> SimilarityState:
        """The state after each row of ``hist``."""
        rows = self._rows(hist.t, hist.hi)
        rho = 1.0 - 1.0 / self.window
        s = np.empty_like(rows)
        for u in range(hist.n_units):
            sl = hist.rows(u)
            s[sl] = forgotten_sums(rows[sl], rho)
        k = np.arange(len(hist.t)) - hist.start[hist.unit]
        return SimilarityState(s=s, t=hist.t.copy(), hi=hist.hi.copy(),
                               n=(k + 1).astype(np.int64))

    def neighbours(self, state: SimilarityState) -> tuple[FloatArray, FloatArray]:
        """(log-weights (B, J), remaining lives (B, J) in the file's time unit), eq. (12)."""
        c = np.asarray(self.coefs).reshape(-1, 3)
        lives = np.asarray(self.lives)
        s = state.s
        n_eff = np.maximum(s[:, 0], 1e-300)
        # sum w (h - f)^2 = s_hh - 2 sum_i c_i s_hx^i + sum_il c_i c_l s_x^(i+l)
        cross = s[:, 5:8] @ c.T
        quad = np.zeros((len(state), c.shape[0]))
        for i in range(3):
            for j in range(3):
                quad += s[:, i + j][:, None] * (c[:, i] * c[:, j])[None, :]
        d = np.maximum(s[:, 8][:, None] - 2.0 * cross + quad, 0.0) / n_eff[:, None]
        x0 = (np.where(state.n > 0, state.t, 0.0) / self.time_scale)[:, None]
        alive = lives[None, :] > x0
        none_alive = ~np.asarray(alive.any(axis=1))
        longest = np.asarray(lives == lives.max())[None, :]
        alive = np.where(none_alive[:, None], longest, alive)
        logw = -0.5 * n_eff[:, None] * d / (self.temperature * self.noise_var)
        logw = np.where(alive, logw, -np.inf)
        logw -= logw.max(axis=1, keepdims=True)
        logw -= np.log(np.exp(logw).sum(axis=1, keepdims=True))
        floor = 0.01 * float(np.median(lives))  # remaining life of an overdue unit's kernel
        remaining = np.maximum(lives[None, :] - x0, floor) * self.time_scale
        return logw, remaining

    def rul_cdf(self, state: SimilarityState, r: FloatArray) -> FloatArray:
        """P(RUL <= r), ``r (B, K)``: the log-normal kernel mixture; 1 once hi >= 1."""
        from scipy.special import ndtr

        logw, rem = self.neighbours(state)
        w = np.exp(logw)
        r = np.asarray(r, dtype=np.float64)
        out = np.empty_like(r)
        with np.errstate(divide="ignore"):
            for k in range(r.shape[1]):
                z = (np.log(np.maximum(r[:, k], 0.0))[:, None] - np.log(rem)) / self.bandwidth
                out[:, k] = (w * ndtr(z)).sum(axis=1)
        return np.where((state.hi >= 1.0)[:, None], 1.0, out)

    def rul_quantiles(self, state: SimilarityState,
                      levels: tuple[float, ...] = (0.5, 0.05, 0.95), iterations: int = 32
                      ) -> tuple[FloatArray, ...]:
        """RUL quantiles per unit (bisection on log r, compiled): > 0 before failure, 0 once
        hi >= 1, NaN before the first acquisition."""
        from rulkit.fleet.learned.filter_kernels import lognormal_mixture_quantiles

        logw, rem = self.neighbours(state)
        out = np.empty((len(levels), len(state)))
        lognormal_mixture_quantiles(np.exp(logw), np.log(rem), self.bandwidth,
                                    np.asarray(levels, dtype=np.float64), iterations, out)
        q = np.where(state.hi >= 1.0, 0.0, out)
        return tuple(np.where(state.n == 0, np.nan, q))

    def to_dict(self) -> dict[str, Any]:
        """The model as JSON-ready numbers."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        for k in ("coefs", "lives", "warnings"):
            d[k] = list(d[k])
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SimilarityModel:
        """Inverse of :meth:`to_dict`."""
        d = {k: v for k, v in d.items() if k != "type"}
        for k in ("coefs", "lives", "warnings"):
            d[k] = tuple(d.get(k, ()))
        return cls(**d)

    def describe(self) -> str:
        """One line with the library and the chosen settings."""
        lives = np.asarray(self.lives) * self.time_scale
        u = self.time_unit or "time units"
        return (f"similarity baseline: a library of {lives.size} failed units' quadratic HI "
                f"curves (lives {lives.min():.4g}-{lives.max():.4g} {u}); matched on about the "
                f"last {self.window:g} acquisitions, temperature {self.temperature:g}, kernel "
                f"log-sd {self.bandwidth:g}; residual sd {math.sqrt(self.noise_var):.3g}")

    def without(self, j: int) -> SimilarityModel:
        """The model with library curve ``j`` removed (leave-one-out scoring)."""
        c = np.asarray(self.coefs).reshape(-1, 3)
        keep = np.arange(c.shape[0]) != j
        return replace(self, coefs=tuple(c[keep].ravel().tolist()),
                       lives=tuple(np.asarray(self.lives)[keep].tolist()))


def library(hist: Histories, tau: float) -> tuple[FloatArray, FloatArray, float]:
    """(coefs (J, 3), lives (J,), pooled residual variance) of the failed units' quadratic
    fits in scaled age."""
    lives = hist.failure_time() / tau
    coefs, lv, rss, dof = [], [], 0.0, 0
    for u in np.flatnonzero(hist.failed):
        sl = hist.rows(int(u))
        x, h = hist.t[sl] / tau, hist.hi[sl]
        deg = min(2, x.size - 1)
        if deg < 1:
            continue
        c = np.polyfit(x, h, deg)[::-1]
        rss += float(np.sum((h - np.polyval(c[::-1], x)) ** 2))
        dof += max(x.size - deg - 1, 0)
        coefs.append(np.pad(c, (0, 3 - c.size)))
        lv.append(lives[u])
    if not coefs:
        raise ValueError("similarity: no failed unit with two or more acquisitions")
    var = rss / dof if dof > 0 and rss > 0 else 1e-4
    return np.asarray(coefs), np.asarray(lv), var


def fit_similarity(hist: Histories, *, window: float | None = None,
                   temperature: float | None = None, bandwidth: float | None = None
                   ) -> SimilarityModel:
    """Build the library and choose the settings by leave-one-library-unit-out scores."""
    from rulkit.fleet.learned.scoring import replay_scores

    tau = time_scale_of(hist)
    coefs, lives, var = library(hist, tau)
    base = SimilarityModel(coefs=tuple(coefs.ravel().tolist()), lives=tuple(lives.tolist()),
                           noise_var=var, time_scale=tau, n_units=hist.n_units,
                           n_failed=int(hist.failed.sum()))
    grid = [(w, k, b) for w in ([window] if window else WINDOWS)
            for k in ([temperature] if temperature else TEMPERATURES)
            for b in ([bandwidth] if bandwidth else BANDWIDTHS)]
    if len(grid) == 1 or lives.size < 3:
        w, k, b = grid[0]
        return replace(base, window=w, temperature=k, bandwidth=b)
    failed = [int(u) for u in np.flatnonzero(hist.failed) if hist.rows(int(u)).stop
              - hist.rows(int(u)).start >= 2]

    def loo_score(model: SimilarityModel) -> float:
        tot = [replay_scores(model.without(j), hist.select([u])).score
               for j, u in enumerate(failed[:lives.size])]
        fin = [v for v in tot if math.isfinite(v)]
        return float(np.mean(fin)) if fin else math.inf

    models = [replace(base, window=w, temperature=k, bandwidth=b) for w, k, b in grid]
    return min(models, key=loo_score)


__all__ = ["BANDWIDTHS", "SUM_COLUMNS", "TEMPERATURES", "WINDOWS", "SimilarityModel",
           "SimilarityState", "fit_similarity", "library"]
