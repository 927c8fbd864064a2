"""Leave-one-unit-out evaluation of fleet RUL models against naive baselines.

docs/fleet-models.md section 4. For every failed unit: learn the model from the *other* units
(failed and censored), replay the unit's acquisitions one by one, and at each acquisition before
its true failure time compare the RUL with the truth (true failure time - t). Beside the model,
two naive point baselines on the raw HI:

* ``origin``: linear through (0, 0) and the current acquisition, RUL = t (1 - hi) / hi;
* ``last2``: linear through the last two acquisitions (+inf when the slope is <= 0 or at the
  first acquisition).

Metrics (:func:`summarise`): median relative error |RUL - truth| / truth over the last half of
each unit's life (t >= t_first + (T - t_first)/2); alpha-lambda pass rate (alpha = 0.2 and 0.3,
lambda = 0.5, t_P = the unit's first acquisition; the prediction is the median); prognostic
horizon (relative alpha = 0.2 cone, must stay inside; as a fraction of the unit's life,
0 when never); 90 % interval coverage (model only); CRPS (model: from posterior draws;
baselines: absolute error, the CRPS of a point forecast), in the file's time unit, with +inf
capped at ``crps_cap`` = 10 x the longest failure time (model: integral of the
squared CDF difference, :func:`rulkit.fleet.learned.degradation.crps`).

Folds run in-process, or on Dask (``scheduler="local"`` starts a LocalCluster, any other string
is a scheduler address); ``folds=K`` groups the units into K folds for large fleets instead of
leaving one unit out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from rulkit.fleet.learned.histories import Histories

METHODS = ("model", "origin", "last2")
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


def _predict_unit_model(train: Histories, test: Histories, kind: str, cap: float
                        ) -> pd.DataFrame:
    from rulkit.fleet.learned.degradation import crps, filtered_states, fit_model

    model = fit_model(train, kind)
    st = filtered_states(model, test)
    med, lo, hi = model.rul_quantiles(st, (0.5, 0.05, 0.95))
    truth = _truth(test)
    ok = np.isfinite(truth)
    score = np.full(truth.shape, np.nan)
    if ok.any():
        sub = type(st)(m=st.m[ok], p=st.p[ok], t=st.t[ok], hi=st.hi[ok], n=st.n[ok])
        score[ok] = crps(model, sub, truth[ok], cap)
    return pd.DataFrame({"median": med, "low": lo, "high": hi, "crps": score})


def _predict_unit_tracker(train: Histories, test: Histories) -> pd.DataFrame:
    from rulkit.fleet.tracking.tracker_chain import fit_tracker_config, track_series

    cfg = fit_tracker_config(train)
    rows = []
    for u in range(test.n_units):
        s = test.rows(u)
        h = track_series(test.t[s], test.hi[s][:, None], cfg)
        rows.append(pd.DataFrame({"median": h["frul"][:, 0], "low": h["rul_low"][:, 0],
                                  "high": h["rul_high"][:, 0]}))
    out = pd.concat(rows, ignore_index=True)
    truth = _truth(test)
    out["crps"] = np.abs(out["median"].to_numpy() - truth)
    return out


def _truth(h: Histories) -> np.ndarray:
    """True RUL per row (NaN for censored units and at/after the failure time)."""
    tf = h.failure_time()[h.unit]
    r = tf - h.t
    return np.where(r > 0, r, np.nan)


def run_fold(hist: Histories, test_units: list[int], kind: str, seed: int = 0,
             n_samples: int = 400) -> pd.DataFrame:
    """Learn without ``test_units``, replay them: one row per acquisition of a test unit."""
    train_units = [u for u in range(hist.n_units) if u not in set(test_units)]
    train, test = hist.select(train_units), hist.select(test_units)
    tf = hist.failure_time()
    cap = 10.0 * float(np.nanmax(tf)) if np.isfinite(tf).any() else math.inf
    if kind == "tracker":
        pred = _predict_unit_tracker(train, test)
    else:
        pred = _predict_unit_model(train, test, kind, cap)
    first = np.zeros(len(test.t), dtype=bool)
    first[test.start[:-1]] = True
    truth = _truth(test)
    tf_rows = test.failure_time()[test.unit]
    t0 = test.t[test.start[:-1]][test.unit]
    out = pd.DataFrame({
        "unit": test.names[test.unit], "t": test.t, "hi": test.hi, "t_fail": tf_rows,
        "t_first": t0, "true_rul": truth,
        "origin": baseline_origin(test.t, test.hi),
        "last2": baseline_last2(test.t, test.hi, first),
    })
    out["model"] = pred["median"].to_numpy()
    out["model_low"] = pred["low"].to_numpy()
    out["model_high"] = pred["high"].to_numpy()
    out["model_crps"] = pred["crps"].to_numpy()
    return out


def _folds(hist: Histories, folds: int) -> list[list[int]]:
    failed = [int(u) for u in np.flatnonzero(hist.failed)]
    if folds <= 0 or folds >= len(failed):
        return [[u] for u in failed]
    return [failed[i::folds] for i in range(folds)]


def predictions(hist: Histories, kind: str = "linear", *, seed: int = 0, folds: int = 0,
                scheduler: str | None = None, n_samples: int = 400) -> pd.DataFrame:
    """All folds' predictions (see :func:`run_fold`), in-process or on Dask."""
    groups = _folds(hist, folds)
    seeds = np.random.SeedSequence(seed).spawn(len(groups))
    ints = [int(s.generate_state(1)[0]) for s in seeds]
    if scheduler is None:
        parts = [run_fold(hist, g, kind, s, n_samples) for g, s in zip(groups, ints,
                                                                        strict=True)]
    else:
        parts = _on_dask(hist, groups, kind, ints, n_samples, scheduler)
    return pd.concat(parts, ignore_index=True)


