"""Where one page of ``GET /api/v1/components`` spends its CPU
(docs/service-load.md): the service's ASGI app called in this process (no sockets, no client),
on a database of ``--components`` components filled as bench_service.py fills its pages' database.

Prints the CPU time per request of the whole app for a few pages and a history, each through
the lean reads (:mod:`rulkit.fleet.service.lean_reads`) and through the FastAPI routes alone
(``create_app(lean_reads=False)``) in turns, with their ratio; then a full collection of
Python's cyclic garbage collector over this process's heap, before and after
``gc.freeze()`` (what ``rulkit serve`` does after start-up); then, for the default page, its
parts through the FastAPI routes, each measured alone over the same repeats: the SQL of the
page and its total, the items built from the rows, the JSON text, the token check (a
query), and the rest (routing, parameters, the access log, a connection from the pool).
``--cprofile`` adds the functions with the most CPU time of their own. ``--all-pages`` adds,
for every page bench_service.py measures (sort x level filter x depth by cursor), the CPU of
its SQL, total and items in process (best of 3), to tell a page slow in its query from one
slow over HTTP; ``--db`` reads an existing database filled as bench_service.py fills it
instead of filling one. FastAPI runs a synchronous endpoint in a worker thread; here it runs
in the event loop's thread, so one profiler sees the whole request.

    .venv/bin/python benchmarks/profile_page.py --components 100000
"""

from __future__ import annotations

import argparse
import asyncio
import cProfile
import gc
import os
import pstats
import sys
import tempfile
import time
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import orjson

sys.path.insert(0, str(Path(__file__).parent))

from bench_service import DEPTHS, PAGE_RULES, fill

PATHS = ("/api/v1/components?limit=50", "/api/v1/components?limit=50&sort=rul&level=ok",
         "/api/v1/components?limit=50&level=stale",
         "/api/v1/components/unit-0000000/history?limit=1000", "/api/v1/summary", "/healthz")


def _caller(app: Any, token: str) -> Any:
    async def call(path: str) -> bytes:
        p, _, q = path.partition("?")
        scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1",
                 "method": "GET", "scheme": "http", "path": p, "raw_path": p.encode(),
                 "query_string": q.encode(), "root_path": "", "client": ("127.0.0.1", 1),
                 "server": ("127.0.0.1", 80),
                 "headers": [(b"host", b"x"), (b"authorization", f"Bearer {token}".encode())]}
        out: list[dict[str, Any]] = []

        async def receive() -> dict[str, Any]:
            return {"type": "http.request", "body": b"", "more_body": False}

        async def send(message: dict[str, Any]) -> None:
            out.append(message)

        await app(scope, receive, send)
        if out[0]["status"] != 200:
            raise SystemExit(f"{path}: {out[0]['status']} {out[1].get('body')!r}")
        return bytes(out[1]["body"])

    def many(path: str, n: int) -> float:
        async def run() -> None:
            for _ in range(n):
                await call(path)

        t0 = time.process_time()
        asyncio.run(run())
        return (time.process_time() - t0) / n * 1e3

    return many


def cpu_ms(fn: Any, n: int) -> float:
    t0 = time.process_time()
    for _ in range(n):
        fn()
    return (time.process_time() - t0) / n * 1e3


def gc_pause() -> None:
    """A full collection of the cyclic garbage collector over this process's heap, then the
    same after ``gc.freeze()`` (medians of 5), as ``rulkit serve`` freezes after start-up."""
    def full() -> float:
        t0 = time.perf_counter()
        gc.collect()
        return (time.perf_counter() - t0) * 1e3

    full()
    before = float(np.median([full() for _ in range(5)]))
    tracked = len(gc.get_objects())
    gc.freeze()
    after = float(np.median([full() for _ in range(5)]))
    gc.unfreeze()
    print(f"  a full garbage collection over {tracked} tracked objects: {before:.1f} ms of "
          f"wall time (every thread waits); after gc.freeze(): {after:.2f} ms")


