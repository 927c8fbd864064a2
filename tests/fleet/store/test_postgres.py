"""The component store's guarantees on both backends (SQLite file, PostgreSQL server).

Validation first, one transaction per batch, concurrent writers without lost or duplicated
rows, consistent snapshots, and the same numbers as the tracker chain run directly.
"""

import struct
import threading

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.service.db import ServiceDB
from rulkit.fleet.store.acquisitions import IngestError
from rulkit.fleet.store.postgres import open_store
from rulkit.fleet.tracking.tracker_chain import TrackerConfig, TrackerState, tracker_update

CFG = TrackerConfig(dt=1.0, lambda_hi=0.5, lambda_rul=0.5, design_life=1e4, warn_rul=30.0)


def batch(components, t0, steps, seed=0):
    rng = np.random.default_rng(seed)
    rows = [(c, float(t0 + s), (0.2 + 0.05 * j) * np.exp(0.02 * (t0 + s)) + rng.normal(0, 0.005))
            for j, c in enumerate(components) for s in range(steps)]
    return pd.DataFrame(rows, columns=["component", "time", "hi"])


def test_matches_direct_tracker_run(db_url):
    df = batch(["a", "b", "c"], 0, 20)
    with open_store(db_url, config=CFG) as store:
        store.ingest(df[df.time < 8])
    with open_store(db_url) as store:  # reopened: configuration read back
        assert store.config == CFG
        store.ingest(df[df.time >= 8])
        status = store.status().set_index("component")
        hist = store.history("b")
        with pytest.raises(ValueError, match="tracker config"):
            open_store(db_url, config=TrackerConfig(dt=2.0))
    wide_t = df.pivot(index="time", columns="component", values="time")
    wide_h = df.pivot(index="time", columns="component", values="hi")
    state = TrackerState.empty(3)
    for k in range(len(wide_t)):
        state, _ = tracker_update(state, wide_t.iloc[k].to_numpy(), wide_h.iloc[k].to_numpy(),
                                  CFG)
    for j, c in enumerate(["a", "b", "c"]):
        for name, col in state.columns().items():
            assert status.loc[c, name] == pytest.approx(col[j], rel=1e-12, abs=1e-12), name
    assert len(hist) == 20 and np.all(np.diff(hist["t"]) > 0)
    assert hist["valid"].dtype == bool and status["n"].tolist() == [20, 20, 20]


def test_validation_first_and_rollback(db_url, monkeypatch):
    with open_store(db_url, config=CFG) as store:
        store.ingest(batch(["a", "b"], 0, 5))
        before = (store.status(), store.history(), store.counts())
        bad = batch(["a", "c"], 5, 3)
        bad.loc[4, "hi"] = np.nan
        with pytest.raises(IngestError, match="row 5"):
            store.ingest(bad)
        back = batch(["c", "a"], 2, 2)  # a goes back before its stored t = 4
        with pytest.raises(IngestError, match="component 'a'"):
            store.ingest(back)

        def boom(*args):
            raise RuntimeError("disk full")

        # after the history rows and the stored component's update were written
        monkeypatch.setattr(store, "_upsert_staged" if hasattr(store, "_upsert_staged")
                            else "_write_states", boom)
        with pytest.raises(RuntimeError, match="disk full"):
            store.ingest(batch(["a", "d"], 5, 3))
        monkeypatch.undo()
        after = (store.status(), store.history(), store.counts())
        pd.testing.assert_frame_equal(before[0], after[0])
        pd.testing.assert_frame_equal(before[1], after[1])
        assert before[2] == after[2]
        store.ingest(batch(["a", "d"], 5, 3))  # the connection is usable after a rollback
        assert store.counts() == (3, 16, 16)


def test_create_false_refuses_a_missing_store(db_url):
    with pytest.raises(FileNotFoundError):
        open_store(db_url, create=False)


