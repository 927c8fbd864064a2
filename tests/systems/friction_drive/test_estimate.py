"""``rulkit drive`` as a library call on simulated records with known truth: paths the
reproduction never runs, other drive constants, corrupted samples, a shifted time origin and
wrong units."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from rulkit.systems.friction_drive.drive import DEFAULT_PARAMS
from rulkit.systems.friction_drive.estimate import (
    DriveModelMismatchError,
    ImpossibleDriveEstimateError,
    _check_physical,
    estimate,
)
from rulkit.systems.friction_drive.machine import read_drive_machine
from rulkit.systems.friction_drive.record import ImplausibleDriveRecordError, drive_record

from .conftest import simulate_record, square_wave

# the defaults with a quick RUL (no LSODA cross-check: tested in test_rul.py / the CLI test)
MACHINE = read_drive_machine(None).with_overrides({
    "samples": ("rul", "samples", 40), "checks": ("rul", "lsoda_checks", 0)})


def _run(frame: pd.DataFrame, machine=MACHINE, seed: int = 0):
    return estimate(drive_record(frame, machine), machine, np.random.default_rng(seed))


def _within(est, truth: np.ndarray, k: float = 3.0) -> np.ndarray:
    """|estimate - truth| / sd of alpha and m at the last sample."""
    err = np.abs(est.track.x[-1, 2:] - truth[-1, 2:]) / est.track.sd[-1, 2:]
    assert np.all(err < k), err
    return err


@pytest.fixture(scope="module")
def seed_record():
    """4 s of the seed's square wave, m constant 0.01."""
    cur = square_wave(4.0)
    return simulate_record(cur, np.full(cur.size, 0.01), seed=11)


def test_constant_wear_recovered_consistently(seed_record) -> None:
    frame, X = seed_record
    est = _run(frame)
    _within(est, X)
    assert est.innovations is not None and est.innovations.consistent
    # the RUL from the truth's last state lies inside the Monte Carlo spread
    r = est.rul
    assert r.pessimistic_h < r.rul.median < r.optimistic_h
    assert r.rul.fraction_censored == 0.0


def test_unseen_current_profile_and_drifting_wear() -> None:
    # a random telegraph current (0 / 12 / 25 A, dwell 0.2-1.5 s) and m drifting up by 50 %
    rng = np.random.default_rng(4)
    levels, cur = [0.0, 12.0, 25.0], []
    while len(cur) < 5000:
        cur += [levels[rng.integers(3)]] * int(rng.uniform(200, 1500))
    cur = np.array(cur[:5000])
    m = np.linspace(0.008, 0.012, cur.size)
    frame, X = simulate_record(cur, m, seed=5)
    est = _run(frame)
    _within(est, X)
    assert est.innovations is not None and est.innovations.nis_ok


def test_another_drive_needs_its_own_machine_file() -> None:
    other = replace(DEFAULT_PARAMS, r1=0.05, r2=0.3, J1=6e-4, J2=0.35, Km=0.06, B1=8e-3,
                    B2=3e-3, alpha0=6.0)
    cur = square_wave(3.0, amplitude=15.0)
    frame, X = simulate_record(cur, np.full(cur.size, 0.02), params=other, seed=6)
    values = {k: getattr(other, k) for k in ("r1", "r2", "B1", "B2", "J1", "J2", "Km",
                                              "alpha0")}
    mine = MACHINE.with_overrides({k: ("drive", k, v) for k, v in values.items()}
                                  | {"a": ("filter", "alpha_init", 6.0)})
    _within(_run(frame, mine), X)
    with pytest.raises(DriveModelMismatchError, match="does not describe this record"):
        _run(frame)  # the seed's drive on another drive's record


def test_corrupted_samples_do_not_move_the_estimate(seed_record) -> None:
    frame, X = seed_record
    clean = _run(frame)
    bad = frame.copy()
    bad.loc[700, "w1_rad_s"] += 2.0  # spikes
    bad.loc[1900, "w2_rad_s"] -= 0.5
    bad.loc[2500, "current_A"] += 8.0  # a current glitch
    bad.loc[1200:1260, "w2_rad_s"] = np.nan  # a dropout of one channel
    bad.loc[3100:3140, "w1_rad_s"] = bad.loc[3100, "w1_rad_s"]  # a stuck sensor
    bad = bad.drop(index=range(2000, 2030))  # a time gap of 30 samples
    est = _run(bad)
    _within(est, X)
    shift = np.abs(est.track.x[-1, 2:] - clean.track.x[-1, 2:]) / clean.track.sd[-1, 2:]
    assert np.all(shift < 0.5), shift
    assert est.record.n_gap_steps == 30 and est.record.n_missing == 61


def test_time_origin_and_date_times_do_not_change_the_estimate(seed_record) -> None:
    frame, _ = seed_record
    base = _run(frame)
    for t in (frame["time_s"] + 1.7e9,
              pd.Timestamp("2024-03-01T00:00:00Z") + pd.to_timedelta(frame["time_s"], "s")):
        moved = _run(frame.assign(time_s=t))
        # times near 1.7e9 s are rounded to 2.4e-7 s: the sampling step from all rows moves by
        # ~2e-11 relative, the estimates by ~1e-4 of their standard deviations
        assert np.max(np.abs(moved.track.x - base.track.x) / base.track.sd) < 1e-3
        assert moved.rul.rul.median == pytest.approx(base.rul.rul.median, rel=1e-5)


def test_wrong_units_are_named_errors(seed_record) -> None:
    frame, _ = seed_record
    rpm = 60.0 / (2.0 * np.pi)
    with pytest.raises(ImplausibleDriveRecordError, match="speed in rpm"):
        _run(frame.assign(w1_rad_s=frame["w1_rad_s"] * rpm, w2_rad_s=frame["w2_rad_s"] * rpm))
    wide = MACHINE.with_overrides({"i": ("limits", "max_current", 1e5)})
    with pytest.raises(DriveModelMismatchError, match=r"samples \(\d+\.\d%\) are outside"):
        _run(frame.assign(current_A=frame["current_A"] * 1000.0), wide)  # mA


def test_negative_contact_quality_or_wear_is_refused(seed_record) -> None:
    frame, _ = seed_record
    est = _run(frame)
    x = est.track.x.copy()
    x[-1, 3] = -10.0 * est.track.sd[-1, 3]
    with pytest.raises(ImpossibleDriveEstimateError, match=r"wear rate m = -.* is negative"):
        _check_physical(replace(est.track, x=x), est.record)
    x[-1, 3] = -2.0 * est.track.sd[-1, 3]  # within its uncertainty of zero: allowed
    _check_physical(replace(est.track, x=x), est.record)
