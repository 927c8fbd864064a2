"""Choosing among the candidates: a fast held-out score, a table, and the choice.

docs/fleet-models.md section 6, eq. (13). Each candidate is fitted on all units (its
log-likelihood of the HI is reported where it has one); then the failed units are dealt into
``folds`` groups (by failure time, round robin, so each fold spans short and long lives; at
most one group per failed unit) and, fold by fold, the candidate is refitted without the group's
units (censored units always train), warm-started from the all-unit fit with its shape kept,
and scored on the held-out units: the log-likelihood of their HI under the fold's fit (the
growth models; per acquisition in the table) and their RUL predictions
(:func:`rulkit.fleet.learned.scoring.predictions`: the median relative error and 90 % interval
coverage over the last half of life, and the score, the mean CRPS in units of life).

The choice (:func:`choose`): the held-out RUL score decides, as long as it can. The candidates
whose score is not clearly worse than the best one's (their per-unit score differences with
the best, paired over the same held-out units, average less than two standard errors) are
statistically tied on RUL; among them, the growth model with the best held-out likelihood is
chosen (it scores every acquisition of every held-out unit, which tells noise scales, shapes
and onsets apart when a few failed units make the RUL scores noisy), and the best-scoring one
when none of them has a likelihood (the similarity and regression baselines). A candidate
that cannot be fitted (e.g. the similarity library needs a failed unit) stays in the table with
its error and is not chosen.
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
    heldout_loglik: float = math.nan
    heldout_acquisitions: int = 0

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
    reason: str = ""
    """Why :attr:`chosen` was chosen (:func:`choose`), as ``rulkit fit`` prints it."""

    @property
    def model(self) -> FleetModel:
        """The chosen candidate's fit on all units."""
        res = next(r for r in self.results if r.name == self.chosen)
        assert res.model is not None
        return res.model

    def table(self) -> pd.DataFrame:
        """One row per candidate: log-likelihood (all units; held-out per acquisition),
        held-out error, coverage, score, choice."""
        rows = []
        for r in self.results:
            s = r.scores
            rows.append({
                "candidate": r.name,
                "log_likelihood": getattr(r.model, "log_likelihood", math.nan),
                "heldout_loglik_per_acq": r.heldout_loglik / r.heldout_acquisitions
                if r.heldout_acquisitions else math.nan,
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
                        groups: list[list[int]]) -> tuple[pd.DataFrame, float]:
    """The candidate refitted without each group (warm start, shape kept) and replayed over
    the group's units: one row per acquisition of a held-out unit, and the held-out units'
    log-likelihood (NaN for a candidate without one)."""
    cap = crps_cap(hist)
    parts, loglik = [], 0.0
    for g in groups:
        keep = sorted(set(range(hist.n_units)) - set(g))
        model = fit_candidate(name, hist.select(keep), start=full, fixed_shape=True)
        test = hist.select(g)
        parts.append(predictions(model, test, cap).assign(
            unit=np.repeat(hist.names[g], np.diff(test.start))))
        of = getattr(model, "log_likelihood_of", None)
        loglik += of(test) if of is not None else math.nan
    return pd.concat(parts, ignore_index=True), loglik


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
            pred, ll = heldout_predictions(name, hist, full, groups)
            n_acq = int(sum(hist.start[u + 1] - hist.start[u] for g in groups for u in g))
            res = CandidateResult(name, full, score(pred), time.perf_counter() - t0,
                                  heldout_loglik=ll, heldout_acquisitions=n_acq)
            preds[name] = pred
        except (ValueError, np.linalg.LinAlgError) as err:
            res = CandidateResult(name, fitted.get(name), None, time.perf_counter() - t0,
                                  error=f"not fitted: {err}")
        results.append(res)
        if progress is not None:
            progress(res)
    chosen, reason = choose(results, preds)
    return Selection(results=results, chosen=chosen, folds=len(groups), predictions=preds,
                     reason=reason)


def unit_scores(pred: pd.DataFrame) -> pd.Series:
    """Per held-out unit: the mean of CRPS / life over its last half of life."""
    p = pred[np.isfinite(pred["true_rul"].to_numpy())]
    p = p[p["t"] >= p["t_first"] + 0.5 * (p["t_fail"] - p["t_first"])]
    life = np.maximum(p["t_fail"] - p["t_first"], 1e-300)
    return (p["crps"] / life).groupby(p["unit"]).mean()


def choose(results: list[CandidateResult], preds: dict[str, pd.DataFrame]
           ) -> tuple[str, str]:
    """The choice of the module docstring: RUL score, ties broken by held-out likelihood;
    (the chosen name, what decided it)."""
    scored = [r for r in results if r.model is not None and r.scores is not None
              and math.isfinite(r.selection_score) and r.name in preds]
    if not scored:
        errors = "; ".join(f"{r.name}: {r.error}" for r in results)
        raise ValueError(f"no candidate could be fitted and scored ({errors})")
    best = min(scored, key=lambda r: r.selection_score)
    ref = unit_scores(preds[best.name])
    tied = []
    for r in scored:
        d = (unit_scores(preds[r.name]) - ref).dropna()
        se = float(d.std(ddof=1) / math.sqrt(d.size)) if d.size > 1 else math.inf
        if r is best or float(d.mean()) < 2.0 * se:
            tied.append(r)
    growth = [r for r in tied if math.isfinite(r.heldout_loglik)]
    if len(tied) == 1:
        return best.name, "the lowest held-out score; no other within two standard errors of it"
    near = f"the {len(tied)} candidates within two standard errors of the lowest held-out score"
    if len(growth) == 1:
        return growth[0].name, f"the one growth model among {near}"
    if growth:
        return (max(growth, key=lambda r: r.heldout_loglik).name,
                f"the best held-out likelihood of the {len(growth)} growth models among {near}")
    return best.name, (f"the lowest held-out score ({len(tied)} candidates within two "
                       "standard errors of it, none with a likelihood)")


__all__ = ["DEFAULT_FOLDS", "CandidateResult", "Selection", "choose", "fold_groups",
           "heldout_predictions", "select_model", "unit_scores"]
