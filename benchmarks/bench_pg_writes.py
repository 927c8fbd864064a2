"""Benchmark: the ways to send a batch's rows to PostgreSQL (docs/service-load.md,
"PostgreSQL ingest").

A batch's writes on PostgreSQL are its ``components`` rows (an upsert of one row per
component: tracker state, RUL columns, five indexes) and its packed history rows
(:mod:`rulkit.fleet.store.history_chunks`). The rows here are a real batch's: ``--size``
components ingested through the store once, their rows captured; each way then writes them
again ``--repeats`` times, the ways in turns, each time with every component's ``t``, ``seen``
and ``rul_median`` moved (so that every index changes, as in a new batch) and its history
rows at new times, one transaction per write. Prints, per way, the median over the repeats of
this process's CPU and of the connection's PostgreSQL backend's CPU (``/proc``), per row,
and their sum's ratio to the store's way.

    .venv/bin/python benchmarks/bench_pg_writes.py                 # sizes 100 and 1000
    .venv/bin/python benchmarks/bench_pg_writes.py --sizes 1000 --repeats 41

The CPU is counted in the kernel's clock ticks (10 ms): a write of 100 rows takes less than
one, so each timed write is ``--inner`` writes of the batch's rows, each in its own
transaction.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np
import pandas as pd

from rulkit.fleet.service.pgtemp import TempPostgres, unavailable_reason
from rulkit.fleet.store import history_chunks
from rulkit.fleet.store.postgres import PgComponentStore
from rulkit.fleet.store.sqlite import ComponentStore

Rows = tuple[list[tuple], tuple[str, ...]]


def captured_rows(store: PgComponentStore, size: int, steps: int
                  ) -> tuple[Rows, list[tuple]]:
    """A batch of ``size`` new components (``steps`` acquisitions each) ingested through
    ``store``: its ``components`` rows (with the extra column names) and history rows."""
    got: dict[str, Any] = {}
    write_states, write_history = store._write_states, store._write_history

    def keep_states(rows: list[tuple], extra: tuple[str, ...] = ()) -> None:
        got["states"] = (list(rows), extra)
        write_states(rows, extra)

    def keep_history(rows: list[tuple]) -> None:
        got.setdefault("history", []).extend(rows)
        write_history(rows)

    store._write_states = keep_states  # type: ignore[method-assign]
    store._write_history = keep_history  # type: ignore[method-assign]
    # the rows as tuples (the base store's way), through keep_states
    store._write_components = partial(  # type: ignore[method-assign]
        ComponentStore._write_components, store)
    rng = np.random.default_rng(0)
    t = np.tile(np.arange(steps, dtype=float), size)
    hi = np.repeat(rng.uniform(0.1, 0.6, size), steps) + 0.01 * t
    store.ingest(pd.DataFrame({"component": np.repeat([f"u{i:06d}" for i in range(size)],
                                                      steps), "time": t, "hi": hi}))
    store._write_states, store._write_history = write_states, write_history  # type: ignore
    del store._write_components
    return got["states"], [(c, a, b, n, i, bytes(d)) for c, a, b, n, i, d in got["history"]]


def moved(states: Rows, k: int) -> Rows:
    """The rows with ``t``, ``seen`` and ``rul_median`` moved by ``k``."""
    rows, extra = states
    cols = ("component", *_state_names(extra))
    at = {c: cols.index(c) for c in ("t", "seen", "rul_median") if c in cols}
    out = []
    for r in rows:
        r = list(r)
        for j in at.values():
            if r[j] is not None:
                r[j] = r[j] + k
        out.append(tuple(r))
    return out, extra


def _state_names(extra: tuple[str, ...]) -> tuple[str, ...]:
    from rulkit.fleet.store.tracker_rows import ROW_FIELDS

    return (*ROW_FIELDS, "max_level", *extra)


def history_at(rows: list[tuple], k: int) -> list[tuple]:
    """The history rows at times moved past every earlier write's."""
    return [(c, a + 1e6 * k, b + 1e6 * k, n, i, d) for c, a, b, n, i, d in rows]