def _on_dask(hist: Histories, groups: list[list[int]], kind: str, seeds: list[int],
             n_samples: int, scheduler: str) -> list[pd.DataFrame]:
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
        futs = [client.submit(run_fold, h, g, kind, s, n_samples, pure=False)
                for g, s in zip(groups, seeds, strict=True)]
        return list(client.gather(futs))
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


@dataclass(frozen=True)
class Evaluation:
    """Predictions (one row per acquisition of a scored unit) and the summary per method."""

    predictions: pd.DataFrame
    summary: pd.DataFrame
    kind: str
    n_units: int
    n_failed: int


def summarise(pred: pd.DataFrame, kind: str = "model") -> pd.DataFrame:
    """The metrics of the module docstring, one row per method."""
    from rulkit.metrics import alpha_lambda, prognostic_horizon

    p = pred[np.isfinite(pred["true_rul"])]
    late = p["t"] >= p["t_first"] + 0.5 * (p["t_fail"] - p["t_first"])
    rows = []
    for m in METHODS:
        pr = p[m].to_numpy()
        tr = p["true_rul"].to_numpy()
        rel = np.abs(pr - tr) / tr
        row: dict[str, object] = {"method": kind if m == "model" else m,
                                  "median_rel_err_last_half": float(np.median(rel[late]))}
        for a in ALPHAS:
            passed = []
            for _, g in p.groupby("unit", sort=False):
                tf = float(g["t_fail"].iloc[0])
                if len(g) == 0 or not tf > g["t"].iloc[0]:
                    continue
                res = alpha_lambda(g["t"].to_numpy(), np.nan_to_num(g[m].to_numpy(), nan=np.inf),
                                   tf, alpha=a, lam=LAMBDA, t_p=float(g["t"].iloc[0]))
                passed.append(res.passed)
            row[f"alpha_lambda_{a:g}"] = float(np.mean(passed)) if passed else math.nan
        ph = []
        for _, g in p.groupby("unit", sort=False):
            tf, t0 = float(g["t_fail"].iloc[0]), float(g["t_first"].iloc[0])
            ph_res = prognostic_horizon(g["t"].to_numpy(), np.nan_to_num(g[m].to_numpy(),
                                                                          nan=np.inf),
                                        tf, alpha=0.2, bounds="relative", stay=True)
            ph.append(0.0 if math.isnan(ph_res.horizon) else ph_res.horizon / (tf - t0))
        row["prognostic_horizon_frac"] = float(np.mean(ph))
        if m == "model":
            cov = (p["model_low"] <= p["true_rul"]) & (p["true_rul"] <= p["model_high"])
            row["coverage_90"] = float(cov.mean())
            row["crps"] = float(p["model_crps"].mean())
        else:
            cap = 10.0 * float(p["t_fail"].max())
            row["coverage_90"] = math.nan
            row["crps"] = float(np.mean(np.minimum(np.abs(pr - tr), cap)))
        row["n_predictions"] = len(p)
        row["n_late"] = int(late.sum())
        rows.append(row)
    return pd.DataFrame(rows)


def evaluate(hist: Histories, kind: str = "linear", *, seed: int = 0, folds: int = 0,
             scheduler: str | None = None, n_samples: int = 400) -> Evaluation:
    """Leave-one-unit-out (or K-fold) evaluation, module docstring."""
    pred = predictions(hist, kind, seed=seed, folds=folds, scheduler=scheduler,
                       n_samples=n_samples)
    return Evaluation(predictions=pred, summary=summarise(pred, kind), kind=kind,
                      n_units=hist.n_units, n_failed=int(hist.failed.sum()))


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
        ax.plot(x, g["model"] / life, "-o", ms=2.5, lw=0.8, color="C0", alpha=0.7,
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


__all__ = ["ALPHAS", "METHODS", "Evaluation", "baseline_last2", "baseline_origin", "evaluate",
           "plot_alpha_lambda", "predictions", "run_fold", "summarise"]
