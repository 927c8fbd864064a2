"""A group commit's batches joined or applied one by one (docs/service-load.md, "Joined batches"):
``ComponentStore.ingest_many`` in this process over groups of ``--group`` validated batches
(``writer_batch``: one acquisition per component, each writer its own components, as
bench_service.py sends them), with ``JOIN_BATCHES`` on and off in turns on new SQLite
databases; the CPU per acquisition of the groups (validation not included), medians of
``--repeats``, and their ratio.

    .venv/bin/python benchmarks/bench_group_join.py --batch-size 100 --group 4
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import pandas as pd

from rulkit.fleet.service.loadgen import writer_batch
from rulkit.fleet.store.acquisitions import validate_acquisitions
from rulkit.fleet.store.sqlite import ComponentStore


def run(path: Path, join: bool, args: argparse.Namespace) -> float:
    """CPU seconds per acquisition of the timed groups."""
    with ComponentStore(path) as store:
        store.JOIN_BATCHES = join
        store.keep_states()

        def group(k: int) -> list:
            return [(validate_acquisitions(pd.DataFrame(writer_batch(w, k, args.batch_size)),
                                           store.config, None), f"w{w}", None)
                    for w in range(args.writers)]

        store.ingest_many(group(0))  # the components exist, as under load
        groups = [group(k) for k in range(1, args.batches + 1)]
        t0 = time.process_time()
        for batches in groups:
            for i in range(0, len(batches), args.group):
                store.ingest_many(batches[i:i + args.group])
        cpu = time.process_time() - t0
    return cpu / (args.batches * args.writers * args.batch_size)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--writers", type=int, default=8)
    ap.add_argument("--batches", type=int, default=20, help="Batches per writer, timed.")
    ap.add_argument("--batch-size", type=int, default=100)
    ap.add_argument("--group", type=int, default=4, help="Batches per group commit.")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    print(f"# bench_group_join: {args.writers} writers x {args.batches} batches of "
          f"{args.batch_size} in groups of {args.group}; load average {os.getloadavg()[0]:.1f}")
    res: dict[bool, list[float]] = {True: [], False: []}
    with tempfile.TemporaryDirectory(prefix="rulkit-join-") as tmp:
        for rep in range(args.repeats):
            for join in (True, False):
                res[join].append(run(Path(tmp) / f"{rep}-{join}.db", join, args))
    med = {k: statistics.median(v) * 1e6 for k, v in res.items()}
    print(f"  joined {med[True]:.1f} us, one by one {med[False]:.1f} us of CPU per acquisition "
          f"(ratio {med[True] / med[False]:.2f}); load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
