"""Reading a drive record: columns, regular grid with gaps, missing speeds, time origin and
date-times, and the plausible ranges that catch wrong units."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from rulkit.systems.friction_drive.machine import read_drive_machine
from rulkit.systems.friction_drive.record import (
    DriveRecordError,
    ImplausibleDriveRecordError,
    drive_record,
    read_drive_record,
)

MACHINE = read_drive_machine(None)


def _frame(n: int = 50, dt: float = 1e-3) -> pd.DataFrame:
    t = np.arange(n) * dt
    return pd.DataFrame({"time_s": t, "current_A": np.where(t < 0.02, 20.0, 0.0),
                         "w1_rad_s": 100.0 * t, "w2_rad_s": 5.0 * t})


def test_csv_and_parquet_read_alike(tmp_path: Path) -> None:
    df = _frame()
    df.to_csv(tmp_path / "r.csv", index=False)
    df.to_parquet(tmp_path / "r.parquet")
    a = read_drive_record(tmp_path / "r.csv", MACHINE)
    b = read_drive_record(tmp_path / "r.parquet", MACHINE)
    assert a.dt == pytest.approx(1e-3, rel=1e-12) and a.n_rows == 50 and a.n_gap_steps == 0
    np.testing.assert_array_equal(a.speeds, b.speeds)
    np.testing.assert_array_equal(a.row, np.arange(50))


def test_gaps_are_whole_steps_with_the_current_held() -> None:
    df = _frame().drop(index=[10, 11, 12]).reset_index(drop=True)
    rec = drive_record(df, MACHINE)
    assert rec.n_rows == 47 and rec.n_gap_steps == 3 and rec.row.size == 50
    np.testing.assert_array_equal(rec.row[9:14], [9, -1, -1, -1, 10])
    assert np.isnan(rec.speeds[10:13]).all()
    np.testing.assert_array_equal(rec.current[10:13], df["current_A"].iloc[9])
    np.testing.assert_array_equal(rec.speeds[13], df[["w1_rad_s", "w2_rad_s"]].iloc[10])


def test_empty_speed_cells_are_missing_but_current_and_time_are_required() -> None:
    df = _frame()
    df.loc[5, "w2_rad_s"] = np.nan
    rec = drive_record(df, MACHINE)
    assert rec.n_missing == 1 and np.isnan(rec.speeds[5, 1]) and np.isfinite(rec.speeds[5, 0])
    df.loc[7, "current_A"] = np.nan
    with pytest.raises(DriveRecordError, match=r"column 'current_A', row 8: NaN"):
        drive_record(df, MACHINE)


def test_time_origin_does_not_matter(tmp_path: Path) -> None:
    df = _frame(2000)
    base = drive_record(df, MACHINE)
    shifted = drive_record(df.assign(time_s=df["time_s"] + 1.7e9), MACHINE)
    assert shifted.dt == pytest.approx(base.dt, rel=1e-9)  # one step from all rows
    np.testing.assert_array_equal(shifted.speeds, base.speeds)
    stamps = pd.Timestamp("2025-01-01T08:00:00") + pd.to_timedelta(df["time_s"], unit="s")
    df.assign(time_s=stamps).to_parquet(tmp_path / "dated.parquet")
    dated = read_drive_record(tmp_path / "dated.parquet", MACHINE)
    assert dated.dt == pytest.approx(base.dt, rel=1e-12)


@pytest.mark.parametrize(
    ("change", "error", "message"),
    [
        (lambda df: df.assign(time_s=df["time_s"] * 1000.0), ImplausibleDriveRecordError,
         r"sampling step 1 s is outside the plausible \[1e-05, 0.01\] s .*time in ms\?"),
        (lambda df: df.assign(current_A=df["current_A"] * 1000.0), ImplausibleDriveRecordError,
         r"column 'current_A', row 1: 20000 A is beyond the plausible max_current .*mA\?"),
        (lambda df: df.assign(w1_rad_s=df["w1_rad_s"] * 200.0), ImplausibleDriveRecordError,
         r"column 'w1_rad_s', row 58: 1140 rad/s is beyond 1.5 x the free-running speed "
         r"Km max_current / B1 \(1126 rad/s; .*rpm\?"),
        (lambda df: df.assign(time_s=df["time_s"].where(df.index != 20, 0.0205)),
         DriveRecordError, r"row 21: step 0.0015 s is not a whole number of sampling steps"),
        (lambda df: df.drop(index=range(10, 1200)), DriveRecordError,
         r"row 11: a gap of 1.191 s \(1191 steps\) is longer than max_gap_steps = 1000"),
        (lambda df: df.assign(time_s=df["time_s"].where(df.index != 4, 0.003)),
         DriveRecordError, r"column 'time_s', row 5: repeated time"),
        (lambda df: df.rename(columns={"w1_rad_s": "omega1"}), DriveRecordError,
         r"missing column\(s\) 'w1_rad_s'; did you mean 'omega1'"),
        (lambda df: df.assign(W2_RAD_S=df["w2_rad_s"]), DriveRecordError,
         r"columns 'w2_rad_s' and 'W2_RAD_S' differ only in case"),
        (lambda df: df.assign(current_A=df["current_A"] > 0), DriveRecordError,
         r"column 'current_A', row 1: True is a boolean"),
    ],
)
def test_refusals_name_the_column_row_and_likely_cause(change, error, message) -> None:
    with pytest.raises(error, match=message):
        drive_record(change(_frame(1300)), MACHINE, source="rec.csv")
