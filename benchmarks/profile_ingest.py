"""Where one ``POST /api/v1/acquisitions`` batch spends its CPU (docs/service-load.md):
the service's ASGI app called in this process (no sockets, no client, no readers) on a new
SQLite database, with the batches bench_service.py sends (``writer_batch``: 8 writers, one
acquisition per component per batch, ``--batches`` batches each, in turns).

Prints, per body type (JSON, CSV, Parquet) and per batch, the CPU time of the whole request
and of its stages, each timed by a wrapper around the function that does it (a few
microseconds of timer per call): the body's columns (``batch_frame``), validation, and the
store's write transaction split into the stored rows' read, the duplicate check, the
trackers, the estimator and rules (of which the RUL quantiles), the history rows, the
components upsert, the level counts, the ingests row, the alerts and the rest (transaction,
savepoint, commit and its sync); the framework's share (routing, the token check, the
response) is the request's CPU less the stages. It also counts the SQL statements one batch
executes (SQLite's trace callback: every execution, so an ``executemany`` of 100 rows counts
100), by kind, over one more round of batches that is not timed (the callback builds each
execution's SQL text in Python). Beside the stages it prints the CPU of every statement the
writer's connection executes (its ``execute`` and ``executemany`` timed through a proxy:
SQLite's own work, most of it in ``sqlite3_step``, which runs without the interpreter lock,
and the binding of the values), the SQL's floor per acquisition.

    .venv/bin/python benchmarks/profile_ingest.py --batches 20
"""

from __future__ import annotations

import argparse
import asyncio
import io
import json
import os
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd

sys.path.insert(0, str(Path(__file__).parent))
from timing import stage_depth, stage_owner

BODY_TYPES = {"json": "application/json", "csv": "text/csv",
              "parquet": "application/vnd.apache.parquet"}
STAGES = (
    ("body", "rulkit.fleet.service.routes_acquisitions", "batch_frame"),
    ("validation", "rulkit.fleet.service.db", "validate_acquisitions"),
    ("write transaction", "rulkit.fleet.service.db.ServiceDB", "_commit"),
    ("  stored rows read", "rulkit.fleet.store.sqlite.ComponentStore", "_load_states"),
    ("  duplicate check", "rulkit.fleet.store.sqlite", "split_duplicates"),
    ("  apply", "rulkit.fleet.store.sqlite.ComponentStore", "_apply"),
    ("    trackers", "rulkit.fleet.store.sqlite", "tracker_run"),
    ("    estimator set-up", "rulkit.fleet.store.prognosis", "current_estimator"),
    ("    estimator and rules", "rulkit.fleet.store.prognosis.BatchPrognosis", "block"),
    ("      RUL quantiles", "rulkit.fleet.store.prognosis", "rul_quantiles"),
    ("    final columns", "rulkit.fleet.store.prognosis.BatchPrognosis", "finish"),
    ("    history rows", "rulkit.fleet.store.sqlite.ComponentStore", "_write_block_history"),
    ("    components upsert", "rulkit.fleet.store.sqlite.ComponentStore", "_write_states"),
    ("    components update", "rulkit.fleet.store.sqlite.ComponentStore", "_update_states"),
    ("    level counts", "rulkit.fleet.store.sqlite", "add_level_counts"),
    ("    ingests row", "rulkit.fleet.store.sqlite.ComponentStore", "_insert_ingest"),
    ("  alerts", "rulkit.fleet.store.sqlite.ComponentStore", "_record_alerts"),
)
"""(label, where the name is looked up, name): the stages timed. Indented ones are inside
the write transaction."""


def instrument(totals: Counter[str]) -> None:
    """Wrap every stage's function so its CPU time adds to ``totals[label]``."""
    for label, where, name in STAGES:
        owner = stage_owner(where)
        fn = getattr(owner, name)

        def timed(*a: Any, _fn: Callable[..., Any] = fn, _label: str = label,
                  **k: Any) -> Any:
            t0 = time.process_time()
            try:
                return _fn(*a, **k)
            finally:
                totals[_label] += time.process_time() - t0

        setattr(owner, name, timed)


