"""Lubricant-loss physics: loss law, scenarios, Euler-Maclaurin truth vs the direct 0.05 s sum."""

from __future__ import annotations

import numpy as np
import pytest

from rulkit.systems.reaction_wheel.lubrication import (
    PATHS,
    SCENARIO_1,
    SCENARIO_2,
    WINDOW_S,
    TemperaturePath,
    loss_rate,
    true_window_increments,
)


def test_loss_rate_closed_form_and_singularity() -> None:
    assert loss_rate(30.0, 37.0, 7.494e-6) == pytest.approx(7.494e-6 * np.exp(-37.0 / 30.0),
                                                             rel=1e-15)
    # sensitivity ~4 % per C at 30 C in deg C units (spec section 4)
    r = loss_rate(np.array([30.0, 31.0]), 37.0, 1.0)
    assert r[1] / r[0] - 1 == pytest.approx(np.exp(37 / 30 - 37 / 31) - 1, rel=1e-12)
    assert 0.035 < r[1] / r[0] - 1 < 0.045
    with pytest.raises(ValueError, match="below 5"):
        loss_rate(np.array([20.0, 2.0]), 37.0, 1.0)
    with pytest.raises(ValueError, match="non-finite"):
        loss_rate(np.array([np.nan]), 37.0, 1.0)


def test_scenarios_table4() -> None:
    t = np.array([158.9 * 60, 159.0 * 60, 159.1 * 60])
    b, beta0 = SCENARIO_1.parameters(t)
    assert list(b) == [37.0, 37.0, 25.0]
    assert list(beta0) == [7.494e-6, 7.494e-6, 8.054e-6]
    b2, beta2 = SCENARIO_2.parameters(t)
    assert list(b2) == [37.0, 37.0, 49.0] and beta2[-1] == 7.0e-6
    # 159 min falls inside window 40 (index 39)
    assert int(SCENARIO_1.fault_time_s // WINDOW_S) == 39


@pytest.mark.parametrize("sid", [1, 2])
def test_euler_maclaurin_truth_matches_direct_sum(sid: int) -> None:
    from rulkit.systems.reaction_wheel.lubrication import SCENARIOS

    direct = true_window_increments(PATHS[sid], SCENARIOS[sid], 120, method="direct")
    em = true_window_increments(PATHS[sid], SCENARIOS[sid], 120)
    np.testing.assert_allclose(em, direct, rtol=1e-12)
    # a path with a much faster orbit still agrees (window far from the fault)
    fast = TemperaturePath(orbit_period_s=1800.0, orbit_amplitude_c=8.0)
    np.testing.assert_allclose(true_window_increments(fast, SCENARIOS[sid], 60),
                               true_window_increments(fast, SCENARIOS[sid], 60, method="direct"),
                               rtol=1e-11)
