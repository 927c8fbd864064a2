"""Rows read and checked one way in every command (rulkit.fleet.rows): field counts of CSV
rows, numbers of a numeric type only, the same id rules in track, fit, evaluate and the
service. Each scenario failed on the code before (a shifted row, True read as 1)."""

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from rulkit.cli import app
from rulkit.fleet.learned.histories import HistoryError, histories_from_frame, read_histories
from rulkit.fleet.rows import (
    CodedText,
    check_component_ids,
    component_codes,
    numeric_values,
    previous_per_component,
    read_csv_columns,
    read_csv_rows,
    read_csv_table,
)
from rulkit.fleet.store.acquisitions import IngestError, read_acquisitions
from rulkit.fleet.store.ingest import ingest_into

runner = CliRunner()


def test_a_csv_row_with_an_extra_field_is_refused_with_its_line(tmp_path):
    f = tmp_path / "a.csv"
    f.write_text("component,time,hi\nc0,0,0.1\nc0,1,0.1,9\nc0,2,0.2\n")
    with pytest.raises(IngestError, match=r"line 3 \(data row 2\) has 4 fields, the header 3"):
        read_acquisitions(f)
    r = runner.invoke(app, ["track", "--db", str(tmp_path / "a.db"), str(f)])
    assert r.exit_code == 1 and "line 3" in r.output, r.output
    assert not (tmp_path / "a.db").exists()
    # every row one field too many: pandas took the first column as the index (shifted)
    f.write_text("component,time,hi\nc0,0,0.1,9\nc0,1,0.1,9\n")
    with pytest.raises(IngestError, match=r"line 2 .* 4 fields"):
        read_acquisitions(f)
    f.write_text("component,time,hi\nc0,0\n")
    with pytest.raises(IngestError, match=r"line 2 .* 2 fields"):
        read_acquisitions(f)


@pytest.mark.parametrize(("first", "value", "row"), [("True", "True", 1), ("False", "True", 1),
                                                    ("0.1", "True", 2), ("0.1", "false", 2)])
def test_a_boolean_in_a_csv_number_column_is_refused(tmp_path, first, value, row):
    # a column of booleans only was read as 1/0 (hi=True an ALARM)
    f = tmp_path / "b.csv"
    f.write_text(f"component,time,hi\nc0,0,{first}\nc0,1,{value}\n")
    r = runner.invoke(app, ["track", "--db", str(tmp_path / "b.db"), str(f)])
    assert r.exit_code == 1, r.output
    assert f"column 'hi', row {row}" in r.output and "ALARM" not in r.output
    assert not (tmp_path / "b.db").exists()


def test_booleans_and_text_in_parquet_number_columns_are_refused(tmp_path):
    base = pd.DataFrame({"component": ["c0", "c0"], "time": [0.0, 1.0], "hi": [0.1, 0.2]})
    for col, values, what in [("hi", [True, False], "is a boolean"),
                              ("time", [False, True], "is a boolean"),
                              ("hi", ["0.1", "0.2"], "is text, not a number")]:
        f = tmp_path / "p.parquet"
        base.assign(**{col: values}).to_parquet(f)
        with pytest.raises(IngestError, match=f"column '{col}', row 1 .*{what}"):
            ingest_into(tmp_path / "p.db", read_acquisitions(f))
        assert not (tmp_path / "p.db").exists()
    # a Python object column mixing numbers and a bool
    with pytest.raises(IngestError, match=r"column 'hi', row 2 .*True is a boolean"):
        ingest_into(tmp_path / "o.db", base.assign(hi=pd.Series([0.1, True], dtype=object)))


def test_numbers_of_numeric_types_are_taken_as_they_are():
    s = pd.Series([1, 2, 3], dtype="int64")
    np.testing.assert_array_equal(numeric_values(s, "x"), [1.0, 2.0, 3.0])
    s = pd.Series([1.5, None], dtype="Float64")
    with pytest.raises(ValueError, match="row 2: NaN"):
        numeric_values(s, "x")
    np.testing.assert_array_equal(numeric_values(pd.Series([0.5, 2], dtype=object), "x"),
                                  [0.5, 2.0])


