"""The onset model's grid on the onset goal fleet: 12 onset values against the refined grid.

docs/fleet-models.md sections 6 and 7. Fits the onset model on all units of the onset goal fleet
(seed 0, 40 units, as ``rulkit fleet-data`` writes it) twice: with its grid kept at 12 values,
and with the step halved until the likelihood converges (``fit_onset``'s default), and prints
each fit's grid, learned law (Paris exponent, rate, onset prior), log-likelihood on its own grid
and on a brute-force grid of 385 values at its parameters, and the generator's true values:

    .venv/bin/python benchmarks/onset_grid.py
"""

from __future__ import annotations

import os
import time

import numpy as np

from rulkit.fleet.learned import onset
from rulkit.fleet.learned.datasets import GOAL_FLEETS, goal_fleet, paris_life
from rulkit.fleet.learned.filter_kernels import negative_log_likelihood
from rulkit.fleet.learned.histories import histories_from_frame


def main() -> None:
    print(f"load average {os.getloadavg()[0]:.1f}")
    ss = np.random.SeedSequence(0).spawn(2 + len(GOAL_FLEETS))
    df, _ = goal_fleet("onset", np.random.default_rng(ss[2 + list(GOAL_FLEETS).index("onset")]))
    hist = histories_from_frame(df, "synthetic_onset")
    kw = GOAL_FLEETS["onset"]
    rate = paris_life(float(kw["h0"]), np.ones(1), float(kw["m"]))[0] / 300.0
    mean_onset = float(kw["onset_frac"]) * 300.0
    print(f"generator: Paris exponent {kw['m']}, median rate {rate:.4g} per time unit, onset "
          f"mean {mean_onset:.4g} (sd {0.3 * mean_onset:.3g})")
    for grid_max in (onset.ONSET_GRID_SIZE, onset.ONSET_GRID_MAX):
        onset.ONSET_GRID_MAX = grid_max
        t0 = time.perf_counter()
        model = onset.fit_onset(hist)
        fine = np.linspace(0.0, model.grid[-1], 12 * 32 + 1)
        exact = -negative_log_likelihood(model.params().theta(), hist.t / model.time_scale,
                                         hist.hi, hist.start.astype(np.int64), model.shape, fine)
        print(f"\ngrid of up to {grid_max} values ({time.perf_counter() - t0:.0f} s): kept "
              f"{len(model.grid)}, step {model.grid[1] * model.time_scale:.3g}; log-likelihood "
              f"{model.log_likelihood:.2f} on it, {exact:.2f} on 385 values\n  "
              + model.describe())


if __name__ == "__main__":
    main()
