"""Leave-one-unit-out evaluation of fleet RUL models against naive baselines.

docs/fleet-models.md section 5. For every failed unit: learn the model from the *other* units
(failed and censored), replay the unit's acquisitions one by one, and at each acquisition before
its true failure time compare the RUL with the truth (true failure time - t). The model is a
candidate of :mod:`rulkit.fleet.learned.candidates` by name, ``auto`` (the candidate ``rulkit
fit`` selects on all units, :func:`rulkit.fleet.learned.selection.select_model`, then evaluated
like any other), ``all`` (every candidate ``fit`` compares, one row each) or ``tracker`` (the
safe tracker chain). Each fold refits every continuous parameter (prior, noises, random walk,
onset prior) without the held-out unit, starting from the fit on all units; the discrete
settings (the Paris exponent on its 0.25 grid, the onset grid, the baselines' windows and
widths) keep their all-unit choice, as the candidate choice of ``auto`` does. Beside the
models, two naive point baselines on the raw HI:

* ``origin``: linear through (0, 0) and the current acquisition, RUL = t (1 - hi) / hi;
* ``last2``: linear through the last two acquisitions (+inf when the slope is <= 0 or at the
  first acquisition).

Metrics (:func:`summarise`): median relative error |RUL - truth| / truth over the last half of
each unit's life (t >= t_first + (T - t_first)/2); alpha-lambda pass rate (alpha = 0.2 and 0.3,
lambda = 0.5, t_P = the unit's first acquisition; the prediction is the median); prognostic
horizon (relative alpha = 0.2 cone, must stay inside; as a fraction of the unit's life,
0 when never); 90 % interval coverage over all predictions and over the last half of life
(models only); CRPS over all
predictions (models: the integral of the squared CDF difference,
:func:`rulkit.fleet.learned.scoring.crps_grid`; baselines: absolute error, the CRPS of a point
forecast), in the file's time unit, with +inf capped at 10 x the longest failure time.

Folds run in-process, or on Dask (``scheduler="local"`` starts a LocalCluster, any other string
is a scheduler address); ``folds=K`` groups the units into K folds for large fleets instead of
leaving one unit out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from rulkit.fleet.learned.histories import Histories
from rulkit.fleet.learned.scoring import crps_cap, truth_rul

BASELINES = ("origin", "last2")
ALPHAS = (0.2, 0.3)
LAMBDA = 0.5


def baseline_origin(t: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """RUL of the line through the origin and (t, hi): t (1 - hi)/hi; inf if hi <= 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(hi > 0, t * (1.0 - hi) / hi, np.inf)
    return np.where(hi >= 1.0, 0.0, np.maximum(r, 0.0))


