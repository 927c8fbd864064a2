"""Choosing among the candidates: a fast held-out score, a table, and the choice.

docs/fleet-models.md section 6, eq. (13). Each candidate is fitted on all units (its
log-likelihood of the HI is reported where it has one); then the failed units are dealt into
``folds`` groups (by failure time, round robin, so each fold spans short and long lives; at
most one group per failed unit) and, fold by fold, the candidate is refitted without the group's
units (censored units always train), warm-started from the all-unit fit with its shape kept,
and replayed over the held-out units (:func:`rulkit.fleet.learned.scoring.predictions`). The
choice is the candidate with the lowest held-out score (mean CRPS in units of life over the
last half of life); the table also shows the held-out median relative error and 90 % interval
coverage. A candidate that cannot be fitted (e.g. the similarity library needs a failed unit)
stays in the table with its error and is not chosen.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from rulkit.fleet.learned.candidates import AUTO_CANDIDATES, FleetModel, fit_candidate
from rulkit.fleet.learned.histories import Histories
from rulkit.fleet.learned.scoring import Scores, crps_cap, predictions, score

DEFAULT_FOLDS = 5


@dataclass
class CandidateResult:
    """One candidate's fit on all units and its held-out scores (or why it failed)."""

    name: str
    model: FleetModel | None
    scores: Scores | None
    seconds: float
    error: str = ""

    @property
    def selection_score(self) -> float:
        """The held-out score (+inf when not scored)."""
        return self.scores.score if self.scores is not None else math.inf


@dataclass
class Selection:
    """The candidates' results, the chosen name and its model."""

    results: list[CandidateResult]
    chosen: str
    folds: int
    predictions: dict[str, pd.DataFrame] = field(default_factory=dict)

    @property
    def model(self) -> FleetModel:
        """The chosen candidate's fit on all units."""
        res = next(r for r in self.results if r.name == self.chosen)
        assert res.model is not None
        return res.model

    def table(self) -> pd.DataFrame:
        """One row per candidate: log-likelihood, held-out error, coverage, score, choice."""
        rows = []
        for r in self.results:
            s = r.scores
            rows.append({
                "candidate": r.name,
                "log_likelihood": getattr(r.model, "log_likelihood", math.nan),
                "heldout_median_rel_err": s.median_rel_err if s else math.nan,
                "heldout_coverage_90": s.coverage_90 if s else math.nan,
                "heldout_score": s.score if s else math.nan,
                "seconds": r.seconds,
                "chosen": "<- chosen" if r.name == self.chosen else (r.error or ""),
            })
        return pd.DataFrame(rows)


def fold_groups(hist: Histories, folds: int) -> list[list[int]]:
    """Failed units dealt into ``folds`` groups in order of failure time (leave one failed
    unit out when ``folds`` >= their number or ``folds`` <= 0)."""
    failed = np.flatnonzero(hist.failed)
    order = failed[np.argsort(hist.failure_time()[failed], kind="stable")]
    if folds <= 0 or folds >= order.size:
        return [[int(u)] for u in order]
    return [[int(u) for u in order[k::folds]] for k in range(folds)]


def heldout_predictions(name: str, hist: Histories, full: FleetModel,
                        groups: list[list[int]]) -> pd.DataFrame:
    """The candidate refitted without each group (warm start, shape kept) and replayed over
    the group's units; one row per acquisition of a held-out unit."""
    cap = crps_cap(hist)
    parts = []
    for g in groups:
        keep = sorted(set(range(hist.n_units)) - set(g))
        model = fit_candidate(name, hist.select(keep), start=full, fixed_shape=True)
        parts.append(predictions(model, hist.select(g), cap).assign(
            unit=np.repeat(hist.names[g], np.diff(hist.select(g).start))))
    return pd.concat(parts, ignore_index=True)


def select_model(hist: Histories, names: tuple[str, ...] = AUTO_CANDIDATES,
                 folds: int = DEFAULT_FOLDS,
                 progress: Callable[[CandidateResult], None] | None = None) -> Selection:
    """Fit every candidate, score it held out, choose the lowest score (module docstring)."""
    groups = fold_groups(hist, folds)
    fitted: dict[str, FleetModel] = {}
    results, preds = [], {}
    for name in names:
        t0 = time.perf_counter()
        try:
            full = fit_candidate(name, hist, fitted=fitted)
            fitted[name] = full
            pred = heldout_predictions(name, hist, full, groups)
            res = CandidateResult(name, full, score(pred), time.perf_counter() - t0)
            preds[name] = pred
        except (ValueError, np.linalg.LinAlgError) as err:
            res = CandidateResult(name, fitted.get(name), None, time.perf_counter() - t0,
                                  error=f"not fitted: {err}")
        results.append(res)
        if progress is not None:
            progress(res)
    scored = [r for r in results if r.model is not None and r.scores is not None
              and math.isfinite(r.selection_score)]
    if not scored:
        errors = "; ".join(f"{r.name}: {r.error}" for r in results)
        raise ValueError(f"no candidate could be fitted and scored ({errors})")
    chosen = min(scored, key=lambda r: r.selection_score).name
    return Selection(results=results, chosen=chosen, folds=len(groups), predictions=preds)


__all__ = ["DEFAULT_FOLDS", "CandidateResult", "Selection", "fold_groups",
           "heldout_predictions", "select_model"]
