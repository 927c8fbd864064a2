"""The component rows a writing connection keeps (rulkit.fleet.store.state_cache): always the
rows the database returns, and forgotten whenever something else writes."""

import sqlite3

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.monitoring.rules import MonitoringRules
from rulkit.fleet.store import sqlite as sqlite_module
from rulkit.fleet.store.acquisitions import ConflictError, IngestError, validate_acquisitions
from rulkit.fleet.store.database_file import StoreError
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.store.state_cache import StateCache
from rulkit.fleet.tracking.tracker_chain import TrackerConfig

CFG = TrackerConfig(dt=1.0, lambda_hi=0.5, lambda_rul=0.5, design_life=1e4, warn_rul=30.0)
NOW = 1.7e9
"""The calendar time of every ingestion here (the stored ``seen``; default the clock)."""


def frame(components, times, rng, rate=0.05):
    """One acquisition per component and time, HI growing past the alarm for some."""
    rows = [(c, float(t), (0.3 + 0.1 * j) * np.exp(rate * t) + rng.normal(0, 0.003))
            for t in times for j, c in enumerate(components)]
    return pd.DataFrame(rows, columns=["component", "time", "hi"])


def many(store, *frames):
    """``frames`` through :meth:`ComponentStore.ingest_many`, one group."""
    return store.ingest_many([(validate_acquisitions(f, store.config, store.hi_model), "t",
                               NOW) for f in frames])


def stored_rows(path, names):
    """The rows of ``names`` as SQLite returns them to a plain connection of its own."""
    cols = ", ".join(("component", *ComponentStore.STATE_COLUMNS))
    with sqlite3.connect(path) as con:
        got = con.execute(f"SELECT {cols} FROM components WHERE component IN "
                          f"({', '.join('?' * len(names))})", names).fetchall()
    return {r[0]: r[1:] for r in got}


def split(cache, names):
    """The kept rows of ``names`` by name, and the names to read."""
    kept, missing = cache.split(names)
    return {n: kept.values[i] for n, i in kept.pos.items()}, missing


def same(kept, read):
    """The same float64 bits as the batch builds its arrays from (None and NaN alike)."""
    x, y = (np.array(r, dtype=np.float64) for r in (kept, read))
    return (np.array_equal(np.isnan(x), np.isnan(y))
            and np.array_equal(x[~np.isnan(x)].view(np.int64), y[~np.isnan(y)].view(np.int64)))


def test_kept_rows_are_the_rows_the_database_returns(tmp_path):
    db = tmp_path / "c.db"
    rng = np.random.default_rng(1)
    names = [f"u{i}" for i in range(6)]
    with ComponentStore(db, config=CFG) as store:
        store.keep_states()
        for k in range(8):  # new components, then updates crossing the warning and alarm
            res = many(store, frame(names[: 3 + k % 4], range(5 * k, 5 * k + 5), rng))
            assert not isinstance(res[0], Exception)
            kept, missing = split(store._states, names)
            truth = stored_rows(db, names)
            assert set(kept) | set(missing) == set(names)
            for name, row in kept.items():
                assert same(row, truth[name]), name
        assert any(r[store.STATE_COLUMNS.index("level")] > 0 for r in truth.values())


def test_results_equal_a_store_that_reads_every_row(tmp_path):
    rng = np.random.default_rng(2)
    frames = [frame(["a", "b", "c"], range(4 * k, 4 * k + 4), rng) for k in range(10)]
    out = []
    for name, keep in (("kept.db", True), ("read.db", False)):
        with ComponentStore(tmp_path / name, config=CFG) as store:
            if keep:
                store.keep_states()
            for k in range(0, 10, 2):
                many(store, frames[k], frames[k + 1])
            out.append((store.status(), store.history()))
    pd.testing.assert_frame_equal(out[0][0], out[1][0], check_exact=True)
    pd.testing.assert_frame_equal(out[0][1], out[1][1], check_exact=True)