class TimedConnection:
    """A connection whose ``execute`` and ``executemany`` add their CPU time to
    ``totals["SQL"]``; everything else is the wrapped connection's."""

    def __init__(self, conn: Any, totals: Counter[str]) -> None:
        self._wrapped, self._totals = conn, totals

    def __getattr__(self, name: str) -> Any:
        return getattr(self._wrapped, name)

    def _timed(self, method: str, *a: Any) -> Any:
        t0 = time.process_time()
        try:
            return getattr(self._wrapped, method)(*a)
        finally:
            self._totals["SQL"] += time.process_time() - t0

    def execute(self, *a: Any) -> Any:
        return self._timed("execute", *a)

    def executemany(self, *a: Any) -> Any:
        return self._timed("executemany", *a)


def body_bytes(rows: list[dict[str, Any]], kind: str) -> bytes:
    """One batch as the body of ``kind``."""
    if kind == "json":
        return json.dumps({"rows": rows}).encode()
    df = pd.DataFrame(rows)
    if kind == "csv":
        return df.to_csv(index=False).encode()
    buf = io.BytesIO()
    df.to_parquet(buf, index=False)
    return buf.getvalue()


def _post(app: Any, token: str, body: bytes, ctype: str) -> None:
    async def run() -> None:
        scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1",
                 "method": "POST", "scheme": "http", "path": "/api/v1/acquisitions",
                 "raw_path": b"/api/v1/acquisitions", "query_string": b"", "root_path": "",
                 "client": ("127.0.0.1", 1), "server": ("127.0.0.1", 80),
                 "headers": [(b"host", b"x"), (b"content-type", ctype.encode()),
                             (b"content-length", str(len(body)).encode()),
                             (b"authorization", f"Bearer {token}".encode())]}
        out: list[dict[str, Any]] = []

        async def receive() -> dict[str, Any]:
            return {"type": "http.request", "body": body, "more_body": False}

        async def send(message: dict[str, Any]) -> None:
            out.append(message)

        await app(scope, receive, send)
        if out[0]["status"] != 200:
            raise SystemExit(f"POST: {out[0]['status']} {out[1].get('body')!r}")

    asyncio.run(run())


def profile(kind: str, args: argparse.Namespace, tmp: str, totals: Counter[str]) -> None:
    from rulkit.fleet.service.app import create_app
    from rulkit.fleet.service.db import ServiceDB
    from rulkit.fleet.service.loadgen import writer_batch

    sdb = ServiceDB(str(Path(tmp) / f"{kind}.db"))
    _, token = sdb.create_token("write", "profile")
    app = create_app(sdb)
    statements: list[str] = []  # classified after the run: the callback stays cheap
    bodies = [body_bytes(writer_batch(w, k, args.batch_size), kind)
              for k in range(args.batches + 1) for w in range(args.writers)]
    traced = bodies[-args.writers:]  # one more round, its statements counted, not timed
    bodies = bodies[:-args.writers]
    for b in bodies[:args.writers]:  # the first batch creates the components: not timed
        _post(app, token, b, BODY_TYPES[kind])
    writer = getattr(sdb, "_writer", None)  # the group commits' own connection, if any
    if writer is not None:
        writer._conn = TimedConnection(writer._conn, totals)
    totals.clear()
    t0 = time.process_time()
    for b in bodies[args.writers:]:
        _post(app, token, b, BODY_TYPES[kind])
    whole = (time.process_time() - t0)
    n = len(bodies) - args.writers
    ms = {k: v / n * 1e3 for k, v in totals.items()}
    ms["whole request"] = whole / n * 1e3
    # SQLite's trace callback builds every execution's SQL with its values in Python (a
    # string of 27 values per components row): it doubled the timed stages' SQL when it ran
    # during the timed batches
    with sdb.store() as s:  # one thread: the pool hands out this connection every time
        s._conn.set_trace_callback(statements.append)
    if writer is not None:
        writer._conn = writer._conn._wrapped
        writer._conn.set_trace_callback(statements.append)
    for b in traced:
        _post(app, token, b, BODY_TYPES[kind])
    sdb.close()
    kinds: Counter[str] = Counter()
    for sql, count in Counter(statements).items():
        kinds[_kind(sql)] += count
    _print(kind, n, len(traced), args.batch_size, ms, kinds)


