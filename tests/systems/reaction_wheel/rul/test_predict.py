"""Step 3 on a user's posterior: the cycle crossing equals the engine's propagate_to_threshold
on the same windows, the closed form at constant temperature, and censoring at the horizon."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from rulkit.prognosis.rul import propagate_to_threshold
from rulkit.systems.reaction_wheel.rul.predict import (
    ProfileError,
    cycle_from_profile,
    cycle_increments,
    predict_rul,
    read_profile,
)

RNG = np.random.default_rng(0)
PARTS = np.column_stack([RNG.uniform(20, 40, 60), RNG.uniform(6e-6, 9e-6, 60)])
W = np.full(60, 1 / 60)


def test_cycle_crossing_equals_the_engine_on_the_same_windows() -> None:
    t = np.arange(0.0, 3 * 86400 + 1, 600.0)
    T = 30 + 3 * np.sin(2 * np.pi * t / 5700) + 0.5 * t / 86400
    cyc = cycle_from_profile(t, T, 6 * 3600.0)
    d = predict_rul(PARTS, W, 1.0, cyc, 6.0, 3650.0)
    inc = cycle_increments(PARTS[:, 0], PARTS[:, 1], cyc)

    def step(x, u, t, dt, g):
        out = x.copy()
        out[:, 0] += inc[:, round(t / (6 * 3600.0)) % inc.shape[1]]
        return out

    e = propagate_to_threshold(np.column_stack([np.ones(60), np.zeros(60)]), step,
                               lambda x: x[:, 0], 6.0, t0=0.0, dt=6 * 3600.0,
                               horizon=3650 * 86400.0, rng=np.random.default_rng(1))
    np.testing.assert_allclose(d.samples, e.samples / 86400.0, rtol=1e-12)


def test_constant_temperature_has_the_closed_form_and_censoring() -> None:
    cyc = cycle_from_profile(np.array([0.0, 86400.0]), np.array([30.0, 30.0]), 3600.0)
    d = predict_rul(PARTS, W, 1.0, cyc, 6.0, 3650.0)
    rate = PARTS[:, 1] * np.exp(-PARTS[:, 0] / 30.0)
    np.testing.assert_allclose(d.samples, 5.0 / rate / 86400.0, rtol=1e-9)
    short = predict_rul(PARTS, W, 1.0, cyc, 6.0, 5.0)
    assert short.censored.all() and np.all(short.samples == 5.0)
    assert predict_rul(PARTS, W, 7.0, cyc, 6.0, 10.0).median == 0.0  # already past


def test_profile_files_are_checked(tmp_path: Path) -> None:
    pd.DataFrame({"time_s": [0, 3600, 7200], "T_C": [30, 31, 30]}).to_csv(tmp_path / "f.csv",
                                                                          index=False)
    t, _ = read_profile(tmp_path / "f.csv")
    assert t[-1] == 7200.0
    pd.DataFrame({"time_s": [5, 3600], "T_C": [30, 31]}).to_csv(tmp_path / "g.csv", index=False)
    with pytest.raises(ProfileError, match="time_s = 0"):
        read_profile(tmp_path / "g.csv")
    with pytest.raises(ProfileError, match=r"reaches 2\.\d+ C"):
        cycle_from_profile(np.array([0.0, 3600.0]), np.array([30.0, 2.0]), 600.0)
