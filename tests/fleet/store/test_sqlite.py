"""Persistent component state in SQLite (embedded-rul.md section 4)."""

import os
import signal
import sqlite3
import subprocess
import sys
import threading
import time

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.monitoring.rules import MonitoringRules
from rulkit.fleet.store.acquisitions import IngestError
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.tracking.health_index import HealthIndexModel
from rulkit.fleet.tracking.tracker_chain import TrackerConfig, TrackerState, tracker_update

CFG = TrackerConfig(dt=1.0, lambda_hi=0.5, lambda_rul=0.5, design_life=1e4, warn_rul=30.0)


def batch(components, t0, steps, rng, k=0.02):
    rows = []
    for j, c in enumerate(components):
        h0 = 0.2 + 0.05 * j
        for s in range(steps):
            t = t0 + s
            rows.append((c, float(t), h0 * np.exp(k * t) + rng.normal(0, 0.005)))
    return pd.DataFrame(rows, columns=["component", "time", "hi"])


def snapshot_tables(path):
    con = sqlite3.connect(path)
    try:
        comps = con.execute("SELECT * FROM components ORDER BY component").fetchall()
        hist = con.execute("SELECT * FROM history ORDER BY component, t_first").fetchall()
        ing = con.execute("SELECT * FROM ingests ORDER BY id").fetchall()
    finally:
        con.close()
    return comps, hist, ing


def test_ingest_matches_direct_tracker_run_and_persists(tmp_path):
    db = tmp_path / "c.db"
    rng = np.random.default_rng(0)
    df = batch(["a", "b", "c"], 0, 20, rng)
    # split in two files, interleaved rows: state must carry over between ingests
    first, second = df[df.time < 8].sample(frac=1, random_state=1), df[df.time >= 8]
    first = first.sort_values("time", kind="stable")
    with ComponentStore(db, config=CFG) as store:
        r1 = store.ingest(first)
        assert r1.n_new_components == 3 and r1.n_rows == len(first)
    with ComponentStore(db) as store:  # reopened: config read from the database
        assert store.config == CFG
        store.ingest(second)
        status = store.status().set_index("component")
        hist = store.history("b")
    # oracle: the same acquisitions through tracker_update directly, one component per column
    wide_t = df.pivot(index="time", columns="component", values="time")
    wide_h = df.pivot(index="time", columns="component", values="hi")
    state = TrackerState.empty(3)
    for k in range(len(wide_t)):
        state, _ = tracker_update(state, wide_t.iloc[k].to_numpy(), wide_h.iloc[k].to_numpy(), CFG)
    for j, c in enumerate(["a", "b", "c"]):
        for name, col in state.columns().items():
            assert status.loc[c, name] == pytest.approx(col[j], rel=1e-12, abs=1e-12), name
    assert len(hist) == 20 and np.all(np.diff(hist["t"]) > 0)
    assert status["n"].tolist() == [20, 20, 20]


def test_alerts_reported_once_per_upward_change(tmp_path):
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 120.0)
    hi = 0.3 * np.exp(0.012 * t)  # crosses 1 at t = 100.3
    df = pd.DataFrame({"component": "gear", "time": t, "hi": hi + rng.normal(0, 1e-4, t.size)})
    rules = MonitoringRules(lead_time=30.0)
    with ComponentStore(tmp_path / "a.db", config=CFG, rules=rules) as store:
        res = store.ingest(df.iloc[:60])
        assert res.alerts == []
        res = store.ingest(df.iloc[60:])
        names = [a.name for a in res.alerts]
        assert names == ["warning", "alarm"]
        warn, alarm = res.alerts
        # the warning when the RUL's 5 % quantile passes 30 (true RUL 100.3 - t = 30 at 70.3),
        # the alarm at the first measured HI >= 1 (t = 101), the RUL then 0 [0, 0]
        assert warn.rul_low < 30.0 and 69.0 <= warn.t <= 72.0
        assert alarm.hi >= 1.0 and alarm.t == 101.0
        assert (alarm.rul, alarm.rul_low, alarm.rul_high) == (0.0, 0.0, 0.0)
        assert "measured HI >= 1" in alarm.reason and "lead time 30" in warn.reason
        assert store.status()["level"].iloc[0] == 2


