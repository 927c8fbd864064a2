"""The alert rules (rulkit.fleet.monitoring.rules) against a row-by-row reference written
from their definition, over random persistence windows, stored states and batch splits."""

import math

import numpy as np
import pytest

from rulkit.fleet.monitoring.rules import (
    MAX_WINDOW,
    MonitoringRules,
    RuleState,
    apply_rules,
    due_time,
    parse_duration,
    stale,
    unit_seconds,
)


def reference(rules, units_rows):
    """Per component: the level, RUL and the highest level before, row by row (EI-20, EI-21)."""
    out = []
    for rows in units_rows:
        crossed, failed, top = [], False, 0
        for hi, med, low, high in rows:
            crossed.append(hi >= rules.alarm_hi)
            if sum(crossed[-rules.alarm_window:]) >= rules.alarm_hits:
                failed = True
            lv = 2 if failed else (1 if math.isfinite(med) and low < rules.lead_time else 0)
            out.append((lv, *((0.0, 0.0, 0.0) if failed else (med, low, high)), top))
            top = max(top, lv)
    return out


@pytest.mark.parametrize("seed", range(6))
def test_rules_equal_the_row_by_row_reference_over_any_batch_split(seed):
    rng = np.random.default_rng(seed)
    window = int(rng.integers(1, MAX_WINDOW + 1))
    rules = MonitoringRules(alarm_hits=int(rng.integers(1, window + 1)), alarm_window=window,
                            lead_time=float(rng.uniform(5, 50)), alarm_hi=1.0)
    b = 12
    counts = rng.integers(0, 40, b)
    units = []
    for n in counts:
        hi = rng.uniform(0.5, 1.2, n) * (rng.random(n) < 0.9)  # spikes over 1 and dips
        med = np.where(rng.random(n) < 0.2, np.nan, rng.uniform(0, 100, n))
        low = med * rng.uniform(0.3, 1.0, n)
        units.append(list(zip(hi, med, low, med * 1.5, strict=True)))
    ref = reference(rules, units)
    # the same rows in 1 to 4 batches: the stored state carries the rest
    for n_parts in (1, 2, 4):
        state = RuleState.empty(b)
        got = [None] * sum(counts)
        cuts = [np.sort(rng.integers(0, c + 1, n_parts - 1)) for c in counts]
        starts = np.concatenate([[0], np.cumsum(counts)])
        for p in range(n_parts):
            lo = [0 if p == 0 else int(c[p - 1]) for c in cuts]
            hi_ = [int(c[p]) if p < n_parts - 1 else int(n) for c, n in zip(cuts, counts,
                                                                            strict=True)]
            pos = [starts[u] + k for u in range(b) for k in range(lo[u], hi_[u])]
            rows = [units[u][k] for u in range(b) for k in range(lo[u], hi_[u])]
            seg = np.concatenate([[0], np.cumsum(np.subtract(hi_, lo))])
            arr = np.array(rows, dtype=float).reshape(-1, 4)
            state, out = apply_rules(rules, seg, np.arange(len(rows), dtype=float), arr[:, 0],
                                     arr[:, 1], arr[:, 2], arr[:, 3], state)
            for i, j in enumerate(pos):
                got[j] = (int(out.level[i]), out.median[i], out.low[i], out.high[i],
                          int(out.previous[i]))
        for g, r in zip(got, ref, strict=True):
            assert g[0] == r[0] and g[4] == r[4]
            np.testing.assert_array_equal(g[1:4], r[1:4])


def test_failed_is_latched_and_remembers_when():
    rules = MonitoringRules(alarm_hits=2, alarm_window=3, lead_time=10.0)
    hi = np.array([0.5, 1.1, 0.6, 1.05, 0.4, 0.3, 0.2])  # 2 of the last 3 at t = 3
    st, out = apply_rules(rules, np.array([0, 7]), np.arange(7.0), hi, *(np.full(7, 50.0),) * 3,
                          RuleState.empty(1))
    assert out.level.tolist() == [0, 0, 0, 2, 2, 2, 2]
    assert out.median.tolist() == [50.0] * 3 + [0.0] * 4
    assert st.failed_at[0] == 3.0 and st.max_level[0] == 2
    assert st.hits[0] == 0b0101000  # bit 0 the newest acquisition


def test_settings_checked_and_round_trip():
    r = MonitoringRules(estimator="tracker", time_unit="h", alarm_hits=2, alarm_window=3,
                        stale_after=3600.0)
    assert MonitoringRules.from_dict(r.to_dict()) == r
    assert r.levels == (0.5, pytest.approx(0.05), pytest.approx(0.95))
    for bad in ({"estimator": "magic"}, {"alarm_hits": 3, "alarm_window": 2},
                {"alarm_window": MAX_WINDOW + 1}, {"lead_time": -1.0}, {"interval": 1.0},
                {"stale_after": 0.0}):
        with pytest.raises(ValueError, match="MonitoringRules"):
            MonitoringRules(**bad)
    with pytest.raises(ValueError, match="unknown keys"):
        MonitoringRules.from_dict({"lead": 3})


def test_durations_units_staleness_and_due_dates():
    assert parse_duration("36h") == 36 * 3600 and parse_duration("2 d") == 172800
    assert parse_duration("90min") == 5400 and parse_duration("15") == 15
    for bad in ("", "h", "-3h", "soon"):
        with pytest.raises(ValueError, match="positive duration"):
            parse_duration(bad)
    assert unit_seconds("Hours") == 3600 and unit_seconds("kcycles") is None
    rules = MonitoringRules(stale_after=3600.0)
    seen = np.array([0.0, 5000.0, np.nan])
    assert stale(seen, 7200.0, rules).tolist() == [True, False, False]
    assert not stale(seen, 1e9, MonitoringRules()).any()
    due = due_time(np.array([1000.0, 1000.0, np.nan, 0.0]), np.array([2.0, np.inf, 1.0, 1.0]),
                   "h")
    assert due[0] == 1000.0 + 7200.0 and np.isnan(due[1:3]).all() and due[3] == 3600.0
    assert np.isnan(due_time(np.array([0.0]), np.array([1.0]), "kcycles")).all()
