"""The toy degradation problem written as a NASA ProgPy model (benchmark-only; needs progpy).

Same discrete-time Markov chain as :class:`rulkit.systems.toy.model.ToyDegradation`:
``damage += rate dt``, noise on both states, ``z = damage`` with N(0, sigma_y^2) noise, failure
at ``damage >= 1``. ProgPy adds process noise as ``dt * N(0, process_noise)`` per step (see
``PrognosticsModel.apply_process_noise``), i.e. a standard deviation ``process_noise * dt``;
rulkit's model uses ``sigma sqrt(dt)``. :func:`make_model` sets
``process_noise = sigma / sqrt(dt)`` so both have the same per-step noise at the step ``dt``
used in a run.

Written against ProgPy's documented interface (a vectorised ``PrognosticsModel`` subclass with
``next_state``, ``output``, ``event_state`` and ``threshold_met``), read from its installed
source; no ProgPy code is copied.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def make_model(sigma_d: float, sigma_r: float, sigma_y: float, dt: float) -> Any:
    """A vectorised ProgPy model of the toy problem whose per-step noise matches at ``dt``."""
    from progpy import PrognosticsModel

    class ToyDegradationProgPy(PrognosticsModel):
        states = ["d", "r"]  # noqa: RUF012 - ProgPy's class-level declaration style
        inputs = []  # noqa: RUF012
        outputs = ["z"]  # noqa: RUF012
        events = ["failure"]  # noqa: RUF012
        is_vectorized = True
        default_parameters = {  # noqa: RUF012
            "x0": {"d": 0.0, "r": 0.01},
            "process_noise": {"d": 0.0, "r": 0.0},
            "measurement_noise": {"z": 0.0},
        }

        def next_state(self, x, u, dt):
            d = np.atleast_1d(x["d"] + x["r"] * dt)
            r = np.atleast_1d(x["r"])
            return self.StateContainer(np.array([d, r]))

        def output(self, x):
            return self.OutputContainer(np.array([np.atleast_1d(x["d"])]))

        def event_state(self, x):
            return {"failure": np.maximum(1.0 - x["d"], 0.0)}

        def threshold_met(self, x):
            return {"failure": x["d"] >= 1.0}

    s = 1.0 / math.sqrt(dt)
    return ToyDegradationProgPy(
        process_noise={"d": sigma_d * s, "r": sigma_r * s},
        measurement_noise={"z": sigma_y},
    )


def unweighted_samples(x: np.ndarray) -> Any:
    """ProgPy ``UnweightedSamples`` holding the rows of ``x`` (N, 2) as states d, r."""
    from progpy.uncertain_data import UnweightedSamples

    return UnweightedSamples({"d": x[:, 0].copy(), "r": x[:, 1].copy()})


def particle_filter(model: Any, particles0: np.ndarray, sigma_y: float) -> Any:
    """ProgPy's particle filter started from exactly ``particles0`` (N, 2)."""
    from progpy.state_estimators import ParticleFilter

    return ParticleFilter(
        model, unweighted_samples(particles0), t0=0.0, measurement_noise={"z": sigma_y}
    )


def run_filter(filt: Any, ys: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Assimilate ``ys[k]`` at ``t = (k + 1) dt``; returns the final particles' mean and std."""
    for k, y in enumerate(ys):
        filt.estimate((k + 1) * dt, {}, {"z": float(y)})
    mat = np.asarray(filt.particles.matrix, dtype=np.float64)  # (2, N)
    return mat.mean(axis=1), mat.std(axis=1)


def monte_carlo_rul(model: Any, samples: np.ndarray, dt: float, horizon: float) -> np.ndarray:
    """ProgPy's ``MonteCarlo`` predictor from ``samples`` (N, 2) at t0 = 0: the failure times
    (NaN where the horizon is reached first). ``save_freq = horizon`` keeps its state saving to
    a minimum (the most favourable setting for the peer)."""
    from progpy.predictors import MonteCarlo

    mc = MonteCarlo(model)
    res = mc.predict(
        unweighted_samples(samples), dt=dt, horizon=horizon, events=["failure"],
        save_freq=horizon, t0=0.0,
    )
    toe = [s["failure"] for s in res.time_of_event]
    return np.array([np.nan if v is None else float(v) for v in toe], dtype=np.float64)
