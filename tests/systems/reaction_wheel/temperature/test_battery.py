"""The battery of simulated records: a case is reproducible and independent of the others,
its paths have the documented shapes, and the score compares matching rows."""

from __future__ import annotations

import numpy as np
import pandas as pd

from rulkit.systems.reaction_wheel.temperature.battery import (
    DURATION_S,
    KINDS,
    BatteryCase,
    battery_cases,
    battery_paths,
    battery_record,
    score,
)


def test_cases_are_reproducible_and_independent() -> None:
    cases = battery_cases(seed=3, runs=2)
    assert len(cases) == (len(KINDS) - 1) * 2 * 2 * 2 + 2 * 2  # table3: the seed wheel only
    a, _, _ = battery_record(cases[5])
    b, _, _ = battery_record(BatteryCase(**vars(cases[5])))
    pd.testing.assert_frame_equal(a, b)
    c, _, _ = battery_record(cases[6])
    assert not np.array_equal(a["speed_rad_s"], c["speed_rad_s"])


def test_paths_have_their_shapes() -> None:
    rng = np.random.default_rng(0)
    T, V = battery_paths("step", rng)
    assert T.size == round(DURATION_S / 0.05) and len(np.unique(T)) == 2
    assert np.all((V >= 1.0) & (V <= 3.0))
    T, _ = battery_paths("ramp", rng)
    assert np.allclose(np.diff(T), np.diff(T)[0])
    T, _ = battery_paths("sine", rng)
    assert 1.0 <= (T.max() - T.min()) / 2 <= 5.0 + 1e-9


def test_score_matches_rows_by_time() -> None:
    truth = pd.DataFrame({"time_s": [0.0, 100.0, 200.0, 300.0], "T_lub_C": [30.0] * 4})
    est = pd.DataFrame({"time_s": [200.0, 300.0], "T_mean": [31.5, 30.0], "T_lo": [29.0, 29.5],
                        "T_hi": [31.0, 30.5]})
    sc = score(truth, est)
    assert np.isclose(sc["rmspe"], 100 * np.sqrt((1.5 / 30) ** 2 / 2))
    assert sc["coverage"] == 1.0
