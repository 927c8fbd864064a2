"""A batch's stored rows and the components rows it writes (rulkit.fleet.store.tracker_rows)."""

import numpy as np
import pytest

from rulkit.fleet.store.tracker_rows import StoredRows, component_rows


def test_component_rows_are_typed_as_the_columns_and_null_where_allowed():
    values = np.array([[1.5, 3.0, 1.0, np.nan, np.nan],
                       [-0.0, 0.0, 0.0, 2.25, np.nan]])
    rows = component_rows(["a", "b"], values, ("t", "n", "valid", "failed_at", "rul"),
                          nullable=("failed_at",))
    assert [r[:5] for r in rows] == [["a", 1.5, 3, True, None], ["b", -0.0, 0, False, 2.25]]
    assert [type(v) for v in rows[0]] == [str, float, int, bool, type(None), float]
    assert np.isnan(rows[0][5]) and np.isnan(rows[1][5])  # not nullable: NaN kept
    assert str(rows[1][1]) == "-0.0"
    last = component_rows(["a", "b"], values, ("t", "n", "valid", "failed_at", "rul"),
                          nullable=("failed_at",), key_last=True)
    assert [r[:4] + r[5:] for r in last] == [[1.5, 3, True, None, "a"],
                                             [-0.0, 0, False, 2.25, "b"]]


def test_component_rows_null_in_a_nullable_integer_column_and_refused_in_another():
    values = np.array([[1.0, np.nan, 2.0], [2.0, 4.0, 1.0]])
    rows = component_rows(["a", "b"], values, ("t", "hits", "n"), nullable=("hits",))
    assert rows == [["a", 1.0, None, 2], ["b", 2.0, 4, 1]]
    assert type(rows[1][2]) is int
    values[0, 2] = np.nan
    with pytest.raises(ValueError, match="column n: NaN"):
        component_rows(["a", "b"], values, ("t", "hits", "n"), nullable=("hits",))


def test_stored_rows_joined_and_taken_by_name():
    a = StoredRows.of_tuples([("x", 1.0, None), ("y", 2.0, 5)], 2)
    b = StoredRows.of_tuples([("z", 3.0, True)], 2)
    both = StoredRows.joined([a, StoredRows.of_tuples([], 2), b])
    known, rows = both.rows_of(["q", "z", "x"])
    assert known.tolist() == [1, 2]
    assert rows[:, 0].tolist() == [3.0, 1.0] and rows[0, 1] == 1.0 and np.isnan(rows[1, 1])
    assert both.last_t() == {"x": 1.0, "y": 2.0, "z": 3.0}
    assert "y" in both and "q" not in both and len(both) == 3
