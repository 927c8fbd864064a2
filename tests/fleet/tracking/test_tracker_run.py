"""tracker_run (two sequential passes per component, compiled for large batches) against the
reference it replaces in ingestion: one vectorised tracker_update per acquisition rank.
Equality is exact (same IEEE operations in the same order), for every initiation, with and
without clipping, from fresh and from stored states, with irregular intervals."""

import numpy as np
import pytest

from rulkit.fleet.tracking import tracker_run as tc
from rulkit.fleet.tracking.tracker_chain import TrackerConfig, TrackerState, tracker_update
from rulkit.fleet.tracking.tracker_run import tracker_run


def random_fleet(rng, b, max_k):
    counts = rng.integers(0, max_k + 1, b)
    seg = np.concatenate([[0], np.cumsum(counts)])
    t, hi = [], []
    for k in counts:
        tt = np.cumsum(rng.uniform(0.5, 1.5, k)) + rng.uniform(0, 5)  # irregular intervals
        h0 = rng.uniform(0.0, 0.8)
        t.append(tt)
        hi.append(np.clip(h0 * np.exp(rng.uniform(0.0, 0.03) * tt) + rng.normal(0, 0.003, k),
                          0.0, 3.0))
    return seg, np.concatenate(t), np.concatenate(hi)


def reference(state, seg, t, hi, cfg):
    """One tracker_update per rank over all components (NaN = no acquisition at that rank)."""
    b = len(state)
    counts = np.diff(seg)
    rows = {k: np.full(len(t), np.nan) for k in
            ("fhi", "dhi", "rul", "frul", "drul", "d2rul", "rul_low", "rul_high")}
    rows["valid"] = np.zeros(len(t), dtype=bool)
    rows["level"] = np.zeros(len(t), dtype=np.int8)
    rows["n"] = np.zeros(len(t), dtype=np.int64)
    for r in range(int(counts.max(initial=0))):
        have = counts > r
        idx = seg[:-1][have] + r
        tt, hh = np.full(b, np.nan), np.full(b, np.nan)
        tt[have], hh[have] = t[idx], hi[idx]
        state, out = tracker_update(state, tt, hh, cfg)
        cols = state.columns()
        for k in ("fhi", "dhi", "rul", "frul", "drul", "d2rul", "n"):
            rows[k][idx] = cols[k][have]
        rows["rul_low"][idx], rows["rul_high"][idx] = out.rul_low[have], out.rul_high[have]
        rows["valid"][idx], rows["level"][idx] = out.valid[have], out.level[have]
    return state, rows


@pytest.mark.parametrize("strategy", ["python", "jit", "ranks"])
@pytest.mark.parametrize("initiation,clip,m", [("floor", False, 2.0), ("two-point", False, 2.0),
                                               ("measured", True, 2.0), ("floor", True, 3.0),
                                               ("measured", False, 2.4)])
@pytest.mark.parametrize("equal", [False, True])
def test_tracker_run_equals_rank_by_rank_updates(strategy, initiation, clip, m, equal):
    rng = np.random.default_rng(11)
    cfg = TrackerConfig(dt=1.0, lambda_hi=0.1, lambda_rul=0.1, design_life=1e4,
                        warn_rul=60.0, hi_sigma=0.02, initiation=initiation, rul_clip=clip,
                        paris_exponent=m)
    b = 40
    # a stored state: the first part of each series, then the rest as a new batch
    seg1, t1, h1 = random_fleet(rng, b, 4)
    start, _ = reference(TrackerState.empty(b), seg1, t1, h1, cfg)
    seg2, t2, h2 = random_fleet(rng, b, 60)
    if equal:  # every unit at every rank (the ranks' direct path): the same length each
        k = 45
        seg2, t2, h2 = random_fleet(rng, b, 200)
        keep = np.diff(seg2) >= k
        idx = (seg2[:-1][keep][:, None] + np.arange(k)).ravel()
        b = int(keep.sum())
        start = start.take(np.flatnonzero(keep))
        seg2, t2, h2 = np.arange(0, b * k + 1, k), t2[idx], h2[idx]
    last = np.where(np.isfinite(start.t), start.t, 0.0)
    t2 = t2 + np.repeat(last, np.diff(seg2))  # after each component's stored time
    exp_state, exp = reference(start, seg2, t2, h2, cfg)
    got_state, got = tracker_run(start, seg2, t2, h2, cfg, strategy=strategy)
    assert exp["valid"].any() and exp["level"].max() == 2, "the fixture must alert"
    for k in exp:
        np.testing.assert_array_equal(got[k], exp[k], err_msg=k)
    for k, v in exp_state.columns().items():
        np.testing.assert_array_equal(got_state.columns()[k], v, err_msg=k)


def test_ranks_of_equal_length_refuse_a_time_not_after_the_last_as_tracker_update_does():
    """A time that does not advance at a later rank of the ranks' direct path: the error
    tracker_update raises for that rank's state (the component and both times named)."""
    cfg = TrackerConfig(dt=1.0, design_life=1e4)
    b, k = 5, 8
    t = np.tile(np.arange(1.0, k + 1), b)
    hi = np.full(b * k, 0.3)
    t[3 * k + 6] = t[3 * k + 5]  # component 3's seventh time repeats its sixth
    seg = np.arange(0, b * k + 1, k)
    with pytest.raises(ValueError, match=r"component index 3: time 6\.0 is not after its last "
                                         r"acquisition 6\.0"):
        tracker_run(TrackerState.empty(b), seg, t, hi, cfg, strategy="ranks")


