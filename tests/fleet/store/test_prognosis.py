"""One RUL per component in the store (rulkit.fleet.store.prognosis): the property of every
estimator (no RUL anywhere negative or outside its own interval; every unit whose measured HI
crossed the threshold in alarm), the estimator in force and its labels, the replay on a rules
change or an upgrade against a fresh ingestion, the calendar time of acquisitions."""

import sqlite3
from typing import Any

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rulkit.fleet.learned.degradation import DegradationModel
from rulkit.fleet.learned.hi_noise import HiNoiseModel
from rulkit.fleet.learned.histories import histories_from_frame
from rulkit.fleet.learned.onset import OnsetModel
from rulkit.fleet.learned.regression import fit_regression
from rulkit.fleet.learned.similarity import fit_similarity
from rulkit.fleet.monitoring.rules import MonitoringRules
from rulkit.fleet.monitoring.unit_trend import TrendConfig, rul_quantiles, trend_posterior
from rulkit.fleet.store.ingest import ingest_into
from rulkit.fleet.store.schema import COMPONENTS, RUL_COLUMNS
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.store.status_view import read_status
from rulkit.fleet.tracking.tracker_chain import TrackerConfig, tracker_rul_interval

MODELS: dict[str, Any] = {
    "linear": DegradationModel(kind="linear", shape=0.0, mean=(0.2, 0.5), cov=(0.01, 0.0, 0.04),
                               noise_sd=0.02, walk_sd=0.01, time_scale=20.0),
    "exponential": DegradationModel(kind="exponential", shape=-0.05, mean=(-1.5, 1.0),
                                    cov=(0.1, 0.01, 0.2), noise_sd=0.05, walk_sd=0.0,
                                    time_scale=20.0),
    "paris": DegradationModel(kind="paris", shape=-0.5, mean=(-2.0, 1.5), cov=(0.2, 0.0, 0.5),
                              noise_sd=0.1, walk_sd=0.1, time_scale=20.0),
}
_GROWTH = {"shape": 0.0, "mean": (-1.5, 1.0), "cov": (0.1, 0.01, 0.2), "hi_noise_sd": 0.03,
           "log_noise_sd": 0.05, "walk_sd": 0.1, "time_scale": 20.0}
MODELS |= {  # the candidates with other states (HI noise, onset mixture, baselines' sums)
    "paris-mixed": HiNoiseModel(noise="mixed", **_GROWTH),
    "onset": OnsetModel(noise="additive", grid=(0.0, 10.0, 30.0), onset_mean=10.0,
                        onset_sd=10.0, **_GROWTH),
}
_BASELINE_FLEET = pd.DataFrame({"component": np.repeat(["a", "b", "c"], 8),
                                "time": np.tile(np.arange(1.0, 9.0), 3),
                                "hi": np.concatenate([0.1 * np.exp(r * np.arange(1.0, 9.0))
                                                      for r in (0.35, 0.3, 0.2)])})
_BASELINE_HIST = histories_from_frame(_BASELINE_FLEET)
MODELS |= {"regression": fit_regression(_BASELINE_HIST, shape=0.0, window=5.0),
           "similarity": fit_similarity(_BASELINE_HIST, window=5.0, temperature=10.0,
                                        bandwidth=0.2)}
ESTIMATORS = ("trend", "tracker-seed", "tracker-safe", *(f"model-{k}" for k in MODELS))


def random_fleet(rng, n_units, max_acq):
    """HI paths of every shape an operator sees: exponential or linear growth, flat, noisy
    (additive noise up to 0.2), single spikes over 1, crossings that stay, zeros."""
    rows = []
    for u in range(n_units):
        k = int(rng.integers(1, max_acq + 1))
        t = np.cumsum(rng.uniform(0.2, 3.0, k)) + rng.uniform(0, 50)
        shape = rng.integers(4)
        h0, rate = rng.uniform(0.0, 0.9), rng.uniform(-0.01, 0.1)
        hi = [h0 * np.exp(rate * (t - t[0])), h0 + rate * (t - t[0]),
              np.full(k, h0), h0 + rng.uniform(0, 0.02) * (t - t[0]) ** 1.5][shape]
        hi = hi + rng.normal(0, rng.choice([0.0, 0.01, 0.2]), k)
        spikes = rng.random(k) < 0.05
        hi = np.where(spikes, hi + 1.0, hi)
        hi = np.where(rng.random(k) < 0.03, 0.0, hi)
        rows += [(f"u{u}", float(tt), float(h)) for tt, h in zip(t, np.clip(hi, 0, 9.5),
                                                                  strict=True)]
    return pd.DataFrame(rows, columns=["component", "time", "hi"])


