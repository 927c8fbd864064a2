"""The packed history layout (rulkit.fleet.store.history_chunks): round trips, refusals, the
readers against a brute-force slice of the whole history, both backends, and the conversion
of a history of one row per acquisition written with the old DDL."""

import sqlite3

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.store import history_chunks as hc
from rulkit.fleet.store.ingest import ingest_into
from rulkit.fleet.store.postgres import open_store
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.store.tracker_rows import HISTORY_FIELDS


def _records(m, rng):
    rec = rng.normal(size=(m, hc.WIDTH))
    rec[:, 0] = np.arange(m, dtype=float) * 0.5  # time increasing
    rec[::3, -1] = np.nan  # no RUL estimate yet
    rec[::5, hc.PACKED_FIELDS.index("rul_high")] = np.inf
    return rec


def test_the_records_hold_the_history_fields_then_the_median():
    assert hc.PACKED_FIELDS == (*HISTORY_FIELDS, "rul_median")


@pytest.mark.parametrize("max_chunk", [1, 3, 4096])
def test_chunks_round_trip_bit_for_bit(max_chunk):
    rng = np.random.default_rng(3)
    rec = _records(23, rng)
    seg = np.array([0, 0, 7, 8, 23])  # a component without rows, one of one, one of 15
    rows = hc.chunk_rows(["a", "b", "c", "d"], seg, rec, 5, max_chunk)
    n = [r[3] for r in rows]
    assert sum(n) == 23 and max(n) <= max_chunk
    assert [r[0] for r in rows] == sorted(r[0] for r in rows)
    got = hc.decode([r[5] for r in rows], n)
    assert got.tobytes() == rec.tobytes()  # NaN and inf included
    at = np.cumsum([0, *n])
    for r, a, b in zip(rows, at[:-1], at[1:], strict=True):
        assert (r[1], r[2], r[4]) == (rec[a, 0], rec[b - 1, 0], 5)
        assert r[5][:8] == hc.HEADER and len(r[5]) == 8 + 8 * hc.WIDTH * r[3]


def test_a_blob_of_another_layout_is_refused():
    rec = _records(4, np.random.default_rng(1))
    (row,) = hc.chunk_rows(["a"], np.array([0, 4]), rec, 1)
    with pytest.raises(hc.LayoutError, match="bytes, not the"):
        hc.decode([row[5][:-8]], [4])
    with pytest.raises(hc.LayoutError, match="bytes, not the"):
        hc.decode([row[5]], [3])
    with pytest.raises(hc.LayoutError, match="bytes, not the"):  # cut inside a float64
        hc.decode([row[5][:-3]], [4])
    with pytest.raises(hc.LayoutError, match="header"):
        hc.decode([b"RKH\x02" + row[5][4:]], [4])


def fleet(rng, comps=5, steps=30, t0=0.0):
    t = t0 + np.arange(float(steps))
    return pd.concat([pd.DataFrame({"component": f"u{i}", "time": t, "hi": 0.2 * np.exp(
        (0.02 + 0.005 * i) * t) + rng.normal(0, 0.003, steps)}) for i in range(comps)])


def test_readers_agree_with_the_whole_history(db_url, monkeypatch):
    """Chunks of several ingestions and sizes: the last rows, a time range and the replay's
    read equal slices of the whole decoded history."""
    monkeypatch.setattr(ComponentStore, "HISTORY_CHUNK", 4)
    rng = np.random.default_rng(0)
    with open_store(db_url) as store:
        for k in range(3):
            store.ingest(fleet(rng, steps=7 + k, t0=20.0 * k))
        whole = store.history()
        with store.snapshot() as conn:
            for comp in ("u0", "u3"):
                mine = whole[whole.component == comp]
                t = mine["t"].to_numpy()
                for limit in (1, 3, 4, 5, 11, 24, 1000):
                    got = hc.read_last(conn, comp, limit)
                    assert hc.field(got, "t").tolist() == t[-limit:].tolist()
                    assert hc.field(got, "hi").tolist() == mine["hi"].to_numpy()[-limit:].tolist()
                for t0, t1 in ((2.0, 21.0), (3.5, 3.5), (-5.0, 100.0), (30.0, 39.0)):
                    got = hc.field(hc.read_range(conn, comp, t0, t1), "t")
                    assert got.tolist() == t[(t >= t0) & (t <= t1)].tolist()
            chunks, rec = hc.read_components(conn, ["u1", "u2"])
            assert [c[0] for c in chunks] == sorted(c[0] for c in chunks)
            assert max(c[2] for c in chunks) == 4
            ref = whole[whole.component.isin(["u1", "u2"])]
            assert hc.field(rec, "fhi").tolist() == ref["fhi"].tolist()
            assert hc.count(conn) == len(whole) == 5 * (7 + 8 + 9)
            assert hc.read_last(conn, "nobody", 10).shape == (0, hc.WIDTH)