def test_another_connections_write_is_not_overlooked(tmp_path):
    db = tmp_path / "c.db"
    rng = np.random.default_rng(3)
    with ComponentStore(db, config=CFG) as store:
        store.keep_states()
        many(store, frame(["a", "b"], range(5), rng))
        assert len(store._states) == 2
        with ComponentStore(db) as other:  # e.g. rulkit track in another process
            other.now = NOW
            other.ingest(frame(["a"], range(5, 9), rng))
        # the kept row of "a" is now stale: the next batch must start from the other's
        res = many(store, frame(["a", "b"], range(9, 12), rng))
        assert not isinstance(res[0], Exception)
        n = store.status().set_index("component")["n"]
        assert n["a"] == 12 and n["b"] == 8
    with ComponentStore(tmp_path / "r.db", config=CFG) as ref:  # the same, read each time
        rng = np.random.default_rng(3)
        ref.now = NOW
        ref.ingest(frame(["a", "b"], range(5), rng))
        ref.ingest(frame(["a"], range(5, 9), rng))
        ref.ingest(frame(["a", "b"], range(9, 12), rng))
        pd.testing.assert_frame_equal(ref.status(), ComponentStore(db).status(),
                                      check_exact=True)


def test_a_rolled_back_batch_leaves_nothing_kept(tmp_path, monkeypatch):
    db = tmp_path / "c.db"
    rng = np.random.default_rng(4)
    with ComponentStore(db, config=CFG) as store:
        store.keep_states()
        many(store, frame(["a", "b", "c"], range(5), rng))
        good = frame(["a"], range(5, 8), rng)
        bad = frame(["b"], [6.0, 2.0], rng).iloc[[1, 0]]  # time 2 before b's last: conflict
        res = many(store, good, bad)
        assert not isinstance(res[0], Exception) and isinstance(res[1], ConflictError)
        # a batch refused after its rows were written (none is today: the checks come
        # first) is rolled back to its savepoint, and so are its kept rows
        real = sqlite_module.add_level_counts

        def refuse_c(conn, old, new):
            real(conn, old, new)
            if split(store._states, ["c"])[0]["c"][1] == 8:  # c written, alone or joined
                raise IngestError("refused after the write")

        monkeypatch.setattr(sqlite_module, "add_level_counts", refuse_c)
        res = many(store, frame(["c"], range(5, 8), rng), frame(["a"], range(8, 9), rng))
        assert isinstance(res[0], IngestError) and not isinstance(res[1], Exception)
        kept, _ = split(store._states, ["a", "b", "c"])
        truth = stored_rows(db, ["a", "b", "c"])
        for name in "abc":
            assert same(kept[name], truth[name]), name
        n = store.STATE_COLUMNS.index("n")
        assert (kept["a"][n], kept["b"][n], kept["c"][n]) == (9, 5, 5)


def test_a_failed_commit_forgets_everything(tmp_path, monkeypatch):
    db = tmp_path / "c.db"
    rng = np.random.default_rng(5)
    with ComponentStore(db, config=CFG) as store:
        store.keep_states()
        many(store, frame(["a"], range(3), rng))

        def boom(*a, **k):
            raise sqlite3.OperationalError("disk I/O error")

        monkeypatch.setattr(store, "_insert_ingest", boom)
        with pytest.raises(Exception, match="disk I/O"):
            many(store, frame(["a"], range(3, 6), rng))
        assert len(store._states) == 0


def test_other_writes_through_the_store_forget_the_rows(tmp_path):
    db = tmp_path / "c.db"
    rng = np.random.default_rng(6)
    with ComponentStore(db, config=CFG) as store:
        store.keep_states()
        many(store, frame(["a", "b"], range(30), rng))
        assert len(store._states) == 2
        store.set_rules(MonitoringRules(alarm_hi=0.5))  # replays every component's level
        assert len(store._states) == 0
        many(store, frame(["a", "b"], range(30, 32), rng))
        kept, _ = split(store._states, ["a", "b"])
        truth = stored_rows(db, ["a", "b"])
        assert same(kept["a"], truth["a"]) and same(kept["b"], truth["b"])


