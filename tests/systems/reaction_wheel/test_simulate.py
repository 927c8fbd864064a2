"""Simulated telemetry: the compiled wheel equals the numpy model's RK4 loop, the noise is the
one asked for, and each corruption does what it says (and nothing else)."""

from __future__ import annotations

import numpy as np
import pytest

from rulkit.systems.reaction_wheel.simulate import CORRUPTIONS, SHIFT_S, corrupt, simulate_telemetry
from rulkit.systems.reaction_wheel.telemetry import COLUMNS
from rulkit.systems.reaction_wheel.wheel import IthacoParams, ReactionWheel, rk4_wheel_step


@pytest.fixture(scope="module")
def df():
    t = np.arange(0.0, 100.0, 0.05)
    return simulate_telemetry(30.0 + 0.02 * t, np.where(t < 50, 1.0, 2.5),
                              np.random.default_rng(0))


def test_simulation_equals_the_numpy_model_and_its_noise(df) -> None:
    p = IthacoParams()
    T, V = df["T_lub_C"].to_numpy(), df["v_comm_V"].to_numpy()
    x = ReactionWheel(p).steady_state(V[0], T[0])[None]
    X = [x[0]]
    for k in range(len(df) - 1):
        x = rk4_wheel_step(x, V[k], T[k], k * 0.05, 0.05, p)
        X.append(x[0])
    X = np.array(X)
    noise_w = df["speed_rad_s"].to_numpy() - X[:, 1]
    noise_I = df["current_A"].to_numpy() - X[:, 0]
    ref = np.random.default_rng(0).standard_normal((len(df), 2)) * [3e-3, 3e-2]
    np.testing.assert_allclose(noise_w, ref[:, 0], atol=1e-9)
    np.testing.assert_allclose(noise_I, ref[:, 1], atol=1e-9)
    assert list(df.columns) == [*COLUMNS, "T_lub_C"]


@pytest.mark.parametrize("kind", CORRUPTIONS)
def test_each_corruption_changes_only_what_it_names(df, kind: str) -> None:
    bad = corrupt(df, kind, np.random.default_rng(1), events=3)
    if kind == "shift":
        # the shift, to the 2.4e-7 s a float64 holds at 1.7e9 s
        np.testing.assert_allclose(bad["time_s"] - SHIFT_S, df["time_s"], rtol=0, atol=3e-7)
        return
    if kind == "gap":
        assert len(bad) < len(df) and np.all(np.diff(bad["time_s"]) > 0)
        assert set(bad["time_s"]) <= set(df["time_s"])
        return
    assert len(bad) == len(df)
    changed = {c for c in COLUMNS if not np.array_equal(bad[c], df[c], equal_nan=True)}
    if kind.startswith("spike_"):
        col = {"spike_speed": "speed_rad_s", "spike_current": "current_A",
               "spike_command": "v_comm_V"}[kind]
        assert changed == {col}
        assert np.count_nonzero(bad[col] != df[col]) == 3
    elif kind == "dropout":
        assert changed and bad[list(changed)].isna().any().all()
    else:  # stuck: runs of equal values (>= 2 s) where the signal moved
        assert changed <= {"speed_rad_s", "current_A"}
        for col in changed:
            assert np.count_nonzero(np.diff(bad[col].to_numpy()) == 0) >= 39
    assert "time_s" not in changed
    with pytest.raises(ValueError, match="kind"):
        corrupt(df, "bitflip", np.random.default_rng(1))