def baseline_last2(t: np.ndarray, hi: np.ndarray, first: np.ndarray) -> np.ndarray:
    """RUL of the line through the last two acquisitions of a unit (rows in time order;
    ``first`` marks each unit's first row, where the RUL is +inf)."""
    dt = np.diff(t, prepend=np.nan)
    dh = np.diff(hi, prepend=np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = dh / dt
        r = np.where(slope > 0, (1.0 - hi) / slope, np.inf)
    r = np.where(first, np.inf, r)
    return np.where(hi >= 1.0, 0.0, np.maximum(r, 0.0))


def _predict_model(train: Histories, test: Histories, kind: str, cap: float,
                   start: Any = None) -> pd.DataFrame:
    from rulkit.fleet.learned.candidates import fit_candidate
    from rulkit.fleet.learned.scoring import predictions as model_predictions

    model = fit_candidate(kind, train, start=start, fixed_shape=start is not None)
    p = model_predictions(model, test, cap, n_grid=600)
    return p[["median", "low", "high", "crps"]]


def _predict_unit_tracker(train: Histories, test: Histories) -> pd.DataFrame:
    from rulkit.fleet.tracking.tracker_chain import track_series
    from rulkit.fleet.tracking.tracker_settings import fit_tracker_config

    cfg = fit_tracker_config(train)
    rows = []
    for u in range(test.n_units):
        s = test.rows(u)
        h = track_series(test.t[s], test.hi[s][:, None], cfg)
        rows.append(pd.DataFrame({"median": h["frul"][:, 0], "low": h["rul_low"][:, 0],
                                  "high": h["rul_high"][:, 0]}))
    out = pd.concat(rows, ignore_index=True)
    out["crps"] = np.abs(out["median"].to_numpy() - truth_rul(test))
    return out


def run_fold(hist: Histories, test_units: list[int], kinds: tuple[str, ...], seed: int = 0,
             starts: dict[str, Any] | None = None) -> pd.DataFrame:
    """Learn without ``test_units``, replay them: one row per acquisition of a test unit,
    with the median, 90 % interval and CRPS of each model in ``kinds`` (columns ``{kind}``,
    ``{kind}_low``, ``{kind}_high``, ``{kind}_crps``) and the baselines."""
    train_units = [u for u in range(hist.n_units) if u not in set(test_units)]
    train, test = hist.select(train_units), hist.select(test_units)
    cap = crps_cap(hist)
    first = np.zeros(len(test.t), dtype=bool)
    first[test.start[:-1]] = True
    out = pd.DataFrame({
        "unit": test.names[test.unit], "t": test.t, "hi": test.hi,
        "t_fail": test.failure_time()[test.unit], "t_first": test.t[test.start[:-1]][test.unit],
        "true_rul": truth_rul(test),
        "origin": baseline_origin(test.t, test.hi),
        "last2": baseline_last2(test.t, test.hi, first),
    })
    for kind in kinds:
        if kind == "tracker":
            pred = _predict_unit_tracker(train, test)
        else:
            pred = _predict_model(train, test, kind, cap, (starts or {}).get(kind))
        out[kind] = pred["median"].to_numpy()
        out[f"{kind}_low"] = pred["low"].to_numpy()
        out[f"{kind}_high"] = pred["high"].to_numpy()
        out[f"{kind}_crps"] = pred["crps"].to_numpy()
    return out


def _folds(hist: Histories, folds: int) -> list[list[int]]:
    failed = [int(u) for u in np.flatnonzero(hist.failed)]
    if folds <= 0 or folds >= len(failed):
        return [[u] for u in failed]
    return [failed[i::folds] for i in range(folds)]


def predictions(hist: Histories, kinds: tuple[str, ...] = ("paris",), *, seed: int = 0,
                folds: int = 0, scheduler: str | None = None,
                fitted: dict[str, Any] | None = None) -> pd.DataFrame:
    """All folds' predictions (see :func:`run_fold`), in-process or on Dask; each fold's fit
    is warm-started from the fit of the same candidate on all units (``fitted``: fits on all
    of ``hist``'s units already made, e.g. by :func:`~rulkit.fleet.learned.selection.
    select_model`, used instead of fitting them again)."""
    from rulkit.fleet.learned.candidates import fit_candidate

    groups = _folds(hist, folds)
    seeds = np.random.SeedSequence(seed).spawn(len(groups))
    ints = [int(s.generate_state(1)[0]) for s in seeds]
    fitted = dict(fitted or {})
    for kind in kinds:
        if kind != "tracker" and kind not in fitted:
            fitted[kind] = fit_candidate(kind, hist, fitted=fitted)
    if scheduler is None:
        parts = [run_fold(hist, g, kinds, s, fitted) for g, s in zip(groups, ints, strict=True)]
    else:
        parts = _on_dask(hist, groups, kinds, ints, fitted, scheduler)
    return pd.concat(parts, ignore_index=True)


def _on_dask(hist: Histories, groups: list[list[int]], kinds: tuple[str, ...],
             seeds: list[int], starts: dict[str, Any], scheduler: str) -> list[pd.DataFrame]:
    try:
        from distributed import Client, LocalCluster
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError("Dask folds need the 'distributed' package: pip install "
                          "'rulkit[dask]'") from err
    cluster = None
    if scheduler == "local":
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                               dashboard_address=None, host="127.0.0.1")
        client = Client(cluster)
    else:
        client = Client(scheduler)
    try:
        h = client.scatter(hist, broadcast=True)
        futs = [client.submit(run_fold, h, g, kinds, s, starts, pure=False)
                for g, s in zip(groups, seeds, strict=True)]
        return list(client.gather(futs))
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


@dataclass(frozen=True)
class Evaluation:
    """Predictions (one row per acquisition of a scored unit) and the summary per method;
    ``kinds`` the models evaluated (``chosen``: the one ``auto`` selected, else empty),
    ``warnings`` what the history checks found."""

    predictions: pd.DataFrame
    summary: pd.DataFrame
    kinds: tuple[str, ...]
    n_units: int
    n_failed: int
    chosen: str = ""
    warnings: tuple[str, ...] = ()

    @property
    def kind(self) -> str:
        """The first (or only) model evaluated."""
        return self.kinds[0]


def _alpha_lambda_rate(p: pd.DataFrame, col: str, alpha: float) -> float:
    from rulkit.metrics import alpha_lambda

    passed = []
    for _, g in p.groupby("unit", sort=False):
        tf = float(g["t_fail"].iloc[0])
        if len(g) == 0 or not tf > g["t"].iloc[0]:
            continue
        res = alpha_lambda(g["t"].to_numpy(), np.nan_to_num(g[col].to_numpy(), nan=np.inf),
                           tf, alpha=alpha, lam=LAMBDA, t_p=float(g["t"].iloc[0]))
        passed.append(res.passed)
    return float(np.mean(passed)) if passed else math.nan


def _horizon(p: pd.DataFrame, col: str) -> float:
    from rulkit.metrics import prognostic_horizon

    ph = []
    for _, g in p.groupby("unit", sort=False):
        tf, t0 = float(g["t_fail"].iloc[0]), float(g["t_first"].iloc[0])
        res = prognostic_horizon(g["t"].to_numpy(), np.nan_to_num(g[col].to_numpy(), nan=np.inf),
                                 tf, alpha=0.2, bounds="relative", stay=True)
        ph.append(0.0 if math.isnan(res.horizon) else res.horizon / (tf - t0))
    return float(np.mean(ph))


