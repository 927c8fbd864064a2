"""Benchmark: the fleet service over HTTP on loopback (docs/service-load.md).

For each backend (SQLite file; PostgreSQL: a throwaway server from the installed binaries):

1. **Ingest.** ``rulkit serve`` in a subprocess; ``--writers`` threads each POST ``--batches``
   JSON batches of each ``--batch-sizes`` (one acquisition per component, distinct components
   per writer) while ``--readers`` threads poll ``GET /api/v1/components?limit=50`` (every
   request's bytes built before the clock starts: :func:`~rulkit.fleet.service.loadgen.run_load`;
   ``--readers 0``: the 8 writers alone, the goals' setup). Prints
   acquisitions/s (wall time until the last writer is done), the service's CPU time per
   acquisition (GETs included; the figure that does not depend on other jobs on the
   machine), p50/p99 latencies, then checks every acquisition is stored exactly once.
2. **Pages at scale.** A database of ``--components`` components (3 acquisitions each,
   filled through the store: every alert level, due dates, half of them stale), then
   ``--readers`` threads x ``--reads`` requests of each page: every sort (worst, rul, due) x
   level filter (all, alarm, ok, stale) x depth (first page, middle and 99 % deep by
   cursor), then the middle page by ``offset``, each request a different page of its kind
   (shifted one component at a time: none is answered from the service's page cache);
   PostgreSQL's fill ends with VACUUM ANALYZE (what autovacuum does to a freshly loaded
   table). Prints p50/p99 and service CPU per
   request after ``--warmup`` requests per reader (their worst latency printed apart), the
   worst p99 of the pages by cursor and how many are under 50 ms, and the full collections of
   Python's garbage collector in the service meanwhile (its ``/metrics``). With ``--against
   SRC`` a second server of that checkout's code serves the same database, each page
   measured on both in turns.
3. **History reads.** ``GET /api/v1/components/{id}/history?limit=1000`` on a database of
   ``--history-rows`` rows and on one of 1 % of them, served at once and read in turns: the
   service's CPU per read (median of ``--turns`` turns) and the p50 of each, and their ratios
   (flat = 1). Where a read's time goes in process: benchmarks/bench_history_read.py.

Every figure is a median or percentile of one run; the load average at start and end is
printed, since client and server share the machine's 2 cores with other jobs. Loopback only;
every loop is bounded by its request count.

    .venv/bin/python benchmarks/bench_service.py                  # both backends, minutes
    .venv/bin/python benchmarks/bench_service.py --quick          # a smoke run
    .venv/bin/python benchmarks/bench_service.py --backend sqlite --batch-sizes 1000
    git archive main src | tar -x -C /tmp/main     # the ingest against main's code, in turns:
    .venv/bin/python benchmarks/bench_service.py --skip pages history --against /tmp/main/src
"""

from __future__ import annotations

import argparse
import http.client
import math
import os
import platform
import shutil
import tempfile
import threading
import time
from collections.abc import Callable
from contextlib import ExitStack
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from rulkit.fleet.monitoring.rules import MonitoringRules
from rulkit.fleet.service.db import ServiceDB
from rulkit.fleet.service.loadgen import (
    request,
    run_load,
    start_server,
    verify_exactly_once,
    writer_batch,
)
from rulkit.fleet.service.pgtemp import TempPostgres, unavailable_reason
from rulkit.fleet.store.postgres import open_store

GET_SAMPLE = 50
"""GETs of the pollers' page timed alone after the ingest phase (their CPU each)."""


