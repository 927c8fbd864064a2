"""Benchmark: the trackers' and the trend's recursions stepped by acquisition rank across units
(numpy) against their compiled per-unit passes (numba), by the width of the step
(docs/service-load.md, "Where track's 2M rows go").

``rulkit track`` runs a wide batch in windows of acquisition ranks of every unit
(``history_stage.plan_pieces``): one vectorised update per rank, whose cost per row falls with
the width (its fixed cost per call is spread over more units), and no compiled pass to load.
A narrow-and-long batch keeps the compiled passes, whose load (numba and its cache) costs
about 0.5 s of CPU and 100 MB once per process. Printed, per width, for
:func:`~rulkit.fleet.tracking.tracker_run.tracker_run` and
:func:`~rulkit.fleet.monitoring.unit_trend.trend_run`: CPU per rank step and per row of the
``"ranks"`` strategy, per row of ``"jit"`` (numba loaded and warm: its load is not in it), their
ratio, whether they gave the same bits, and the per-rank and per-row constants of the cost rule
(``_COST_PER_RANK``, ``_COST_PER_RANK_ROW``) fitted to the widths by least squares.

    .venv/bin/python benchmarks/bench_tracker_steps.py
    .venv/bin/python benchmarks/bench_tracker_steps.py --widths 25 2000 --length 500
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from rulkit.fleet.monitoring.unit_trend import TrendConfig, TrendState, trend_run
from rulkit.fleet.tracking.tracker_chain import TrackerConfig, TrackerState
from rulkit.fleet.tracking.tracker_run import tracker_run


def _tracker(width: int) -> Callable[..., Any]:
    cfg = TrackerConfig()

    def run(seg: Any, t: Any, z: Any, strategy: str) -> list[Any]:
        state, rows = tracker_run(TrackerState.empty(width), seg, t, z, cfg, strategy=strategy)
        return [*rows.values(), *state.columns().values()]
    return run


def _trend(width: int) -> Callable[..., Any]:
    cfg = TrendConfig()

    def run(seg: Any, t: Any, z: Any, strategy: str) -> list[Any]:
        state, rows = trend_run(TrendState.empty(width), seg, t, z, cfg, strategy=strategy)
        return [rows.s, rows.n, state.s]
    return run


def measure(make: Callable[[int], Callable[..., Any]], width: int, length: int, repeats: int,
            rng: np.random.Generator) -> tuple[float, float, bool]:
    """(ranks CPU s, jit CPU s, same bits) of one call over ``width`` units of ``length``
    rows each, medians of ``repeats`` in turns."""
    m = width * length
    t = np.tile(np.arange(length, dtype=np.float64), width)
    z = np.clip(np.repeat(rng.uniform(0.05, 0.3, width), length) * np.exp(0.002 * t)
                + rng.normal(0.0, 0.005, m), 0.0, 10.0)
    seg = np.arange(0, m + 1, length, dtype=np.int64)
    run = make(width)
    run(seg, t, z, "jit")  # warm: numba loaded
    cpu: dict[str, list[float]] = {"ranks": [], "jit": []}
    outs: dict[str, list[Any]] = {}
    for _ in range(repeats):  # in turns
        for name in cpu:
            c0 = time.process_time()
            outs[name] = run(seg, t, z, name)
            cpu[name].append(time.process_time() - c0)
    same = all(np.array_equal(a, b, equal_nan=True)
               for a, b in zip(outs["ranks"], outs["jit"], strict=True))
    return statistics.median(cpu["ranks"]), statistics.median(cpu["jit"]), same


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--widths", type=int, nargs="+", default=[25, 250, 2000, 8000])
    ap.add_argument("--length", type=int, default=200, help="acquisitions per unit")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    print(f"{args.length} acquisitions per unit, medians of {args.repeats} in turns; "
          f"load average {os.getloadavg()[0]:.1f}")
    rng = np.random.default_rng(0)
    for label, make in (("trackers (tracker_run)", _tracker), ("trend (trend_run)", _trend)):
        ranks_cpu = []
        for width in args.widths:
            c_r, c_j, same = measure(make, width, args.length, args.repeats, rng)
            m = width * args.length
            ranks_cpu.append(c_r / args.length)
            print(f"{label} width {width:5d}: ranks {c_r * 1e6 / args.length:7.1f} us/step "
                  f"{c_r * 1e9 / m:7.1f} ns/row; compiled {c_j * 1e9 / m:5.1f} ns/row; "
                  f"ranks / compiled {c_r / c_j:6.1f}; same bits {same}")
        # a step's CPU = per rank + per row x width, least squares over the widths
        a = np.column_stack([np.ones(len(args.widths)), np.array(args.widths, dtype=float)])
        (per_rank, per_row), *_ = np.linalg.lstsq(a, np.array(ranks_cpu), rcond=None)
        print(f"  {label} rank steps: {per_rank * 1e6:.0f} us per rank + "
              f"{per_row * 1e9:.0f} ns per row")


if __name__ == "__main__":
    main()
