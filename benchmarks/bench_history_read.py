"""Benchmark: a component's history read in process on SQLite, at 10^5 and 10^7 history rows
(docs/service-load.md, "History reads at 10^7 rows, packed").

The databases are filled as benchmarks/bench_service.py fills its history databases (1000
acquisitions per component, the packed layout: one chunk of 1000 records, a 104 KB blob, per
component). For each, the read of ``/api/v1/components/{id}/history?limit=1000`` without
HTTP (:meth:`rulkit.fleet.service.db.ServiceDB.history`) and its SQL alone, CPU per read
(median of ``--turns`` turns, the two databases in turns), with the read system calls and
bytes of this process per read (``/proc/self/io``):

* **warm**: one connection, the same read again (SQLite's page cache holds its pages);
* **new connection**: a connection opened for each read (SQLite's page cache empty, the
  operating system's warm), its opening measured alone and subtracted;
* **OS cold**: as "new connection", after the file's pages are dropped from the operating
  system's page cache (``posix_fadvise(DONTNEED)`` while this process holds no connection to
  it, so no SQLite lock is lost); wall time per read beside the CPU;
* each with SQLite's default page cache (2 MB) and ``mmap_size`` 0, then with ``mmap_size``
  256 MB, then with a 64 MB page cache.

Then the history table's B-tree: its depth and pages per level (SQLite's ``dbstat``), which
is what grows with the table.

    .venv/bin/python benchmarks/bench_history_read.py            # fills both (about a minute)
    .venv/bin/python benchmarks/bench_history_read.py --dir /tmp/h --keep   # reuse them
"""

from __future__ import annotations

import argparse
import os
import sqlite3
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

from bench_service import fill
from rulkit.fleet.service.db import ServiceDB
from rulkit.fleet.store import history_chunks
from rulkit.fleet.store.postgres import open_store

COMPONENT = "unit-0000000"
VARIANTS = {"default": (), "mmap 256 MB": ("PRAGMA mmap_size=268435456",),
            "cache 64 MB": ("PRAGMA cache_size=-65536",)}
"""The connection settings measured: SQLite's defaults, then one setting changed."""


def io_counts() -> np.ndarray:
    """(read system calls, bytes read through them) of this process so far."""
    fields = dict(line.split(": ") for line in Path("/proc/self/io").read_text().splitlines())
    return np.array([int(fields["syscr"]), int(fields["rchar"])], dtype=float)


def per_read(fn: Callable[[], object], n: int) -> tuple[float, float, np.ndarray]:
    """(CPU ms, wall ms, [read syscalls, bytes]) per call of ``fn`` over ``n`` calls."""
    io0, c0, w0 = io_counts(), time.process_time(), time.perf_counter()
    for _ in range(n):
        fn()
    return ((time.process_time() - c0) / n * 1e3, (time.perf_counter() - w0) / n * 1e3,
            (io_counts() - io0) / n)


def drop_os_cache(path: str) -> None:
    """Drop ``path``'s pages (and its WAL's) from the operating system's page cache. Only
    while this process holds no SQLite connection to it: closing any descriptor of a file
    drops every POSIX lock the process holds on it."""
    for p in (path, path + "-wal"):
        if os.path.exists(p):
            fd = os.open(p, os.O_RDONLY)
            try:
                os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
            finally:
                os.close(fd)


def fresh_read(db: str, pragmas: tuple[str, ...], read: bool, cold: bool) -> None:
    """Open a store on ``db`` with ``pragmas``, read the history (when ``read``), close it;
    with ``cold`` the file's pages are first dropped from the OS page cache."""
    if cold:
        drop_os_cache(db)
    with open_store(db, create=False) as store:
        for p in pragmas:
            store._conn.execute(p)
        if read:
            with store.snapshot() as conn:
                history_chunks.read_last(conn, COMPONENT, 1000)