def open_with(path, estimator, rules):
    cfg = TrackerConfig.safe() if estimator == "tracker-safe" else TrackerConfig()
    kind = "tracker" if estimator.startswith("tracker") else (
        "trend" if estimator == "trend" else "auto")
    store = ComponentStore(path, config=cfg, rules=MonitoringRules(
        estimator=kind, alarm_hits=rules[0], alarm_window=rules[1], lead_time=rules[2]))
    if estimator.startswith("model-"):
        store.set_degradation_model(MODELS[estimator[6:]])
    return store


def crossed(df, hits, window, alarm_hi=1.0):
    """Units whose measured HI reached alarm_hi in `hits` of some `window` consecutive
    acquisitions (the alarm rule, by brute force)."""
    out = set()
    for comp, g in df.groupby("component"):
        c = (g.sort_values("time")["hi"].to_numpy() >= alarm_hi).astype(int)
        if any(c[max(0, i + 1 - window):i + 1].sum() >= hits for i in range(c.size)):
            out.add(comp)
    return out


def check_interval(med, low, high, where):
    med, low, high = (np.asarray(v, dtype=float) for v in (med, low, high))
    assert np.all(low >= 0) and np.all(high >= low), where
    est = ~np.isnan(med)
    assert np.all(med[est] >= 0), where
    assert np.all((low[est] <= med[est]) & (med[est] <= high[est])), where
    assert np.all((low[~est] == 0) & (high[~est] == np.inf)), where  # not estimated yet


@pytest.mark.parametrize("estimator", ESTIMATORS)
@settings(max_examples=6)
@given(seed=st.integers(0, 2**32 - 1), window=st.integers(1, 4), batches=st.integers(1, 3))
def test_every_estimator_one_rul_inside_its_interval_and_crossings_alarm(
        tmp_path_factory, estimator, seed, window, batches):
    rng = np.random.default_rng(seed)
    hits = int(rng.integers(1, window + 1))
    df = random_fleet(rng, int(rng.integers(1, 7)), 30)
    path = tmp_path_factory.mktemp("p") / "f.db"
    alerts = []
    with open_with(path, estimator, (hits, window, float(rng.uniform(1, 200)))) as store:
        cuts = np.sort(rng.uniform(df.time.min(), df.time.max(), batches - 1))
        for lo, hi in zip([-np.inf, *cuts], [*cuts, np.inf], strict=True):
            part = df[(df.time > lo) & (df.time <= hi)]
            if len(part):
                alerts += store.ingest(part).alerts
        comps = store.status().set_index("component")
        hist = store.history()
    check_interval(hist.rul_median, hist.rul_low, hist.rul_high, "history")
    check_interval(comps.rul_median, comps.rul_low, comps.rul_high, "components")
    got = read_status(path, now=0.0)
    assert got is not None
    cols = got[1]
    check_interval(cols["rul"], cols["rul_low"], cols["rul_high"], "status")
    for a in alerts:
        check_interval([a.rul], [a.rul_low], [a.rul_high], "alert")
    failed = crossed(df, hits, window)
    assert {c for c in comps.index if comps.loc[c, "level"] == 2} == failed
    assert set(comps.index[comps.failed_at.notna()]) == failed
    assert sorted(a.component for a in alerts if a.level == 2) == sorted(failed)
    for c in failed:  # failed is shown as failed: RUL 0 [0, 0]
        assert tuple(comps.loc[c, ["rul_median", "rul_low", "rul_high"]]) == (0.0, 0.0, 0.0)