def every_page(sdb: Any) -> None:
    """The CPU of each page's SQL, total and items (:meth:`ServiceDB.components`), best of
    3, for every sort x level filter x depth by cursor of bench_service.py's pages."""
    now = time.time()
    for sort in ("worst", "rul", "due"):
        for level in (None, "alarm", "ok", "stale"):
            total = sdb.components(limit=1, level=level, sort=sort, now=now)[0]
            for depth, frac in DEPTHS.items():
                after = None
                if frac is not None:
                    k = min(int(total * frac), max(total - 2, 0))
                    after = sdb.components(limit=1, offset=k, level=level, sort=sort,
                                           now=now)[2]
                page = partial(sdb.components, limit=50, level=level, sort=sort, now=now,
                               after=after)
                ms = min(cpu_ms(page, 1) for _ in range(3))
                label = f"{sort}/{level or 'all'}/{depth}"
                print(f"  {label:24s} {ms:.2f} ms of CPU in process")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--components", type=int, default=100_000)
    ap.add_argument("--repeats", type=int, default=300)
    ap.add_argument("--cprofile", action="store_true")
    ap.add_argument("--all-pages", action="store_true")
    ap.add_argument("--db", help="An existing database filled as bench_service.py fills it.")
    args = ap.parse_args()
    import fastapi.routing

    async def inline(func: Any, *a: Any, **k: Any) -> Any:
        return func(*a, **k)

    fastapi.routing.run_in_threadpool = inline  # type: ignore[assignment]
    from rulkit.fleet.service import fleet_view, lean_reads

    lean_reads.run_in_threadpool = inline  # type: ignore[assignment]
    from rulkit.fleet.service.app import create_app
    from rulkit.fleet.service.db import ServiceDB
    from rulkit.fleet.store.prognosis import current_estimator

    with tempfile.TemporaryDirectory(prefix="rulkit-profile-") as tmp:
        db = args.db or str(Path(tmp) / "pages.db")
        fill_s = 0.0 if args.db else fill(db, args.components, steps=3, rules=PAGE_RULES)
        sdb = ServiceDB(db)
        _, token = sdb.create_token("read", "profile")
        lean = _caller(create_app(sdb), token)
        many = _caller(create_app(sdb, lean_reads=False), token)
        n = args.repeats
        size = sdb.summary()["total"]
        print(f"# profile_page: {size} components (filled in {fill_s:.0f} s), "
              f"{n} requests each, load average {os.getloadavg()[0]:.1f}; CPU per request "
              "(median of 5 turns), lean reads / FastAPI routes alone:")
        for path in PATHS:
            lean(path, 5), many(path, 5)
            turns = [(lean(path, n // 5), many(path, n // 5)) for _ in range(5)]
            a, b = (float(np.median(t)) for t in zip(*turns, strict=True))
            print(f"  {path:52s} {a:.2f} ms / {b:.2f} ms = {a / b:.2f}")
        gc_pause()
        now = time.time()
        with sdb.store() as s, s.snapshot() as conn:
            est = current_estimator(s)
            sql, params = fleet_view.page_query("worst", None, est, now, None, 50)
            rows = conn.execute(sql, params).fetchall()
            query = cpu_ms(lambda: (conn.execute(sql, params).fetchall(),
                                    fleet_view.level_total(conn, None, est, now)), n)
        items = [r[:len(fleet_view.FIELDS)] for r in rows]
        build = cpu_ms(lambda: fleet_view.component_items(items, est, now), n)
        body = {"total": 1, "items": fleet_view.component_items(items, est, now)}
        dump = cpu_ms(lambda: orjson.dumps(body), n)
        auth = cpu_ms(lambda: sdb.check_token(token), n)
        whole = many(PATHS[0], n)
        rest = whole - query - build - dump - auth
        print(f"  {PATHS[0]}: whole {whole:.2f} ms = query and total {query:.2f} + items "
              f"{build:.2f} + JSON {dump:.3f} + token check {auth:.2f} + the rest {rest:.2f}")
        if args.cprofile:
            prof = cProfile.Profile(time.process_time)
            prof.enable()
            many(PATHS[0], n)
            prof.disable()
            pstats.Stats(prof).sort_stats("tottime").print_stats(15)
        if args.all_pages:
            every_page(sdb)
        sdb.close()


if __name__ == "__main__":
    main()
