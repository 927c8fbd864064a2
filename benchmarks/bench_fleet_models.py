"""Benchmark: learned fleet models, one acquisition for each of 10^6 components (issue 11).

For each model (linear, exponential, paris), in one run on one core (medians of repeats):

* ``update_state``: one vectorised Kalman update of B components (docs/fleet-models.md eq. (2));
* ``rul_quantiles``: median and 90 % interval of the RUL of the B components (eq. (5));

printed as component updates per second and quantile triples per second, beside the seed's
tracker chain (``tracker_update``, state only) on the same B for scale (ratio = tracker time /
model time).

    .venv/bin/python benchmarks/bench_fleet_models.py              # B = 1e6, 5 repeats
    .venv/bin/python benchmarks/bench_fleet_models.py --n 100000 --repeats 3
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse

import numpy as np

from rulkit.fleet.learned.degradation import DegradationModel, UnitState, update_state
from rulkit.fleet.tracking.tracker_chain import TrackerConfig, TrackerState, tracker_update
from timing import median_time

MODELS = {
    "linear": DegradationModel(kind="linear", shape=0.0, mean=(0.1, 0.8),
                               cov=(1e-3, 0.0, 0.04), noise_sd=0.02, walk_sd=0.05,
                               time_scale=1000.0),
    "exponential": DegradationModel(kind="exponential", shape=-0.05, mean=(-2.0, 2.0),
                                    cov=(0.01, 0.0, 0.1), noise_sd=0.05, walk_sd=0.1,
                                    time_scale=1000.0),
    "paris": DegradationModel(kind="paris", shape=-0.5, mean=(-1.5, 1.5),
                              cov=(1e-3, 0.0, 0.1), noise_sd=0.03, walk_sd=0.05,
                              time_scale=1000.0),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=1_000_000, help="components (default 1e6)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    rng = np.random.default_rng(a.seed)
    b = a.n
    t1 = rng.uniform(50, 150, b)
    t2 = t1 + rng.uniform(5, 20, b)
    hi1 = rng.uniform(0.2, 0.5, b)
    hi2 = hi1 + rng.uniform(0.0, 0.1, b)
    cfg = TrackerConfig(dt=10.0)
    ts = tracker_update(TrackerState.empty(b), t1, hi1, cfg, outputs=False)[0]
    t_tr = median_time(lambda: tracker_update(ts, t2, hi2, cfg, outputs=False), a.repeats)
    print(f"B = {b} components, {a.repeats} repeats (median), seed {a.seed}, one core")
    print(f"{'model':12s} {'update s':>9s} {'updates/s':>11s} {'quantiles s':>12s} "
          f"{'triples/s':>10s} {'tracker/update':>15s}")
    for name, m in MODELS.items():
        st = update_state(UnitState.empty(m, b), m, t1, hi1)
        t_up = median_time(lambda m=m, st=st: update_state(st, m, t2, hi2), a.repeats)
        st2 = update_state(st, m, t2, hi2)
        t_q = median_time(lambda m=m, st2=st2: m.rul_quantiles(st2), max(1, a.repeats // 2))
        print(f"{name:12s} {t_up:9.3f} {b / t_up:11.3g} {t_q:12.3f} {b / t_q:10.3g} "
              f"{t_tr / t_up:15.2f}")
    print(f"{'seed tracker':12s} {t_tr:9.3f} {b / t_tr:11.3g}  (tracker_update, state only)")


if __name__ == "__main__":
    main()
