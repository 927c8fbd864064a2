"""Benchmark: learned fleet models, one acquisition for each of 10^6 components.

For each candidate, in one run on one core (medians of repeats):

* ``update``: one acquisition for each of B components (docs/fleet-models.md eq. (2), (8));
* ``rul_quantiles``: median and 90 % interval of the RUL of the B components (eq. (5), (10));

printed as component updates per second and quantile triples per second, beside the seed's
tracker chain (``tracker_update``, state only) on the same B for scale (ratio = tracker time /
model time). The Gaussian models (linear, exponential, paris, paris-additive, the baselines)
run on B = ``--n`` components; the onset model, whose state is 12 Gaussians per unit, on
B = ``--n-onset``.

    .venv/bin/python benchmarks/bench_fleet_models.py              # B = 1e6, 5 repeats
    .venv/bin/python benchmarks/bench_fleet_models.py --n 100000 --repeats 3
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse

import numpy as np

from rulkit.fleet.learned.degradation import DegradationModel
from rulkit.fleet.learned.hi_noise import HiNoiseModel
from rulkit.fleet.learned.onset import OnsetModel
from rulkit.fleet.learned.regression import RegressionModel
from rulkit.fleet.learned.similarity import SimilarityModel
from rulkit.fleet.tracking.tracker_chain import TrackerConfig, TrackerState, tracker_update
from timing import median_time

GROWTH = {"shape": 0.0, "mean": (-2.3, 1.5), "cov": (0.01, 0.0, 0.2), "hi_noise_sd": 0.02,
          "log_noise_sd": 0.0, "walk_sd": 0.05, "time_scale": 1000.0}

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
    "paris-additive": HiNoiseModel(noise="additive", **GROWTH),
    "regression": RegressionModel(shape=0.0, window=20.0, noise_var=1e-3, time_scale=1000.0),
    "similarity": SimilarityModel(
        coefs=tuple(np.column_stack([np.full(20, 0.1), np.linspace(0.4, 0.9, 20),
                                     np.zeros(20)]).ravel()),
        lives=tuple(np.linspace(1.0, 2.2, 20)), noise_var=4e-4, time_scale=1000.0),
    "onset": OnsetModel(noise="additive", grid=tuple(np.linspace(0.0, 2.0, 12)),
                        onset_mean=0.6, onset_sd=0.3, **GROWTH),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=1_000_000, help="components (default 1e6)")
    ap.add_argument("--n-onset", type=int, default=100_000,
                    help="components for the onset model (default 1e5)")
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
    print(f"{'model':14s} {'update s':>9s} {'updates/s':>11s} {'quantiles s':>12s} "
          f"{'triples/s':>10s} {'tracker/update':>15s}")
    for name, m in MODELS.items():
        k = a.n_onset if name == "onset" else b
        st = m.update(m.empty_state(k), t1[:k], hi1[:k])
        t_up = median_time(lambda m=m, st=st, k=k: m.update(st, t2[:k], hi2[:k]), a.repeats)
        st2 = m.update(st, t2[:k], hi2[:k])
        t_q = median_time(lambda m=m, st2=st2: m.rul_quantiles(st2), max(1, a.repeats // 2))
        ratio = t_tr * k / b / t_up
        print(f"{name:14s} {t_up:9.3f} {k / t_up:11.3g} {t_q:12.3f} {k / t_q:10.3g} "
              f"{ratio:15.2f}" + (f"  (B = {k})" if k != b else ""))
    print(f"{'seed tracker':14s} {t_tr:9.3f} {b / t_tr:11.3g}  (tracker_update, state only)")


if __name__ == "__main__":
    main()