def backend_seconds(pid: int) -> float:
    """User + system CPU seconds of the PostgreSQL backend ``pid`` so far."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


# ---------------------------------------------------------------- the candidate ways
def upsert_sql(cols: tuple[str, ...], source: str) -> str:
    updates = ", ".join(f"{c} = excluded.{c}" for c in cols[1:])
    return (f"INSERT INTO components ({', '.join(cols)}) {source} "
            f"ON CONFLICT (component) DO UPDATE SET {updates}")


def states_executemany(store: PgComponentStore, states: Rows) -> None:
    """One ``INSERT ... ON CONFLICT`` per row through psycopg's ``executemany`` (the SQLite
    store's write)."""
    ComponentStore._write_states(store, *states)


def states_store(store: PgComponentStore, states: Rows) -> None:
    """The store's own write (:meth:`PgComponentStore._write_states`)."""
    store._write_states(*states)


def states_store_update(store: PgComponentStore, states: Rows) -> None:
    """The store's own write of stored components (:meth:`PgComponentStore._update_states`:
    COPY binary, one ``UPDATE ... FROM``; the rows' reordering, key last, timed with it)."""
    rows, extra = states
    store._update_states([(*r[1:], r[0]) for r in rows], extra)


def _unnest(fmt: str) -> Callable[[PgComponentStore, Rows], None]:
    def write(store: PgComponentStore, states: Rows) -> None:
        rows, extra = states
        cols = ("component", *_state_names(extra))
        types = column_types(store)
        arrays = [list(c) for c in zip(*rows, strict=True)]
        source = "SELECT * FROM unnest(" + ", ".join(
            f"%{fmt}::{types[c]}[]" for c in cols) + ")"
        store._conn.raw.cursor().execute(upsert_sql(cols, source), arrays)
    write.__doc__ = f"One statement, one array per column (unnest), parameters as %{fmt}."
    return write


def _stage(store: PgComponentStore, states: Rows, binary: bool) -> tuple[Any, tuple[str, ...]]:
    """The rows copied into the temporary table ``bench_in``; (the cursor, the columns)."""
    rows, extra = states
    cols = ("component", *_state_names(extra))
    cur = store._conn.raw.cursor()
    cur.execute("CREATE TEMP TABLE IF NOT EXISTS bench_in (LIKE components) "
                "ON COMMIT DELETE ROWS")
    types = column_types(store)
    fmt = " (FORMAT BINARY)" if binary else ""
    with cur.copy(f"COPY bench_in ({', '.join(cols)}) FROM STDIN{fmt}") as copy:
        if binary:
            copy.set_types([types[c] for c in cols])
        for r in rows:
            copy.write_row(r)
    return cur, cols


def copy_merge(store: PgComponentStore, states: Rows) -> None:
    """COPY binary into a temporary table, one MERGE (update the matched, insert the rest)."""
    cur, cols = _stage(store, states, binary=True)
    sets = ", ".join(f"{c} = b.{c}" for c in cols[1:])
    cur.execute(f"MERGE INTO components c USING bench_in b ON c.component = b.component "
                f"WHEN MATCHED THEN UPDATE SET {sets} WHEN NOT MATCHED THEN INSERT "
                f"({', '.join(cols)}) VALUES ({', '.join('b.' + c for c in cols)})")


def _copy_temp(binary: bool) -> Callable[[PgComponentStore, Rows], None]:
    def write(store: PgComponentStore, states: Rows) -> None:
        cur, cols = _stage(store, states, binary)
        cur.execute(upsert_sql(cols, f"SELECT {', '.join(cols)} FROM bench_in"))
    write.__doc__ = ("COPY " + ("binary" if binary else "text") + " into a temporary table, "
                     "one INSERT ... SELECT ... ON CONFLICT")
    return write


def column_types(store: PgComponentStore) -> dict[str, str]:
    """PostgreSQL's type of each column of ``components``."""
    got = store._conn.execute(
        "SELECT attname, format_type(atttypid, atttypmod) FROM pg_attribute WHERE attrelid "
        "= 'components'::regclass AND attnum > 0 AND NOT attisdropped").fetchall()
    return {a: t for a, t in got}


