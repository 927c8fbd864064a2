"""rulkit.reporting: one markdown-table writer for every report."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rulkit.reporting import NAN_TEXT, format_float, format_value, markdown_rows, markdown_table


def test_markdown_table_layout_and_cells() -> None:
    df = pd.DataFrame({
        "method": ["pf", "ekf"],
        "runs": np.array([20, 13600], dtype=np.int64),
        "rmse": [0.123456, np.nan],
        "rul": [np.inf, -np.inf],
        "ok": [True, False],
        "note": [None, "x"],
    })
    text = markdown_table(df)
    assert text.splitlines() == [
        "| method | runs | rmse | rul | ok | note |",
        "|---|---|---|---|---|---|",
        "| pf | 20 | 0.1235 | inf | True |  |",
        "| ekf | 13600 |  | -inf | False | x |",
    ]


def test_integer_column_keeps_integers_beside_floats() -> None:
    # DataFrame.iterrows would upcast this all-numeric row to float and print 1.36e+04
    df = pd.DataFrame({"cycles": [13600], "bias": [1.5e-10]})
    assert markdown_table(df, ".3g").splitlines()[2] == "| 13600 | 1.5e-10 |"


@pytest.mark.parametrize(
    ("value", "spec", "expected"),
    [
        (106.09, ".5g", "106.09"),
        (106.09, ".3g", "106"),
        (2.5, ".3f", "2.500"),
        (float("nan"), ".3f", NAN_TEXT),
        (np.float32(np.nan), ".3f", NAN_TEXT),
        (float("inf"), ".3f", "inf"),
        (-np.inf, ".4g", "-inf"),
        (np.float64(1e-5), ".4g", "1e-05"),
    ],
)
def test_format_float(value: float, spec: str, expected: str) -> None:
    assert format_value(value, spec) == expected


def test_format_float_and_value_agree_and_none_is_missing() -> None:
    assert format_float(0.5) == format_value(np.float64(0.5)) == "0.5"
    assert format_value(None) == NAN_TEXT
    assert format_value(np.int64(7)) == "7"
    assert format_value(np.bool_(True)) == "True"
    assert format_value("a|b") == "a|b"


def test_ragged_rows_are_rejected() -> None:
    with pytest.raises(ValueError, match="2 cells, the header 3"):
        markdown_rows(["a", "b", "c"], [[1, 2]])


def test_module_docstring_example_runs() -> None:
    import doctest

    import rulkit.reporting

    result = doctest.testmod(rulkit.reporting)
    assert result.attempted >= 1 and result.failed == 0