def test_concurrent_writers_lose_and_duplicate_nothing(db_url):
    sdb = ServiceDB(db_url, pool_size=6)
    shared = batch([f"shared-{i}" for i in range(5)], 0, 4, seed=9)
    n_threads, n_batches, errors = 4, 6, []
    snapshots = []
    stop = threading.Event()

    def writer(k):
        try:
            for b in range(n_batches):
                sdb.ingest(batch([f"w{k}-{i}" for i in range(10)], 3 * b, 3, seed=k), f"w{k}")
                sdb.ingest(shared, f"w{k}-shared")  # same batch from every writer
        except Exception as err:
            errors.append(err)

    def reader():
        with sdb.store() as s:
            while not stop.is_set():
                snapshots.append(s.counts())

    threads = [threading.Thread(target=writer, args=(k,)) for k in range(n_threads)]
    rt = threading.Thread(target=reader)
    rt.start()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    stop.set()
    rt.join()
    assert errors == []
    with sdb.store() as s:
        n_comp, n_sum, n_hist = s.counts()
        hist = s.history()
    expected = n_threads * n_batches * 30 + len(shared)
    assert (n_comp, n_sum, n_hist) == (n_threads * 10 + 5, expected, expected)
    assert not hist.duplicated(["component", "t"]).any()
    # every snapshot a reader took is a committed state: per-component counts add up
    assert snapshots and all(s[1] == s[2] for s in snapshots)
    sdb.close()


EDGE_FLOATS = [0.1, -0.0, 5e-324, 1.7976931348623157e308, 1 / 3, -2.5e-310, np.nan, np.inf,
               -np.inf, 123456.78901234567]


def _bits(v):
    return struct.pack("<d", v) if isinstance(v, float) else v


def test_bulk_writes_store_every_float64_bit_and_upsert(pg_server):
    """The binary COPY of component and history rows: values read back (binary results)
    are the bits written, on insert and on the conflict's update, and a second write in the
    same transaction upserts only its own rows."""
    from rulkit.fleet.store import history_chunks
    from rulkit.fleet.store.tracker_rows import ROW_FIELDS

    cols = ("component", *ROW_FIELDS, "max_level")
    ints = {"n": 7, "level": 2, "max_level": 1, "valid": True}

    def rows(names, shift):
        return [tuple([name] + [ints[c] if c in ints else
                                EDGE_FLOATS[(j + k + shift) % len(EDGE_FLOATS)]
                                for j, c in enumerate(cols[1:])])
                for k, name in enumerate(names)]

    rec = np.array(EDGE_FLOATS * 13, dtype=np.float64).reshape(10, 13)
    hist = history_chunks.chunk_rows(["a", "b"], np.array([0, 4, 10]), rec, 3)
    with open_store(pg_server.create_schema(), config=CFG) as store:
        with store._transaction():
            store._write_states(rows(["a", "b", "c"], 0))
            store._write_history(hist)
        with store._transaction():  # a and b updated, d new; then c alone
            store._write_states(rows(["a", "b", "d"], 3))
            store._write_states(rows(["c"], 5))
        with store._conn.raw.cursor(binary=True) as cur:
            got = cur.execute(f"SELECT {', '.join(cols)} FROM components "
                              "ORDER BY component").fetchall()
            blobs = cur.execute("SELECT component, t_first, t_last, n, ingest, data FROM "
                                "history ORDER BY component").fetchall()
    second = rows(["a", "b", "d"], 3)
    want = second[:2] + rows(["c"], 5) + second[2:]
    assert [tuple(map(_bits, r)) for r in got] == [tuple(map(_bits, r)) for r in want]
    assert [(r[0], _bits(r[1]), _bits(r[2]), r[3], r[4], bytes(r[5])) for r in blobs] == [
        (r[0], _bits(r[1]), _bits(r[2]), r[3], r[4], bytes(r[5])) for r in hist]


def _many(store, frames, now=1.7e9):
    from rulkit.fleet.store.acquisitions import validate_acquisitions

    return store.ingest_many([(validate_acquisitions(f, store.config, store.hi_model), "t", now)
                              for f in frames])


def _row_bits(row):
    """A stored row as the batch reads it: float64 bits, NaN (and NULL) as None."""
    return [None if np.isnan(v) else _bits(v) for v in np.array(row, dtype=np.float64).tolist()]