def test_csv_text_ids_stay_text_and_only_an_empty_cell_is_missing(tmp_path):
    f = tmp_path / "ids.csv"
    f.write_text('component,time,hi\nNA,0,0.1\nNone,0,0.1\nnull,0,0.1\n007,0,0.1\n"",1,0.1\n')
    df = read_csv_rows(f)
    assert df["component"].astype(object).tolist()[:4] == ["NA", "None", "null", "007"]
    with pytest.raises(ValueError, match="row 5: empty component name"):
        check_component_ids(df["component"])


def test_plain_csv_columns_are_the_frames_values_without_pandas(tmp_path):
    """read_csv_columns gives a plain CSV as arrays (ids as codes) equal to the frame's
    columns; any other column type is left to the frame, so it is refused the frame's way."""
    f = tmp_path / "a.csv"
    rng = np.random.default_rng(3)
    ids = rng.choice(["b", "a", " a", "c-9", "\u00e9t\u00e9"], 300)
    pd.DataFrame({"component": ids, "time": np.arange(300), "hi": rng.uniform(0, 1, 300),
                  "ci": rng.normal(size=300)}).to_csv(f, index=False)
    with open(f, "a") as out:
        out.write("b,300,,0.5\n")  # an empty cell in a floating column: NaN in both
    cols, frame = read_csv_columns(f), read_csv_rows(f)
    assert isinstance(cols, dict) and isinstance(cols["component"], CodedText)
    assert frame["time"].dtype == np.int64  # inferred; read as float64 without inference
    for c in ("time", "hi", "ci"):
        assert cols[c].dtype == np.float64
        np.testing.assert_array_equal(cols[c], frame[c].to_numpy(dtype=np.float64))
    codes, names = component_codes(cols["component"])
    f_codes, f_names = component_codes(frame["component"])
    np.testing.assert_array_equal(codes, f_codes)
    assert names == f_names == list(dict.fromkeys(i.strip() for i in ids))  # " a" is "a"
    for text in ("component,time,hi\nc0,0,True\n",  # a boolean column
                 "component,time,hi\nc0,2024-01-01T00:00:00,0.1\n",  # date-times
                 'component,time,hi\n"",0,0.1\n'):  # an empty id
        f.write_text(text)
        assert isinstance(read_csv_columns(f), pd.DataFrame)


def test_float_columns_parse_as_the_inferred_types_convert(tmp_path):
    """The float64 parse of read_csv_columns gives the values of pyarrow's inferred types
    converted to float64 (integers beyond 2**53, exponents, NaN and infinity texts, empty
    cells), and a column that is not all numbers, in the first block or a later one, is read
    with its inferred type, as without the float parse (the frame, and its refusal)."""
    import pyarrow as pa

    f = tmp_path / "a.csv"
    cells = ["0", "-7", "9007199254740993", "18446744073709551615", "1e308", "2.5e-320",
             "0.1", "-0.0", "nan", "inf", "", "123456789012345678"]
    f.write_text("component,time,hi\n" + "".join(
        f"c{i % 3},{c or 1},{c}\n" for i, c in enumerate(cells)))
    cols = read_csv_columns(f)
    inferred = read_csv_table(f)
    for c in ("time", "hi"):
        ref = inferred.column(c).cast(pa.float64()).to_numpy(zero_copy_only=False)
        np.testing.assert_array_equal(cols[c], ref)
        assert cols[c].tobytes() == ref.tobytes()  # the same bits (-0.0, NaN)
    rows = [f"c{i % 7},{i},0.{i}" for i in range(200_000)]  # beyond the first 4 MB block
    for late in ("True", "x1", "2024-01-01"):
        f.write_text("component,time,hi\n" + "\n".join(rows) + f"\nc0,200001,{late}\n")
        got = read_csv_columns(f)
        assert isinstance(got, pd.DataFrame)
        pd.testing.assert_frame_equal(got, read_csv_rows(f))
        assert got["hi"].iloc[-1] == late


