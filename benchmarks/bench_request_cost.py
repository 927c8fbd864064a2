"""Benchmark: the service's fixed CPU cost per request (docs/service-load.md, "The framework's
share").

``rulkit serve`` on a new SQLite database in a subprocess, one client thread on one kept-alive
connection sending requests whose bytes are built before the clock starts, one kind after the
other: ``GET /healthz`` (no token, no database), ``GET /readyz`` (a database query), ``GET
/api/v1/summary`` (the token check and a FastAPI route), the smallest page ``GET
/api/v1/components?limit=1`` (the lean path), the same with an invalid token (401: the
token check, then FastAPI's answer), and ``POST /api/v1/acquisitions`` of one acquisition
(a new component time each). For each kind: the service's CPU per request (its process's
user + system time over ``--requests`` requests; the median of ``--repeats`` rounds), the
event loop thread's share, and the client's CPU. With ``--against SRC`` a second server of
that checkout's ``src`` serves the same kinds on its own database, in turns, and the ratio of
the medians is printed.

    .venv/bin/python benchmarks/bench_request_cost.py --requests 400 --repeats 3
    .venv/bin/python benchmarks/bench_request_cost.py --against /tmp/main/src
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from rulkit.fleet.service.db import ServiceDB
from rulkit.fleet.service.loadgen import Exchange, Server, raw_request, start_server


def kinds(token: str, n: int, round_: int) -> dict[str, tuple[int, list[bytes]]]:
    """(expected status, the requests' bytes) of each kind for round ``round_``."""
    def post(k: int) -> bytes:
        rows = [{"component": "c0", "time": float(round_ * n + k), "hi": 0.2}]
        return raw_request("POST", "/api/v1/acquisitions", token,
                           json.dumps({"rows": rows}).encode())

    return {
        "GET /healthz": (200, [raw_request("GET", "/healthz", None)] * n),
        "GET /readyz": (200, [raw_request("GET", "/readyz", None)] * n),
        "GET summary": (200, [raw_request("GET", "/api/v1/summary", token)] * n),
        "GET page limit=1": (200, [raw_request("GET", "/api/v1/components?limit=1",
                                               token)] * n),
        "GET page, bad token (401)": (401, [raw_request(
            "GET", "/api/v1/components?limit=1", "rk_" + "x" * 43)] * n),
        "POST 1 acquisition": (200, [post(k) for k in range(n)]),
    }


def measure(srv: Server, reqs: list[bytes], status: int) -> tuple[float, float, float]:
    """(service CPU, event loop CPU, client CPU) per request, seconds."""
    conn = Exchange(srv.port)
    try:
        conn.send(reqs[0])  # warm-up, not counted (POST: the component's row)
        cpu0, loop0, client0 = srv.cpu_seconds(), srv.loop_cpu_seconds(), time.process_time()
        for data in reqs[1:]:
            got, _ = conn.send(data)
            if got != status:
                raise SystemExit(f"expected {status}, got {got}")
        k = len(reqs) - 1
        return ((srv.cpu_seconds() - cpu0) / k, (srv.loop_cpu_seconds() - loop0) / k,
                (time.process_time() - client0) / k)
    finally:
        conn.close()


def serve(tmp: Path, name: str, src: Path | None) -> tuple[Server, str]:
    db = str(tmp / f"{name}.db")
    sdb = ServiceDB(db)
    _, token = sdb.create_token("write", "bench")
    sdb.close()
    env = None if src is None else {"PYTHONPATH": str(src.resolve())}
    return start_server(db, env=env), token


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--requests", type=int, default=400, help="Requests per kind and round.")
    ap.add_argument("--repeats", type=int, default=3, help="Rounds (medians are printed).")
    ap.add_argument("--against", type=Path, default=None,
                    help="Another checkout's src/ directory, measured in turns.")
    args = ap.parse_args()
    print(f"# bench_request_cost: {os.cpu_count()} cores, load average "
          f"{os.getloadavg()[0]:.1f} at start; {args.requests} requests per kind and round, "
          f"{args.repeats} rounds, one client connection")
    tmp = Path(tempfile.mkdtemp(prefix="rulkit-reqcost-"))
    sides = {"ours": None} if args.against is None else {"ours": None, "theirs": args.against}
    servers = {}
    try:
        for side, src in sides.items():
            servers[side] = serve(tmp, side, src)
        got: dict[tuple[str, str], list[tuple[float, float, float]]] = {}
        for r in range(args.repeats):
            for side, (srv, token) in servers.items():
                for kind, (status, reqs) in kinds(token, args.requests + 1, r).items():
                    got.setdefault((side, kind), []).append(measure(srv, reqs, status))
    finally:
        for srv, _ in servers.values():
            srv.stop()
        shutil.rmtree(tmp, True)
    for kind in kinds("t", 1, 0):
        line = f"  {kind:28s}"
        med = {}
        for side in servers:
            m = np.median(np.array(got[(side, kind)]), axis=0) * 1e6
            med[side] = m[0]
            line += (f"  {side}: service {m[0]:6.0f} us (event loop {m[1]:5.0f} us), client "
                     f"{m[2]:4.0f} us")
        if "theirs" in med:
            line += f"  ratio {med['ours'] / med['theirs']:.2f}"
        print(line)
    print(f"load average at end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
