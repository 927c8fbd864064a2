"""Benchmark: the fleet service over HTTP on loopback (issue 12 goals, docs/service.md).

For each backend (SQLite file; PostgreSQL: a throwaway server from the installed binaries):

1. **Write load.** ``rulkit serve`` in a subprocess; ``--writers`` threads each POST
   ``--batches`` JSON batches of ``--batch-size`` acquisitions (one per component, distinct
   components per writer) while ``--readers`` threads poll ``GET /api/v1/components?limit=50``.
   Prints acquisitions/s (all acquisitions / wall time until the last writer is done) and
   p50/p99 latencies, then checks that every acquisition is stored exactly once.
2. **Read latency at scale.** A fresh database with ``--components`` components (filled by
   the store directly), then ``--readers`` threads x ``--reads`` requests of
   ``GET /api/v1/components?limit=50`` (and the same with ``offset`` in the middle);
   prints p50/p99.

Client and server share the machine (2 cores here), so the figures include the client's
cost. Loopback only; every loop is bounded by its request count.

    .venv/bin/python benchmarks/bench_service.py                  # ~1 min of load per backend
    .venv/bin/python benchmarks/bench_service.py --quick          # a smoke run
    .venv/bin/python benchmarks/bench_service.py --backend sqlite
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import pandas as pd

from rulkit.fleet.service.db import ServiceDB
from rulkit.fleet.service.loadgen import run_load, start_server, verify_exactly_once
from rulkit.fleet.service.pgtemp import TempPostgres, unavailable_reason


def write_phase(db: str, args: argparse.Namespace) -> dict[str, float]:
    sdb = ServiceDB(db)
    _, token = sdb.create_token("write", "bench")
    sdb.close()
    srv = start_server(db)
    try:
        cpu0, client0 = srv.cpu_seconds(), time.process_time()
        res = run_load(srv.port, token, writers=args.writers, readers=args.readers,
                       batches=args.batches, batch_size=args.batch_size,
                       max_reads=args.batches * 4)
        cpu, client = srv.cpu_seconds() - cpu0, time.process_time() - client0
    finally:
        srv.stop()
    if res.errors:
        raise SystemExit(f"errors during the load: {res.errors[:5]}")
    verify_exactly_once(db, args.writers, args.batches, args.batch_size)
    return {**res.summary(), "server_cpu_s": cpu, "client_cpu_s": client}


def read_phase(db: str, args: argparse.Namespace) -> dict[str, float]:
    sdb = ServiceDB(db)
    _, token = sdb.create_token("read", "bench")
    n = args.components
    rng = np.random.default_rng(0)
    df = pd.DataFrame({"component": [f"unit-{i:06d}" for i in range(n)], "time": 0.0,
                       "hi": rng.uniform(0.1, 1.2, n)})
    t0 = time.perf_counter()
    sdb.ingest(df, "bench-fill")
    fill = time.perf_counter() - t0
    sdb.close()
    srv = start_server(db)
    out: dict[str, float] = {"components": n, "fill_s": fill}
    try:
        for label, path in [("first_page", "/api/v1/components?limit=50"),
                            ("middle_page", f"/api/v1/components?limit=50&offset={n // 2}")]:
            cpu0 = srv.cpu_seconds()
            lat = _reads(srv.port, token, path, args.readers, args.reads)
            out[f"{label}_cpu_ms"] = (srv.cpu_seconds() - cpu0) / len(lat) * 1e3
            out[f"{label}_p50_ms"] = float(np.percentile(lat, 50)) * 1e3
            out[f"{label}_p99_ms"] = float(np.percentile(lat, 99)) * 1e3
            out[f"{label}_requests"] = len(lat)
    finally:
        srv.stop()
    return out


def _reads(port: int, token: str, path: str, threads: int, per_thread: int) -> list[float]:
    import http.client
    import threading

    from rulkit.fleet.service.loadgen import request

    lat: list[float] = []
    lock = threading.Lock()
    errors: list[str] = []

    def run() -> None:
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
        try:
            for _ in range(per_thread):
                t0 = time.perf_counter()
                status, _ = request(port, "GET", path, None, token, conn)
                dt = time.perf_counter() - t0
                with lock:
                    lat.append(dt)
                    if status != 200:
                        errors.append(str(status))
        finally:
            conn.close()

    ts = [threading.Thread(target=run) for _ in range(threads)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    if errors:
        raise SystemExit(f"read errors: {errors[:5]}")
    return lat


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--backend", choices=["sqlite", "postgresql", "both"], default="both")
    ap.add_argument("--writers", type=int, default=8)
    ap.add_argument("--readers", type=int, default=8)
    ap.add_argument("--batches", type=int, default=150, help="POSTs per writer.")
    ap.add_argument("--batch-size", type=int, default=100)
    ap.add_argument("--components", type=int, default=100_000)
    ap.add_argument("--reads", type=int, default=100, help="GETs per reader thread.")
    ap.add_argument("--quick", action="store_true", help="Small counts (smoke run).")
    args = ap.parse_args()
    if args.quick:
        args.batches, args.components, args.reads = 10, 10_000, 20
    backends = ["sqlite", "postgresql"] if args.backend == "both" else [args.backend]
    print(f"# bench_service: {platform.node()}, {os.cpu_count()} cores, load average "
          f"{os.getloadavg()[0]:.1f} at start; writers={args.writers} readers={args.readers} "
          f"batches/writer={args.batches} batch={args.batch_size} "
          f"components(read phase)={args.components}")
    rows = []
    for backend in backends:
        with ExitStack() as stack:
            tmp = Path(tempfile.mkdtemp(prefix="rulkit-bench-"))
            stack.callback(shutil.rmtree, tmp, True)
            if backend == "sqlite":
                dbs = [str(tmp / "write.db"), str(tmp / "read.db")]
            else:
                reason = unavailable_reason()
                if reason:
                    print(f"postgresql: skipped ({reason})")
                    continue
                pg = stack.enter_context(TempPostgres())
                dbs = [pg.create_database("write"), pg.create_database("read")]
            w = write_phase(dbs[0], args)
            r = read_phase(dbs[1], args)
            rows.append((backend, w, r))
            print(f"\n## {backend}")
            print(f"write load: {int(w['acquisitions'])} acquisitions in {w['seconds']:.1f} s = "
                  f"{w['acq_per_s']:.0f} acquisitions/s; POST p50 {w['post_p50_ms']:.0f} ms, "
                  f"p99 {w['post_p99_ms']:.0f} ms; concurrent GET limit=50 ({int(w['gets'])} "
                  f"requests) p50 {w['get_p50_ms']:.0f} ms, p99 {w['get_p99_ms']:.0f} ms; "
                  "every acquisition stored exactly once: yes")
            print(f"CPU: service process {w['server_cpu_s']:.1f} s "
                  f"({w['acquisitions'] / w['server_cpu_s']:.0f} acquisitions per service "
                  f"CPU-second, GETs included), load client {w['client_cpu_s']:.1f} s"
                  + ("" if backend == "sqlite" else "; PostgreSQL's own processes not counted"))
            print(f"read latency, {int(r['components'])} components (filled in "
                  f"{r['fill_s']:.1f} s), {args.readers} readers x {args.reads}: "
                  f"first page p50 {r['first_page_p50_ms']:.1f} ms, p99 "
                  f"{r['first_page_p99_ms']:.1f} ms; middle page p50 "
                  f"{r['middle_page_p50_ms']:.1f} ms, p99 {r['middle_page_p99_ms']:.1f} ms; "
                  f"service CPU per request {r['first_page_cpu_ms']:.1f} / "
                  f"{r['middle_page_cpu_ms']:.1f} ms")
    print(f"\nload average at end {os.getloadavg()[0]:.1f}")
    print("\n| backend | acquisitions/s | per service CPU-s | POST p50 / p99 ms | GET p99 ms "
          "under load | GET limit=50 p99 ms at N components (first / middle page) |")
    print("|---|---|---|---|---|---|")
    for backend, w, r in rows:
        print(f"| {backend} | {w['acq_per_s']:.0f} | "
              f"{w['acquisitions'] / w['server_cpu_s']:.0f} | {w['post_p50_ms']:.0f} / "
              f"{w['post_p99_ms']:.0f} | {w['get_p99_ms']:.0f} | "
              f"{r['first_page_p99_ms']:.1f} / {r['middle_page_p99_ms']:.1f} "
              f"(N = {int(r['components'])}) |")


if __name__ == "__main__":
    main()