def write_phase(db: str, args: argparse.Namespace, batch_size: int,
                src: Path | None = None, db_cpu: Callable[[], float] | None = None
                ) -> dict[str, float]:
    """The ingest load on a new database ``db``, served by this code or, with ``src``, by
    that checkout's ``src`` directory (``PYTHONPATH``); ``db_cpu``: the database server's
    CPU seconds so far (PostgreSQL's processes), counted over the load."""
    sdb = ServiceDB(db)
    _, token = sdb.create_token("write", "bench")
    sdb.close()
    srv = start_server(db, env=None if src is None else {"PYTHONPATH": str(src.resolve())})
    try:
        cpu0, client0, loop0 = srv.cpu_seconds(), time.process_time(), srv.loop_cpu_seconds()
        db0 = _cpu_or_nan(db_cpu)
        res = run_load(srv.port, token, writers=args.writers, readers=args.readers,
                       batches=args.batches, batch_size=batch_size,
                       max_reads=args.batches * 4)
        cpu, client = srv.cpu_seconds() - cpu0, time.process_time() - client0
        loop = srv.loop_cpu_seconds() - loop0
        db_s = _cpu_or_nan(db_cpu) - db0
        hits, misses = page_cache_counts(metrics_text(srv.port))  # the pollers' pages
        cpu1 = srv.cpu_seconds()  # the pollers' GET alone, to part it from the batches' CPU
        db1 = _cpu_or_nan(db_cpu)
        timed_reads(srv.port, token, "/api/v1/components?limit=50", 1, GET_SAMPLE)
        get_cpu = (srv.cpu_seconds() - cpu1) / GET_SAMPLE
        get_db = (_cpu_or_nan(db_cpu) - db1) / GET_SAMPLE
    finally:
        srv.stop()
    if res.errors:
        raise SystemExit(f"errors during the load: {res.errors[:5]}")
    verify_exactly_once(db, args.writers, args.batches, batch_size)
    return {**res.summary(), "server_cpu_s": cpu, "client_cpu_s": client,
            "get_cpu_s": get_cpu, "loop_cpu_s": loop, "cache_hits": hits,
            "cache_misses": misses, "db_cpu_s": db_s, "get_db_cpu_s": get_db}


def page_cache_counts(text: str) -> tuple[int, int]:
    """(hits, misses) of the service's page cache so far, by its ``/metrics`` text (0, 0 for
    a service without one, or on PostgreSQL)."""
    counts = {"hit": 0, "miss": 0}
    for outcome in counts:
        head = f'rulkit_page_cache_total{{outcome="{outcome}"}} '
        for line in text.splitlines():
            if line.startswith(head):
                counts[outcome] = int(float(line[len(head):]))
    return counts["hit"], counts["miss"]


def _cpu_or_nan(db_cpu: Callable[[], float] | None) -> float:
    """The database server's CPU seconds so far, or NaN (SQLite: no server)."""
    return math.nan if db_cpu is None else db_cpu()


def bare_floor(db: str, args: argparse.Namespace, batch_size: int,
               db_cpu: Callable[[], float] | None = None) -> dict[str, float]:
    """The hardware estimate under the ingest phase: the same acquisitions' rows written bare
    into a new database of the same schema, one transaction per batch as the service commits
    them (the store's own connection: WAL and synchronous=FULL on SQLite, the write lock on
    PostgreSQL): the packed history rows (one per component of the batch,
    :mod:`rulkit.fleet.store.history_chunks`) by the store's own history write
    (``executemany`` on SQLite, binary COPY on PostgreSQL), then the upsert of each
    component's row in ``components`` (tracker state and RUL columns, the five secondary
    indexes) by the store's own write (one statement per row on SQLite; on PostgreSQL a
    binary COPY and one statement, :meth:`~rulkit.fleet.store.postgres.PgComponentStore.
    _write_states`). No HTTP, no validation, no tracker, no rules; the rows' values are made
    before the clock starts (the history's packing is timed: the store's work). CPU of this
    process, and of the database server's processes by ``db_cpu`` (PostgreSQL)."""
    from rulkit.fleet.store import history_chunks as hc
    from rulkit.fleet.store.schema import COMPONENTS

    ccols = COMPONENTS.names
    extra = ccols[ccols.index("max_level") + 1:]  # _write_states' order: the table's
    batches = []
    for kb in range(args.batches):
        for w in range(args.writers):
            rows = writer_batch(w, kb, batch_size)
            rec = np.empty((len(rows), hc.WIDTH))
            rec[:] = np.array([r["hi"] for r in rows])[:, None]
            rec[:, 0] = [r["time"] for r in rows]
            batches.append(([r["component"] for r in rows], rec,
                            [tuple(_bare_value(c, r) for c in ccols) for r in rows]))
    with open_store(db) as store:
        cpu0, t0, db0 = time.process_time(), time.perf_counter(), _cpu_or_nan(db_cpu)
        for names, rec, comps in batches:
            hist = hc.chunk_rows(names, np.arange(len(names) + 1), rec, 1)
            with store._transaction("IMMEDIATE"):
                store._write_history(hist)
                store._write_states(comps, extra)
        cpu, wall = time.process_time() - cpu0, time.perf_counter() - t0
        db_s = _cpu_or_nan(db_cpu) - db0
    return {"cpu_s": cpu, "wall_s": wall, "db_cpu_s": db_s,
            "acquisitions": float(args.batches * args.writers * batch_size)}


def _bare_value(col: str, row: dict[str, Any]) -> Any:
    """A value of the column's type for the bare floor's rows (the acquisition's own
    component, time and HI; 1 or True in integer and boolean columns, the HI elsewhere)."""
    if col in ("component", "hi"):
        return row[col]
    if col == "t":
        return row["time"]
    if col == "valid":
        return True
    return 1 if col in ("n", "level", "ingest", "max_level", "hits") else row["hi"]


