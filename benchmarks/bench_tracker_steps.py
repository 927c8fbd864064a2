"""Benchmark: the trackers' HI recursion stepped in numpy across units against numba's compiled
pass, by the width of the step (docs/service.md, "Where track's 2M rows go").

``rulkit track`` runs the trackers' recursions (rulkit.fleet.tracking.tracker_run) compiled by
numba for long series; loading numba costs about 0.5 s of CPU and 100 MB once per process. The
alternative measured here steps the recursion in numpy: one step is one acquisition rank
across all the units of a call, so its cost per row falls with the width. ``track`` calls the
trackers per block of consecutive components of at most ``ComponentStore.BLOCK_ROWS`` rows
(25,000: 25 units of 1,000 acquisitions), so the width is that block's unit count unless the
block grows, and its per-row outputs with it. Printed, per width: CPU per step and per row of
the numpy steps, per row of the compiled pass (numba loaded and warm, so its load is not in
it), their ratio, and whether the two gave the same bits.

The numpy stepping below exists only here, to measure that rule; rulkit does not use it.

    .venv/bin/python benchmarks/bench_tracker_steps.py
    .venv/bin/python benchmarks/bench_tracker_steps.py --widths 25 2000 --length 500
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from typing import Any

import numpy as np

from rulkit.fleet.tracking.tracker_run import _passes


def hi_steps(seg: Any, t: Any, z: Any, t0: Any, n0: Any, hi0: Any, fhi0: Any, dhi0: Any,
             dt_fresh: float, a1: float, b1: float, dhi_min: float, two_point: bool,
             fhi_out: Any, dhi_out: Any, dt_out: Any) -> None:
    """The compiled HI pass's arguments and results, stepped by rank across units (every
    unit with the same number of rows: the benchmark's series)."""
    start = seg[:-1]
    tp, n, hp, x, v = t0.copy(), n0.copy(), hi0.copy(), fhi0.copy(), dhi0.copy()
    for r in range(int(np.diff(seg).max())):
        i = start + r
        ti, zi = t[i], z[i]
        first = n == 0
        dt = np.where(first, dt_fresh, ti - tp)
        xp = x + v * dt
        res = zi - xp
        x1 = xp + a1 * res
        v1 = v + b1 * res / dt
        v1 = np.where(v1 < dhi_min, dhi_min, v1)
        x1, v1 = np.where(first, zi, x1), np.where(first, dhi_min, v1)
        if two_point:
            second = n == 1
            s = (zi - hp) / dt
            x1 = np.where(second, zi, x1)
            v1 = np.where(second, np.where(s < dhi_min, dhi_min, s), v1)
        fhi_out[i], dhi_out[i], dt_out[i] = x1, v1, dt
        x, v, tp, hp, n = x1, v1, ti, zi, n + 1


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--widths", type=int, nargs="+", default=[25, 250, 2000])
    ap.add_argument("--length", type=int, default=1000, help="acquisitions per unit")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    jit_pass = _passes("jit")[0]
    print(f"HI recursion, {args.length} acquisitions per unit, medians of {args.repeats}; "
          f"load average {os.getloadavg()[0]:.1f}")
    rng = np.random.default_rng(0)
    for width in args.widths:
        m = width * args.length
        t = np.tile(np.arange(args.length, dtype=np.float64), width)
        z = rng.uniform(0.1, 0.5, m)
        seg = np.arange(0, m + 1, args.length, dtype=np.int64)
        zero, n0 = np.zeros(width), np.zeros(width, dtype=np.int64)
        outs = [np.empty(m) for _ in range(6)]
        common = (seg, t, z, zero, n0, zero, zero, zero, 1.0, 0.3, 0.05, 1e-3, True)
        jit_pass(*common, *outs[3:])  # warm
        cpu: dict[str, list[float]] = {"numpy": [], "jit": []}
        for _ in range(args.repeats):  # in turns
            for name, fn, out in (("numpy", hi_steps, outs[:3]), ("jit", jit_pass, outs[3:])):
                c0 = time.process_time()
                fn(*common, *out)
                cpu[name].append(time.process_time() - c0)
        c_np, c_jit = statistics.median(cpu["numpy"]), statistics.median(cpu["jit"])
        same = all(np.array_equal(a, b) for a, b in zip(outs[:3], outs[3:], strict=True))
        print(f"width {width:5d}: numpy {c_np * 1e6 / args.length:7.1f} us/step "
              f"{c_np * 1e9 / m:7.1f} ns/row; compiled {c_jit * 1e9 / m:5.1f} ns/row; "
              f"numpy / compiled {c_np / c_jit:6.1f}; same bits {same}")


if __name__ == "__main__":
    main()