def fleet_frame(n=4, k=40, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(float(k))
    return pd.concat([pd.DataFrame({"component": f"c{i}", "time": t, "hi": 0.2 * np.exp(
        (0.02 + 0.01 * i) * t) + rng.normal(0, 0.005, k)}) for i in range(n)])


def table(path, name):
    if name == "history":  # packed: every acquisition's values, decoded
        with ComponentStore(path, readonly=True) as store:
            return store.history()
    con = sqlite3.connect(path)
    try:
        return pd.read_sql_query(f"SELECT * FROM {name} ORDER BY component", con)
    finally:
        con.close()


def test_estimator_in_force_writes_its_own_rul(tmp_path):
    """What each choice stores, against the estimator's own function on the same state."""
    df = fleet_frame()
    for kind in ("trend", "tracker"):
        db = tmp_path / f"{kind}.db"
        rules = MonitoringRules(estimator=kind, lead_time=10.0)
        ingest_into(db, df, rules=rules)
        h = table(db, "history")
        if kind == "tracker":
            ref = tracker_rul_interval(h["fhi"], h["frul"], TrackerConfig())
        else:
            from rulkit.fleet.monitoring.unit_trend import TrendState, trend_run

            seg = np.concatenate([[0], np.cumsum(h.groupby("component").size().to_numpy())])
            _, rows = trend_run(TrendState.empty(seg.size - 1), seg, h["t"], h["hi"],
                                TrendConfig())
            ref = rul_quantiles(trend_posterior(rows, TrendConfig()), rules.levels)
        run = h["level"].to_numpy() < 2
        for col, r in zip(("rul_median", "rul_low", "rul_high"), ref, strict=True):
            got, r = h[col].to_numpy()[run], np.asarray(r)[run]
            known = ~np.isnan(r)
            np.testing.assert_allclose(got[known], r[known], rtol=1e-12, err_msg=col)


def test_rules_change_replays_like_a_fresh_database(tmp_path):
    df = fleet_frame()
    rules = MonitoringRules(alarm_hits=2, alarm_window=3, lead_time=25.0, time_unit="h")
    ingest_into(tmp_path / "a.db", df)
    with ComponentStore(tmp_path / "a.db") as s:
        assert s.set_rules(rules) == 4
    ingest_into(tmp_path / "b.db", df, rules=rules)
    for name in ("components", "history"):
        a, b = table(tmp_path / "a.db", name), table(tmp_path / "b.db", name)
        cols = [c for c in a.columns if c not in ("seen", "due", "ingest")]  # the clock
        pd.testing.assert_frame_equal(a[cols], b[cols], check_exact=False, rtol=1e-12)


def test_batches_continue_the_stored_rules_and_trend_like_one_batch(tmp_path):
    """A later batch starts from the stored rule and trend columns (read with the tracker
    state in one query): the fleet in three batches, some components absent from some, ends
    with the same components and history as in one batch."""
    df = fleet_frame(n=5, k=30, seed=3)
    rules = MonitoringRules(alarm_hi=0.3, alarm_hits=2, alarm_window=3, lead_time=25.0)
    ingest_into(tmp_path / "one.db", df, rules=rules)
    # the first batch ends with the fleet's first crossing: its alarm needs that stored hit
    cut = df.loc[df["hi"] >= 0.3, "time"].min() + 0.5
    later = df["time"] > cut
    parts = [df[~later], df[later & (df["component"] != "c1")],
             df[later & (df["component"] == "c1")]]
    for part in parts:
        ingest_into(tmp_path / "three.db", part, rules=rules)
    for name in ("components", "history"):
        a, b = table(tmp_path / "one.db", name), table(tmp_path / "three.db", name)
        cols = [c for c in a.columns if c not in ("seen", "due", "ingest")]  # the clock
        pd.testing.assert_frame_equal(a[cols], b[cols], check_exact=False, rtol=1e-12)
    assert (table(tmp_path / "one.db", "components")["level"] > 0).any()  # rules at work


def test_an_older_database_is_upgraded_in_place(tmp_path, row_history):
    """A database written before the one-RUL columns and the packed history (rebuilt here by
    dropping them, the history in its old DDL of one row per acquisition) gains them on its
    first writable opening, its RULs and levels replayed from the acquisitions; `rulkit
    status` on it before then says what to do."""
    df = fleet_frame()
    ingest_into(tmp_path / "new.db", df)
    ingest_into(tmp_path / "old.db", df)
    frame = table(tmp_path / "old.db", "history")
    con = sqlite3.connect(tmp_path / "old.db")
    with con:
        row_history(con, frame, median=False)
        for name, _ in COMPONENTS.indexes:  # the pages' indexes and counts came later
            con.execute(f"DROP INDEX {name}")
        con.execute("DROP TABLE level_counts")
        for col in RUL_COLUMNS:
            con.execute(f"ALTER TABLE components DROP COLUMN {col.name}")
        con.execute("DELETE FROM meta WHERE key = 'monitoring'")
        con.execute("UPDATE history SET rul_low = 1.0, rul_high = 2.0, level = 0")
    con.close()
    with pytest.raises(ValueError, match="written by an older rulkit"):
        read_status(tmp_path / "old.db", now=0.0)
    ComponentStore(tmp_path / "old.db").close()
    for name in ("components", "history"):
        a, b = table(tmp_path / "old.db", name), table(tmp_path / "new.db", name)
        cols = [c for c in b.columns if c not in ("seen", "due", "ingest")]  # the clock
        pd.testing.assert_frame_equal(a[cols], b[cols], check_exact=False, rtol=1e-12)
    assert read_status(tmp_path / "old.db", now=0.0) is not None


def test_calendar_time_of_the_last_acquisition(tmp_path):
    """Date-times in the file: seen is the acquisition's own time; ages: the ingestion's."""
    stamps = pd.date_range("2024-05-01", periods=6, freq="min", tz="UTC")
    df = pd.DataFrame({"component": "a", "time": stamps.strftime("%Y-%m-%dT%H:%M:%SZ"),
                       "hi": 0.2 + 0.01 * np.arange(6)})
    ingest_into(tmp_path / "cal.db", df, rules=MonitoringRules(time_unit="s"))
    assert table(tmp_path / "cal.db", "components")["seen"][0] == stamps[-1].timestamp()
    with ComponentStore(tmp_path / "age.db") as s:
        s.now = 1.7e9
        s.ingest(df.assign(time=np.arange(6.0)))
    assert table(tmp_path / "age.db", "components")["seen"][0] == 1.7e9
