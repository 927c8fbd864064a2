"""A large plain CSV parsed in two halves on two threads (rulkit.fleet.csv_halves) against
one pass: the same columns, codes and ids, and one pass (its refusals) wherever the halves
could differ."""

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet import csv_halves, rows
from rulkit.fleet.rows import CodedText, read_csv_columns, read_csv_table
from rulkit.fleet.store.acquisitions import IngestError, read_acquisitions


@pytest.fixture
def halves(monkeypatch):
    """Halves for any file (small blocks: many per half); the calls and what they gave."""
    monkeypatch.setattr(csv_halves, "MIN_BYTES", 0)
    monkeypatch.setattr(rows, "CSV_BLOCK_BYTES", 512)
    calls = []
    read = csv_halves.read
    monkeypatch.setattr(csv_halves, "read", lambda *a: calls.append(read(*a)) or calls[-1])
    return calls


def _one_pass(monkeypatch, f, reader=read_csv_columns):
    with monkeypatch.context() as m:
        m.setattr(csv_halves, "MIN_BYTES", 1 << 62)
        return reader(f)


def _same_columns(a, b):
    assert a.keys() == b.keys()
    for k in a:
        if isinstance(a[k], CodedText):
            assert a[k].values == b[k].values
            np.testing.assert_array_equal(a[k].codes, b[k].codes)
        else:
            assert a[k].dtype == b[k].dtype and a[k].tobytes() == b[k].tobytes()


@pytest.mark.parametrize("newline", ["\n", "\r\n"])
def test_halves_give_the_columns_of_one_pass(tmp_path, monkeypatch, halves, newline):
    """Ids first seen in either half (numbered by first appearance in the file), empty cells
    (NaN), negative zero and exponents: the halves' columns equal one pass's, bit for bit."""
    rng = np.random.default_rng(4)
    n = 3000
    ids = np.array([f"u{i}" for i in rng.integers(0, 40, n)], dtype=object)
    ids[n // 2:] = [f"late{i % 9}" if i % 5 == 0 else x for i, x in enumerate(ids[n // 2:])]
    hi = rng.uniform(0, 1, n).astype(str)
    hi[::97] = ""
    hi[5] = "-0.0"
    hi[n - 3] = "1e-300"
    f = tmp_path / "a.csv"
    f.write_bytes(("component,time,hi" + newline + "".join(
        f"{c},{i},{h}{newline}" for i, (c, h) in enumerate(zip(ids, hi, strict=True))
    )).encode())
    got = read_csv_columns(f)
    assert halves and halves[0] is not None  # read in halves
    _same_columns(got, _one_pass(monkeypatch, f))
    assert "late0" in got["component"].values  # an id first seen in the second half


@pytest.mark.parametrize("where", ["first", "second"])
def test_a_quote_anywhere_reads_the_file_in_one_pass(tmp_path, monkeypatch, halves, where):
    """A quoted value may hold a newline, so a file with a quote character is read in one
    pass: the same columns."""
    lines = [f"c{i % 7},{i},0.{i}" for i in range(2000)]
    lines[100 if where == "first" else 1900] = '"c1",100,0.5'
    f = tmp_path / "q.csv"
    f.write_text("component,time,hi\n" + "\n".join(lines) + "\n")
    got = read_csv_columns(f)
    assert halves == [None]
    _same_columns(got, _one_pass(monkeypatch, f))


def test_the_second_halfs_refusals_are_one_pass_ones(tmp_path, monkeypatch, halves):
    """A bad field count or a text cell in the second half: the halves are dropped and the
    file read in one pass gives its refusal, naming the line or the row."""
    lines = ["component,time,hi"] + [f"c{i % 7},{i},0.3" for i in range(2000)]
    f = tmp_path / "t.csv"
    lines[1800] = "c0,1799,0.3,7"
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(IngestError, match=r"line 1801 \(data row 1800\) has 4 fields"):
        read_acquisitions(f, columns=True)
    assert halves[0] is None
    lines[1800] = "c0,1799,0.3x"
    f.write_text("\n".join(lines) + "\n")
    got = read_acquisitions(f, columns=True)
    assert isinstance(got, pd.DataFrame)  # the frame, whose validation names the row
    assert got["hi"].iloc[1799] == "0.3x"


def test_a_second_half_typed_otherwise_is_read_in_one_pass(tmp_path, monkeypatch, halves):
    """Without the float parse (types inferred): integers in the first half, fractions in
    the second; the halves are dropped and the table is one pass's."""
    f = tmp_path / "i.csv"
    f.write_text("component,time,hi\n" + "".join(
        f"c{i % 3},{i},{i if i < 1000 else i + 0.5}\n" for i in range(2000)))
    got = read_csv_table(f)
    assert halves[-1] is None
    assert got.equals(_one_pass(monkeypatch, f, read_csv_table))


def test_small_files_and_compressed_ones_are_read_in_one_pass(tmp_path):
    """Below MIN_BYTES, and for a compressed file, no halves."""
    f = tmp_path / "s.csv"
    f.write_text("component,time,hi\nc0,0,0.1\n")
    assert csv_halves.read(f, None, 512) is None
    assert isinstance(read_csv_columns(f), dict)


def test_no_newline_near_the_middle_reads_the_file_in_one_pass(tmp_path, monkeypatch):
    """A line longer than the scan past the middle (or a header longer than half the file):
    no halves, the file read as one pass reads it."""
    monkeypatch.setattr(csv_halves, "MIN_BYTES", 0)
    monkeypatch.setattr(csv_halves, "_SCAN_BYTES", 64)
    f = tmp_path / "long.csv"
    f.write_text("component,time,hi\n" + "c0,0," + "1" * 400 + "\nc0,1,0.5\n")
    assert csv_halves.read(f, None, 512) is None
    f.write_text("component,time," + "x" * 400 + "\nc0,0,0.5\n")
    assert csv_halves.read(f, None, 512) is None
