"""Bad histories get named errors (issue 11); good ones are grouped per unit."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.learned.histories import HistoryError, histories_from_frame, read_histories


def _frame():
    return pd.DataFrame({"component": ["a", "a", "a", "b", "b"],
                         "time": [0.0, 1.0, 2.0, 0.5, 1.5], "hi": [0.1, 0.5, 1.1, 0.2, 0.4]})


def test_groups_units_and_failure_times():
    h = histories_from_frame(_frame())
    assert list(h.names) == ["a", "b"] and list(h.failed) == [True, False]
    assert h.failure_time()[0] == pytest.approx(1.0 + 0.5 / 0.6)
    assert np.isnan(h.failure_time()[1])


@pytest.mark.parametrize(("edit", "match"), [
    (lambda d: d[d.component == "a"], "1 unit"),
    (lambda d: d.assign(hi=d.hi.clip(upper=0.9)), "no unit has failed"),
    (lambda d: d.assign(time=[0.0, 2.0, 1.0, 0.5, 1.5]), r"row 3 \(component 'a'\): time 1"),
    (lambda d: d.assign(hi=[0.1, np.nan, 1.1, 0.2, 0.4]), r"'hi', row 2 .*must be a finite number"),
    (lambda d: d.assign(hi=[0.1, 0.5, 1.1, -0.2, 0.4]), r"row 4 .*hi = -0.2 < 0"),
    (lambda d: d.drop(columns="time"), "missing column"),
    (lambda d: d.assign(installed=[0.0, 0.0, 0.1, 0.0, 0.0]), "not constant within"),
    (lambda d: d.assign(time=["2024-01-01", "x", "2024-01-03", "2024-01-01", "2024-01-02"]),
     r"'time', row 2 \(component 'a'\): 'x' is not a date-time"),
    (lambda d: d.assign(failed=["x", "x", "x", 0, 0]), "failed = 'x'"),
])
def test_named_errors(edit, match):
    with pytest.raises(HistoryError, match=match):
        histories_from_frame(edit(_frame()), "h.csv")


def test_date_times_become_ages():
    d = _frame().assign(time=pd.to_datetime(_frame().time, unit="h"))
    h = histories_from_frame(d, unit="h")
    assert list(h.t) == [0.0, 1.0, 2.0, 0.0, 1.0]  # since each unit's first acquisition
    inst = histories_from_frame(_frame().assign(installed=[-1.0] * 3 + [0.5] * 2))
    assert list(inst.t) == [1.0, 2.0, 3.0, 0.0, 1.0] and inst.axis.origin == "installed"


def test_failed_column_overrides_the_threshold(tmp_path):
    d = _frame().assign(failed=[0, 0, 0, 1, 1])
    p = tmp_path / "h.csv"
    d.to_csv(p, index=False)
    h = read_histories(p)
    assert list(h.failed) == [False, True]
    assert h.failure_time()[1] == 1.5  # flagged failed without reaching 1: last time
    with pytest.raises(HistoryError, match="no such file"):
        read_histories(tmp_path / "missing.csv")
