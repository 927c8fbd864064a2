"""What a fresh service process spends on the trend's Student-t quantiles (docs/service-load.md,
"The writer's path on PostgreSQL at batches of 100"): ``ServiceDB.ingest`` in this process on
a new SQLite database, fed bench_service.py's batches (8 writers, one acquisition per
component per batch, ``--batches`` batches each, in turns, one at a time), with the
bisections that fill the quantiles' table timed (its CPU, and how many passes). With
``--against SRC`` the same run is made with another checkout's ``src`` in a fresh interpreter,
in turns with this one (``--repeats`` each; medians).

    .venv/bin/python benchmarks/bench_quantile_warmup.py --batches 20 --against /tmp/old/src
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def one_run(batches: int, batch_size: int) -> dict[str, float]:
    """The ingest's CPU, the bisections' CPU and their count, in this process."""
    import pandas as pd

    from rulkit.fleet.monitoring import unit_trend
    from rulkit.fleet.service.db import ServiceDB
    from rulkit.fleet.service.loadgen import writer_batch

    spent = {"seconds": 0.0, "passes": 0}
    bisect = unit_trend._t_quantiles

    def timed(*args):  # type: ignore[no-untyped-def]
        t = time.process_time()
        out = bisect(*args)
        spent["seconds"] += time.process_time() - t
        spent["passes"] += 1
        return out

    unit_trend._t_quantiles = timed  # type: ignore[assignment]
    frames = [[pd.DataFrame(writer_batch(w, k, batch_size)) for w in range(8)]
              for k in range(batches)]
    with tempfile.TemporaryDirectory(prefix="rulkit-quantile-warmup-") as tmp:
        sdb = ServiceDB(Path(tmp) / "fleet.db")
        try:
            t0 = time.process_time()
            for row in frames:
                for df in row:
                    sdb.ingest(df, "bench")
            total = time.process_time() - t0
        finally:
            sdb.close()
    return {"ingest": total, "quantiles": spent["seconds"], "passes": spent["passes"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--batches", type=int, default=20)
    ap.add_argument("--batch-size", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--against", type=Path, default=None)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(one_run(args.batches, args.batch_size)))
        return
    codes = {"this checkout": None} | ({str(args.against): args.against}
                                       if args.against else {})
    runs: dict[str, list[dict[str, float]]] = {name: [] for name in codes}
    for _ in range(args.repeats):
        for name, src in codes.items():
            env = dict(os.environ)
            if src is not None:
                env["PYTHONPATH"] = str(src.resolve())
            out = subprocess.run([sys.executable, __file__, "--child", "--batches",
                                  str(args.batches), "--batch-size", str(args.batch_size)],
                                 env=env, check=True, capture_output=True, text=True)
            runs[name].append(json.loads(out.stdout.strip().splitlines()[-1]))
    print(f"bench_quantile_warmup: 8 writers x {args.batches} batches of {args.batch_size} "
          f"through ServiceDB.ingest on a new SQLite database, medians of {args.repeats} "
          f"fresh processes; load average {os.getloadavg()[0]:.1f}")
    med = {}
    for name, rs in runs.items():
        med[name] = {k: statistics.median(r[k] for r in rs) for k in rs[0]}
        m = med[name]
        print(f"  {name}: ingest {m['ingest']:.3f} s of CPU, of which the quantiles' "
              f"bisections {m['quantiles']:.3f} s in {m['passes']:.0f} passes "
              f"({m['quantiles'] / m['ingest']:.0%})")
    if args.against:
        a, b = med["this checkout"], med[str(args.against)]
        print(f"  ratio (this / against): ingest {a['ingest'] / b['ingest']:.2f}, "
              f"bisections {a['quantiles'] / b['quantiles']:.2f}")


if __name__ == "__main__":
    main()
