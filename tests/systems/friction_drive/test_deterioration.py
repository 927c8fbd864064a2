"""The compiled augmented EKF against the engine's EKF (the same filter, built by the
reproduction), its exponential against scipy, missing channels against a huge-variance
oracle, and the gate on corrupted samples."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from rulkit.systems.friction_drive import drive
from rulkit.systems.friction_drive import reproduce as fr
from rulkit.systems.friction_drive.deterioration import (
    GATED,
    ONE_CHANNEL,
    EKFSettings,
    expm_taylor,
    track,
)

from .conftest import simulate_record, square_wave

Q = np.array([*drive.SPEED_Q_RATE, 0.0, 3e-8])


@pytest.fixture(scope="module")
def jump_record():
    """1 s of the seed's jump scenario (m: 0.01 -> 0.02 at 0.5 s) sampled every 2 ms."""
    dt = 2e-3
    cur = square_wave(1.0, dt)
    m = np.where(np.arange(cur.size) * dt < 0.5, 0.01, 0.02)
    frame, X = simulate_record(cur, m, dt=dt, seed=3)
    ys = frame[["w1_rad_s", "w2_rad_s"]].to_numpy()
    x0 = np.array([ys[0, 0], ys[0, 1], 10.004, 0.011])
    return ys, frame["current_A"].to_numpy(), x0, X


@pytest.mark.parametrize("scale", [1e-3, 0.3, 5.0, 80.0])
def test_expm_matches_scipy(scale: float) -> None:
    M = np.random.default_rng(1).standard_normal((8, 8)) * scale
    np.testing.assert_allclose(expm_taylor(M), expm(M), rtol=1e-12,
                               atol=1e-13 * np.abs(expm(M)).max())


@pytest.mark.parametrize(("midpoint", "n_sub"), [(False, 1), (True, 1), (True, 2)])
def test_kernel_is_the_engines_ekf(jump_record, midpoint: bool, n_sub: int) -> None:
    ys, cur, x0, _ = jump_record
    dt = 2e-3
    P0 = drive.SEED_P0.copy()
    ekf = fr.make_ekf(np.array([Q[3]]), np.zeros(1), drive.SEED_R[None], dt,
                      q_speed=Q[:2][None], midpoint=np.array([midpoint]), substeps=n_sub)
    ref = fr.run_filter(ekf, ys[1:, None, :], cur[:-1, None], x0[None], P0)
    got = track(ys, cur, x0, P0, EKFSettings(dt, n_sub, 0.0, 0.0, midpoint),
                drive.DEFAULT_PARAMS, Q, drive.SEED_R)
    sd = np.sqrt(ref.Pdiag[:, 0])
    # the same filter; rounding differs (Taylor vs Pade exponential, explicit 2 x 2 inverse)
    assert np.max(np.abs(got.x - ref.x[:, 0]) / sd) < 1e-5
    np.testing.assert_allclose(got.sd, sd, rtol=1e-6)
    assert np.max(np.abs(got.nu[1:] - ref.nu[:, 0]) / sd[1:, :2]) < 1e-5
    np.testing.assert_allclose(got.P, ref.P_final[0], rtol=1e-6, atol=1e-12)


def test_same_input_same_bits(jump_record) -> None:
    ys, cur, x0, _ = jump_record
    runs = [track(ys, cur, x0, drive.SEED_P0, EKFSettings(2e-3, 1, 0.0, 1e4, True),
                  drive.DEFAULT_PARAMS, Q, drive.SEED_R) for _ in range(2)]
    np.testing.assert_array_equal(runs[0].x, runs[1].x)
    np.testing.assert_array_equal(runs[0].P, runs[1].P)


def test_missing_samples_are_predictions_and_one_channel_is_an_infinite_variance(
        jump_record) -> None:
    ys, cur, x0, _ = jump_record
    st = EKFSettings(2e-3, 1, 0.0, 0.0, True)
    gap = ys.copy()
    gap[100:110] = np.nan
    ekf = fr.make_ekf(np.array([Q[3]]), np.zeros(1), drive.SEED_R[None], 2e-3,
                      q_speed=Q[:2][None], midpoint=np.array([True]))
    ref = fr.run_filter(ekf, gap[1:, None, :], cur[:-1, None], x0[None], drive.SEED_P0)
    got = track(gap, cur, x0, drive.SEED_P0, st, drive.DEFAULT_PARAMS, Q, drive.SEED_R)
    assert np.max(np.abs(got.x - ref.x[:, 0]) / np.sqrt(ref.Pdiag[:, 0])) < 1e-5
    one = ys.copy()
    one[200:260, 1] = np.nan  # the wheel's channel lost for 60 samples
    got = track(one, cur, x0, drive.SEED_P0, st, drive.DEFAULT_PARAMS, Q, drive.SEED_R)
    assert (got.status[200:260] == ONE_CHANNEL).all()
    # oracle: both channels with the wheel's variance made enormous over those samples
    # equals dropping it (the kernel takes R fixed: run the two spans separately)
    huge = drive.SEED_R.copy()
    huge[1, 1] = 1e30
    a = track(ys[:200], cur[:200], x0, drive.SEED_P0, st, drive.DEFAULT_PARAMS, Q,
              drive.SEED_R)
    filled = ys[199:260].copy()
    filled[1:, 1] = 0.0
    b = track(filled, cur[199:260], a.x[-1], a.P, st, drive.DEFAULT_PARAMS, Q, huge)
    assert np.max(np.abs(got.x[259] - b.x[-1]) / got.sd[259]) < 1e-6


def test_gate_keeps_a_spike_and_a_current_glitch_out_of_alpha_and_m(jump_record) -> None:
    ys, cur, x0, _ = jump_record
    st = EKFSettings(2e-3, 1, 0.0, 1e4, True)
    clean = track(ys, cur, x0, drive.SEED_P0, st, drive.DEFAULT_PARAMS, Q, drive.SEED_R)
    assert clean.count(GATED) == 0  # the jump of m stays far below the gate
    spiked = ys.copy()
    spiked[150, 0] += 1.0  # +1 rad/s on the motor speed
    glitch = cur.copy()
    glitch[120] += 5.0  # +5 A on one sample: the prediction is wrong, the speeds right
    for y, c, k in ((spiked, cur, 150), (ys, glitch, 121)):
        got = track(y, c, x0, drive.SEED_P0, st, drive.DEFAULT_PARAMS, Q, drive.SEED_R)
        assert got.status[k] == GATED and got.count(GATED) <= 2
        # alpha and m lose two samples' information, no more
        off = np.abs(got.x[-1, 2:] - clean.x[-1, 2:]) / clean.sd[-1, 2:]
        assert np.all(off < 0.2), off
        ungated = track(y, c, x0, drive.SEED_P0, st._replace(gate=0.0), drive.DEFAULT_PARAMS,
                        Q, drive.SEED_R)
        # without the gate the same sample moves the estimate by many standard deviations
        assert np.max(np.abs(ungated.x[k + 5, 2:] - clean.x[k + 5, 2:])
                      / clean.sd[k + 5, 2:]) > 3.0
