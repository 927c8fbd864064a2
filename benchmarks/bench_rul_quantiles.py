"""The CPU of a learned model's RUL quantiles (docs/fleet-models.md, eq. (5b)) per unit: a
paris-mixed model's states after 30 acquisitions at an exponential cadence, the median
(and 5 %, 95 %) of 1, 100 and 10,000 units at once, medians of 7 timings. With ``--against
SRC`` the same states are timed with another checkout's ``src`` in a fresh interpreter, in
turns with this one, and the ratio of the medians is printed.

    .venv/bin/python benchmarks/bench_rul_quantiles.py --against /tmp/old/src
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

SIZES = (1, 100, 10_000)


def timings() -> dict[int, float]:
    """Seconds per call of ``rul_quantiles`` for each size (medians of 7)."""
    import numpy as np

    from rulkit.fleet.learned.hi_noise import HiNoiseModel

    model = HiNoiseModel(noise="mixed", shape=0.0, mean=(-2.3, 1.5), cov=(0.01, 0.0, 0.2),
                         hi_noise_sd=0.01, log_noise_sd=0.04, walk_sd=0.05, time_scale=1000.0)
    rng = np.random.default_rng(0)
    out = {}
    for size in SIZES:
        state = model.empty_state(size)
        t = np.zeros(size)
        for _ in range(30):
            t = t + rng.exponential(20.0, size)
            hi = np.exp(-2.3 + 1.5 * t / 1000.0) + 0.01 * rng.standard_normal(size)
            state = model.update(state, t, np.clip(hi, 0.01, 0.99))
        model.rul_quantiles(state)  # compiles or loads the kernels
        reps = max(2, 300 // size)
        runs = []
        for _ in range(7):
            t0 = time.process_time()
            for _ in range(reps):
                model.rul_quantiles(state)
            runs.append((time.process_time() - t0) / reps)
        out[size] = statistics.median(runs)
    return out


def _in_child(src: str | None) -> dict[int, float]:
    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = src
    res = subprocess.run([sys.executable, __file__, "--json"], env=env, check=True,
                         capture_output=True, text=True)
    return {int(k): v for k, v in json.loads(res.stdout).items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--against", help="Another checkout's src, timed in turns.")
    ap.add_argument("--turns", type=int, default=2)
    ap.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.json:
        print(json.dumps(timings()))
        return
    print(f"bench_rul_quantiles: load average {os.getloadavg()[0]:.1f}")
    sides = {"this code": None} | ({args.against: args.against} if args.against else {})
    got: dict[str, list[dict[int, float]]] = {k: [] for k in sides}
    for _ in range(args.turns):
        for name, src in sides.items():
            got[name].append(_in_child(src))
    for size in SIZES:
        med = {k: statistics.median(r[size] for r in v) for k, v in got.items()}
        line = ", ".join(f"{k} {v * 1e6:.0f} us ({v / size * 1e6:.2f} us per unit)"
                         for k, v in med.items())
        if args.against:
            line += f"; ratio {med['this code'] / med[args.against]:.2f}"
        print(f"  {size:>6} units: {line}")
    print(f"load average at end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
