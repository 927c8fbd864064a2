"""Reader/validator of a user's pull-up test data (issue #4)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from rulkit.systems.motor_damping.pullup import (
    ACCELERATION_DERIVED,
    ACCELERATION_MEASURED,
    PullupDataError,
    estimate_noise_sd,
    read_pullup,
)


def _frame(n_cycles: int = 3, n: int = 30, acc: bool = True) -> pd.DataFrame:
    t = 0.1 * np.arange(n)
    rows = []
    for c in range(1, n_cycles + 1):
        d = {"cycle": c, "time": 1000.0 * c + t, "current": 2.0 + np.exp(-t),
             "speed": 10.0 * t + c}
        if acc:
            d["acceleration"] = np.full(n, 10.0)
        rows.append(pd.DataFrame(d))
    return pd.concat(rows, ignore_index=True)


def _write(df: pd.DataFrame, tmp_path: Path, name: str = "p.csv") -> Path:
    p = tmp_path / name
    if name.endswith(".parquet"):
        df.to_parquet(p)
    else:
        df.to_csv(p, index=False)
    return p


def test_reads_csv_and_parquet_alike(tmp_path: Path) -> None:
    df = _frame()
    a = read_pullup(_write(df, tmp_path, "p.csv"))
    b = read_pullup(_write(df, tmp_path, "p.parquet"))
    np.testing.assert_array_equal(a.cycle, [1, 2, 3])
    np.testing.assert_array_equal(a.n_samples, [30, 30, 30])
    np.testing.assert_allclose(a.time[1], 0.1 * np.arange(30), atol=1e-9)  # relative to start
    np.testing.assert_allclose(a.speed, b.speed)
    assert a.acceleration_measured and a.acceleration_source == ACCELERATION_MEASURED


def test_column_names_case_insensitive_and_extra_columns_ignored(tmp_path: Path) -> None:
    df = _frame().rename(columns={"speed": "Speed", "cycle": " CYCLE"})
    df["temperature"] = 60.0
    d = read_pullup(_write(df, tmp_path))
    assert d.n_cycles == 3


def test_uneven_cycle_lengths_are_padded(tmp_path: Path) -> None:
    df = _frame()
    df = df.drop(index=df.index[(df["cycle"] == 2)][25:]).reset_index(drop=True)
    d = read_pullup(_write(df, tmp_path))
    np.testing.assert_array_equal(d.n_samples, [30, 25, 30])
    assert np.isnan(d.speed[1, 25:]).all() and np.isfinite(d.speed[1, :25]).all()


def test_missing_acceleration_is_derived_exactly_for_a_quadratic(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    t = np.sort(rng.uniform(0, 5, 40))  # non-uniform grid
    df = pd.DataFrame({"cycle": 1, "time": t, "current": 2.0, "speed": 3.0 * t**2 + t})
    d = read_pullup(_write(df, tmp_path))
    assert not d.acceleration_measured and d.acceleration_source == ACCELERATION_DERIVED
    # second-order differences are exact for a quadratic, also at the ends (edge_order=2)
    np.testing.assert_allclose(d.acceleration[0, :40], 6.0 * (t - t[0]) + 6.0 * t[0] + 1.0,
                               rtol=1e-9)


@pytest.mark.parametrize("drop", ["cycle", "time", "current", "speed"])
def test_missing_column_named(tmp_path: Path, drop: str) -> None:
    p = _write(_frame().drop(columns=[drop]), tmp_path)
    with pytest.raises(PullupDataError, match=f"missing column\\(s\\) {drop}"):
        read_pullup(p)


def test_nan_and_inf_reported_with_row(tmp_path: Path) -> None:
    df = _frame()
    df.loc[17, "speed"] = np.nan
    with pytest.raises(PullupDataError, match=r"column 'speed', row 18: NaN"):
        read_pullup(_write(df, tmp_path))
    df = _frame()
    df.loc[40, "current"] = np.inf
    with pytest.raises(PullupDataError, match=r"column 'current', row 41: inf"):
        read_pullup(_write(df, tmp_path, "q.parquet"))


def test_non_numeric_value(tmp_path: Path) -> None:
    df = _frame().astype({"time": object})
    df.loc[5, "time"] = "noon"
    with pytest.raises(PullupDataError, match=r"column 'time', row 6: 'noon' is not a number"):
        read_pullup(_write(df, tmp_path))


@pytest.mark.parametrize("kind,value", [("repeated", 1000.4), ("decreasing", 1000.2)])
def test_time_not_increasing_within_cycle(tmp_path: Path, kind: str, value: float) -> None:
    df = _frame()
    df.loc[35, "time"] = value + 1000.0  # row 36 is cycle 2, sample 5 (time 2000.5)
    df.loc[34, "time"] = 2000.4
    with pytest.raises(PullupDataError, match=rf"row 36 \(cycle 2\).*\({kind}\)"):
        read_pullup(_write(df, tmp_path))


def test_cycles_out_of_order_and_non_integer(tmp_path: Path) -> None:
    df = _frame()
    df = pd.concat([df[df.cycle == 2], df[df.cycle == 1]], ignore_index=True)
    with pytest.raises(PullupDataError, match=r"cycles out of order at row 31: cycle 1 after "
                                              r"cycle 2"):
        read_pullup(_write(df, tmp_path))
    df = _frame()
    # cycle 2 interrupted by cycle 3 then resumed: also out of order
    df.loc[45, "cycle"] = 3
    with pytest.raises(PullupDataError, match="out of order at row 47"):
        read_pullup(_write(df, tmp_path))
    df = _frame().astype({"cycle": float})
    df.loc[3, "cycle"] = 1.5
    with pytest.raises(PullupDataError, match=r"row 4: 1.5 is not an integer"):
        read_pullup(_write(df, tmp_path))


def test_empty_files(tmp_path: Path) -> None:
    p = tmp_path / "empty.csv"
    p.write_text("")
    with pytest.raises(PullupDataError, match="empty file"):
        read_pullup(p)
    p.write_text("cycle,time,current,speed\n")
    with pytest.raises(PullupDataError, match="no data rows"):
        read_pullup(p)
    with pytest.raises(PullupDataError, match="file not found"):
        read_pullup(tmp_path / "nope.csv")
    q = tmp_path / "x.xlsx"
    q.write_text("a")
    with pytest.raises(PullupDataError, match="unknown file type"):
        read_pullup(q)


def test_cycle_too_short(tmp_path: Path) -> None:
    df = _frame()
    df = df.drop(index=df.index[df["cycle"] == 3][5:]).reset_index(drop=True)
    with pytest.raises(PullupDataError, match=r"cycle 3 \(rows 61-65\) has 5 sample\(s\); at "
                                              r"least 20"):
        read_pullup(_write(df, tmp_path))
    assert read_pullup(_write(df, tmp_path), min_samples=5).n_cycles == 3


def test_noise_sd_estimate() -> None:
    rng = np.random.default_rng(1)
    t = np.linspace(0, 35, 701)
    smooth = 300 * (1 - np.exp(-t / 10.0))
    x = smooth + 0.05 * rng.standard_normal((20, t.size))
    assert estimate_noise_sd(x) == pytest.approx(0.05, rel=0.05)
    with pytest.raises(ValueError, match="fewer than 3"):
        estimate_noise_sd(np.array([1.0, 2.0]))


def test_min_samples_below_three_refused(tmp_path: Path) -> None:
    from rulkit.systems.motor_damping import pullup

    # np.gradient(edge_order=2) needs 3 samples: refused up front with the option named
    with pytest.raises(ValueError, match="min_samples: expected an integer >= 3"):
        pullup.from_frame(pd.DataFrame({"cycle": [1], "time": [0.0], "current": [1.0],
                                 "speed": [0.0]}), min_samples=2)


def test_case_colliding_columns_refused(tmp_path: Path) -> None:
    df = _frame()
    df["SPEED"] = df["speed"] * 9.549  # the same channel in rpm beside it
    with pytest.raises(PullupDataError, match="columns 'speed' and 'SPEED' differ only in case"):
        read_pullup(_write(df, tmp_path))


def test_boolean_column_refused(tmp_path: Path) -> None:
    df = _frame()
    df["current"] = df["current"] > 2.5
    with pytest.raises(PullupDataError, match=r"column 'current', row 1: True is a boolean"):
        read_pullup(_write(df, tmp_path, "b.parquet"))


def test_timestamps_read_as_seconds_and_origin_does_not_matter(tmp_path: Path) -> None:
    df = _frame()
    base = read_pullup(_write(df, tmp_path))
    stamps = pd.Timestamp("2024-05-01T00:00:00") + pd.to_timedelta(df["time"], unit="s")
    dated = read_pullup(_write(df.assign(time=stamps), tmp_path, "d.parquet"))
    np.testing.assert_allclose(dated.time, base.time, atol=1e-9)
    shifted = read_pullup(_write(df.assign(time=df["time"] + 1.7e9), tmp_path, "s.csv"))
    np.testing.assert_allclose(shifted.time, base.time, atol=1e-6)  # float64 at 1.7e9: 2.4e-7


@pytest.mark.parametrize(
    ("column", "factor", "message"),
    [
        ("speed", 60 / (2 * np.pi), r"column 'speed', cycle 1, sample 30: 1002\.68 is beyond "
                                    r"the plausible 1000 rad/s .*speed in rpm\?"),
        ("current", 1000.0, r"column 'current', cycle 1, sample 1: 3000 is beyond the "
                            r"plausible 20 A .*current in mA\?"),
        ("time", 1000.0, r"column 'time', cycle 1, sample 2: 100 is beyond the plausible 1 s "
                         r"between samples .*time in ms\?"),
        ("time", 1e-5, r"column 'time', cycle 1, sample 2: 1e-06 is below the plausible 1e-05 "
                       r"s between samples"),
    ],
)
def test_implausible_units_refused_with_the_likely_cause(tmp_path: Path, column: str,
                                                         factor: float, message: str) -> None:
    from rulkit.systems.motor_damping.pullup import (
        ImplausiblePullupError,
        PullupLimits,
        check_plausible,
    )

    df = _frame()
    df["speed"] = df["speed"] * 3.5  # up to 111 rad/s: plausible in rad/s, not in rpm
    check_plausible(read_pullup(_write(df, tmp_path)), PullupLimits())
    df[column] = df[column] * factor
    data = read_pullup(_write(df, tmp_path, "bad.csv"))
    with pytest.raises(ImplausiblePullupError, match=message):
        check_plausible(data, PullupLimits())
    wide = PullupLimits(max_speed=1e5, max_current=1e4, max_step=1e3, min_step=1e-9)
    check_plausible(data, wide)  # the limits are the machine file's, not hard-wired
