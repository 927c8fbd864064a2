"""One RUL per component and the alert rules on a pump fleet like the one of issue 18.

40 pumps exported from a historian: a daily HI from installation (ages in hours), exponential
growth HI = h0 exp(r t) with additive noise of sd 0.02; 24 run until their measured HI
reached 1, 16 still running (stopped at 30-90 % of their life). The whole history goes through
the component store (`rulkit track`'s ingestion, `rulkit status`'s reader) once per estimator:
the default without a fitted model (the per-unit trend), the seed-004 tracker chain chosen
explicitly, and a model fitted on the same fleet (`rulkit fit` on the histories, in sample, as
a user would run it). Printed per estimator:

* RULs anywhere (status rows, history rows) negative or outside their own interval;
* the failed pumps in alarm, the running pumps in alarm (false alarms);
* the failed pumps warned before their failure (RUL low quantile < the lead time), and the
  median warning lead (true failure time - first warning);
* on the running pumps: median relative error of the RUL median against the truth, and the
  share of 90 % intervals holding the truth.

    .venv/bin/python benchmarks/fleet_alerts.py            # seed 0
    .venv/bin/python benchmarks/fleet_alerts.py --seed 1 --lead-time 200
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from rulkit.fleet.learned.degradation import fit_model
from rulkit.fleet.learned.histories import histories_from_frame
from rulkit.fleet.monitoring.rules import MonitoringRules
from rulkit.fleet.store.ingest import ingest_into
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.store.status_view import read_status
from rulkit.fleet.tracking.tracker_chain import TrackerConfig
from rulkit.reporting import markdown_table


def pump_fleet(rng: np.random.Generator, n: int = 40, n_failed: int = 24
               ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(acquisitions, truth): the fleet and per pump its true failure time (h0 e^(r T) = 1)
    and its last age."""
    rows, truth = [], []
    for i in range(n):
        h0 = rng.uniform(0.05, 0.15)
        life = rng.uniform(1500.0, 6000.0)  # hours to the true HI = 1
        r = np.log(1.0 / h0) / life
        t = np.arange(0.0, 1.5 * life, 24.0)
        hi = np.clip(h0 * np.exp(r * t) + rng.normal(0.0, 0.02, t.size), 0.0, 5.0)
        if i < n_failed:  # the historian stops at the first measured HI >= 1
            k = int(np.flatnonzero(hi >= 1.0)[0])
        else:
            k = int(np.searchsorted(t, rng.uniform(0.3, 0.9) * life))
        name = f"P-{101 + i}"
        rows.append(pd.DataFrame({"component": name, "time": t[:k + 1], "hi": hi[:k + 1]}))
        truth.append((name, life, t[k], i < n_failed))
    return (pd.concat(rows, ignore_index=True),
            pd.DataFrame(truth, columns=["component", "life", "t_last", "to_failure"]))


def run(name: str, df: pd.DataFrame, truth: pd.DataFrame, rules: MonitoringRules,
        model: object, out: Path) -> dict[str, object]:
    db = out / f"{name.split()[0]}.db"
    cfg = TrackerConfig(dt=24.0, design_life=1e6, warn_rul=rules.lead_time)
    ComponentStore(db, config=cfg, rules=rules).close()
    if model is not None:
        with ComponentStore(db) as s:
            s.set_degradation_model(model)
    res, _ = ingest_into(db, df)
    with ComponentStore(db, readonly=True) as s:
        hist = s.history()
    got = read_status(db, now=time.time())
    assert got is not None
    cols = pd.DataFrame({k: got[1][k] for k in ("component", "level", "rul", "rul_low",
                                                  "rul_high", "failed")})
    both = truth.merge(cols, on="component")

    def bad(med: pd.Series, low: pd.Series, high: pd.Series) -> tuple[int, int]:
        est = med.notna()
        outside = est & ((med < low) | (med > high))
        return int(outside.sum()), int((est & (med < 0)).sum() + (low < 0).sum())

    out_s, neg_s = bad(cols.rul, cols.rul_low, cols.rul_high)
    out_h, neg_h = bad(hist.rul_median, hist.rul_low, hist.rul_high)
    failed, running = both[both.to_failure], both[~both.to_failure]
    warn = pd.DataFrame([(a.component, a.t) for a in res.alerts if a.level == 1],
                        columns=["component", "t"]).groupby("component")["t"].min()
    lead = failed.set_index("component")["life"] - warn.reindex(failed.component).to_numpy()
    true_rul = running.life - running.t_last
    known = running.rul.notna()
    rel = (np.abs(running.rul - true_rul) / true_rul)[known]
    inside = ((running.rul_low <= true_rul) & (true_rul <= running.rul_high))[known]
    return {"estimator": name, "status rows outside / negative": f"{out_s} / {neg_s}",
            "history rows outside / negative": f"{out_h} / {neg_h} of {len(hist)}",
            "failed pumps in alarm": f"{int((failed.level == 2).sum())} / {len(failed)}",
            "running pumps in alarm": f"{int((running.level == 2).sum())} / {len(running)}",
            "failed warned before failure": f"{int((lead > 0).sum())} / {len(failed)}",
            "median warning lead (h)": float(np.nanmedian(lead)) if lead.notna().any()
            else float("nan"),
            "running: median rel. error": float(np.median(rel)) if len(rel) else float("nan"),
            "running: 90 % coverage": float(inside.mean()) if len(inside) else float("nan"),
            "running estimated": f"{int(known.sum())} / {len(running)}"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--lead-time", type=float, default=200.0)
    args = ap.parse_args()
    df, truth = pump_fleet(np.random.default_rng(args.seed))
    rules = MonitoringRules(time_unit="h", lead_time=args.lead_time)
    hist = histories_from_frame(df, "pump fleet")
    print(f"pump fleet, seed {args.seed}: {len(truth)} pumps ({int(truth.to_failure.sum())} "
          "run to failure), "
          f"{len(df)} daily acquisitions; lead time {args.lead_time:g} h")
    t0 = time.perf_counter()
    models = {kind: fit_model(hist, kind, time_unit="h") for kind in ("paris", "exponential")}
    print(f"fitted in {time.perf_counter() - t0:.1f} s: "
          + "; ".join(f"{k}: {m.describe().split(':')[0]}" for k, m in models.items()))
    rows = []
    with tempfile.TemporaryDirectory() as d:
        out = Path(d)
        rows.append(run("trend (default, no model)", df, truth, rules, None, out))
        rows.append(run("tracker chain (seed 004, chosen)", df, truth,
                        MonitoringRules(estimator="tracker", time_unit="h",
                                        lead_time=args.lead_time), None, out))
        for kind, m in models.items():
            rows.append(run(f"{kind} (fitted in sample)", df, truth, rules, m, out))
    table = pd.DataFrame(rows).set_index("estimator").T.reset_index(names="")
    print(markdown_table(table, ".3g"))


if __name__ == "__main__":
    main()