def test_a_history_of_one_row_per_acquisition_is_converted(tmp_path, row_history):
    """A database whose history has the old DDL (rows of two ingestions per component):
    opened for writing, its history is packed (same values, same order), later batches
    continue it and a duplicate of a converted row is still recognised."""
    rng = np.random.default_rng(1)
    df = fleet(rng, comps=4, steps=40)
    first, second = df[df.time < 25], df[df.time >= 25]
    for name in ("old.db", "new.db"):
        ingest_into(tmp_path / name, first)
        ingest_into(tmp_path / name, second)
    with ComponentStore(tmp_path / "old.db") as s:
        before = s.history()
    con = sqlite3.connect(tmp_path / "old.db")
    with con:
        row_history(con, before)
    con.close()
    with pytest.raises(ValueError, match="open it for writing once"):
        with ComponentStore(tmp_path / "old.db", readonly=True) as s:
            s.history()
    with ComponentStore(tmp_path / "old.db") as s:  # converted here
        pd.testing.assert_frame_equal(s.history(), before)
        assert s.counts() == (4, 160, 160)
        n_rows = s._conn.execute("SELECT COUNT(*) FROM history").fetchone()[0]
        assert n_rows == 8  # one chunk per component and ingestion
        res = s.ingest(df[df.time >= 35])  # already stored: duplicates, nothing added
        assert res.n_duplicates == 5 * 4 and res.n_rows == 0
        more = fleet(np.random.default_rng(2), comps=4, steps=3, t0=40.0)
        s.ingest(more)
    with ComponentStore(tmp_path / "new.db") as s:
        s.ingest(more)
        want = s.history()
    with ComponentStore(tmp_path / "old.db", readonly=True) as s:
        got = s.history()
    pd.testing.assert_frame_equal(got.drop(columns="ingest"), want.drop(columns="ingest"))


def test_conversion_on_postgresql(pg_server, row_history):
    """The same conversion inside PostgreSQL's write transaction."""
    url = pg_server.create_schema()
    with open_store(url) as s:
        s.ingest(fleet(np.random.default_rng(4), comps=3, steps=9))
        before = s.history()
        with s._transaction() as conn:
            row_history(conn, before, dialect="postgresql")
    with open_store(url) as s:
        pd.testing.assert_frame_equal(s.history(), before)
        assert s.counts() == (3, 27, 27)


def _history_sql(path):
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        return con.execute("SELECT sql FROM sqlite_master WHERE name = 'history'"
                           ).fetchone()[0]
    finally:
        con.close()


def test_a_clustered_history_is_rebuilt_with_its_key_indexed_apart(tmp_path):
    """A new database's history has rowids and its key in an index of its own (a seek does
    not read whole chunks); one made ``WITHOUT ROWID`` by an older rulkit is rebuilt when
    opened for writing, every chunk as it was, and read as before."""
    rng = np.random.default_rng(5)
    df = fleet(rng, comps=5, steps=30)
    ingest_into(tmp_path / "f.db", df[df.time < 20])
    ingest_into(tmp_path / "f.db", df[df.time >= 20])
    assert "WITHOUT ROWID" not in _history_sql(tmp_path / "f.db").upper()
    with ComponentStore(tmp_path / "f.db") as s:
        before = s.history()
        chunks = s._conn.execute("SELECT * FROM history ORDER BY component, t_first").fetchall()
        plan = " ".join(str(r[-1]) for r in s._conn.execute(
            "EXPLAIN QUERY PLAN SELECT t_first, n FROM history WHERE component = ? ORDER BY "
            "t_first DESC LIMIT 5", ("u0",)).fetchall())
        assert "sqlite_autoindex_history" in plan, plan
        cols = ", ".join(hc.COLUMNS)
        with s._transaction("IMMEDIATE") as conn:  # the table as an older rulkit made it
            conn.execute("ALTER TABLE history RENAME TO history_now")
            conn.execute("CREATE TABLE history (component TEXT NOT NULL, t_first REAL NOT NULL,"
                         " t_last REAL NOT NULL, n INTEGER NOT NULL, ingest INTEGER NOT NULL, "
                         "data BLOB NOT NULL, PRIMARY KEY (component, t_first)) WITHOUT ROWID")
            conn.execute(f"INSERT INTO history ({cols}) SELECT {cols} FROM history_now")
            conn.execute("DROP TABLE history_now")
    assert "WITHOUT ROWID" in _history_sql(tmp_path / "f.db").upper()
    with ComponentStore(tmp_path / "f.db", readonly=True) as s:  # read as it is
        pd.testing.assert_frame_equal(s.history(), before)
    with ComponentStore(tmp_path / "f.db") as s:  # rebuilt here
        assert s._conn.execute("SELECT * FROM history ORDER BY component, t_first"
                               ).fetchall() == chunks
        with s.snapshot() as conn:
            last = hc.read_last(conn, "u1", 12)
        want = before[before.component == "u1"].tail(12)
        np.testing.assert_array_equal(hc.field(last, "t"), want["t"].to_numpy())
    assert "WITHOUT ROWID" not in _history_sql(tmp_path / "f.db").upper()
