"""Where a PostgreSQL group commit spends the writer's time (docs/service-load.md, "Where
PostgreSQL stands against the goals"): ``ServiceDB.ingest`` in this process (no HTTP) on a
throwaway PostgreSQL server with its durable defaults, ``--writers`` threads each sending
``--batches`` batches of ``--batch-size`` (bench_service.py's batches, each with a write
token, checked in the group's transaction), after one untimed round.

Prints, per group commit: its batches, its wall time through the writer, the writer
thread's CPU in it, and the wall time of each kind of statement the writer's connection
sends (each timed from its send to its result, the wait for the interpreter's lock after it
included), with how many a group sends. The rate is the groups' batches over the writer's
time per group: the writer is busy nearly all the time.

    .venv/bin/python benchmarks/profile_pg_groups.py --batches 60
"""

from __future__ import annotations

import argparse
import os
import threading
import time
from collections import Counter, defaultdict
from typing import Any

import pandas as pd

from rulkit.fleet.service.db import ServiceDB
from rulkit.fleet.service.loadgen import writer_batch
from rulkit.fleet.service.pgtemp import TempPostgres, unavailable_reason
from rulkit.fleet.store import postgres

WALL: defaultdict[str, float] = defaultdict(float)
COUNT: Counter[str] = Counter()
GROUPS: list[tuple[int, float, float]] = []  # batches, wall, writer CPU


def _kind(sql: str) -> str:
    return " ".join(sql.split()[:5])[:48]


def instrument() -> None:
    """Time the writer's statements (only the thread inside a group commit) and its groups."""
    writer: list[int] = []
    conn_cls = postgres.PgConnection

    def timed(name: str, fn: Any, label: Any) -> None:
        def run(self: Any, first: Any, *a: Any) -> Any:
            if threading.get_ident() not in writer:
                return fn(self, first, *a)
            t0 = time.perf_counter()
            try:
                return fn(self, first, *a)
            finally:
                WALL[label(first)] += time.perf_counter() - t0
                COUNT[label(first)] += 1

        setattr(conn_cls, name, run)

    timed("execute", conn_cls.execute, _kind)
    timed("executemany", conn_cls.executemany, lambda sql: "many " + _kind(sql))
    timed("copy_binary", conn_cls.copy_binary, lambda table: f"COPY {table} (rows)")
    timed("copy_data", conn_cls.copy_data, lambda table: f"COPY {table} (bytes)")
    insert = postgres._insert_rows

    def insert_rows(conn: Any, table: Any, *a: Any) -> list[int]:
        t0 = time.perf_counter()
        try:
            return insert(conn, table, *a)
        finally:
            WALL[f"INSERT {table.name} (arrays)"] += time.perf_counter() - t0
            COUNT[f"INSERT {table.name} (arrays)"] += 1

    postgres._insert_rows = insert_rows  # type: ignore[assignment]
    commit = ServiceDB._commit

    def group(self: ServiceDB, pending: list[Any]) -> None:
        writer[:] = [threading.get_ident()]
        t0, c0 = time.perf_counter(), time.thread_time()
        commit(self, pending)
        GROUPS.append((len(pending), time.perf_counter() - t0, time.thread_time() - c0))

    ServiceDB._commit = group  # type: ignore[method-assign]


def run(args: argparse.Namespace, url: str) -> float:
    """The load, after an untimed round; the acquisitions per second."""
    sdb = ServiceDB(url)
    token = sdb.create_token("write", "profile")[1]
    frames = [[pd.DataFrame(writer_batch(w, k, args.batch_size))
               for k in range(args.batches + 1)] for w in range(args.writers)]

    def send(w: int, ks: range) -> None:
        for k in ks:
            sdb.ingest(frames[w][k], "api:", token=token)

    def threads(ks: range) -> None:
        ts = [threading.Thread(target=send, args=(w, ks)) for w in range(args.writers)]
        for t in ts:
            t.start()
        for t in ts:
            t.join()

    try:
        threads(range(1))
        GROUPS.clear()
        WALL.clear()
        COUNT.clear()
        t0 = time.perf_counter()
        threads(range(1, args.batches + 1))
        return args.writers * args.batches * args.batch_size / (time.perf_counter() - t0)
    finally:
        sdb.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--batches", type=int, default=60, help="Batches per writer.")
    ap.add_argument("--writers", type=int, default=8)
    ap.add_argument("--batch-size", type=int, default=100)
    args = ap.parse_args()
    reason = unavailable_reason()
    if reason:
        raise SystemExit(reason)
    instrument()
    print(f"# profile_pg_groups: {args.writers} writers x {args.batches} batches of "
          f"{args.batch_size}, in process; load average {os.getloadavg()[0]:.1f}")
    with TempPostgres(durable=True) as pg:
        rate = run(args, pg.create_database("profile"))
    n = len(GROUPS)
    wall = sum(g[1] for g in GROUPS) / n
    print(f"{rate:.0f} acquisitions/s; {n} group commits of {sum(g[0] for g in GROUPS) / n:.2f} "
          f"batches; the writer per group: {wall * 1e3:.2f} ms of wall, of which its thread's "
          f"CPU {sum(g[2] for g in GROUPS) / n * 1e3:.2f} ms")
    print("the writer's statements per group (wall from send to result):")
    for k, v in sorted(WALL.items(), key=lambda kv: -kv[1]):
        print(f"  {k:48s} {COUNT[k] / n:5.2f} x  {v / n * 1e3:6.2f} ms")
    print(f"  {'all':48s} {sum(COUNT.values()) / n:5.2f} x  {sum(WALL.values()) / n * 1e3:6.2f} ms")
    print(f"load average at end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
