"""Benchmark: per-component tracker chain updates (embedded-rul.md section 2 budget).

Measures, on one core, in one run (medians of several repeats):

* ``tracker_update`` on B components in one vectorised call (the lean state-only path and
  the full path with validity, alert level and confidence limits), for B = 10^6 and, as
  1000 calls, B = 10^3;
* the same chain as a per-component Python loop (``tracker_update_loop``, the seed's
  pseudo-code with ``math`` scalars) on fewer components, per update;
* a memory floor: one read + write of the whole state (``np.copyto`` of its 7 float64 arrays
  + t + n), the least any update of the state must move;

and prints ratios (loop / vectorised, vectorised / memory floor), the cost per component update
and the state size per component.

    .venv/bin/python benchmarks/bench_trackers.py            # default: B = 1e6, 7 repeats
    .venv/bin/python benchmarks/bench_trackers.py --n 200000 --repeats 5
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np

from rulkit.fleet.tracking.tracker_chain import (
    TrackerConfig,
    TrackerState,
    tracker_update,
    tracker_update_loop,
)


def warm_state(b: int, cfg: TrackerConfig, rng: np.random.Generator) -> tuple[TrackerState, float]:
    """B components after 5 acquisitions (past the two-point initiation): steady-state path."""
    state = TrackerState.empty(b)
    h0 = rng.uniform(0.1, 0.6, b)
    k = rng.uniform(0.002, 0.02, b)
    t = 0.0
    for _ in range(5):
        z = h0 * np.exp(k * t) + rng.normal(0, 0.01, b)
        state, _ = tracker_update(state, np.full(b, t), z, cfg, outputs=False)
        t += cfg.dt
    return state, t


def timed(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1_000_000, help="components per vectorised call")
    ap.add_argument("--n-loop", type=int, default=20_000, help="components in the Python loop")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    cfg = TrackerConfig(dt=1.0, lambda_hi=0.5, lambda_rul=0.1, design_life=1e4, hi_sigma=0.01)
    gains = cfg.gains()

    b = args.n
    state, t = warm_state(b, cfg, rng)
    z = rng.uniform(0.1, 0.9, b)
    tt = np.full(b, t)

    lean = timed(lambda: tracker_update(state, tt, z, cfg, gains, outputs=False), args.repeats)
    full = timed(lambda: tracker_update(state, tt, z, cfg, gains, outputs=True), args.repeats)

    small_b, n_calls = 1000, 1000
    s_small, t_small = warm_state(small_b, cfg, rng)
    z_small = rng.uniform(0.1, 0.9, small_b)
    tt_small = np.full(small_b, t_small)

    def many_small() -> None:
        for _ in range(n_calls):
            tracker_update(s_small, tt_small, z_small, cfg, gains, outputs=False)

    small = timed(many_small, max(3, args.repeats // 2))

    bl = args.n_loop
    s_loop, t_loop = warm_state(bl, cfg, rng)
    z_loop = rng.uniform(0.1, 0.9, bl)
    tt_loop = np.full(bl, t_loop)
    loop = timed(lambda: tracker_update_loop(s_loop, tt_loop, z_loop, cfg, gains),
                 max(3, args.repeats // 2))

    # the vectorised call and the loop give the same numbers (tested; checked here too)
    a, _ = tracker_update(s_loop, tt_loop, z_loop, cfg, gains, outputs=False)
    r = tracker_update_loop(s_loop, tt_loop, z_loop, cfg, gains)
    assert np.allclose(a.abg, r.abg, rtol=1e-12, atol=1e-12)

    arrays = [state.t, state.n, state.hi, state.ab, state.rul, state.abg]
    dst = [np.empty_like(x) for x in arrays]

    def copy_state() -> None:
        for d, s in zip(dst, arrays, strict=True):
            np.copyto(d, s)

    floor = timed(copy_state, args.repeats)

    per_vec = lean / b
    per_full = full / b
    per_small = small / (small_b * n_calls)
    per_loop = loop / bl
    print(f"tracker chain, one core, medians of {args.repeats} repeats (seed {args.seed})")
    print(f"state size: {state.nbytes / b:.0f} bytes per component "
          "(7 tracker numbers + last time + count, float64/int64)")
    rows = [
        (f"vectorised, state only, B = {b}, 1 call", lean, per_vec),
        (f"vectorised + validity/alerts/limits, B = {b}, 1 call", full, per_full),
        (f"vectorised, state only, B = {small_b}, {n_calls} calls", small, per_small),
        (f"per-component Python loop, B = {bl}", loop, per_loop),
        (f"memory floor: copy the state once, B = {b}", floor, floor / b),
    ]
    print(f"{'path':58s} {'total s':>9s} {'ns/update':>10s}")
    for label, total, per in rows:
        print(f"{label:58s} {total:9.4f} {per * 1e9:10.1f}")
    print(f"10^6 component updates, vectorised state only: {per_vec * 1e6:.3f} s "
          f"(with outputs {per_full * 1e6:.3f} s; budget 1 s)")
    print(f"ratio Python loop / vectorised (state only): {per_loop / per_vec:.0f}x")
    print(f"ratio Python loop / vectorised (with outputs): {per_loop / per_full:.0f}x")
    print(f"ratio vectorised (state only) / memory floor: {lean / floor:.1f}x")


if __name__ == "__main__":
    main()