def test_hi_from_ci_columns(tmp_path):
    rng = np.random.default_rng(2)
    base = rng.rayleigh(1.5, size=(500, 2))
    model = HealthIndexModel.fit(base, pfa=1e-6, names=["so1", "so2"], offset="none")
    ci = rng.rayleigh(1.5, size=(5, 2))
    df = pd.DataFrame({"component": "shaft", "time": np.arange(5.0),
                       "so1": ci[:, 0], "so2": ci[:, 1]})
    with ComponentStore(tmp_path / "ci.db", config=CFG, hi_model=model) as store:
        store.ingest(df)
        hist = store.history("shaft")
    np.testing.assert_allclose(hist["hi"], model.health_index(ci), rtol=1e-12)
    with ComponentStore(tmp_path / "ci.db") as store:
        assert store.hi_model is not None and store.hi_model.names == ("so1", "so2")


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda d: d.assign(extra=1.0), r"unknown column\(s\) \['extra'\]"),
        (lambda d: d.drop(columns="time"), r"missing required column\(s\) \['time'\]"),
        (lambda d: d.assign(hi=d.hi.where(d.index != 4, np.nan)),
         r"column 'hi', row 5 \(component 'a'\): NaN \(an empty or NaN cell\) is not allowed: "
         r"every value must be a finite number, no NaN/inf \(1 non-finite value\(s\)"),
        (lambda d: d.assign(hi=d.hi.where(d.index != 3, 12.0)),
         r"row 4 \(component 'a'\): hi = 12.0 is outside \[0, 10.0\]"),
        (lambda d: d.assign(hi=d.hi.where(d.index != 2, -0.1)), r"row 3 .* outside"),
        (lambda d: d.assign(time=d.time.where(d.index != 6, 102.0)),
         r"row 7 \(component 'a'\): time 102.0 goes backwards from the previous acquisition "
         r"of that component at 105.0"),
        (lambda d: d.assign(time=d.time.where(d.index != 6, 105.0)),
         r"row 7 .* time 105.0 repeats"),
        (lambda d: d.assign(time=d.time - 100.0),  # stored times, other values: a conflict
         r"row 1 \(component 'a'\): time 0.0 is already stored with hi = "),
        (lambda d: d.assign(time=d.time - 100.5),
         r"row 1 \(component 'a'\): time -0.5 is before the component's last stored "
         r"acquisition at 4.0 and is not stored"),
        (lambda d: d.iloc[:0], r"no acquisitions \(0 rows\)"),
        (lambda d: d.assign(time=d.time.astype(object).where(d.index != 1, "soon")),
         r"column 'time', row 2 \(component 'a'\): 'soon' is not a number \(1 non-numeric"),
    ],
)
def test_bad_batches_are_rejected_and_leave_db_unchanged(tmp_path, mutate, message):
    db = tmp_path / "bad.db"
    rng = np.random.default_rng(3)
    with ComponentStore(db, config=CFG) as store:
        store.ingest(batch(["a", "b"], 0, 5, rng))
    before = snapshot_tables(db)
    good = batch(["a"], 100, 10, rng)  # times 100 .. 109
    bad = mutate(good)
    with ComponentStore(db) as store:
        with pytest.raises(IngestError, match=message):
            store.ingest(bad)
    assert snapshot_tables(db) == before


def test_exception_mid_batch_rolls_back(tmp_path, monkeypatch):
    db = tmp_path / "x.db"
    rng = np.random.default_rng(4)
    with ComponentStore(db, config=CFG) as store:
        store.ingest(batch(["a", "b"], 0, 5, rng))
    before = snapshot_tables(db)

    def boom(self, *args):
        raise RuntimeError("injected failure after the history rows were written")

    with ComponentStore(db) as store:
        monkeypatch.setattr(ComponentStore, "_write_states", boom)
        with pytest.raises(RuntimeError, match="injected"):
            store.ingest(batch(["a", "b", "c"], 5, 5, rng))
        monkeypatch.undo()
        assert snapshot_tables(db) == before
        # the store is still usable and the same batch now goes in
        store.ingest(batch(["a", "b", "c"], 5, 5, rng))
    comps, hist, _ = snapshot_tables(db)
    assert len(comps) == 3 and sum(row[3] for row in hist) == 2 * 10 + 5  # history: n


CHILD = r"""
import sys, time, pathlib
import numpy as np, pandas as pd
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.tracking.tracker_chain import TrackerConfig

class Slow(ComponentStore):
    def _write_history(self, rows):
        super()._write_history(rows)
        pathlib.Path(sys.argv[2]).write_text("in transaction")
        time.sleep(60)  # killed here, mid-transaction

cfg = TrackerConfig(dt=1.0, lambda_hi=0.5, lambda_rul=0.5, design_life=1e4, warn_rul=30.0)
n = 2000
df = pd.DataFrame({"component": [f"u{i}" for i in range(n)], "time": 50.0,
                   "hi": np.linspace(0.2, 0.9, n)})
with Slow(sys.argv[1], config=cfg) as store:
    store.ingest(df)
"""


