"""One notion of time: a time column (numbers or date-times) becomes an age on a TimeAxis."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.time_axis import TimeAxis, TimeAxisError, infer_axis, unit_origins


def test_date_times_are_converted_into_the_unit():
    col = pd.Series(["2024-01-01T00:00:00", "2024-01-02T12:00:00"])
    ax = infer_axis(col, unit="d")
    assert ax.timestamps and ax.origin == "first" and ax.unit == "d"
    v = ax.values(col)
    assert v[1] - v[0] == pytest.approx(1.5)
    # 2024-01-01 is 19723 days after 1970-01-01 (the same count from datetime)
    assert v[0] == pytest.approx((pd.Timestamp("2024-01-01") - pd.Timestamp("1970-01-01")).days)


def test_defaults_and_installed_origin():
    assert infer_axis(pd.Series([1.0, 2.0])) == TimeAxis(unit="", timestamps=False,
                                                          origin="time")
    assert infer_axis(pd.Series(["2024-01-01"])).unit == "h"
    assert infer_axis(pd.Series([1.0]), has_installed=True).origin == "installed"


def test_the_kinds_must_match_what_was_fitted():
    numbers = TimeAxis(unit="kcycles")
    with pytest.raises(TimeAxisError, match=r"holds date-times.*numbers in kcycles"):
        numbers.values(pd.Series(["2024-01-01"]), where="batch")
    stamps = TimeAxis(unit="h", timestamps=True, origin="first")
    with pytest.raises(TimeAxisError, match=r"holds numbers.*date-times"):
        stamps.values(pd.Series([1.0, 2.0]))
    with pytest.raises(TimeAxisError, match="a duration"):
        TimeAxis(unit="kcycles", timestamps=True)
    with pytest.raises(TimeAxisError, match="age origin"):
        TimeAxis(origin="install")


def test_unit_origins():
    t = np.array([5.0, 7.0, 1.0, 3.0])
    codes = np.array([0, 0, 1, 1])
    assert list(unit_origins(TimeAxis(), t, codes, 2)) == [0.0, 0.0]
    assert list(unit_origins(TimeAxis(origin="first"), t, codes, 2)) == [5.0, 1.0]
    inst = np.array([4.0, 4.0, 0.5, 0.5])
    assert list(unit_origins(TimeAxis(origin="installed"), t, codes, 2, inst)) == [4.0, 0.5]
    assert TimeAxis.from_dict(TimeAxis(unit="d", origin="first").to_dict()) == TimeAxis(
        unit="d", origin="first")