def test_coded_ids_are_numbered_by_first_appearance():
    """A dictionary in any order, unused entries, and the refusals of component_codes."""
    values = ["z", "y", "x", "unused"]
    raw = np.array([2, 0, 2, 1, 0], dtype=np.int32)
    codes, names = component_codes(CodedText(codes=raw, values=values))
    np.testing.assert_array_equal(codes, [0, 1, 0, 2, 1])
    assert names == ["x", "z", "y"]
    ref = component_codes(np.array([values[k] for k in raw], dtype=object))
    np.testing.assert_array_equal(codes, ref[0])
    assert names == ref[1]
    in_order = CodedText(codes=np.array([0, 0, 1, 0, 2], dtype=np.int32), values=["a", "b", "c"])
    assert component_codes(in_order)[1] == ["a", "b", "c"]
    with pytest.raises(ValueError, match="row 2: empty component name"):
        component_codes(CodedText(codes=np.array([0, -1], dtype=np.int32), values=["a"]))
    with pytest.raises(ValueError, match=r"row 3: .*non-printable"):
        component_codes(CodedText(codes=np.array([0, 0, 1], dtype=np.int32),
                                  values=["a", "b\x1b"]))


def _histories(comps=("NA", "None", "null"), hi_last=1.1):
    rows = [(c, float(t), 0.3 + (hi_last - 0.3) * t / 4) for c in comps for t in range(5)]
    return pd.DataFrame(rows, columns=["component", "time", "hi"])


@pytest.mark.parametrize("ext", ["csv", "parquet"])
def test_fit_takes_the_ids_track_takes(tmp_path, ext):
    df = _histories()
    f = tmp_path / f"h.{ext}"
    df.to_csv(f, index=False) if ext == "csv" else df.to_parquet(f)
    h = read_histories(f)
    assert sorted(h.names.tolist()) == ["NA", "None", "null"]
    # and refuses what track refuses, naming the row
    bad = df.assign(component=df["component"].where(df.index != 7, "bad\x1bid"))
    with pytest.raises(HistoryError, match=r"row 8: component id .* non-printable"):
        histories_from_frame(bad)


@pytest.mark.parametrize("cmd", ["fit", "evaluate"])
def test_fit_and_evaluate_refuse_booleans(tmp_path, cmd):
    df = _histories(("a", "b", "c")).astype({"hi": object})
    df.loc[3, "hi"] = True
    f = tmp_path / "h.csv"
    df.to_csv(f, index=False)
    args = [cmd, str(f)]
    args += ["--db", str(tmp_path / "f.db")] if cmd == "fit" else ["--out", str(tmp_path / "o")]
    r = runner.invoke(app, args)
    assert r.exit_code == 1, r.output
    assert "column 'hi', row 4" in r.output and "True" in r.output


def test_a_typo_in_a_later_block_is_named_by_row(tmp_path, monkeypatch):
    """The CSV is read in blocks; a text cell in a block after the one that typed the column
    as numbers is still named by column and row (and a bad field count anywhere)."""
    from rulkit.fleet import rows

    monkeypatch.setattr(rows, "CSV_BLOCK_BYTES", 256)
    lines = ["component,time,hi"] + [f"c{i % 7},{i // 7},0.3" for i in range(400)]
    lines[300] = f"c{299 % 7},{299 // 7},0.3x"
    f = tmp_path / "t.csv"
    f.write_text("\n".join(lines) + "\n")
    for columns in (False, True):  # the frame, and track's float64 columns (read again)
        with pytest.raises(IngestError, match=r"column 'hi', row 300 .*'0.3x' is not a numb"):
            ingest_into(tmp_path / "t.db", read_acquisitions(f, columns=columns))
    lines[300] = "c0,1,0.3,7"
    f.write_text("\n".join(lines) + "\n")
    for columns in (False, True):
        with pytest.raises(IngestError, match=r"line 301 \(data row 300\) has 4 fields"):
            read_acquisitions(f, columns=columns)
    lines[300] = "c0,1,0.3"
    f.write_text("\n".join(lines) + "\n")
    assert len(read_csv_rows(f)) == 400


def test_previous_per_component_is_pandas_groupby_shift():
    """Against pandas' groupby(...).shift(1) on random interleaved components, and the empty
    and one-row cases."""
    rng = np.random.default_rng(5)
    for n in (0, 1, 2, 50, 1000):
        codes = rng.integers(0, 7, n)
        t = rng.normal(size=n)
        want = pd.Series(t).groupby(codes).shift(1).to_numpy(dtype=np.float64)
        np.testing.assert_array_equal(previous_per_component(codes, t), want)
