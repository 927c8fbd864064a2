"""Benchmark: the middle page by ``offset`` over HTTP, this checkout's service beside another's.

docs/service-load.md, "Pages by offset". A SQLite database of ``--components`` components filled as
bench_service.py fills its pages' database (or ``--db``, an existing one), then ``rulkit
serve`` on it and ``--readers`` threads x ``--reads`` requests of
``GET /api/v1/components?limit=50&offset=<half>`` (after one warm-up request): the service's
CPU time per request and the wall time. With ``--against SRC`` (the ``src`` folder of another
checkout, e.g. ``git archive main src | tar -x -C /tmp/main``) the service runs that code too,
in turns with this one (``--rounds`` rounds), and the ratio of the medians is printed, with
the load average: the machine is shared, so only CPU figures taken in turns compare.

    .venv/bin/python benchmarks/bench_offset_page.py --against /tmp/main/src
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from bench_service import PAGE_RULES, fill, timed_reads
from rulkit.fleet.service.db import ServiceDB
from rulkit.fleet.service.loadgen import start_server


def offset_cpu(db: str, token: str, path: str, src: str | None, readers: int, reads: int
               ) -> tuple[float, float]:
    """(service CPU ms per request, wall s) of ``path`` with the service of ``src`` (this
    checkout's when ``None``)."""
    saved = os.environ.get("PYTHONPATH")
    if src is not None:
        os.environ["PYTHONPATH"] = src  # the server's subprocess imports rulkit from there
    try:
        srv = start_server(db)
    finally:
        os.environ.pop("PYTHONPATH", None)
        if saved is not None:
            os.environ["PYTHONPATH"] = saved
    try:
        timed_reads(srv.port, token, path, 1, 1)  # warm-up
        cpu0, wall0 = srv.cpu_seconds(), time.perf_counter()
        lat = timed_reads(srv.port, token, path, readers, reads)
        return (srv.cpu_seconds() - cpu0) / len(lat) * 1e3, time.perf_counter() - wall0
    finally:
        srv.stop()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--components", type=int, default=1_000_000)
    ap.add_argument("--db", help="An existing database filled as bench_service.py fills it.")
    ap.add_argument("--against", help="Another checkout's src folder, measured in turns.")
    ap.add_argument("--readers", type=int, default=8)
    ap.add_argument("--reads", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=1)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="rulkit-offset-") as tmp:
        db = args.db or str(Path(tmp) / "pages.db")
        if args.db is None:
            print(f"filled {args.components} components in "
                  f"{fill(db, args.components, steps=3, rules=PAGE_RULES):.0f} s")
        sdb = ServiceDB(db)
        _, token = sdb.create_token("read", "bench-offset")
        total = sdb.summary()["total"]
        sdb.close()
        path = f"/api/v1/components?limit=50&offset={total // 2}"
        sides = {"this checkout": None, **({"against": args.against} if args.against else {})}
        cpu: dict[str, list[float]] = {name: [] for name in sides}
        print(f"# bench_offset_page: {path} of {total}, {args.readers} readers x {args.reads}, "
              f"load average {os.getloadavg()[0]:.1f}")
        for _ in range(args.rounds):
            for name, src in sides.items():
                ms, wall = offset_cpu(db, token, path, src, args.readers, args.reads)
                cpu[name].append(ms)
                print(f"  {name:14s} {ms:7.0f} ms of service CPU per request, wall {wall:.1f} s"
                      f"; load average {os.getloadavg()[0]:.1f}", flush=True)
        med = {name: statistics.median(v) for name, v in cpu.items()}
        if args.against:
            print(f"median CPU per request: this checkout {med['this checkout']:.0f} ms, against "
                  f"{med['against']:.0f} ms: ratio {med['this checkout'] / med['against']:.3f}")


if __name__ == "__main__":
    main()