def test_killed_mid_ingest_keeps_last_committed_state(tmp_path):
    db = tmp_path / "k.db"
    flag = tmp_path / "flag"
    rng = np.random.default_rng(5)
    with ComponentStore(db, config=CFG) as store:
        store.ingest(batch(["u0", "u1"], 0, 5, rng))
    before = snapshot_tables(db)
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    proc = subprocess.Popen([sys.executable, str(script), str(db), str(flag)])
    try:
        deadline = time.monotonic() + 30
        while not flag.exists():
            assert proc.poll() is None, "child exited before reaching the transaction"
            assert time.monotonic() < deadline, "child never reached the transaction"
            time.sleep(0.05)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    con.close()
    assert snapshot_tables(db) == before
    with ComponentStore(db) as store:  # no stale lock; the database takes new batches
        store.ingest(batch(["u0", "u1"], 5, 2, rng))
        assert store.counts() == (2, 14, 14)


def test_reader_sees_a_consistent_snapshot_while_writer_commits(tmp_path):
    db = tmp_path / "r.db"
    rng = np.random.default_rng(6)
    with ComponentStore(db, config=CFG) as w:
        w.ingest(batch(["a", "b"], 0, 3, rng))
    reader = ComponentStore(db, create=False)
    writer = ComponentStore(db)
    try:
        with reader.snapshot() as conn:
            n_before = conn.execute("SELECT SUM(n) FROM components").fetchone()[0]
            writer.ingest(batch(["a", "b", "c"], 3, 4, rng))  # commits while the reader reads
            n_inside = conn.execute("SELECT SUM(n) FROM components").fetchone()[0]
            h_inside = conn.execute("SELECT SUM(n) FROM history").fetchone()[0]
        assert n_before == n_inside == h_inside == 6
        assert reader.counts() == (3, 18, 18)

        # a reader thread checking the invariant sum(n) == history rows in every snapshot
        errors: list[str] = []
        stop = threading.Event()

        def read_loop():
            r = ComponentStore(db, create=False)
            try:
                while not stop.is_set():
                    _, n_sum, n_hist = r.counts()
                    if n_sum != n_hist:
                        errors.append(f"{n_sum} != {n_hist}")
            finally:
                r.close()

        th = threading.Thread(target=read_loop)
        th.start()
        for s in range(7, 27):
            writer.ingest(batch([f"u{i}" for i in range(50)] + ["a"], s, 1, rng))
        stop.set()
        th.join(timeout=30)
        assert errors == []
    finally:
        reader.close()
        writer.close()


def test_open_checks(tmp_path):
    with pytest.raises(FileNotFoundError):
        ComponentStore(tmp_path / "missing.db", create=False)
    with ComponentStore(tmp_path / "o.db", config=CFG):
        pass
    with pytest.raises(ValueError, match="refusing to continue with a different"):
        ComponentStore(tmp_path / "o.db", config=TrackerConfig(dt=2.0))
    (tmp_path / "empty.csv").write_text("")
    with ComponentStore(tmp_path / "o.db") as store:
        with pytest.raises(IngestError, match="empty"):
            store.ingest_file(tmp_path / "empty.csv")
        with pytest.raises(IngestError, match="unknown file type"):
            (tmp_path / "a.xlsx").write_text("x")
            store.ingest_file(tmp_path / "a.xlsx")


def test_a_wide_batch_runs_in_rank_windows_without_compiled_passes(tmp_path, monkeypatch):
    """By the trackers' cost rule a batch wider than long runs in windows of acquisition ranks
    (no compiled pass loaded: numba's load would cost more than the rank steps) and a narrow,
    long one in blocks of components (the per-component passes)."""
    from rulkit.fleet.monitoring import unit_trend
    from rulkit.fleet.store.batch_order import order_by_component
    from rulkit.fleet.store.ingest import ingest_into
    from rulkit.fleet.tracking import tracker_run

    monkeypatch.setattr(ComponentStore, "BLOCK_ROWS", 100)
    monkeypatch.setattr(ComponentStore, "WINDOW_ROWS", 700)
    from rulkit.fleet.store.history_stage import plan_pieces

    def pieces(units, ranks):
        codes = np.tile(np.arange(units, dtype=np.int32), ranks)
        order = order_by_component(codes, [f"u{i}" for i in range(units)])
        got, tracker, trend, stage = plan_pieces(order, codes.size, 100, 700, tmp_path)
        if stage is not None:
            stage.__exit__()
        return [p.rank0 for p in got], tracker, trend, stage is not None

    monkeypatch.setattr(tracker_run, "_JITTED", {})  # numba not loaded yet
    monkeypatch.setattr(unit_trend, "_COMPILED", {})
    assert pieces(300, 10) == ([0, 2, 4, 6, 8], "ranks", "ranks", True)  # 2 ranks a window
    assert pieces(2, 1500)[0] == [0, 0]  # one block per component
    rng = np.random.default_rng(3)
    df = pd.DataFrame({"component": np.tile([f"u{i:03d}" for i in range(300)], 10),
                       "time": np.repeat(np.arange(10.0), 300),
                       "hi": rng.uniform(0.1, 0.3, 3000)})
    res, _ = ingest_into(tmp_path / "w.db", df)
    assert res.n_rows == 3000
    assert not tracker_run._JITTED and not unit_trend._COMPILED  # no compiled pass loaded


