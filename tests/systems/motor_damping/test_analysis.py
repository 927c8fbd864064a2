"""The multi-scale EKF on a user's records: a clearly negative damping is refused as
physically impossible (wrong units or constants), never reported."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rulkit.systems.motor_damping.analysis import (
    NegativeDampingError,
    analyse_pullup,
    check_damping_physical,
)
from rulkit.systems.motor_damping.motor import LifeTestConfig, MotorConstants, simulate_life_test
from rulkit.systems.motor_damping.pullup import from_frame


def _life_test_frame(consts: MotorConstants | None = None) -> tuple[pd.DataFrame, np.ndarray]:
    cfg = LifeTestConfig(n_cycles=5, duration=15.0, c0=6e-5, slope=1e-5, scatter_sd=1e-6,
                         **({"consts": consts} if consts else {}))
    lt = simulate_life_test(cfg, np.random.default_rng(1))
    n, t = lt.speed.shape
    return pd.DataFrame({
        "cycle": np.repeat(lt.cycle.astype(int), t), "time": np.tile(lt.time, n),
        "current": lt.current.ravel(), "speed": lt.speed.ravel(),
        "acceleration": lt.acceleration.ravel()}), lt.damping


def test_speed_in_rpm_gives_a_named_error_not_a_negative_damping() -> None:
    df, _ = _life_test_frame()
    rpm = 60.0 / (2.0 * np.pi)
    bad = df.assign(speed=df["speed"] * rpm, acceleration=df["acceleration"] * rpm)
    with pytest.raises(NegativeDampingError, match=r"f.csv: cycle 1: estimated damping c = "
                                                   r"-\d.*negative.*5 of 5 cycles.*not rpm"):
        analyse_pullup(from_frame(bad, source="f.csv"), mc_samples=10)


def test_other_motor_constants_recovered_with_its_machine_values() -> None:
    other = MotorConstants(K=0.05, J=5e-3, T_L=3e-3, I_s=2.0, I_p=2.0, tau_I=0.5)
    df, truth = _life_test_frame(other)
    res = analyse_pullup(from_frame(df), other, mc_samples=10)
    err = (res.table["damping"] - truth) / res.table["damping_sd"]
    assert np.all(np.abs(err) < 5.0)
    # the synthetic motor's constants on this record: far off (or impossible)
    try:
        wrong = analyse_pullup(from_frame(df), mc_samples=10)
    except NegativeDampingError:
        return
    assert np.all(np.abs(wrong.table["damping"] - truth) > 50 * res.table["damping_sd"])


def test_negative_within_its_uncertainty_is_not_an_error() -> None:
    c = np.array([1e-6, -2e-9, 3e-6])
    check_damping_physical(np.array([1.0, 2.0, 3.0]), c, np.full(3, 1e-18))  # 2 sd: chance
    with pytest.raises(NegativeDampingError, match=r"cycle 2: .*1 of 3 cycles"):
        check_damping_physical(np.array([1.0, 2.0, 3.0]), c, np.full(3, 1e-20))  # 20 sd


@pytest.mark.parametrize(("column", "offset"), [("current", 3.0), ("speed", 50.0),
                                                ("acceleration", 100.0)])
def test_a_corrupted_sample_costs_one_sample_not_the_cycles_damping(column: str,
                                                                    offset: float) -> None:
    from rulkit.systems.motor_damping.machine import read_motor_machine

    df, truth = _life_test_frame()
    kw = read_motor_machine(None).analysis_kwargs()  # the command's settings: gate 100
    kw["mc_samples"] = 10
    clean = analyse_pullup(from_frame(df), **kw)
    t = len(df) // 5
    bad = df.copy()
    bad.loc[2 * t + 150, column] += offset  # one sample in cycle 3
    got = analyse_pullup(from_frame(bad), **kw)
    shift = np.abs(got.table["damping"] - clean.table["damping"]) / clean.table["damping_sd"]
    assert shift[2] < 3.0 and got.table["gated"].iloc[2] >= 1
    assert np.all(np.abs(got.table["damping"] - truth) < 5 * got.table["damping_sd"])
    if column == "current":  # without the gate the glitch moves that cycle by far more
        kw["micro"] = read_motor_machine(None).with_overrides(
            {"--gate": ("micro", "gate", 0.0)}).micro
        off = analyse_pullup(from_frame(bad), **kw)
        assert abs(off.table["damping"][2] - clean.table["damping"][2]) > 50 * clean.table[
            "damping_sd"][2]