def measure(db: str, pragmas: tuple[str, ...], args: argparse.Namespace) -> dict[str, float]:
    """One turn of every figure of ``db`` with ``pragmas``."""
    out: dict[str, float] = {}
    sdb = ServiceDB(db, pool_size=1)
    try:
        with sdb.store() as s:
            for p in pragmas:
                s._conn.execute(p)
        sdb.history(COMPONENT, limit=1000)
        out["warm"], _, io = per_read(lambda: sdb.history(COMPONENT, limit=1000), args.reads)
        out["warm_syscr"] = io[0]
        with sdb.store() as s, s.snapshot() as conn:
            out["sql"] = per_read(lambda: history_chunks.read_last(conn, COMPONENT, 1000),
                                  args.reads)[0]
    finally:
        sdb.close()
    n = max(args.reads // 10, 3)
    opened = per_read(lambda: fresh_read(db, pragmas, False, False), n)
    new = per_read(lambda: fresh_read(db, pragmas, True, False), n)
    out["new"] = new[0] - opened[0]
    out["new_syscr"], out["new_kb"] = (new[2] - opened[2]) * [1, 1 / 1024]
    cold = per_read(lambda: fresh_read(db, pragmas, True, True), n)
    out["cold"], out["cold_wall"] = cold[0] - opened[0], cold[1] - opened[1]
    out["cold_syscr"], out["cold_kb"] = (cold[2] - opened[2]) * [1, 1 / 1024]
    return out


def btree(db: str) -> str:
    """The history table's depth and pages per kind (``dbstat``), or why not."""
    conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        rows = conn.execute("SELECT pagetype, COUNT(*), SUM(ncell) FROM dbstat WHERE name = "
                            "'history' GROUP BY pagetype ORDER BY pagetype").fetchall()
        depth = conn.execute("SELECT MAX(LENGTH(path) - LENGTH(REPLACE(path, '/', ''))) "
                             "FROM dbstat WHERE name = 'history' AND pagetype != "
                             "'overflow'").fetchone()[0]
    except sqlite3.OperationalError as err:  # SQLite built without dbstat
        return f"dbstat unavailable ({err})"
    finally:
        conn.close()
    return f"depth {depth + 1} levels; " + ", ".join(f"{k} {n} pages ({c} cells)"
                                                    for k, n, c in rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rows", type=int, default=10_000_000, help="The larger history.")
    ap.add_argument("--reads", type=int, default=200, help="Warm reads per turn.")
    ap.add_argument("--turns", type=int, default=5)
    ap.add_argument("--dir", type=Path, default=None, help="Where the databases are or go.")
    ap.add_argument("--keep", action="store_true", help="Keep the databases in --dir.")
    args = ap.parse_args()
    tmp = args.dir or Path(tempfile.mkdtemp(prefix="rulkit-history-"))
    tmp.mkdir(parents=True, exist_ok=True)
    sizes = (args.rows // 100, args.rows)
    dbs = {rows: str(tmp / f"h_{rows}.db") for rows in sizes}
    for rows, db in dbs.items():
        if not os.path.exists(db):
            print(f"# filling {rows} rows: {fill(db, rows // 1000, steps=1000):.0f} s")
    print(f"# bench_history_read: load average {os.getloadavg()[0]:.1f} at start; "
          f"{args.turns} turns in turns of the two databases, medians; CPU per read in ms")
    for name, pragmas in VARIANTS.items():
        turns: dict[int, list[dict[str, float]]] = {rows: [] for rows in sizes}
        for _ in range(args.turns):
            for rows, db in dbs.items():
                turns[rows].append(measure(db, pragmas, args))
        med = {rows: {k: float(np.median([t[k] for t in ts])) for k in ts[0]}
               for rows, ts in turns.items()}
        for rows in sizes:
            m = med[rows]
            print(f"  {name:12s} {rows:>9d} rows: warm {m['warm']:.3f} (its SQL {m['sql']:.3f};"
                  f" {m['warm_syscr']:.1f} read calls)  new connection {m['new']:.3f} "
                  f"({m['new_syscr']:.0f} read calls, {m['new_kb']:.0f} KB)  OS cold "
                  f"{m['cold']:.3f}, wall {m['cold_wall']:.2f} ({m['cold_syscr']:.0f} read "
                  f"calls, {m['cold_kb']:.0f} KB)")
        small, large = med[sizes[0]], med[sizes[1]]
        print(f"  {name:12s} ratio {sizes[1]} / {sizes[0]}: warm "
              f"{large['warm'] / small['warm']:.2f}, its SQL {large['sql'] / small['sql']:.2f},"
              f" new connection {large['new'] / small['new']:.2f}, OS cold "
              f"{large['cold'] / small['cold']:.2f} (wall "
              f"{large['cold_wall'] / small['cold_wall']:.2f})")
    for rows, db in dbs.items():
        print(f"  history B-tree at {rows} rows ({os.path.getsize(db) / 2**20:.0f} MB): "
              f"{btree(db)}")
    print(f"# load average at end {os.getloadavg()[0]:.1f}")
    if not args.keep:
        for db in dbs.values():
            for suffix in ("", "-wal", "-shm"):
                Path(db + suffix).unlink(missing_ok=True)


if __name__ == "__main__":
    main()