def test_strategy_follows_the_shape_of_the_batch(monkeypatch):
    monkeypatch.setattr(tc, "_JITTED", {})
    assert tc.tracker_strategy(1, 100_000) == "ranks"  # a fleet's periodic batch
    assert tc.tracker_strategy(50, 200) == "python"  # a short history
    assert tc.tracker_strategy(20 * 1000, 2_000_000) == "jit"  # 20 blocks of 1000 ranks
    assert tc.tracker_strategy(2_000_000, 2_000_000) == "jit"  # one long series
    monkeypatch.setattr(tc, "_JITTED", {"hi": None})
    assert tc.tracker_strategy(20, 500) == "jit"  # once loaded, compiled loops are the cheapest


@pytest.mark.parametrize("strategy", ["python", "jit", "ranks"])
@pytest.mark.parametrize("block", [3, 250_000])
def test_ingest_history_and_alerts_equal_the_rank_by_rank_reference(tmp_path, monkeypatch, block,
                                                                    strategy):
    """The store's blocked ingestion (tracker_run per block of components, history in key
    order, alerts from a running maximum) with the tracker chain as the chosen estimator,
    against tracker_update per rank and the alert rules row by row: exact equality of every
    stored number and the same alerts in the same order, over two batches."""
    import pandas as pd

    from rulkit.fleet.monitoring.rules import MonitoringRules
    from rulkit.fleet.store.ingest import ingest_into
    from rulkit.fleet.store.sqlite import ComponentStore
    from rulkit.fleet.tracking.tracker_chain import tracker_rul_interval

    monkeypatch.setattr(ComponentStore, "BLOCK_ROWS", block)
    import rulkit.fleet.store.history_stage as store_module

    monkeypatch.setattr(store_module, "tracker_strategy", lambda n_ranks, n_rows: strategy)
    rng = np.random.default_rng(5)
    cfg = TrackerConfig(dt=1.0, lambda_hi=0.1, lambda_rul=0.1, design_life=1e4, warn_rul=60.0,
                        hi_sigma=0.02, initiation="two-point")
    rules = MonitoringRules(estimator="tracker", lead_time=60.0)
    b = 25
    names = np.array([f"c{i}" for i in rng.permutation(b)], dtype=object)
    seg, t, hi = random_fleet(rng, b, 50)
    cut = seg[:-1] + (np.diff(seg) + 1) // 3  # the first third of each series, then the rest
    state = TrackerState.empty(b)
    ref_rows, ref_alerts, level, n_alerts = [], [], np.zeros(b, dtype=np.int8), 0
    failed = np.zeros(b, dtype=bool)
    for part in range(2):
        lo, hi_end = (seg[:-1], cut) if part == 0 else (cut, seg[1:])
        idx = np.concatenate([np.arange(a, e) for a, e in zip(lo, hi_end, strict=True)])
        comp = np.repeat(np.arange(b), hi_end - lo)
        sub_seg = np.concatenate([[0], np.cumsum(hi_end - lo)])
        state, rows = reference(state, sub_seg, t[idx], hi[idx], cfg)
        med, low, high = tracker_rul_interval(rows["fhi"], rows["frul"], cfg)
        for j in range(len(idx)):  # the rules, row by row in time order per component
            c = comp[j]
            failed[c] |= hi[idx][j] >= 1.0
            rows["level"][j] = 2 if failed[c] else int(low[j] < 60.0)
            if failed[c]:
                med[j] = low[j] = high[j] = 0.0
        rows.update(rul_median=med, rul_low=low, rul_high=high)
        order = np.lexsort((-comp, t[idx]))  # interleaved in time: as a feed delivers them
        df = pd.DataFrame({"component": names[comp[order]], "time": t[idx][order],
                           "hi": hi[idx][order]})
        res, _ = ingest_into(tmp_path / "r.db", df, config=cfg, rules=rules)
        for j in order:  # alerts in acquisition-rank order, then batch order
            c = comp[j]
            if rows["level"][j] > level[c]:
                rank = j - sub_seg[c]
                ref_alerts.append((rank, int(np.flatnonzero(order == j)[0]), names[c],
                                   int(rows["level"][j]), int(level[c]), med[j]))
                level[c] = rows["level"][j]
        got = [(a.component, a.level, a.previous, a.rul) for a in res.alerts]
        assert got == [a[2:] for a in sorted(ref_alerts)]
        n_alerts += len(got)
        ref_alerts = []
        ref_rows.append(pd.DataFrame({"component": names[comp], "t": t[idx], **{
            k: rows[k] for k in ("fhi", "dhi", "rul", "frul", "drul", "d2rul", "rul_median",
                                 "rul_low", "rul_high", "valid", "level")}}))
    with ComponentStore(tmp_path / "r.db", readonly=True) as s:
        hist = s.history()
        comps = s.status().set_index("component").sort_index()
    exp = pd.concat(ref_rows).sort_values(["component", "t"]).reset_index(drop=True)
    for k in exp.columns:
        np.testing.assert_array_equal(hist[k].to_numpy(), exp[k].to_numpy(), err_msg=k)
    for k, v in state.columns().items():
        np.testing.assert_array_equal(comps[k].to_numpy(),
                                      pd.Series(v, index=names).sort_index().to_numpy(),
                                      err_msg=k)
    assert level.max() == 2 and n_alerts > 0
