"""Scoring RUL predictions against the truth: what selection and evaluation both measure.

docs/fleet-models.md section 5 and eq. (13). A prediction is a model's RUL distribution at one
acquisition of a failed unit, before its failure; the truth is the unit's failure time (the
interpolated time of its measured hi = 1) minus the acquisition's time. :func:`predictions`
replays a model over held-out units and returns, per acquisition, the median, the 90 %
interval, and the CRPS; :func:`score` summarises them over the last half of each unit's life
(t >= t_first + (T - t_first) / 2):

* median relative error |median - truth| / truth,
* 90 % interval coverage,
* the selection score: the mean of CRPS / (T - t_first), the continuous ranked probability score
  in units of the unit's observed life (a proper score of the whole distribution, so it rewards
  a sharp and calibrated RUL alike; divided by the life so that every unit weighs the same).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from rulkit.fleet.learned.histories import Histories

FloatArray = NDArray[np.float64]
LEVELS = (0.5, 0.05, 0.95)


def truth_rul(h: Histories) -> FloatArray:
    """True RUL per row (NaN for censored units and at/after the failure time)."""
    tf = h.failure_time()[h.unit]
    r = tf - h.t
    return np.where(r > 0, r, np.nan)


def crps_grid(model: Any, state: Any, y: FloatArray, cap: float, n_grid: int = 400
              ) -> FloatArray:
    """CRPS of ``model``'s RUL distribution at the truth ``y (B,)``: the integral over
    [0, cap] of (F(r) - 1{r >= y})^2, split at y (int_0^y F^2 + int_y^cap (1 - F)^2, each by
    the trapezoidal rule on ``n_grid / 2`` points of its own interval, so the step of the
    indicator costs no accuracy); the never-failing mass stays in F's deficit up to ``cap``."""
    y = np.minimum(np.asarray(y, dtype=np.float64), cap)
    u = np.linspace(0.0, 1.0, max(n_grid // 2, 2))
    below = y[:, None] * u[None, :]
    above = y[:, None] + (cap - y)[:, None] * u[None, :]
    f_lo = model.rul_cdf(state, below)
    f_hi = model.rul_cdf(state, above)
    a = np.trapezoid(f_lo**2, below, axis=1)
    b = np.trapezoid((1.0 - f_hi) ** 2, above, axis=1)
    return np.asarray(a + b)


def predictions(model: Any, test: Histories, cap: float, n_grid: int = 400) -> pd.DataFrame:
    """Per row of ``test``: t, the truth, median / low / high (90 %), CRPS, life and whether
    the row is in the last half of its unit's life (NaN truth: censored or after failure)."""
    st = model.replay(test)
    med, lo, hi = model.rul_quantiles(st, LEVELS)
    truth = truth_rul(test)
    ok = np.isfinite(truth)
    c = np.full(truth.shape, np.nan)
    if ok.any():
        c[ok] = crps_grid(model, st.take(ok), truth[ok], cap, n_grid)
    t_fail = test.failure_time()[test.unit]
    t_first = test.t[test.start[:-1]][test.unit]
    return pd.DataFrame({"t": test.t, "true_rul": truth, "median": med, "low": lo, "high": hi,
                         "crps": c, "t_fail": t_fail, "t_first": t_first})


@dataclass(frozen=True)
class Scores:
    """Summary of predictions over the last half of life (module docstring)."""

    median_rel_err: float
    coverage_90: float
    score: float
    n_late: int


def score(pred: pd.DataFrame) -> Scores:
    """The module docstring's summary of a :func:`predictions` frame (NaN when no row)."""
    p = pred[np.isfinite(pred["true_rul"].to_numpy())]
    late = (p["t"] >= p["t_first"] + 0.5 * (p["t_fail"] - p["t_first"])).to_numpy()
    p = p[late]
    if len(p) == 0:
        return Scores(math.nan, math.nan, math.nan, 0)
    tr = p["true_rul"].to_numpy()
    rel = np.abs(p["median"].to_numpy() - tr) / tr
    cov = (p["low"].to_numpy() <= tr) & (tr <= p["high"].to_numpy())
    life = np.maximum((p["t_fail"] - p["t_first"]).to_numpy(), 1e-300)
    return Scores(median_rel_err=float(np.median(rel)), coverage_90=float(cov.mean()),
                  score=float(np.mean(p["crps"].to_numpy() / life)), n_late=int(late.sum()))


def crps_cap(h: Histories) -> float:
    """The CRPS integration limit: 10 x the longest failure time (or the longest age)."""
    tf = h.failure_time()
    longest = float(np.nanmax(tf)) if np.isfinite(tf).any() else float(h.t.max())
    return 10.0 * max(longest, 1e-12)


def replay_scores(model: Any, hist: Histories, n_grid: int = 200) -> Scores:
    """:func:`score` of ``model`` replayed over the failed units of ``hist`` (in-sample: for
    choosing a baseline's settings on its training units)."""
    failed = hist.select(list(np.flatnonzero(hist.failed)))
    return score(predictions(model, failed, crps_cap(hist), n_grid))


__all__ = ["LEVELS", "Scores", "crps_cap", "crps_grid", "predictions", "replay_scores",
           "score", "truth_rul"]