def history_copy(binary: bool) -> Callable[[PgComponentStore, list[tuple]], None]:
    def write(store: PgComponentStore, rows: list[tuple]) -> None:
        fmt = " (FORMAT BINARY)" if binary else ""
        with store._conn.raw.cursor() as cur, cur.copy(
                f"COPY history ({', '.join(history_chunks.COLUMNS)}) FROM STDIN{fmt}") as copy:
            if binary:
                copy.set_types(["text", "float8", "float8", "int8", "int8", "bytea"])
            for r in rows:
                copy.write_row(r)
    write.__doc__ = "COPY " + ("binary" if binary else "text")
    return write


def history_store(store: PgComponentStore, rows: list[tuple]) -> None:
    """The store's own write (:meth:`PgComponentStore._write_history`)."""
    store._write_history(rows)


def history_executemany(store: PgComponentStore, rows: list[tuple]) -> None:
    """One INSERT per row through psycopg's ``executemany`` (the SQLite store's write)."""
    ComponentStore._write_history(store, rows)


def history_unnest(store: PgComponentStore, rows: list[tuple]) -> None:
    """One INSERT of arrays (unnest), binary parameters."""
    arrays = [list(c) for c in zip(*rows, strict=True)]
    store._conn.raw.cursor().execute(
        f"INSERT INTO history ({', '.join(history_chunks.COLUMNS)}) SELECT * FROM unnest("
        "%b::text[], %b::float8[], %b::float8[], %b::int8[], %b::int8[], %b::bytea[])", arrays)


STATE_WAYS: dict[str, Callable[[PgComponentStore, Rows], None]] = {
    "executemany": states_executemany, "unnest %s": _unnest("s"), "unnest %b": _unnest("b"),
    "copy text + insert": _copy_temp(False), "copy binary + insert": _copy_temp(True),
    "copy binary + merge": copy_merge, "store: copy binary + insert": states_store,
    "store: copy binary + update": states_store_update}
HISTORY_WAYS: dict[str, Callable[[PgComponentStore, list[tuple]], None]] = {
    "executemany": history_executemany, "copy text": history_copy(False),
    "unnest %b": history_unnest, "store (copy binary)": history_store}


def measure(url: str, size: int, steps: int, repeats: int, inner: int) -> None:
    """Each way's CPU per row in turns (see the module docstring)."""
    with PgComponentStore(url) as store:
        states, hist = captured_rows(store, size, steps)
        pid = int(store._conn.execute("SELECT pg_backend_pid()").fetchone()[0])
        k = 0
        for label, ways, kind in (("components", STATE_WAYS, "states"),
                                  ("history", HISTORY_WAYS, "history")):
            cpu: dict[str, list[tuple[float, float]]] = {w: [] for w in ways}
            for _ in range(repeats):
                for name, way in ways.items():
                    args = []
                    for _ in range(inner):
                        k += 1
                        args.append(moved(states, k) if kind == "states"
                                    else history_at(hist, k))
                    c0, b0 = time.process_time(), backend_seconds(pid)
                    for a in args:
                        with store._transaction("IMMEDIATE"):
                            way(store, a)  # type: ignore[arg-type]
                    cpu[name].append((time.process_time() - c0, backend_seconds(pid) - b0))
            n = (len(states[0]) if kind == "states" else len(hist)) * inner
            base = None
            for name in ways:
                client = float(np.median([c for c, _ in cpu[name]])) / n * 1e6
                server = float(np.median([s for _, s in cpu[name]])) / n * 1e6
                base = base or client + server
                print(f"  {label} batch={size} {name:22s} client {client:6.2f} us, PostgreSQL "
                      f"{server:6.2f} us per row; sum {client + server:6.2f} us "
                      f"({(client + server) / base:.2f} of the first)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[100, 1000])
    ap.add_argument("--steps", type=int, default=1,
                    help="Acquisitions per component and batch (the service's load: 1).")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--inner", type=int, default=0,
                    help="Writes per timed write (default: 5,000 rows' worth).")
    args = ap.parse_args()
    reason = unavailable_reason()
    if reason:
        raise SystemExit(f"postgresql: {reason}")
    print(f"# bench_pg_writes: {os.cpu_count()} cores, load average "
          f"{os.getloadavg()[0]:.1f} at start; medians of {args.repeats} repeats, ways in turns")
    with TempPostgres() as pg:
        for size in args.sizes:
            inner = args.inner or max(1, 5_000 // size)
            measure(pg.create_database(f"b{size}"), size, args.steps, args.repeats, inner)
    print(f"load average at end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
