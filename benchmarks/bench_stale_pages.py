"""Benchmark: the stale filter's pages on a fleet whose stale components are all in one
level (docs/service-load.md, "Stale pages when a level has few stale components"), in process,
on SQLite or on a throwaway PostgreSQL server (analysed after the fill).

A fleet of ``--components`` components acquired now, ``--alarm-share`` of them alarms, and
``--stale`` more acquired two days ago at the ``ok`` level (stale under the rules'
``stale_after`` of a day): an export from a historian where the units that stopped
reporting are healthy ones. Beyond ``STALE_BY_SEEN`` stale components, a page of the stale
filter reads each level's order and skips the fresh components; a level that has no stale
component is read to its end. Prints the service's CPU and the wall time (PostgreSQL's work
is in its own processes) for the first stale page and the one after it, per sort (the best of
``--repeats``), beside the first page of all components, and whether both stale pages hold
stale components only.

    .venv/bin/python benchmarks/bench_stale_pages.py                   # 10^6 components
    .venv/bin/python benchmarks/bench_stale_pages.py --components 100000
    .venv/bin/python benchmarks/bench_stale_pages.py --backend postgresql
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).parent))
from bench_service import PAGE_RULES
from rulkit.fleet.service.db import ServiceDB
from rulkit.fleet.service.fleet_view import STALE_BY_SEEN
from rulkit.fleet.service.pgtemp import TempPostgres
from rulkit.fleet.store.postgres import open_store

STEPS = 3
"""Acquisitions per component."""


def fill(db: str, n: int, stale: int, alarm_share: float, now: float) -> float:
    """The fleet of the module docstring in a new database; seconds."""
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    with open_store(db) as store:
        store.set_rules(PAGE_RULES)
        per = 200_000 // STEPS
        t = np.arange(STEPS, dtype=float)
        for prefix, count, when in (("unit", n, now), ("old", stale, now - 2 * 86400.0)):
            for i0 in range(0, count, per):
                k = min(per, count - i0)
                names = np.array([f"{prefix}-{i:07d}" for i in range(i0, i0 + k)], dtype=object)
                base = rng.uniform(0.1, 0.5, k)
                if prefix == "unit":
                    base[rng.random(k) < alarm_share] = 0.97  # past PAGE_RULES' alarm_hi
                hi = np.repeat(base, STEPS) + np.repeat(rng.uniform(0.0, 0.02, k), STEPS) * \
                    np.tile(t, k)
                store.now = when
                store.ingest(pd.DataFrame({"component": np.repeat(names, STEPS),
                                           "time": np.tile(t, k), "hi": hi}), "bench")
    return time.perf_counter() - t0


def page_cost(sdb: ServiceDB, repeats: int, **query: object) -> tuple[float, float]:
    """The least CPU time and the least wall time of ``repeats`` reads of one page, in ms."""
    cpu = wall = np.inf
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        sdb.components(limit=50, **query)  # type: ignore[arg-type]
        cpu = min(cpu, time.process_time() - c0)
        wall = min(wall, time.perf_counter() - w0)
    return float(cpu) * 1e3, float(wall) * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--components", type=int, default=1_000_000)
    ap.add_argument("--stale", type=int, default=5_000)
    ap.add_argument("--alarm-share", type=float, default=0.06)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--backend", choices=("sqlite", "postgresql"), default="sqlite")
    args = ap.parse_args()
    if args.stale <= STALE_BY_SEEN:
        raise SystemExit(f"--stale {args.stale}: at most STALE_BY_SEEN ({STALE_BY_SEEN}) "
                         "stale components are read in the seen index; ask for more")
    with contextlib.ExitStack() as stack:
        if args.backend == "postgresql":
            db = stack.enter_context(TempPostgres()).create_database("stale")
        else:
            db = str(Path(stack.enter_context(tempfile.TemporaryDirectory())) / "fleet.db")
        run(db, args)


def run(db: str, args: argparse.Namespace) -> None:
    """Fill ``db`` and print the pages' figures."""
    now = time.time()
    took = fill(db, args.components, args.stale, args.alarm_share, now)
    if args.backend == "postgresql":
        with open_store(db) as store:  # what autovacuum does to freshly loaded tables
            store._conn.execute("VACUUM ANALYZE")
    sdb = ServiceDB(db)
    try:
        print(f"# bench_stale_pages ({args.backend}): {args.components} fresh components "
              f"({args.alarm_share:.0%} alarms) and {args.stale} stale ok ones, filled in "
              f"{took:.0f} s; load average {os.getloadavg()[0]:.1f}; service CPU / wall per "
              f"page of 50 in ms, best of {args.repeats}")
        with sdb.store() as s, s.snapshot() as conn:
            stale_names = {r[0] for r in conn.execute(
                "SELECT component FROM components WHERE seen < ?",
                (now - PAGE_RULES.stale_after,)).fetchall()}
        for sort in ("worst", "rul", "due"):
            total, first, cur = sdb.components(limit=50, level="stale", sort=sort, now=now)
            _, second, _ = sdb.components(limit=50, level="stale", sort=sort, after=cur, now=now)
            right = total == len(stale_names) and all(
                i["component"] in stale_names for i in first + second)
            costs = (page_cost(sdb, args.repeats, level="stale", sort=sort, now=now),
                     page_cost(sdb, args.repeats, level="stale", sort=sort, after=cur, now=now),
                     page_cost(sdb, args.repeats, sort=sort, now=now))
            a, b, c = (f"{cpu:5.1f} / {wall:5.1f}" for cpu, wall in costs)
            print(f"  {sort:5s}  stale first {a}  stale second {b}  all first {c}  (stale "
                  f"total {total}; both stale pages of stale components only: {right})")
    finally:
        sdb.close()

if __name__ == "__main__":
    main()
