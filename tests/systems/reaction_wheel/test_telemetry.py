"""Wheel telemetry reader/validator: every bad input gets a specific error (column, row)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rulkit.systems.reaction_wheel.telemetry import (
    COLUMNS,
    TelemetryError,
    read_wheel_telemetry,
    validate_wheel_telemetry,
)


def _frame(n: int = 50, dt: float = 0.05) -> pd.DataFrame:
    t = np.arange(n) * dt
    return pd.DataFrame({"time_s": t, "v_comm_V": np.where(t < 1, 1.0, 3.0),
                         "speed_rad_s": 90 + t, "current_A": np.full(n, 0.19),
                         "note": ["x"] * n})


def test_csv_and_parquet_round_trip(tmp_path) -> None:
    df = _frame()
    df.to_csv(tmp_path / "a.csv", index=False)
    df.to_parquet(tmp_path / "a.parquet")
    for name in ("a.csv", "a.parquet"):
        out = read_wheel_telemetry(tmp_path / name)
        assert list(out.columns) == list(COLUMNS)  # extra columns dropped
        assert out.attrs["dt"] == pytest.approx(0.05)
        np.testing.assert_allclose(out["speed_rad_s"], df["speed_rad_s"])
        assert all(out[c].dtype == np.float64 for c in COLUMNS)


def test_missing_and_misnamed_columns_suggest_names() -> None:
    df = _frame().rename(columns={"speed_rad_s": "speed_rpm", "current_A": "current"})
    with pytest.raises(TelemetryError) as e:
        validate_wheel_telemetry(df)
    msg = str(e.value)
    assert "missing column 'speed_rad_s'" in msg and "'speed_rpm'" in msg
    assert "missing column 'current_A'" in msg and "'current'" in msg
    with pytest.raises(TelemetryError, match="did you mean 'time_sec'"):
        validate_wheel_telemetry(_frame().rename(columns={"time_s": "time_sec"}))


@pytest.mark.parametrize(("value", "word"), [(np.nan, "nan"), (np.inf, "inf")])
def test_nan_inf_name_column_and_row(tmp_path, value: float, word: str) -> None:
    df = _frame()
    df.loc[17, "current_A"] = value
    with pytest.raises(TelemetryError, match=r"'current_A', row 17:.*NaN/inf") as err:
        validate_wheel_telemetry(df)
    assert ("use the default method 'imm'" in str(err.value)) == (word == "nan")
    df.to_csv(tmp_path / "b.csv", index=False)
    with pytest.raises(TelemetryError, match=r"row 17 \(file line 19\)"):
        read_wheel_telemetry(tmp_path / "b.csv")


def test_non_numeric_value(tmp_path) -> None:
    df = _frame().astype({"v_comm_V": object})
    df.loc[3, "v_comm_V"] = "1,0"
    with pytest.raises(TelemetryError,
                       match=r"'v_comm_V', row 3: '1,0' is not a number \(1 non-numeric"):
        validate_wheel_telemetry(df)


def test_time_order_and_sampling() -> None:
    df = _frame()
    df.loc[10, "time_s"] = df.loc[9, "time_s"]
    with pytest.raises(TelemetryError, match="row 10: repeated time"):
        validate_wheel_telemetry(df)
    df = _frame()
    df.loc[[20, 21], "time_s"] = df.loc[[21, 20], "time_s"].to_numpy()
    with pytest.raises(TelemetryError, match=r"row 21: time .* before the previous"):
        validate_wheel_telemetry(df)
    df = _frame()
    df.loc[30:, "time_s"] += 0.01  # one step of 0.06 s
    with pytest.raises(TelemetryError, match=r"row 30: step 0.06 s differs .*irregular"):
        validate_wheel_telemetry(df)
    # within tolerance: accepted
    df = _frame()
    df["time_s"] += np.random.default_rng(0).uniform(-1e-5, 1e-5, len(df))
    assert validate_wheel_telemetry(df).attrs["dt"] == pytest.approx(0.05, rel=1e-3)


def test_implausible_units() -> None:
    df = _frame()
    df["speed_rad_s"] *= 60 / (2 * np.pi) * 10  # rpm of a fast wheel
    with pytest.raises(TelemetryError, match=r"speed_rad_s.*row 0.*looks like rpm"):
        validate_wheel_telemetry(df)
    df = _frame()
    df["current_A"] *= 1000
    with pytest.raises(TelemetryError, match=r"current_A.*looks like mA"):
        validate_wheel_telemetry(df)
    df = _frame()
    df.loc[5, "v_comm_V"] = 12.0
    with pytest.raises(TelemetryError, match=r"v_comm_V', row 5.*0-5 V"):
        validate_wheel_telemetry(df)


def test_empty_and_degenerate_files(tmp_path) -> None:
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(TelemetryError, match="empty file"):
        read_wheel_telemetry(tmp_path / "empty.csv")
    (tmp_path / "head.csv").write_text(",".join(COLUMNS) + "\n")
    with pytest.raises(TelemetryError, match="no data rows"):
        read_wheel_telemetry(tmp_path / "head.csv")
    _frame(1).to_csv(tmp_path / "one.csv", index=False)
    with pytest.raises(TelemetryError, match="at least 2 rows"):
        read_wheel_telemetry(tmp_path / "one.csv")
    (tmp_path / "x.txt").write_text("a")
    with pytest.raises(TelemetryError, match="unknown file type"):
        read_wheel_telemetry(tmp_path / "x.txt")
    with pytest.raises(TelemetryError, match="no such file"):
        read_wheel_telemetry(tmp_path / "nope.csv")
    (tmp_path / "bad.parquet").write_text("not parquet")
    with pytest.raises(TelemetryError, match="cannot be read"):
        read_wheel_telemetry(tmp_path / "bad.parquet")


def test_failed_validation_leaves_input_untouched() -> None:
    df = _frame()
    df.loc[4, "speed_rad_s"] = np.nan
    before = df.copy()
    with pytest.raises(TelemetryError):
        validate_wheel_telemetry(df)
    pd.testing.assert_frame_equal(df, before)


def test_parquet_datetime_time_column_is_read_as_seconds(tmp_path) -> None:
    """Issue 13: a datetime64 time column was nanoseconds since 1970 taken as seconds."""
    df = _frame()
    start = pd.Timestamp("2026-03-01 12:00:00")
    df["time_s"] = start + pd.to_timedelta(df["time_s"], unit="s")
    df.to_parquet(tmp_path / "dt.parquet")
    out = read_wheel_telemetry(tmp_path / "dt.parquet")
    assert out.attrs["dt"] == pytest.approx(0.05, rel=1e-5)  # float64 epoch seconds: ~2e-7 s
    assert out["time_s"].iloc[0] == pytest.approx(start.timestamp())
    np.testing.assert_allclose(np.diff(out["time_s"]), 0.05, atol=1e-6)
    # time zone aware and durations too
    tz = _frame()
    tz["time_s"] = (start + pd.to_timedelta(tz["time_s"], unit="s")).dt.tz_localize("Europe/Paris")
    assert validate_wheel_telemetry(tz).attrs["dt"] == pytest.approx(0.05, rel=1e-5)
    td = _frame()
    td["time_s"] = pd.to_timedelta(td["time_s"], unit="s")
    assert validate_wheel_telemetry(td)["time_s"].iloc[-1] == pytest.approx(49 * 0.05)


@pytest.mark.parametrize(("change", "match"), [
    (lambda d: d.assign(time_s=d["time_s"] * 1e306), "sampling step"),
    (lambda d: d.assign(speed_rad_s=0.0, current_A=0.0, v_comm_V=0.0), "no temperature"),
    (lambda d: pd.concat([d, d], ignore_index=True).assign(
        time_s=np.arange(2 * len(d)) * 0.05), "speed jumps"),
])
def test_physically_implausible_records_are_refused(change, match) -> None:
    """Issue 13: all-zero signals, time scaled by 1e306 and tiled telemetry ran and reported
    temperatures (below absolute zero); now a named error says what is wrong and where."""
    from rulkit.systems.reaction_wheel.telemetry import ImplausibleTelemetryError

    df = _frame(200).drop(columns="note")
    df["speed_rad_s"] = 90 + 0.5 * df["time_s"]  # 90 -> 95 rad/s over the record
    with pytest.raises(ImplausibleTelemetryError, match=match):
        validate_wheel_telemetry(change(df))


@pytest.mark.parametrize("lenient", [False, True])
def test_booleans_and_case_colliding_columns_are_refused(tmp_path, lenient: bool) -> None:
    """v_comm_V = True is not a command of 1 V, and 'speed_rad_s' next to 'SPEED_RAD_S' leaves
    it open which one holds the speed: both refused, in both modes (CSV and Parquet)."""
    df = _frame().drop(columns="note")
    df["v_comm_V"] = True
    df.to_parquet(tmp_path / "b.parquet")
    with pytest.raises(TelemetryError, match=r"'v_comm_V', row 0: .*boolean"):
        read_wheel_telemetry(tmp_path / "b.parquet", lenient=lenient)
    df.to_csv(tmp_path / "b.csv", index=False)
    with pytest.raises(TelemetryError, match=r"v_comm_V.*boolean"):
        read_wheel_telemetry(tmp_path / "b.csv", lenient=lenient)
    twice = _frame().drop(columns="note")
    twice["SPEED_RAD_S"] = twice["speed_rad_s"] * 9.55
    with pytest.raises(TelemetryError, match="differ only by case"):
        validate_wheel_telemetry(twice, lenient=lenient)


def test_lenient_mode_keeps_dropouts_gaps_and_rare_out_of_range_values() -> None:
    df = _frame(200).drop(columns="note")
    df.loc[5, "current_A"] = np.nan
    df = df.drop(index=range(50, 60)).reset_index(drop=True)  # a 0.5 s gap
    df.loc[100, "speed_rad_s"] = 5e4  # one impossible sample: kept as missing
    out = validate_wheel_telemetry(df, lenient=True)
    assert np.isnan(out.loc[5, "current_A"]) and np.isnan(out.loc[100, "speed_rad_s"])
    assert out.attrs["n_out_of_range"] == 1
    with pytest.raises(TelemetryError, match="irregular"):
        validate_wheel_telemetry(df.assign(current_A=0.19, speed_rad_s=90.0))
    rpm = df.assign(speed_rad_s=df["speed_rad_s"] * 60)  # every value: wrong units
    with pytest.raises(TelemetryError, match="looks like rpm"):
        validate_wheel_telemetry(rpm, lenient=True)
