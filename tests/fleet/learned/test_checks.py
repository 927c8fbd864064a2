"""Implausible histories and fits get a named error or a warning that says what to do."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.learned.checks import check_fit, check_histories
from rulkit.fleet.learned.datasets import synthetic_linear_fleet
from rulkit.fleet.learned.degradation import fit_model
from rulkit.fleet.learned.histories import HistoryError, histories_from_frame


@pytest.fixture(scope="module")
def frame():
    df, _ = synthetic_linear_fleet(np.random.default_rng(0), 10, n_acq=8)
    return df


def _warnings(df, **kw):
    return check_histories(histories_from_frame(df, "h.csv", **kw))


def test_a_plausible_fleet_has_no_warning(frame):
    assert _warnings(frame) == []


def test_epoch_like_ages(frame):
    w = _warnings(frame.assign(time=frame["time"] + 1e9))
    assert len(w) == 1 and "epoch timestamps" in w[0] and "--age-from first" in w[0]
    assert _warnings(frame.assign(time=frame["time"] + 1e9), origin="first") == []


def test_hi_in_percent(frame):
    with pytest.raises(HistoryError, match="percent"):  # every unit starts "failed"
        _warnings(frame.assign(hi=frame["hi"] * 100))
    w = _warnings(frame.assign(hi=frame["hi"] * 2.5))  # another scale: fails early, far above
    assert any("percent" in m and "Normalise" in m for m in w)


def test_a_lone_zero(frame):
    df = frame.copy()
    df.loc[5, "hi"] = 0.0
    w = _warnings(df)
    assert len(w) == 1 and "row 6" in w[0] and "hi = 0" in w[0] and "Drop the row" in w[0]


def test_one_row_per_unit(frame):
    with pytest.raises(HistoryError, match="single acquisition"):
        _warnings(frame.groupby("component").tail(1))
    most = pd.concat([frame.groupby("component").tail(1).iloc[:7],
                      frame[frame["component"].isin(frame["component"].unique()[7:])]])
    assert any("have one acquisition" in m for m in _warnings(most))


def test_a_duplicated_column(frame, tmp_path):
    from rulkit.fleet.learned.histories import read_histories

    with pytest.raises(HistoryError, match=r"'hi' and 'hi.1'"):
        histories_from_frame(frame.assign(**{"hi.1": frame["hi"]}), "h.csv")
    p = tmp_path / "dup.csv"
    p.write_text("component,time,hi,hi\na,1,0.1,0.2\na,2,1.1,1.2\nb,1,0.1,0.1\nb,2,0.2,0.2\n")
    with pytest.raises(HistoryError, match="appears twice"):
        read_histories(p)


def test_timestamps_are_read_not_refused(frame):
    stamps = frame.assign(time=(pd.Timestamp("2024-01-01") + pd.to_timedelta(
        frame["time"], unit="h")).dt.strftime("%Y-%m-%dT%H:%M:%S"))
    h = histories_from_frame(stamps, unit="h")
    assert h.axis.timestamps and h.axis.origin == "first"
    ref = histories_from_frame(frame)
    first = ref.t[ref.start[:-1]][ref.unit]
    np.testing.assert_allclose(h.t, ref.t - first, atol=1e-3)  # ages since the first (s text)
    assert check_histories(h) == []


def test_falling_hi_and_ignored_columns(frame):
    failed = frame.groupby("component")["hi"].transform("last") >= 1.0
    falling = frame.assign(hi=(1.2 - frame["hi"]).clip(lower=0.0), note="x", failed=failed)
    w = _warnings(falling)
    assert any("falls over time" in m for m in w) and any("ignored" in m for m in w)


def test_fit_checks_say_what_to_do(frame):
    m = fit_model(histories_from_frame(frame), "linear")
    assert check_fit(m, coverage=0.9) == []
    w = check_fit(m, coverage=0.5)
    assert len(w) == 1 and "50%" in w[0] and "too narrow" in w[0]
    assert "too wide" in check_fit(m, coverage=1.0)[0]