def test_kept_rows_are_the_rows_postgresql_returns(pg_server):
    """The writer's kept rows (keep_states) hold the bits a fresh connection reads, batch
    after batch; a write by any other connection (here plain SQL that takes no rulkit lock)
    is seen by the next batch."""
    url = pg_server.create_schema()
    names = [f"u{i}" for i in range(6)]
    with open_store(url, config=CFG) as store, open_store(url) as other:
        store.keep_states()
        for k in range(6):
            res = _many(store, [batch(names[: 3 + k % 4], 4 * k, 4, seed=k)])
            assert not isinstance(res[0], Exception)
            kept, _ = store._states.split(names)
            truth = other._load_states(names)
            assert set(kept.pos) == set(names[:max(3 + j % 4 for j in range(k + 1))])
            for n in kept.pos:
                assert _row_bits(kept.values[kept.pos[n]]) == _row_bits(
                    truth.values[truth.pos[n]]), n
        n0 = int(other.status().set_index("component")["n"]["u1"])
        other._conn.execute("UPDATE components SET n = n + 100 WHERE component = 'u1'")
        _many(store, [batch(["u1"], 40, 1)])
        assert int(store.status().set_index("component")["n"]["u1"]) == n0 + 101


def test_kept_negative_zero_is_the_one_postgresql_returns(pg_server):
    """-0.0 written to a float8 column reads back as -0.0: the kept rows keep it."""
    from rulkit.fleet.store.state_cache import StateCache

    with open_store(pg_server.create_schema(), config=CFG) as store:
        back = store._conn.execute("SELECT ?::float8", (-0.0,)).fetchone()[0]
        store.keep_states()
        assert isinstance(store._states, StateCache) and store._states.signed_zeros
    cache = StateCache(("x",), limit=2, signed_zeros=True)
    cache.begin(1)
    cache.put(["a"], np.array([[-0.0]]))
    kept = cache.split(["a"])[0]
    assert _bits(float(kept.values[kept.pos["a"], 0])) == _bits(back) == _bits(-0.0)


