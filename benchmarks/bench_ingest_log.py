"""A measurement, not a design in use: the write floor of the service's ingest today beside the
floor of a durable per-batch log with the ``components`` rows and the history materialised
behind it in bulk (docs/service-load.md, "How far the goals remain").

Three ways to write the same acquisitions (``writer_batch``: 8 writers, one acquisition per
component per batch, as bench_service.py sends them) into new SQLite databases of the store's
schema, through the store's own connection (WAL, ``synchronous=FULL``), CPU of this one
thread per acquisition, the median of ``--repeats``:

* **today**: per batch one transaction: one packed history row per component (one
  acquisition each) and one upsert per component of its ``components`` row (the pages' three
  secondary indexes) - what bench_service.py calls the bare writes;
* **log append**: per batch one transaction holding one row of a log table: a blob of the
  batch's acquisitions (the history's packed records) and its components' new rows (the
  ``components`` columns as float64) and their names - what would be durable before the 200;
* **materialise every c batches**: the components' rows and history of ``c`` batches of each
  writer written at once: one packed history row of ``c`` acquisitions and one upsert per
  component, and the log rows deleted - the work behind the log, coalesced.

The log design's write floor per acquisition is the append plus the materialisation divided
over its ``c`` batches. What it leaves out, and a design must add: computing the new rows
(trackers, estimator and rules), the reads that must overlay the log's tail or materialise it
first (pages, history, ``rulkit status`` in other processes), and the recovery that replays
the log after a crash.

    .venv/bin/python benchmarks/bench_ingest_log.py --batch-size 1000
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from rulkit.fleet.service.loadgen import writer_batch
from rulkit.fleet.store import history_chunks as hc
from rulkit.fleet.store.schema import COMPONENTS
from rulkit.fleet.store.sqlite import ComponentStore

CCOLS = COMPONENTS.names
UPSERT = (f"INSERT INTO components ({', '.join(CCOLS)}) VALUES ({', '.join('?' * len(CCOLS))}) "
          "ON CONFLICT(component) DO UPDATE SET "
          + ", ".join(f"{c} = excluded.{c}" for c in CCOLS[1:]))
LOG = "CREATE TABLE IF NOT EXISTS ingest_log (id INTEGER PRIMARY KEY, data BLOB NOT NULL)"


def batch_arrays(w: int, k: int, size: int) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Writer ``w``'s batch ``k``: component names, packed history records (one per
    component) and the components' new rows (float64, the columns after ``component``)."""
    rows = writer_batch(w, k, size)
    names = [r["component"] for r in rows]
    hi = np.array([r["hi"] for r in rows])
    rec = np.repeat(hi[:, None], hc.WIDTH, axis=1)
    rec[:, 0] = float(k)
    state = np.repeat(hi[:, None], len(CCOLS) - 1, axis=1)
    for j, c in enumerate(CCOLS[1:]):
        if c == "t":
            state[:, j] = float(k)
        elif c in ("n", "hits"):
            state[:, j] = k + 1
        elif c in ("level", "max_level", "valid"):
            state[:, j] = 0
    return names, rec, state


def component_rows(names: list[str], state: np.ndarray) -> list[tuple]:
    """``components`` rows for the upsert (integers where the column is one)."""
    ints = [j for j, c in enumerate(CCOLS[1:]) if c in ("n", "hits", "level", "max_level",
                                                         "valid")]
    cols: list[list] = [names]
    for j in range(state.shape[1]):
        cols.append(state[:, j].astype(np.int64).tolist() if j in ints
                    else state[:, j].tolist())
    return list(zip(*cols, strict=True))


def today(store: ComponentStore, batches: list) -> None:
    for names, rec, state in batches:
        with store._transaction("IMMEDIATE") as conn:
            store._write_history(hc.chunk_rows(names, np.arange(len(names) + 1), rec, 1))
            conn.executemany(UPSERT, component_rows(names, state))


def log_append(store: ComponentStore, batches: list) -> None:
    for names, rec, state in batches:
        blob = b"".join((np.int64(len(names)).tobytes(), rec.tobytes(), state.tobytes(),
                         "\x00".join(names).encode()))
        with store._transaction("IMMEDIATE") as conn:
            conn.execute("INSERT INTO ingest_log (data) VALUES (?)", (blob,))


def materialise(store: ComponentStore, batches: list, c: int, writers: int) -> None:
    """Every ``c`` rounds of the writers' batches: each component's ``c`` acquisitions in one
    history row and its last state in one upsert, the log emptied, in one transaction."""
    for r0 in range(0, len(batches), c * writers):
        group = batches[r0:r0 + c * writers]
        with store._transaction("IMMEDIATE") as conn:
            for w in range(writers):
                mine = group[w::writers]
                names = mine[0][0]
                rec = np.stack([b[1] for b in mine], axis=1).reshape(-1, hc.WIDTH)
                seg = np.arange(len(names) + 1) * len(mine)
                store._write_history(hc.chunk_rows(names, seg, rec, 1))
                conn.executemany(UPSERT, component_rows(names, mine[-1][2]))
            conn.execute("DELETE FROM ingest_log")


def timed(fn, *a) -> float:
    t0 = time.process_time()
    fn(*a)
    return time.process_time() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--writers", type=int, default=8)
    ap.add_argument("--batches", type=int, default=64, help="Batches per writer, timed.")
    ap.add_argument("--batch-size", type=int, default=1000)
    ap.add_argument("--coalesce", type=int, nargs="+", default=[1, 4, 16, 64])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    print(f"# bench_ingest_log: {args.writers} writers x {args.batches} batches of "
          f"{args.batch_size}, SQLite; load average {os.getloadavg()[0]:.1f}")
    first = [batch_arrays(w, 0, args.batch_size) for w in range(args.writers)]
    timed_batches = [batch_arrays(w, k, args.batch_size) for k in range(1, args.batches + 1)
                     for w in range(args.writers)]
    n = len(timed_batches) * args.batch_size
    res: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory(prefix="rulkit-log-") as tmp:
        for rep in range(args.repeats):
            runs = [("today", today, ()), ("log append", log_append, ())]
            runs += [(f"materialise every {c}", materialise, (c, args.writers))
                     for c in args.coalesce]
            for label, fn, extra in runs:
                with ComponentStore(Path(tmp) / f"{rep}-{label}.db") as store:
                    store._conn.execute(LOG)
                    today(store, first)  # the components exist, as in the service's load
                    res.setdefault(label, []).append(timed(fn, store, timed_batches, *extra)
                                                     / n * 1e6)
    med = {k: statistics.median(v) for k, v in res.items()}
    for label, v in med.items():
        print(f"  {label:24s} {v:6.2f} us of CPU per acquisition")
    print(f"  log design's write floor (append + materialisation over c batches) against "
          f"today's {med['today']:.2f} us:")
    for c in args.coalesce:
        floor = med["log append"] + med[f"materialise every {c}"]
        print(f"    c = {c:3d}: {floor:6.2f} us (ratio {floor / med['today']:.2f})")
    print(f"load average at end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
