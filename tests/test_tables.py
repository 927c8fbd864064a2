"""Shared reader helpers (rulkit.tables): file-level refusals, CSV/Parquet round trips,
numeric coercion with the offending row, column-name suggestions; and that the three readers
built on them (telemetry, pull-up, acquisitions) keep their own error classes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.store.acquisitions import IngestError, read_acquisitions
from rulkit.systems.motor_damping.pullup import PullupDataError, read_pullup
from rulkit.systems.reaction_wheel.telemetry import TelemetryError, read_wheel_telemetry
from rulkit.tables import (
    did_you_mean,
    numeric_columns,
    read_table,
    suggest_column,
    table_format,
)


class MyError(ValueError):
    pass


def test_empty_file_and_blank_lines(tmp_path: Path) -> None:
    p = tmp_path / "e.csv"
    p.write_text("")
    with pytest.raises(MyError, match=r"e.csv: empty file \(no header, no rows; expected a "
                                      r"header with columns \['a', 'b'\]\)"):
        read_table(p, error=MyError, expected_columns=["a", "b"])
    p.write_text("\n\n")  # not 0 bytes, but no header either
    with pytest.raises(MyError, match=r"empty file \(no header, no rows\)"):
        read_table(p, error=MyError)


def test_header_only_csv_and_parquet(tmp_path: Path) -> None:
    p = tmp_path / "h.csv"
    p.write_text("a,b\n")
    with pytest.raises(MyError, match=r"h.csv: no data rows \(header only\)"):
        read_table(p, error=MyError)
    df = read_table(p, allow_no_rows=True)
    assert list(df.columns) == ["a", "b"] and len(df) == 0
    q = tmp_path / "h.parquet"
    pd.DataFrame({"a": np.array([], float)}).to_parquet(q)
    with pytest.raises(MyError, match="no data rows"):
        read_table(q, error=MyError)


def test_missing_directory_unknown_type_unreadable(tmp_path: Path) -> None:
    with pytest.raises(MyError, match=r"nope\.csv: file not found"):
        read_table(tmp_path / "nope.csv", error=MyError)
    with pytest.raises(MyError, match="is a directory"):
        read_table(tmp_path, error=MyError)
    x = tmp_path / "data.xlsx"
    x.write_text("a")
    with pytest.raises(MyError, match=r"unknown file type '.xlsx'; expected .csv, .parquet "
                                      r"or .pq"):
        read_table(x, error=MyError)
    with pytest.raises(MyError, match=r"'.txt'; expected .csv or .parquet"):
        table_format("a.txt", error=MyError, parquet_suffixes=(".parquet",))
    assert table_format("A.CSV") == "csv" and table_format("b.PQ") == "parquet"
    with pytest.raises(MyError, match=r"'\.xlsx'"):  # not '.v2.xlsx'
        table_format("run.v2.xlsx", error=MyError)
    with pytest.raises(MyError, match=r"'\.tsv\.gz'; expected \.csv\.gz or \.parquet"):
        table_format("a.tsv.gz", error=MyError, csv_suffixes=(".csv.gz",),
                     parquet_suffixes=(".parquet",))
    bad = tmp_path / "bad.parquet"
    bad.write_text("not parquet")
    with pytest.raises(MyError, match=r"bad\.parquet: cannot be read as Parquet"):
        read_table(bad, error=MyError)


def test_default_error_is_valueerror(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="file not found"):
        read_table(tmp_path / "x.csv")


def test_parquet_and_csv_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    df = pd.DataFrame({"component": ["007", "b", "c"], "x": rng.normal(size=3),
                       "n": np.array([1, 2, 3], np.int64)})
    df.to_parquet(tmp_path / "r.pq")
    got = read_table(tmp_path / "r.pq")
    pd.testing.assert_frame_equal(got, df)
    assert got.attrs == {"source": str(tmp_path / "r.pq"), "format": "parquet"}
    # CSV (gzip-compressed, a multi-part ending): the identifier keeps its leading zeros
    df.to_csv(tmp_path / "r.csv.gz", index=False)
    got = read_table(tmp_path / "r.csv.gz", csv_suffixes=(".csv.gz",),
                     csv_dtype={"component": str})
    assert got["component"].tolist() == ["007", "b", "c"] and got.attrs["format"] == "csv"
    np.testing.assert_array_equal(got["x"].to_numpy(), df["x"].to_numpy())  # repr round trip


def test_numeric_columns_values_and_mapping() -> None:
    df = pd.DataFrame({"A ": ["1.5", "2", "-3e2"], "b": [1, 2, 3]}, index=[10, 11, 12])
    out = numeric_columns(df, {"a": "A ", "b": "b"})
    np.testing.assert_array_equal(out["a"], [1.5, 2.0, -300.0])
    assert out["a"].dtype == np.float64 and out["b"].dtype == np.float64
    out["b"][0] = 99.0  # a fresh array: the frame is not touched
    assert df["b"].iloc[0] == 1


def test_non_numeric_cell_names_column_row_and_count() -> None:
    df = pd.DataFrame({"t": [0.0, 1.0, 2.0, 3.0], "v": ["1", "1,0", "x", "4"]})
    with pytest.raises(MyError, match=r"^f.csv: column 'v', row 2: '1,0' is not a number "
                                      r"\(2 non-numeric value\(s\) in this column\)$"):
        numeric_columns(df, ["t", "v"], error=MyError, source="f.csv")
    with pytest.raises(MyError, match=r"column 'v', row 1 \(file line 3\): '1,0'"):
        numeric_columns(df, ["v"], error=MyError,
                        row_label=lambda i: f"row {i} (file line {i + 2})")


@pytest.mark.parametrize(("value", "shown"), [(np.nan, "NaN (an empty or NaN cell)"),
                                              (np.inf, "inf"), (-np.inf, "-inf")])
def test_nan_inf_cell_names_row(value: float, shown: str) -> None:
    df = pd.DataFrame({"a": [0.0, 1.0, 2.0], "b": [0.0, 1.0, 2.0, 3.0, 4.0][:3]})
    df.loc[1, "b"] = value
    df.loc[2, "b"] = np.nan
    with pytest.raises(MyError) as info:
        numeric_columns(df, ["a", "b"], error=MyError)
    msg = str(info.value)
    assert msg.startswith(f"column 'b', row 2: {shown} is not allowed")
    assert "finite" in msg and "(2 non-finite value(s) in this column)" in msg


def test_empty_csv_cell_is_reported_as_nan(tmp_path: Path) -> None:
    p = tmp_path / "c.csv"
    p.write_text("a,b\n1,2\n3,\n")
    with pytest.raises(MyError, match=r"column 'b', row 2: NaN \(an empty or NaN cell\)"):
        numeric_columns(read_table(p), ["a", "b"], error=MyError)


def test_first_listed_column_is_checked_first() -> None:
    df = pd.DataFrame({"a": [1.0, np.nan], "b": ["x", "1"]})
    with pytest.raises(MyError, match="column 'b', row 1: 'x'"):
        numeric_columns(df, ["b", "a"], error=MyError)
    with pytest.raises(MyError, match="column 'a', row 2: NaN"):
        numeric_columns(df, ["a", "b"], error=MyError)


def test_suggest_column() -> None:
    present = ["Time", "RPM", "curent", "qz"]
    assert suggest_column("speed_rad_s", present, aliases=("w", "rpm")) == ["RPM"]
    assert suggest_column("current", present) == ["curent"]
    assert suggest_column("time", present) == ["Time"]  # case differs only
    assert suggest_column("voltage", present) == []
    assert did_you_mean("voltage", present) == ""
    assert did_you_mean("current", present) == "; did you mean 'curent'? (rename it to 'current')"


READERS = [
    (read_wheel_telemetry, TelemetryError),
    (read_pullup, PullupDataError),
    (read_acquisitions, IngestError),
]


@pytest.mark.parametrize(("reader", "error"), READERS)
def test_readers_keep_their_error_class(tmp_path: Path, reader, error) -> None:
    cases = {"empty.csv": "", "head.csv": "a,b\n", "x.xlsx": "a"}
    expect = {"empty.csv": "empty file", "head.csv": "no data rows",
              "x.xlsx": "unknown file type", "absent.csv": "file not found"}
    for name, content in cases.items():
        (tmp_path / name).write_text(content)
    for name, words in expect.items():
        with pytest.raises(error, match=words) as info:
            reader(tmp_path / name)
        assert type(info.value) is error and str(info.value).startswith(str(tmp_path / name))


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_boolean_cells_are_refused_not_read_as_one_and_zero(tmp_path: Path, fmt: str) -> None:
    from rulkit.tables import numeric_columns

    p = tmp_path / f"b.{fmt}"
    df = pd.DataFrame({"x": [1.0, 2.0, 3.0], "flag": [False, True, True]})
    df.to_csv(p, index=False) if fmt == "csv" else df.to_parquet(p)
    back = read_table(p)
    with pytest.raises(ValueError, match=r"column 'flag', row 1: False is a boolean "
                                         r"\(true/false\), not a number \(3 boolean"):
        numeric_columns(back, ["x", "flag"])
    mixed = pd.DataFrame({"v": pd.Series([1.5, True], dtype=object)})
    with pytest.raises(ValueError, match="column 'v', row 2: True is a boolean"):
        numeric_columns(mixed, ["v"])
    assert numeric_columns(back, ["x"])["x"].tolist() == [1.0, 2.0, 3.0]


def test_match_columns_ignores_case_and_refuses_collisions() -> None:
    from rulkit.tables import match_columns

    assert match_columns(["Time", " SPEED", "other"], ["time", "speed", "current"]) == {
        "time": "Time", "speed": " SPEED"}
    with pytest.raises(KeyError, match=r"f.csv: columns 'speed' and 'SPEED' differ only in case"):
        match_columns(["speed", "SPEED"], ["speed"], error=KeyError, source="f.csv")
    # a collision among columns nobody asked for is not our business
    assert match_columns(["a", "A", "speed"], ["speed"]) == {"speed": "speed"}