def test_writers_with_kept_rows_in_turns_lose_nothing(pg_server):
    """Two writers keeping rows on one database (e.g. two services) write the same
    components in turns, then halves of them at once, then in turns again: every batch
    starts from the other's rows, as one writer that reads every row."""
    url, ref = pg_server.create_schema(), pg_server.create_schema()
    names = [f"c{i}" for i in range(4)]
    turns = [batch(names, 3 * k, 3, seed=k) for k in range(6)]
    halves = [[batch(names[:2], 18 + 3 * k, 3, seed=k) for k in range(4)],
              [batch(names[2:], 18 + 3 * k, 3, seed=10 + k) for k in range(4)]]
    after = [batch(names, 30 + 3 * k, 3, seed=20 + k) for k in range(4)]
    errors = []

    def run(store, frames):
        try:
            for f in frames:
                res = _many(store, [f])
                assert not isinstance(res[0], Exception), res[0]
        except Exception as err:  # pragma: no cover - reported below
            errors.append(err)

    with open_store(url, config=CFG) as a, open_store(url) as b:
        a.keep_states()
        b.keep_states()
        for k, f in enumerate(turns):
            run((a, b)[k % 2], [f])
        threads = [threading.Thread(target=run, args=(w, h))
                   for w, h in zip((a, b), halves, strict=True)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        for k, f in enumerate(after):
            run((b, a)[k % 2], [f])
        assert errors == []
        got = a.status()
    with open_store(ref, config=CFG) as store:
        for f in [*turns, *halves[0], *halves[1], *after]:
            run(store, [f])
        want = store.status()
    pd.testing.assert_frame_equal(got, want, check_exact=True)


def test_a_role_that_may_not_make_the_counter_keeps_no_rows(pg_server):
    """A writing role that does not own the tables cannot make the write counter: it keeps
    no rows and reads every one; once the owner has made it, that role's writes are counted
    (the trigger runs as its owner) and the owner's kept rows see them."""
    import psycopg

    url = pg_server.create_schema()
    schema = url.rsplit("%3D", 1)[1]
    with open_store(url, config=CFG) as owner:
        owner.ingest(batch(["a", "b"], 0, 3))
    with psycopg.connect(pg_server.url(), autocommit=True) as admin:
        admin.execute("DROP ROLE IF EXISTS limited")
        admin.execute("CREATE ROLE limited LOGIN")
        admin.execute(f'GRANT USAGE ON SCHEMA "{schema}" TO limited')
        admin.execute(f'GRANT SELECT, INSERT, UPDATE, DELETE ON ALL TABLES IN SCHEMA "{schema}" '
                      "TO limited")
        admin.execute(f'GRANT USAGE ON ALL SEQUENCES IN SCHEMA "{schema}" TO limited')
    limited_url = url.replace("rulkit@", "limited@")
    with open_store(limited_url) as store:
        store.keep_states()
        assert store._states is None
        _many(store, [batch(["a", "b"], 3, 2)])
    with open_store(url) as owner, open_store(limited_url) as other:
        owner.keep_states()
        assert owner._states is not None
        _many(owner, [batch(["a", "b"], 5, 2)])
        other.keep_states()  # may not lock the owner's counter: keeps nothing
        assert other._states is None
        _many(other, [batch(["a"], 7, 2)])
        _many(owner, [batch(["a", "b"], 9, 1)])
        n = owner.status().set_index("component")["n"]
        assert (n["a"], n["b"]) == (3 + 2 + 2 + 2 + 1, 3 + 2 + 2 + 1)


def test_a_kept_row_the_table_lacks_fails_the_group_on_postgresql(pg_server):
    """The UPDATE of the stored components (COPY, then UPDATE ... FROM) counts the rows it
    updated: a component read as stored that the table lacks fails the group, nothing is
    written and the kept rows are dropped."""
    from rulkit.fleet.store.database_file import StoreError

    with open_store(pg_server.create_schema(), config=CFG) as store:
        store.keep_states()
        _many(store, [batch(["a"], 0, 3)])
        before = (store.status(), store.history())
        kept = store._states
        kept.begin(kept.version)  # a row of "b" kept as if committed, which no one wrote
        got = kept.split(["a"])[0]
        kept.put(["b"], got.values[[got.pos["a"]]])
        kept.release()
        kept.commit()
        with pytest.raises(StoreError, match="not in table components"):
            _many(store, [batch(["a", "b"], 3, 2)])
        pd.testing.assert_frame_equal(store.status(), before[0], check_exact=True)
        pd.testing.assert_frame_equal(store.history(), before[1], check_exact=True)
        assert len(store._states) == 0


def test_a_groups_ingests_and_alerts_rows_carry_their_own_ids(db_url):
    """A group's ``ingests`` rows and a batch's alerts are inserted by one statement each on
    PostgreSQL: every id returned is the id of its own row (an alert read back by
    component, time and level; a batch's history rows carry its ``ingests`` row, the one
    with its source)."""
    with open_store(db_url, config=CFG) as store:
        store.ingest(batch(["a", "b", "c", "d"], 0, 40))
        frames = [batch([f"g{k}"], 0, 3, seed=k) for k in range(5)]
        from rulkit.fleet.store.acquisitions import validate_acquisitions

        store.ingest_many([(validate_acquisitions(f, CFG, None), f"s{k}", 1.7e9)
                           for k, f in enumerate(frames)])
        rises = pd.DataFrame([(c, 40.0 + s, 0.4 + 0.12 * s + 0.05 * j)
                              for j, c in enumerate("abcd") for s in range(8)],
                             columns=["component", "time", "hi"])
        alerts = store.ingest(rises).alerts
        con = store._conn
        stored = {(c, t, lvl): i for i, c, t, lvl in con.execute(
            "SELECT id, component, t, level FROM alerts").fetchall()}
        sources = dict(con.execute("SELECT id, source FROM ingests").fetchall())
        owner = dict(con.execute("SELECT component, ingest FROM history").fetchall())
    assert len(alerts) >= 4
    assert [stored[(a.component, a.t, a.level)] for a in alerts] == [a.id for a in alerts]
    assert [sources[owner[f"g{k}"]] for k in range(5)] == [f"s{k}" for k in range(5)]
