"""Simulated drive records with known truth for the tests of ``rulkit drive``."""

from __future__ import annotations

import numpy as np
import pandas as pd

from rulkit.systems.friction_drive import drive as fd


def simulate_record(currents: np.ndarray, m_path: np.ndarray, *, dt: float = 1e-3,
                    params: fd.FrictionDriveParams = fd.DEFAULT_PARAMS,
                    sigma: tuple[float, float] = (1e-4, 1e-5), seed: int = 0,
                    alpha_start: float | None = None) -> tuple[pd.DataFrame, np.ndarray]:
    """A record of K + 1 samples: the full model from rest (alpha at ``alpha_start``, default
    ``params.alpha0``) integrated with 10 RK4 sub-steps per sample under ``currents`` (K,)
    (sample k's current held to sample k+1) and ``m_path`` (K,), speeds with Gaussian noise
    ``sigma``. Returns the frame (time_s, current_A, w1_rad_s, w2_rad_s) and the truth (K+1,
    4)."""
    a0 = params.alpha0 if alpha_start is None else alpha_start
    x0 = np.array([[0.0, 0.0, a0, m_path[0]]])
    X = fd.integrate_path(x0, currents, dt, n_sub=10, m_path=m_path, params=params)[:, 0]
    X[1:, 3] = m_path
    rng = np.random.default_rng(seed)
    ys = X[:, :2] + rng.standard_normal((X.shape[0], 2)) * np.asarray(sigma)
    t = np.arange(X.shape[0]) * dt
    frame = pd.DataFrame({"time_s": t, "current_A": np.append(currents, currents[-1]),
                          "w1_rad_s": ys[:, 0], "w2_rad_s": ys[:, 1]})
    return frame, X


def square_wave(duration: float, dt: float = 1e-3, amplitude: float = 20.0) -> np.ndarray:
    """The seed's 0/amplitude square wave (on during [2k, 2k+1) s) over ``duration``, (K,)."""
    return fd.square_wave_current(np.arange(round(duration / dt)) * dt, amplitude)
