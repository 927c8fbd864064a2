"""The vectorised formatting of `rulkit status --format table` gives the same text as the
per-cell reference (format(), rulkit.tables.text_table) it replaced."""

import math

import numpy as np
import pytest

from rulkit.fleet.store import status_view
from rulkit.fleet.store.cli import (
    _aligned_table,
    _ascii_texts,
    _fmt,
    _format_all,
    _format_distinct,
    rul_texts,
)
from rulkit.tables import safe_text, text_table

EDGES = [0.0, -0.0, 1e-300, 5e-324, -1.5, 0.0005, 0.9995, 123456.789, 1e16, -2.5e-7, 1e308,
         math.inf, -math.inf, 0.1 + 0.2, 2.675, 999.5, 1e-5]


def values(rng):
    return EDGES + rng.normal(0, 10.0 ** rng.integers(-8, 9, 300)).tolist()


def test_format_all_equals_format_for_every_spec():
    rng = np.random.default_rng(1)
    vals = values(rng)
    for spec in (".3f", ".3g", "g"):
        assert _format_all("%" + spec, vals) == [format(v, spec) for v in vals], spec
    ints = [0, 1, -7, 2**62, 12345]
    assert _format_all("%d", ints) == [str(v) for v in ints]
    assert _format_all("%g", []) == []


def test_aligned_table_equals_text_table():
    rng = np.random.default_rng(3)
    n = 50
    ids = [safe_text(s, 40) for s in
           ["a", "x\x1b[2Jy", "long-" * 20, "ünï", "tab\tid", *[f"c{i}" for i in range(n - 5)]]]
    cols = {
        "component": ids,
        "level": rng.choice(["ok", "warning", "alarm"], n).tolist(),
        "HI": _format_all("%.3f", rng.uniform(0, 2, n).tolist()),
        "RUL": rul_texts(np.where(rng.random(n) < 0.2, np.nan, rng.normal(0, 1e3, n)),
                         rng.normal(0, 1e3, n), rng.normal(0, 1e3, n), np.zeros(n, bool)),
        "valid": rng.choice(["yes", "no"], n).tolist(),
        "last t": _format_all("%g", rng.uniform(0, 1e7, n).tolist()),
    }
    left = ("component", "level")
    assert "".join(_aligned_table(cols, left)) == text_table(cols, left=left)
    # a left-aligned last column: trailing blanks are stripped as in text_table
    cols2 = {"x": ["1", "22"], "name": ["a", "bbbbb"]}
    assert "".join(_aligned_table(cols2, ("name",))) == text_table(cols2, left=("name",))
    assert "".join(_aligned_table({"a": [], "b": []}, ())) == text_table({"a": [], "b": []})


@pytest.mark.parametrize("chunk", [4096, 7, 1])
def test_aligned_table_of_ascii_cells_equals_text_table(monkeypatch, chunk):
    """Printable ASCII cells take the byte-matrix layout: the same text as text_table with
    empty cells, blank rows, a last column of width 0, a name wider than its cells, one row,
    in one chunk of rows or many."""
    monkeypatch.setattr(status_view, "CHUNK_ROWS", chunk)
    rng = np.random.default_rng(4)
    n = 200
    words = ["", "a", "ok", "warning", "12.5 [3, 40]", "x" * 40, "~!#$%&'()*+,-./:;<=>?@[\\]^_`{|}"]
    cols = {
        "component": [f"c{i}" for i in range(n)],
        "level": rng.choice(words, n).tolist(),
        "a much longer heading": rng.choice(words, n).tolist(),
        "HI": _format_all("%.3f", rng.uniform(0, 2, n).tolist()),
        "": rng.choice(["", "stale"], n).tolist(),
    }
    assert _ascii_texts(list(cols), list(cols.values())) is not None  # this path
    for left in [("component", "level", ""), (), tuple(cols)]:
        assert "".join(_aligned_table(cols, left)) == text_table(cols, left=left), left
    blank = {"x": ["", "", "1"], "": ["", "", ""]}  # the dashes' line ends in two blanks
    assert "".join(_aligned_table(blank, ("",))) == text_table(blank, left=("",))
    one = {"component": ["c1"], "level": ["ok"]}
    assert "".join(_aligned_table(one, ("level",))) == text_table(one, left=("level",))
    assert "".join(_aligned_table({"a": [], "": []}, ())) == text_table({"a": [], "": []})


def test_rul_texts_equal_per_row_format():
    """The RUL cells from one %-format equal the per-row texts: `.3g` with NaN as `-` inside
    the brackets, -0.0 as 0, `-` while not estimated, `failed` once failed."""
    rng = np.random.default_rng(5)
    vals = [*values(rng), math.nan, -0.0]
    m, lo, hi = (rng.permutation(vals) for _ in range(3))
    failed = rng.random(len(vals)) < 0.2
    want = ["failed" if f else "-" if math.isnan(a) else f"{_fmt(a)} [{_fmt(b)}, {_fmt(c)}]"
            for a, b, c, f in zip(m, lo, hi, failed, strict=True)]
    assert rul_texts(m, lo, hi, failed) == want
    assert rul_texts([], [], [], []) == []


def test_format_distinct_equals_format_per_value():
    """Each distinct value formatted once gives the per-value texts: -0.0 apart from 0.0,
    NaN and infinities, repeats in any order, int64 counts."""
    rng = np.random.default_rng(6)
    vals = np.array([*values(rng), -0.0, 0.0, math.nan, -math.nan])
    vals = rng.choice(vals, 1000)
    assert _format_distinct("%g", vals) == [format(v, "g") for v in vals.tolist()]
    ints = rng.choice([0, 1, 3, 12, 2**62, -7], 500)
    assert _format_distinct("%d", ints) == [str(v) for v in ints.tolist()]
    assert _format_distinct("%g", np.zeros(0)) == []
