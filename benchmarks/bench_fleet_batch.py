"""Benchmark: ``rulkit track`` over a directory of Parquet partitions, serial vs Dask.

docs/service.md, "Fleet batch on Dask". Generates ``--acquisitions`` rows of ``--components``
components in ``--partitions`` time-sliced Parquet files (every component spans every file),
then tracks them into a new SQLite database twice: serially in this process
(:func:`rulkit.fleet.store.partitions.track_directory` without a scheduler) and on a local
Dask cluster of ``--workers`` single-threaded worker processes. Prints wall time,
acquisitions/s, acquisitions per second per core used (serial: 1; Dask: the workers, plus
this process for the merge), the CPU seconds of each side, the merge's share, and checks both
databases hold the same history. Medians of ``--repeats``; the load average is printed since
the machine is shared.

    .venv/bin/python benchmarks/bench_fleet_batch.py                       # 10^7 x 10^5
    .venv/bin/python benchmarks/bench_fleet_batch.py --acquisitions 1000000 --components 10000
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from rulkit.fleet.store.partitions import track_directory
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.tracking.tracker_chain import TrackerConfig

CFG = TrackerConfig(dt=1.0, design_life=1e5)


def write_partitions(d: Path, n_acq: int, n_comp: int, n_parts: int, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    steps = n_acq // n_comp
    rate = rng.uniform(1e-4, 2e-3, n_comp)
    names = np.array([f"unit-{i:06d}" for i in range(n_comp)], dtype=object)
    edges = np.linspace(0, steps, n_parts + 1).astype(int)
    for p in range(n_parts):
        t = np.arange(edges[p], edges[p + 1], dtype=float)
        hi = 0.2 * np.exp(np.outer(t, rate)) + rng.normal(0, 2e-3, (t.size, n_comp))
        pd.DataFrame({"component": np.tile(names, t.size), "time": np.repeat(t, n_comp),
                      "hi": hi.ravel().clip(0.0, 1.5)}).to_parquet(
            d / f"part-{p:03d}.parquet", index=False)


def _cpu() -> float:
    t = os.times()
    return t.user + t.system


def run(d: Path, db: Path, client: object | None) -> tuple[float, float, float, float]:
    """(wall s, this process's CPU s, workers' CPU s, merge s) of one track_directory."""
    for side in ("", "-wal", "-shm"):
        Path(f"{db}{side}").unlink(missing_ok=True)
    w0 = sum(client.run(_cpu).values()) if client is not None else 0.0  # type: ignore[attr-defined]
    c0, t0 = _cpu(), time.perf_counter()
    track_directory(db, d, config=CFG, scheduler=client)
    wall, cpu = time.perf_counter() - t0, _cpu() - c0
    w1 = sum(client.run(_cpu).values()) if client is not None else 0.0  # type: ignore[attr-defined]
    return wall, cpu, w1 - w0, 0.0


def warm() -> float:
    """CPU seconds of a tiny run of the ingestion in this process (imports, numba's cached
    kernels loaded): a process's one-off start-up, kept out of the per-acquisition figures."""
    c0 = _cpu()
    with tempfile.TemporaryDirectory(prefix="rulkit-warm-") as tmp:
        t = np.arange(20.0)
        df = pd.DataFrame({"component": np.repeat(["a", "b"], 10), "time": np.tile(t[:10], 2),
                           "hi": np.tile(0.2 + 0.01 * t[:10], 2)})
        track_directory(Path(tmp) / "w.db", _one_partition(Path(tmp), df), config=CFG)
    return _cpu() - c0


def _one_partition(tmp: Path, df: pd.DataFrame) -> Path:
    d = tmp / "p"
    d.mkdir()
    df.to_parquet(d / "p.parquet", index=False)
    return d


def same_history(a: Path, b: Path) -> bool:
    """Whether the two databases hold the same acquisitions' values (the packed history,
    decoded; which ingestion wrote them aside)."""
    with ComponentStore(a, readonly=True) as sa, ComponentStore(b, readonly=True) as sb:
        return sa.history().drop(columns="ingest").equals(sb.history().drop(columns="ingest"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--acquisitions", type=int, default=10_000_000)
    ap.add_argument("--components", type=int, default=100_000)
    ap.add_argument("--partitions", type=int, default=10)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=1)
    args = ap.parse_args()
    from distributed import Client, LocalCluster

    tmp = Path(tempfile.mkdtemp(prefix="rulkit-batch-"))
    try:
        d = tmp / "parts"
        d.mkdir()
        write_partitions(d, args.acquisitions, args.components, args.partitions)
        n = args.acquisitions // args.components * args.components
        print(f"# bench_fleet_batch: {os.cpu_count()} cores, load average "
              f"{os.getloadavg()[0]:.1f}; {n} acquisitions of {args.components} components in "
              f"{args.partitions} partitions; Dask: {args.workers} worker processes x 1 thread")
        start = warm()
        serial = [run(d, tmp / "serial.db", None) for _ in range(args.repeats)]
        with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                          dashboard_address=None) as lc, Client(lc) as client:
            w_start = sum(client.run(warm).values())
            dask = [run(d, tmp / "dask.db", client) for _ in range(args.repeats)]
        same = same_history(tmp / "serial.db", tmp / "dask.db")
        size = sum(f.stat().st_size for f in tmp.glob("serial.db*"))
        sw, sc = statistics.median(r[0] for r in serial), statistics.median(r[1] for r in serial)
        dw = statistics.median(r[0] for r in dask)
        dc, dwk = statistics.median(r[1] for r in dask), statistics.median(r[2] for r in dask)
        print(f"serial: wall {sw:.1f} s, CPU {sc:.1f} s: {n / sw:,.0f} acquisitions/s, "
              f"{n / sw:,.0f} per core")
        print(f"dask:   wall {dw:.1f} s, workers' CPU {dwk:.1f} s, this process (split, "
              f"merge) CPU {dc:.1f} s: {n / dw:,.0f} acquisitions/s, "
              f"{n / dw / (args.workers + 1):,.0f} per core ({args.workers} workers + merge)")
        print(f"start-up (imports, numba's cached kernels; not in the figures above): this "
              f"process {start:.2f} s, the workers {w_start:.2f} s in all")
        print(f"ratio dask/serial wall = {dw / sw:.2f}; CPU per acquisition: serial "
              f"{sc / n * 1e6:.1f} us, dask {(dc + dwk) / n * 1e6:.1f} us; same history: "
              f"{'yes' if same else 'NO'}; the serial database {size / n:.0f} bytes per "
              f"acquisition; load average at end {os.getloadavg()[0]:.1f}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
