"""A batch validated from arrays (the service's JSON columns) or from a frame (CSV, Parquet,
``rulkit track``): the same :class:`Batch`, the same refusals; its rows kept by ``take``."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.store.acquisitions import IngestError, validate_acquisitions
from rulkit.fleet.tracking.tracker_chain import TrackerConfig


def columns(comp: list[str], t: list[float], hi: list[float]) -> dict[str, np.ndarray]:
    c = np.empty(len(comp), dtype=object)
    c[:] = comp
    return {"component": c, "time": np.array(t, dtype=np.float64),
            "hi": np.array(hi, dtype=np.float64)}


def test_arrays_and_frame_give_the_same_batch():
    comp = ["b", "a", "b", "c", "a"]
    t, hi = [1.0, 1.0, 2.0, 5.0, 3.0], [0.1, 0.2, 0.3, 0.4, 0.5]
    cols = columns(comp, t, hi)
    got = validate_acquisitions(cols, TrackerConfig(), None)
    ref = validate_acquisitions(pd.DataFrame(cols), TrackerConfig(), None)
    codes, uniques = pd.factorize(pd.Series(comp))  # first appearance, as pandas numbers them
    for b in (got, ref):
        assert b.names == list(uniques)
        np.testing.assert_array_equal(b.codes, codes)
        np.testing.assert_array_equal(b.t, t)
        np.testing.assert_array_equal(b.hi, hi)
        np.testing.assert_array_equal(b.row, np.arange(1, 6))
        assert not b.calendar and b.seconds_per_unit == 1.0


def test_take_renumbers_the_kept_components_by_first_appearance():
    comp = ["b", "a", "b", "c", "a", "d"]
    batch = validate_acquisitions(columns(comp, [1, 1, 2, 1, 2, 1], [0.1] * 6),
                                  TrackerConfig(), None)
    keep = np.array([False, True, True, True, False, True])
    sub = batch.take(keep)
    kept = [c for c, k in zip(comp, keep, strict=True) if k]
    codes, uniques = pd.factorize(pd.Series(kept))
    assert sub.names == list(uniques) == ["a", "b", "c", "d"]
    np.testing.assert_array_equal(sub.codes, codes)
    np.testing.assert_array_equal(sub.row, [2, 3, 4, 6])
    np.testing.assert_array_equal(sub.first_rows(), [0, 1, 2, 3])


@pytest.mark.parametrize(("comp", "t", "hi", "match"), [
    (["a", "b"], [1.0, 2.0], [0.1, np.nan],
     r"column 'hi', row 2 \(component 'b'\): NaN \(an empty or NaN cell\) is not allowed"),
    (["a", "a"], [2.0, 2.0], [0.1, 0.2],
     r"row 2 \(component 'a'\): time 2.0 repeats the previous acquisition"),
    (["a", "b"], [1.0, np.inf], [0.1, 0.2], r"column 'time', row 2 \(component 'b'\): inf"),
    (["a", "b\x1b"], [1.0, 2.0], [0.1, 0.2], r"row 2: component id .* non-printable"),
    (["a", "b"], [1.0, 2.0], [0.1, 99.0], r"row 2 \(component 'b'\): hi = 99.0 is outside"),
])
def test_refusals_from_arrays_name_the_row(comp, t, hi, match):
    with pytest.raises(IngestError, match=match):
        validate_acquisitions(columns(comp, t, hi), TrackerConfig(), None)
    with pytest.raises(IngestError, match=match):  # the frame says the same
        validate_acquisitions(pd.DataFrame(columns(comp, t, hi)), TrackerConfig(), None)


def test_columns_of_different_lengths_are_refused():
    cols = columns(["a", "b"], [1.0, 2.0], [0.1, 0.2])
    cols["hi"] = cols["hi"][:1]
    with pytest.raises(IngestError, match="different lengths"):
        validate_acquisitions(cols, TrackerConfig(), None)