def fill(db: str, n: int, steps: int = 1, chunk: int = 200_000,
         rules: MonitoringRules | None = None) -> float:
    """``n`` components with ``steps`` acquisitions each, through the store; seconds. With
    ``rules``: those rules first, and the first half of the components acquired two days
    ago (stale under ``rules.stale_after`` of a day), the rest now."""
    rng = np.random.default_rng(0)
    t0, now = time.perf_counter(), time.time()  # the calendar time the service judges by
    with open_store(db) as store:
        if rules is not None:
            store.set_rules(rules)
        names = np.array([f"unit-{i:07d}" for i in range(n)], dtype=object)
        per = max(1, chunk // steps)
        for i0 in range(0, n, per):
            comp = names[i0:i0 + per]
            t = np.tile(np.arange(steps, dtype=float), len(comp))
            rate = np.repeat(rng.uniform(0.0, 0.15 / steps, len(comp)), steps)  # HI < 1.1
            hi = np.repeat(rng.uniform(0.1, 0.95, len(comp)), steps) + rate * t
            store.now = None if rules is None else now - (2 * 86400.0 if i0 < n // 2 else 0.0)
            store.ingest(pd.DataFrame({"component": np.repeat(comp, steps), "time": t,
                                       "hi": hi}), "bench-fill")
        if getattr(store, "dialect", "sqlite") == "postgresql":
            # what autovacuum does to freshly loaded tables, at once instead of when it wakes:
            # the planner's statistics, the visibility map and the hint bits
            store._conn.execute("VACUUM ANALYZE")
    return time.perf_counter() - t0


PAGE_RULES = MonitoringRules(time_unit="h", alarm_hi=0.95, lead_time=50.0,
                             stale_after=86400.0)
"""The rules of the pages' database: every level, due dates (hours), half of it stale."""
DEPTHS = {"first": None, "middle": 0.5, "deep": 0.99}
"""Page depths by cursor: the fraction of the matching components before the page."""


def _cursor(port: int, token: str, query: str, depth: float, room: int) -> str | None:
    """The cursor after ``depth`` of the matching components, moved back so that ``room``
    components follow it where the filter matches that many (one request by offset: its
    ``next``; ``None`` when nothing matches)."""
    _, body = request(port, "GET", f"/api/v1/components?limit=1&{query}", None, token)
    k = max(min(int(body["total"] * depth), body["total"] - 2 - room), 0)
    status, body = request(port, "GET", f"/api/v1/components?limit=1&offset={k}&{query}",
                           None, token, timeout=600.0)
    if status != 200:
        raise SystemExit(f"cursor request failed: {status} {body!r}")
    return body["next"]


def _cursors_from(port: int, token: str, query: str, start: str | None, n: int
                  ) -> list[str | None]:
    """``start`` and the cursors after each of the next ``n - 1`` components (one request of
    one component each), as far as the filter matches components."""
    from urllib.parse import quote

    out = [start]
    while len(out) < n:
        after = "" if out[-1] is None else f"&after={quote(out[-1])}"
        status, body = request(port, "GET", f"/api/v1/components?limit=1&{query}{after}",
                               None, token)
        if status != 200:
            raise SystemExit(f"cursor request failed: {status} {body!r}")
        if body["next"] is None:
            break
        out.append(body["next"])
    return out


def metrics_text(port: int) -> str:
    """The service's ``/metrics`` text."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    try:
        conn.request("GET", "/metrics")
        return conn.getresponse().read().decode()
    finally:
        conn.close()


def served_over(text: str, route: str, bound: str = "0.05") -> int:
    """Requests of ``route`` the service itself took longer than ``bound`` seconds to answer
    so far, by its ``/metrics`` text (the histogram from the app's first byte in to its last
    byte out, so without the client's time, the connection and uvicorn's HTTP parsing)."""
    head = f'rulkit_http_request_seconds_bucket{{method="GET",route="{route}",le='
    total = under = 0
    for line in text.splitlines():
        if line.startswith(head):
            le, n = line[len(head):].split("} ")
            if le == f'"{bound}"':
                under = int(n)
            elif le == '"+Inf"':
                total = int(n)
    return total - under


def gc_pauses(text: str, generation: int = 2) -> tuple[int, float]:
    """(collections, seconds) of the cyclic garbage collector's ``generation`` so far, by the
    service's ``/metrics`` text (0 for a service that does not time them)."""
    count, total = 0, 0.0
    for line in text.splitlines():
        if line.startswith(f'rulkit_gc_seconds_count{{generation="{generation}"}} '):
            count = int(line.rsplit(" ", 1)[1])
        elif line.startswith(f'rulkit_gc_seconds_sum{{generation="{generation}"}} '):
            total = float(line.rsplit(" ", 1)[1])
    return count, total


def page_kinds(port: int, token: str, n: int, need: int) -> list[tuple[str, list[str]]]:
    """(label, paths) of every page: sort x level filter x depth by cursor, then the middle
    page of the default order by offset. Each kind has ``need`` paths, one per request, each
    a different page: the page of its depth and the pages after it, shifted one component
    at a time (so that no request is answered from the service's page cache, which keys on
    the query); a filter matching fewer components repeats its pages."""
    from urllib.parse import quote

    kinds = []
    for sort in ("worst", "rul", "due"):
        for level in ("all", "alarm", "ok", "stale"):
            query = f"sort={sort}" + ("" if level == "all" else f"&level={level}")
            for depth, frac in DEPTHS.items():
                start = None
                if frac is not None:
                    start = _cursor(port, token, query, frac, need)
                    if start is None:
                        continue
                cursors = _cursors_from(port, token, query, start, need)
                paths = [f"/api/v1/components?limit=50&{query}"
                         + ("" if c is None else f"&after={quote(c)}") for c in cursors]
                kinds.append((f"{sort}/{level}/{depth}",
                              [paths[j % len(paths)] for j in range(need)]))
    kinds.append(("worst/all/middle_offset",
                  [f"/api/v1/components?limit=50&offset={n // 2 + j}" for j in range(need)]))
    return kinds


def measure_page(srv: Any, token: str, paths: list[str], args: argparse.Namespace
                 ) -> dict[str, float]:
    """One page's figures on server ``srv``: each reader's ``--warmup`` requests (their
    worst latency), then ``--readers`` x ``--reads`` timed ones: p50, p99, the service's CPU
    per request and busy fraction, the requests it served over 50 ms, its full garbage
    collections meanwhile."""
    n_warm = args.readers * args.warmup
    warm = timed_reads(srv.port, token, paths[:n_warm], args.readers, args.warmup) \
        if args.warmup else [math.nan]
    text = metrics_text(srv.port)
    over0, gc0 = served_over(text, "/api/v1/components"), gc_pauses(text)
    cpu0, wall0 = srv.cpu_seconds(), time.perf_counter()
    lat = timed_reads(srv.port, token, paths[n_warm:], args.readers, args.reads)
    cpu = srv.cpu_seconds() - cpu0
    busy = cpu / (time.perf_counter() - wall0)
    text = metrics_text(srv.port)
    gc1 = gc_pauses(text)
    return {"warmup_ms": max(warm) * 1e3, "cpu_ms": cpu / len(lat) * 1e3, "busy": busy,
            "served_over": served_over(text, "/api/v1/components") - over0,
            "gc2": gc1[0] - gc0[0], "gc2_ms": (gc1[1] - gc0[1]) * 1e3,
            "p50_ms": float(np.percentile(lat, 50)) * 1e3,
            "p99_ms": float(np.percentile(lat, 99)) * 1e3}


def pages_phase(db: str, args: argparse.Namespace) -> dict[str, Any]:
    """The figures of every page (:func:`page_kinds`, :func:`measure_page`) at
    ``--components``; with ``--against SRC``, a second server of that checkout's code on the
    same database, each page measured on both in turns (ours first)."""
    n = args.components
    out: dict[str, Any] = {"components": n,
                           "fill_s": fill(db, n, steps=3, rules=PAGE_RULES)}
    sdb = ServiceDB(db)
    _, token = sdb.create_token("read", "bench")
    sdb.close()
    servers = {"ours": start_server(db)}
    try:
        if args.against is not None:
            servers["theirs"] = start_server(db, env={"PYTHONPATH": str(args.against.resolve())})
        kinds = page_kinds(servers["ours"].port, token, n,
                           args.readers * (args.warmup + args.reads))
        for label, paths in kinds:
            for side, srv in servers.items():
                out[(side, label)] = measure_page(srv, token, paths, args)
    finally:
        for srv in servers.values():
            srv.stop()
    out["kinds"] = [k for k, _ in kinds]
    out["sides"] = list(servers)
    return out


def print_pages(backend: str, r: dict[str, Any], args: argparse.Namespace) -> None:
    """The pages' lines and, per side, the worst p99 by cursor and how many are under 50 ms."""
    cores = os.cpu_count() or 1
    print(f"pages at {int(r['components'])} components (filled in {r['fill_s']:.0f} s"
          + ("" if backend == "sqlite" else ", then VACUUM ANALYZE") +
          f"), {args.readers} readers x {args.reads} each after {args.warmup} warm-up "
          f"request(s) each (warm-up: their worst latency); load average "
          f"{os.getloadavg()[0]:.1f}" + ("" if args.against is None else
                                         f"; in turns with {args.against} (theirs)") + ":")
    print(f"  (queue: {args.readers} readers x service CPU per page / {cores} cores, the "
          "latency if the pages only waited for CPU; busy: service CPU / wall time, 1.0 = one "
          f"core; served > 50 ms: of the {args.readers * args.reads} timed requests, those the "
          "service's app itself took over 50 ms to answer, by its /metrics histogram; gc2: "
          "full collections of Python's garbage collector during them and their total pause, "
          "by its /metrics)")
    for kind in r["kinds"]:
        for side in r["sides"]:
            f = r[(side, kind)]
            name = kind if side == "ours" else "  " + side
            print(f"  {name:24s} p50 {f['p50_ms']:7.1f} ms  p99 {f['p99_ms']:7.1f} ms  service "
                  f"CPU {f['cpu_ms']:.2f} ms per request  queue "
                  f"{args.readers * f['cpu_ms'] / cores:.0f} ms  busy {f['busy']:.2f}  warm-up "
                  f"{f['warmup_ms']:.0f} ms  served > 50 ms {int(f['served_over'])}  gc2 "
                  f"{int(f['gc2'])} ({f['gc2_ms']:.1f} ms)")
    by_cursor = [k for k in r["kinds"] if "offset" not in k]
    med = {}
    for side in r["sides"]:
        worst = max(by_cursor, key=lambda k: r[(side, k)]["p99_ms"])
        med[side] = float(np.median([r[(side, k)]["cpu_ms"] for k in by_cursor]))
        under = sum(r[(side, k)]["p99_ms"] < 50.0 for k in by_cursor)
        print(f"  {side}: worst p99 over the {len(by_cursor)} pages by cursor "
              f"{r[(side, worst)]['p99_ms']:.1f} ms ({worst}; goal < 50 ms); {under} of "
              f"{len(by_cursor)} under 50 ms; median service CPU per page {med[side]:.2f} ms; "
              f"load average {os.getloadavg()[0]:.1f}")
    if "theirs" in med:
        print(f"  median service CPU per page, ours / theirs: {med['ours'] / med['theirs']:.2f}")


def history_phase(dbs: list[str], args: argparse.Namespace) -> dict[str, float]:
    """History reads at 1 % of ``--history-rows`` and at all of them (1000 rows per
    component), both servers up at once and read in turns: ``--turns`` turns of ``--reads``
    reads each after one warm-up read; the median over the turns of the service's CPU per
    read (a turn's CPU is counted in the kernel's clock ticks of 10 ms, so a turn must hold
    tens of milliseconds), the CPU of all turns over all their reads (the finer figure: its
    resolution is one tick over all the reads) and the p50 latency of all reads."""
    out: dict[str, float] = {}
    servers = {}
    path = "/api/v1/components/unit-0000000/history?limit=1000"
    try:
        for db, rows in zip(dbs, (args.history_rows // 100, args.history_rows), strict=True):
            out[f"fill_{rows}_s"] = fill(db, rows // 1000, steps=1000)
            sdb = ServiceDB(db)
            _, token = sdb.create_token("read", "bench")
            sdb.close()
            servers[rows] = (start_server(db), token)
            timed_reads(servers[rows][0].port, token, path, 1, 1)  # the first read of the file
        cpu: dict[int, list[float]] = {rows: [] for rows in servers}
        lat: dict[int, list[float]] = {rows: [] for rows in servers}
        for _ in range(args.turns):
            for rows, (srv, token) in servers.items():
                cpu0 = srv.cpu_seconds()
                got = timed_reads(srv.port, token, path, 1, args.reads)
                cpu[rows].append(srv.cpu_seconds() - cpu0)
                lat[rows] += got
    finally:
        for srv, _ in servers.values():
            srv.stop()
    for rows in servers:
        out[f"history_{rows}_cpu_ms"] = float(np.median(cpu[rows])) / args.reads * 1e3
        out[f"history_{rows}_all_cpu_ms"] = sum(cpu[rows]) / len(lat[rows]) * 1e3
        out[f"history_{rows}_p50_ms"] = float(np.percentile(lat[rows], 50)) * 1e3
    return out


def timed_reads(port: int, token: str, path: str | list[str], threads: int, per_thread: int
                ) -> list[float]:
    """Latencies of ``threads`` x ``per_thread`` GETs on one connection per thread: of
    ``path`` each, or of the list's paths, thread ``i`` requesting ``path[i * per_thread:
    (i + 1) * per_thread]``."""
    paths = [path] * (threads * per_thread) if isinstance(path, str) else path
    if len(paths) < threads * per_thread:
        raise ValueError(f"{len(paths)} paths for {threads} x {per_thread} requests")
    lat: list[float] = []
    lock = threading.Lock()
    errors: list[str] = []

    def run(i: int) -> None:
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=600)  # offset pages: s
        try:
            for j in range(per_thread):
                t0 = time.perf_counter()
                status, _ = request(port, "GET", paths[i * per_thread + j], None, token, conn)
                dt = time.perf_counter() - t0
                with lock:
                    lat.append(dt)
                    if status != 200:
                        errors.append(str(status))
        finally:
            conn.close()

    ts = [threading.Thread(target=run, args=(i,)) for i in range(threads)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    if errors:
        raise SystemExit(f"read errors: {errors[:5]}")
    return lat


def _sqlite_path(tmp: Path, name: str) -> str:
    return str(tmp / f"{name}.db")


def _print_write(backend: str, size: int, w: dict[str, float], bare: dict[str, float]
                 ) -> None:
    n = w["acquisitions"]
    ours = w["server_cpu_s"] / n * 1e6
    floor = bare["cpu_s"] / bare["acquisitions"] * 1e6
    cores = os.cpu_count() or 1
    print(f"{backend} batch={size}: {int(n)} acquisitions in {w['seconds']:.1f} s = "
          f"{w['acq_per_s']:.0f} acquisitions/s; service CPU {w['server_cpu_s']:.1f} s = "
          f"{w['server_cpu_s'] / n * 1e6:.1f} us per acquisition (GETs included"
          + ("" if backend == "sqlite" else "; PostgreSQL's processes not counted")
          + f"), client CPU {w['client_cpu_s'] / n * 1e6:.1f} us per acquisition; POST p50 "
          f"{w['post_p50_ms']:.0f} ms, p99 {w['post_p99_ms']:.0f} ms; GET p99 under load "
          f"{w['get_p99_ms']:.0f} ms; exactly once: yes")
    print(f"  beside it, the same rows written bare (one transaction per batch, no HTTP, no "
          f"validation, no tracker): {floor:.1f} us of CPU per acquisition "
          f"({bare['acquisitions'] / bare['wall_s']:.0f} acquisitions/s on one thread); "
          f"service / bare CPU = {ours / floor:.1f}; CPU-bound ceiling of the service on "
          f"{cores} cores: {cores * 1e6 / ours:.0f} acquisitions/s "
          f"(bare: {cores * 1e6 / floor:.0f}/s); load average "
          f"{os.getloadavg()[0]:.1f}")
    batches = n / size
    ms, bare_ms = ours * size / 1e3, floor * size / 1e3
    gets_ms = w["gets"] * w["get_cpu_s"] * 1e3 / batches
    print(f"  per batch of {size}: service {ms:.2f} ms of CPU, of which the readers' "
          f"{w['gets'] / batches:.1f} GETs {gets_ms:.2f} ms ({w['get_cpu_s'] * 1e3:.2f} ms "
          f"each, timed alone after the load) and the POST {ms - gets_ms:.2f} ms; bare writes "
          f"{bare_ms:.2f} ms; the POST's cost above its writes {ms - gets_ms - bare_ms:.2f} ms")
    hits, reads = w.get("cache_hits", 0), w.get("cache_hits", 0) + w.get("cache_misses", 0)
    if reads:  # a service with a page cache (SQLite)
        print(f"  the pollers' pages during the load: {int(hits)} of {int(reads)} served from "
              "the page cache, the others read after a commit")
    loop_ms = w["loop_cpu_s"] / batches * 1e3
    print(f"  by thread: the event loop (HTTP, routing, the routes' coroutines) {loop_ms:.2f} ms"
          f" per batch, the worker threads (bodies, validation, the writes, the GETs' "
          f"queries) {ms - loop_ms:.2f} ms")


def _print_db_cpu(size: int, w: dict[str, float], bare: dict[str, float],
                  theirs: dict[str, float] | None) -> None:
    """The database server's CPU per acquisition beside the service's and the client's, the
    bare writes' likewise, and what the goals (100,000/s at batches of 1,000, 20,000/s at
    100) leave per acquisition on this machine's cores for all three together."""
    cores = os.cpu_count() or 1

    def per(d: dict[str, float], key: str, n_key: str = "acquisitions") -> float:
        return d[key] / d[n_key] * 1e6

    total = sum(per(w, k) for k in ("server_cpu_s", "db_cpu_s", "client_cpu_s"))
    floor = per(bare, "cpu_s") + per(bare, "db_cpu_s")
    goal = 100_000 if size >= 1000 else 20_000
    print(f"  PostgreSQL's processes: {per(w, 'db_cpu_s'):.1f} us of CPU per acquisition "
          f"under the load (service {per(w, 'server_cpu_s'):.1f}, client "
          f"{per(w, 'client_cpu_s'):.1f}: {total:.1f} us in all, a CPU-bound ceiling of "
          f"{cores * 1e6 / total:.0f} acquisitions/s on {cores} cores); bare writes: "
          f"{per(bare, 'cpu_s'):.1f} us in this process + {per(bare, 'db_cpu_s'):.1f} us in "
          f"PostgreSQL = {floor:.1f} us (ceiling {cores * 1e6 / floor:.0f}/s)")
    print(f"  the goal of {goal}/s at batches of {size} leaves {cores * 1e6 / goal:.1f} us of "
          f"CPU per acquisition on {cores} cores for service, PostgreSQL and client together; "
          f"they take {total / (cores * 1e6 / goal):.2f} times that, the bare writes "
          f"{floor / (cores * 1e6 / goal):.2f} times")
    print(f"  the pollers' GET timed alone after the load: PostgreSQL's processes "
          f"{w['get_db_cpu_s'] * 1e3:.2f} ms of CPU per GET meanwhile (its autovacuum of the "
          "load's old row versions included, if it ran then; the service's is above)")
    if theirs is not None:
        print(f"  PostgreSQL's CPU per acquisition, ours against theirs: "
              f"{per(w, 'db_cpu_s'):.1f} against {per(theirs, 'db_cpu_s'):.1f} us (ratio "
              f"{w['db_cpu_s'] / theirs['db_cpu_s']:.2f}); service + PostgreSQL "
              f"{per(w, 'server_cpu_s') + per(w, 'db_cpu_s'):.1f} against "
              f"{per(theirs, 'server_cpu_s') + per(theirs, 'db_cpu_s'):.1f} us; during the "
              f"pollers' GET alone after the load {w['get_db_cpu_s'] * 1e3:.2f} against "
              f"{theirs['get_db_cpu_s'] * 1e3:.2f} ms")


def ingest_phase(backend: str, new_db: Any, args: argparse.Namespace, size: int,
                 db_cpu: Callable[[], float] | None = None) -> None:
    """The ingest load with batches of ``size`` and its bare floor; with ``--against SRC``,
    ``--repeats`` turns of this code then SRC's on new databases, and the ratios of their
    medians. ``db_cpu``: the database server's CPU seconds so far (PostgreSQL)."""
    if args.against is None:
        w = write_phase(new_db(f"w{size}"), args, size, db_cpu=db_cpu)
        bare = bare_floor(new_db(f"bare{size}"), args, size, db_cpu)
        _print_write(backend, size, w, bare)
        if db_cpu is not None:
            _print_db_cpu(size, w, bare, None)
        return
    runs: dict[str, list[dict[str, float]]] = {"ours": [], "theirs": []}
    for k in range(args.repeats):
        runs["ours"].append(write_phase(new_db(f"w{size}_{k}"), args, size, db_cpu=db_cpu))
        runs["theirs"].append(write_phase(new_db(f"a{size}_{k}"), args, size, args.against,
                                          db_cpu))
    med = {side: {key: float(np.median([r[key] for r in rs])) for key in
                  ("acq_per_s", "server_cpu_s", "acquisitions", "get_cpu_s", "loop_cpu_s",
                   "db_cpu_s", "client_cpu_s", "get_db_cpu_s")}
           for side, rs in runs.items()}
    bare = bare_floor(new_db(f"bare{size}"), args, size, db_cpu)
    _print_write(backend, size, {**runs["ours"][-1], **med["ours"]}, bare)
    if db_cpu is not None:
        _print_db_cpu(size, med["ours"], bare, med["theirs"])
    cpu = {side: m["server_cpu_s"] / m["acquisitions"] * 1e6 for side, m in med.items()}
    print(f"  in turns with {args.against} ({args.repeats} each, medians): "
          f"{med['ours']['acq_per_s']:.0f} against {med['theirs']['acq_per_s']:.0f} "
          f"acquisitions/s; service CPU {cpu['ours']:.1f} against {cpu['theirs']:.1f} us per "
          f"acquisition (ratio {cpu['ours'] / cpu['theirs']:.2f}); the pollers' GET "
          f"{med['ours']['get_cpu_s'] * 1e3:.2f} against {med['theirs']['get_cpu_s'] * 1e3:.2f}"
          f" ms; load average {os.getloadavg()[0]:.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--backend", choices=["sqlite", "postgresql", "both"], default="both")
    ap.add_argument("--writers", type=int, default=8)
    ap.add_argument("--readers", type=int, default=8)
    ap.add_argument("--batches", type=int, default=40, help="POSTs per writer and size.")
    ap.add_argument("--batch-sizes", type=int, nargs="+", default=[100, 1000])
    ap.add_argument("--components", type=int, default=1_000_000)
    ap.add_argument("--history-rows", type=int, default=10_000_000)
    ap.add_argument("--reads", type=int, default=50, help="GETs per reader thread and kind.")
    ap.add_argument("--turns", type=int, default=7,
                    help="Turns of --reads history reads on each database.")
    ap.add_argument("--warmup", type=int, default=1,
                    help="GETs per reader thread and page before the timed ones (their worst "
                    "latency is printed apart).")
    ap.add_argument("--skip", nargs="*", default=[], choices=["ingest", "pages", "history"])
    ap.add_argument("--quick", action="store_true", help="Small counts (smoke run).")
    ap.add_argument("--against", type=Path, default=None,
                    help="Another checkout's src/ directory: its ingest and its pages in "
                    "turns with ours.")
    ap.add_argument("--repeats", type=int, default=3,
                    help="Turns of each side with --against.")
    args = ap.parse_args()
    if args.quick:
        args.batches, args.components, args.reads = 5, 10_000, 10
        args.history_rows = 100_000
    backends = ["sqlite", "postgresql"] if args.backend == "both" else [args.backend]
    print(f"# bench_service: {platform.node()}, {os.cpu_count()} cores, load average "
          f"{os.getloadavg()[0]:.1f} at start; writers={args.writers} readers={args.readers} "
          f"batches/writer={args.batches} batch sizes={args.batch_sizes} "
          f"components={args.components} history rows={args.history_rows}")
    for backend in backends:
        with ExitStack() as stack:
            tmp = Path(tempfile.mkdtemp(prefix="rulkit-bench-"))
            stack.callback(shutil.rmtree, tmp, True)
            if backend == "sqlite":
                new_db = partial(_sqlite_path, tmp)
            else:
                reason = unavailable_reason()
                if reason:
                    print(f"postgresql: skipped ({reason})")
                    continue
                pg = stack.enter_context(TempPostgres(durable=True))
                new_db = pg.create_database
            print(f"\n## {backend}" + (" (WAL, synchronous=FULL)" if backend == "sqlite" else
                                        " (fsync, synchronous_commit and full_page_writes on)"))
            if "ingest" not in args.skip:
                for size in args.batch_sizes:
                    ingest_phase(backend, new_db, args, size,
                                 None if backend == "sqlite" else pg.cpu_seconds)
            if "pages" not in args.skip:
                print_pages(backend, pages_phase(new_db("pages"), args), args)
            if "history" not in args.skip:
                h = history_phase([new_db("h_small"), new_db("h_large")], args)
                small, large = args.history_rows // 100, args.history_rows
                print(f"history limit=1000: p50 {h[f'history_{small}_p50_ms']:.1f} ms at "
                      f"{small} rows, {h[f'history_{large}_p50_ms']:.1f} ms at {large} rows "
                      f"(filled in {h[f'fill_{large}_s']:.0f} s): ratio="
                      f"{h[f'history_{large}_p50_ms'] / h[f'history_{small}_p50_ms']:.2f}; "
                      f"service CPU per read {h[f'history_{small}_cpu_ms']:.1f} and "
                      f"{h[f'history_{large}_cpu_ms']:.1f} ms: ratio "
                      f"{h[f'history_{large}_cpu_ms'] / h[f'history_{small}_cpu_ms']:.2f} "
                      f"(medians of {args.turns} turns of {args.reads} reads on each, in turns,"
                      f" after one warm-up read each); over all the turns' reads "
                      f"{h[f'history_{small}_all_cpu_ms']:.2f} and "
                      f"{h[f'history_{large}_all_cpu_ms']:.2f} ms: ratio "
                      f"{h[f'history_{large}_all_cpu_ms'] / h[f'history_{small}_all_cpu_ms']:.2f}"
                      f"; load average {os.getloadavg()[0]:.1f}")
    print(f"\nload average at end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