def summarise(pred: pd.DataFrame, kinds: tuple[str, ...] = ("paris",),
              labels: dict[str, str] | None = None) -> pd.DataFrame:
    """The metrics of the module docstring, one row per model in ``kinds`` (labelled by
    ``labels``), then the two baselines."""
    p = pred[np.isfinite(pred["true_rul"])]
    late = p["t"] >= p["t_first"] + 0.5 * (p["t_fail"] - p["t_first"])
    tr = p["true_rul"].to_numpy()
    cap = 10.0 * float(p["t_fail"].max()) if len(p) else math.inf
    rows = []
    for m in (*kinds, *BASELINES):
        pr = p[m].to_numpy()
        rel = np.abs(pr - tr) / tr
        row: dict[str, object] = {"method": (labels or {}).get(m, m),
                                  "median_rel_err_last_half": float(np.median(rel[late]))
                                  if late.any() else math.nan}
        for a in ALPHAS:
            row[f"alpha_lambda_{a:g}"] = _alpha_lambda_rate(p, m, a)
        row["prognostic_horizon_frac"] = _horizon(p, m)
        if m in BASELINES:
            row["coverage_90"] = row["coverage_90_last_half"] = math.nan
            row["crps"] = float(np.mean(np.minimum(np.abs(pr - tr), cap)))
        else:
            cov = (p[f"{m}_low"] <= p["true_rul"]) & (p["true_rul"] <= p[f"{m}_high"])
            row["coverage_90"] = float(cov.mean()) if len(cov) else math.nan
            row["coverage_90_last_half"] = float(cov[late].mean()) if late.any() else math.nan
            row["crps"] = float(p[f"{m}_crps"].mean())
        row["n_predictions"] = len(p)
        row["n_late"] = int(late.sum())
        rows.append(row)
    return pd.DataFrame(rows)


def evaluate(hist: Histories, kind: str = "auto", *, seed: int = 0, folds: int = 0,
             scheduler: str | None = None, selection_folds: int = 5,
             progress: Any = None) -> Evaluation:
    """Leave-one-unit-out (or K-fold) evaluation of ``kind`` (module docstring)."""
    from rulkit.fleet.learned.candidates import AUTO_CANDIDATES
    from rulkit.fleet.learned.checks import check_histories

    warnings = tuple(check_histories(hist))
    chosen = ""
    if kind == "auto":
        from rulkit.fleet.learned.selection import select_model

        chosen = select_model(hist, folds=selection_folds, progress=progress).chosen
        kinds: tuple[str, ...] = (chosen,)
    elif kind == "all":
        kinds = AUTO_CANDIDATES
    else:
        kinds = (kind,)
    pred = predictions(hist, kinds, seed=seed, folds=folds, scheduler=scheduler)
    labels = {chosen: f"{chosen} (chosen by fit)"} if chosen else None
    return Evaluation(predictions=pred, summary=summarise(pred, kinds, labels), kinds=kinds,
                      n_units=hist.n_units, n_failed=int(hist.failed.sum()), chosen=chosen,
                      warnings=warnings)


def plot_alpha_lambda(ev: Evaluation, path: Path, alpha: float = 0.2) -> Path:
    """The alpha-lambda plot: RUL / life against the life fraction lambda, truth and cone."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p = ev.predictions[np.isfinite(ev.predictions["true_rul"])]
    fig, ax = plt.subplots(figsize=(7, 5))
    lam = np.linspace(0, 1, 50)
    ax.plot(lam, 1 - lam, "k-", lw=1.2, label="true RUL")
    ax.fill_between(lam, (1 - alpha) * (1 - lam), (1 + alpha) * (1 - lam), color="k",
                    alpha=0.1, label=f"+-{alpha:.0%}")
    for i, (_, g) in enumerate(p.groupby("unit", sort=False)):
        life = g["t_fail"].iloc[0] - g["t_first"].iloc[0]
        x = (g["t"] - g["t_first"]) / life
        ax.plot(x, g[ev.kind] / life, "-o", ms=2.5, lw=0.8, color="C0", alpha=0.7,
                label=f"{ev.kind} (median)" if i == 0 else None)
        ax.plot(x, g["origin"] / life, ":", lw=0.8, color="C1", alpha=0.6,
                label="linear through origin" if i == 0 else None)
        ax.plot(x, g["last2"] / life, "--", lw=0.6, color="C2", alpha=0.5,
                label="linear through last two" if i == 0 else None)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 2)
    ax.set_xlabel("fraction of life (t - t_first) / (T - t_first)")
    ax.set_ylabel("RUL / life")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    ax.set_title(f"alpha-lambda, leave-one-unit-out, {ev.n_failed} failed units")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


__all__ = ["ALPHAS", "BASELINES", "Evaluation", "baseline_last2", "baseline_origin", "evaluate",
           "plot_alpha_lambda", "predictions", "run_fold", "summarise"]