def test_new_databases_have_16_kb_pages_and_4_kb_ones_store_the_same_values(tmp_path):
    """A new database is made with 16 KB pages; one of SQLite's default 4 KB pages (every
    database made before) takes the same second batch to the same stored values."""
    from rulkit.fleet.store.ingest import ingest_into

    rng = np.random.default_rng(3)
    rows = [(f"u{i}", float(s), 0.05 * np.exp(0.03 * s) + abs(rng.normal(0, 0.01)))
            for i in range(5) for s in range(80)]
    df = pd.DataFrame(rows, columns=["component", "time", "hi"]).sort_values("time",
                                                                            kind="stable")
    first, second = df[df.time < 40], df[df.time >= 40]
    big, small = tmp_path / "16k.db", tmp_path / "4k.db"
    ingest_into(big, first)
    ingest_into(small, first)
    con = sqlite3.connect(small)
    con.execute("PRAGMA journal_mode=DELETE")
    con.execute("PRAGMA page_size=4096")
    con.execute("VACUUM")  # rewritten with 4 KB pages
    con.execute("PRAGMA journal_mode=WAL")
    con.close()
    sizes = {}
    for db in (big, small):
        ingest_into(db, second)
        con = sqlite3.connect(db)
        sizes[db] = con.execute("PRAGMA page_size").fetchone()[0]
        con.close()
    assert sizes == {big: 16384, small: 4096}

    def dump(db):
        con = sqlite3.connect(db)
        try:
            cols = [c for (c,) in con.execute("SELECT name FROM pragma_table_info('components')")
                    if c not in ("seen", "due")]  # the clock at the ingestion
            return (con.execute(f"SELECT {', '.join(cols)} FROM components ORDER BY 1"
                                ).fetchall(),
                    con.execute("SELECT * FROM history ORDER BY rowid").fetchall(),
                    con.execute("SELECT component, t, level, hi, rul FROM alerts ORDER BY id"
                                ).fetchall())
        finally:
            con.close()

    assert dump(big) == dump(small)
    with ComponentStore(small, readonly=True) as store:
        assert store.history("u3")["t"].tolist() == df[df.component == "u3"].time.tolist()


def test_recorded_alerts_carry_the_ids_they_were_stored_with(tmp_path):
    """The alerts of a batch are inserted in one statement: each alert returned carries the
    id of its own row (read back by component and time), also after the table's last rows
    were deleted (ids continue from the largest one left)."""
    rng = np.random.default_rng(8)
    rows = [(f"u{i}", float(s), min(0.05 * np.exp((0.04 + 0.01 * i) * s)
                                    + abs(rng.normal(0, 0.01)), 1.5))
            for i in range(12) for s in range(60)]
    df = pd.DataFrame(rows, columns=["component", "time", "hi"]).sort_values("time",
                                                                            kind="stable")
    db = tmp_path / "a.db"
    with ComponentStore(db, config=CFG) as store:
        first = store.ingest(df[df.time < 30]).alerts
        store._conn.execute("DELETE FROM alerts WHERE id >= ?", (first[-1].id - 1,))
        second = store.ingest(df[df.time >= 30]).alerts
    assert len(first) > 2 and len(second) > 2
    con = sqlite3.connect(db)
    stored = {(c, t, lvl): i for i, c, t, lvl in con.execute(
        "SELECT id, component, t, level FROM alerts")}
    top = con.execute("SELECT max(id) FROM alerts WHERE id < ?", (second[0].id,)).fetchone()[0]
    con.close()
    assert [stored[(a.component, a.t, a.level)] for a in second] == [a.id for a in second]
    assert [a.id for a in second] == list(range(top + 1, top + 1 + len(second)))
    assert top == first[-1].id - 2