def _kind(sql: str) -> str:
    words = sql.split()
    head = " ".join(words[:1]).upper()
    for w in ("FROM", "INTO", "UPDATE"):
        if w in (x.upper() for x in words[:6]):
            i = [x.upper() for x in words].index(w)
            return f"{head} {words[i + 1] if w != 'UPDATE' else words[1]}"
    return head


def _print(kind: str, n: int, n_traced: int, size: int, ms: dict[str, float],
           statements: Counter[str]) -> None:
    whole = ms["whole request"]
    print(f"\n{kind} body, {n} batches of {size}: {whole:.2f} ms of CPU per batch "
          f"({whole / size * 1e3:.0f} us per acquisition)")
    labels = [label for label, _, _ in STAGES]
    for j, label in enumerate(labels):
        v = ms.get(label, 0.0)
        print(f"  {label:26s} {v:6.2f} ms  {v / whole:5.1%}")
        d = stage_depth(label)
        kids = []  # its direct children follow it, one level deeper
        for other in labels[j + 1:]:
            if stage_depth(other) <= d:
                break
            if stage_depth(other) == d + 1:
                kids.append(other)
        if kids:
            rest = v - sum(ms.get(k, 0.0) for k in kids)
            print(f"  {'  ' * (d + 1) + 'the rest':26s} {rest:6.2f} ms  {rest / whole:5.1%}"
                  + ("  (BEGIN, savepoint, COMMIT and its sync)" if d == 0 else ""))
    outer = sum(ms.get(label, 0.0) for label in labels if stage_depth(label) == 0)
    print(f"  {'framework and token':26s} {whole - outer:6.2f} ms  "
          f"{(whole - outer) / whole:5.1%}  (routing, the token check, the response)")
    sql = ms.get("SQL", 0.0)
    print(f"  {'SQL (writer, all stages)':26s} {sql:6.2f} ms  {sql / whole:5.1%}  "
          f"({sql / size * 1e3:.1f} us per acquisition; the rest "
          f"{(whole - sql) / size * 1e3:.1f} us, under one interpreter lock)")
    per = {k: v / n_traced for k, v in statements.items()}
    print(f"  SQL statements executed per batch (another {n_traced} batches, traced, not "
          f"timed): {sum(per.values()):.1f}: "
          + ", ".join(f"{k} {v:.1f}" for k, v in sorted(per.items(), key=lambda x: -x[1])))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--batches", type=int, default=20, help="Batches per writer.")
    ap.add_argument("--writers", type=int, default=8)
    ap.add_argument("--batch-size", type=int, default=100)
    ap.add_argument("--body", nargs="+", default=list(BODY_TYPES), choices=list(BODY_TYPES))
    args = ap.parse_args()
    import fastapi.concurrency
    import fastapi.routing

    async def inline(func: Any, *a: Any, **k: Any) -> Any:
        return func(*a, **k)

    # one thread: the profiler's timers and the trace callback see the whole request
    fastapi.routing.run_in_threadpool = inline  # type: ignore[assignment]
    import rulkit.fleet.service.routes_acquisitions as app_module

    app_module.run_in_threadpool = inline  # type: ignore[assignment]
    print(f"# profile_ingest: {args.writers} writers x {args.batches} batches of "
          f"{args.batch_size} in turns, in process; load average {os.getloadavg()[0]:.1f}")
    totals: Counter[str] = Counter()
    instrument(totals)
    with tempfile.TemporaryDirectory(prefix="rulkit-profile-") as tmp:
        for kind in args.body:
            profile(kind, args, tmp, totals)


if __name__ == "__main__":
    main()