def test_values_as_sqlite_returns_them_and_the_limit():
    cache = StateCache(("x", "k"), limit=2)
    written = [(-0.0, 3), (float("nan"), True), (5, 0), (-2.5, False)]
    cache.begin(7)
    cache.put(list("abcd"), np.array(written, dtype=np.float64))
    cache.release()
    cache.commit()
    kept, missing = split(cache, list("abcd"))
    assert missing == ["a", "b"]  # over the limit: the first kept are dropped
    with sqlite3.connect(":memory:") as con:  # the oracle: SQLite's own round trip
        con.execute("CREATE TABLE t (x REAL, k INTEGER)")
        con.executemany("INSERT INTO t VALUES (?, ?)", written)
        rows = con.execute("SELECT x, k FROM t ORDER BY rowid").fetchall()
    kept, _ = split(cache, ["c", "d"])
    assert same(kept["c"], rows[2]) and same(kept["d"], rows[3])
    cache.limit = 4
    cache.begin(7)
    cache.put(list("abcd"), np.array(written, dtype=np.float64))
    cache.release()
    cache.commit()
    kept, _ = split(cache, list("abcd"))
    for name, row in zip("abcd", rows, strict=True):
        assert same(kept[name], row), name
    assert rows[0][0] == 0.0 and str(kept["a"][0]) == str(rows[0][0]) == "0.0"
    cache.begin(8)  # another connection committed
    assert split(cache, ["c", "d"]) == ({}, ["c", "d"])


def test_kept_rows_follow_a_dictionary_of_rows():
    """Random savepoints, rollbacks, commits and drops over a small limit: the kept rows are
    those of a plain dictionary kept the same way (rows by name, the first kept dropped
    first), whatever rows of the array the names were given."""
    rng = np.random.default_rng(8)
    cache = StateCache(("x", "y"), limit=7)
    committed: dict[str, tuple] = {}
    cache.begin(1)
    pending: dict[str, tuple] = {}
    for _ in range(400):
        names = [str(v) for v in rng.choice(12, size=int(rng.integers(1, 6)), replace=False)]
        values = rng.normal(size=(len(names), 2))
        values[rng.random(values.shape) < 0.2] = np.nan
        cache.put(names, values)
        step = rng.choice(["release", "rollback", "commit", "drop"], p=[0.5, 0.2, 0.25, 0.05])
        if step == "rollback":
            cache.rollback()
        else:
            cache.release()
            pending.update(zip(names, map(tuple, values.tolist()), strict=True))
        if step == "commit":
            cache.commit()
            committed.update(pending)
            for name in list(committed)[:max(0, len(committed) - 7)]:
                del committed[name]
            pending = {}
            cache.begin(1)
        elif step == "drop":
            cache.drop()
            committed, pending = {}, {}
            cache.begin(1)
        kept, missing = split(cache, [str(v) for v in range(12)])
        expect = {**committed, **pending}
        assert sorted(kept) == sorted(expect) and len(cache) == len(committed)
        assert set(missing) == {str(v) for v in range(12)} - set(expect)
        for name, row in kept.items():
            assert same(row, expect[name]), name


def test_a_kept_row_the_table_lacks_fails_the_group_and_writes_nothing(tmp_path):
    db = tmp_path / "c.db"
    rng = np.random.default_rng(9)
    with ComponentStore(db, config=CFG) as store:
        store.keep_states()
        many(store, frame(["a"], range(3), rng))
        before = (store.status(), store.history())
        kept = store._states
        kept.begin(kept.version)  # a row of "b" kept as if committed, which no one wrote
        kept.put(["b"], np.asarray(split(kept, ["a"])[0]["a"])[None, :])
        kept.release()
        kept.commit()
        with pytest.raises(StoreError, match="not in table components"):
            many(store, frame(["a", "b"], range(3, 5), rng))
        pd.testing.assert_frame_equal(store.status(), before[0], check_exact=True)
        pd.testing.assert_frame_equal(store.history(), before[1], check_exact=True)
        assert len(store._states) == 0


def test_the_kept_rows_of_the_default_limit_take_about_11_mb():
    """keep_states' docstring: a float64 row and the name per component, about 0.4 KB with
    the array's spare rows (allocations traced, not a timing)."""
    import tracemalloc

    cache = StateCache(ComponentStore.STATE_COLUMNS, limit=25_000)
    rows = np.zeros((1000, len(ComponentStore.STATE_COLUMNS)))
    tracemalloc.start()
    try:
        cache.begin(1)
        for k in range(25):
            cache.put([f"w{k % 8}-c{i}-{k}" for i in range(1000)], rows)
            cache.release()
            cache.commit()
            cache.begin(1)
        used = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    assert len(cache) == 25_000
    assert 8e6 < used < 12e6, used
