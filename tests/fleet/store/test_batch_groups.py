"""Batches of one group commit joined when they share no component
(rulkit.fleet.store.batch_groups): the database and every batch's result are those of the
batches applied one by one."""

import sqlite3

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.store.acquisitions import IngestError, validate_acquisitions
from rulkit.fleet.store.batch_groups import Admission, disjoint_runs, join
from rulkit.fleet.store.history_stage import plan_pieces
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.tracking.tracker_chain import TrackerConfig

CFG = TrackerConfig(dt=1.0, lambda_hi=0.5, lambda_rul=0.5, design_life=1e4, warn_rul=30.0)
NOW = 1.7e9
TABLES = ("components", "history", "ingests", "alerts", "level_counts", "seen_counts")


def frame(names, times, rate=0.06, seed=0):
    """HI of each component and time the same in every frame (a repeated row is a
    duplicate); ``seed`` shifts the components' levels."""
    rows = [(c, float(t), (0.3 + 0.08 * ((j + seed) % 8)) * np.exp(rate * t)
             + 0.003 * np.sin(7.3 * t + sum(map(ord, c))))
            for t in times for j, c in enumerate(names)]
    return pd.DataFrame(rows, columns=["component", "time", "hi"])


GROUPS = [
    # new components in disjoint batches, then one sharing "a" (a new run)
    [frame(["a", "b"], range(5)), frame(["c", "d"], range(5), seed=1),
     frame(["a"], range(5, 8), seed=2), frame(["e"], range(3), seed=3)],
    # rising HI: warnings and alarms in several batches of one run
    [frame(["a", "b"], range(8, 30), seed=4), frame(["c", "d"], range(5, 30), seed=5),
     frame(["e", "f"], range(3, 30), seed=6)],
    # a batch of duplicates only, one with duplicates and new rows, one new
    [frame(["c", "d"], range(5, 30), seed=5), frame(["e", "f"], range(25, 33), seed=6),
     frame(["g"], range(4), seed=7)],
    # a conflict (time 2 before b's last, another HI) in a run: applied one by one
    [frame(["a"], range(30, 33), seed=8), frame(["b"], [2.0], rate=0.5, seed=9),
     frame(["g"], range(4, 6), seed=10)],
]


def ingest_groups(path, join_batches, block_rows=None):
    out = []
    with ComponentStore(path, config=CFG) as store:
        store.JOIN_BATCHES = join_batches
        if block_rows is not None:  # blocks, and windows of ranks with a staged history
            store.BLOCK_ROWS, store.WINDOW_ROWS = block_rows, block_rows
        store.keep_states()
        for group in GROUPS:
            res = store.ingest_many([(validate_acquisitions(f, CFG, None), f"s{i}", NOW)
                                     for i, f in enumerate(group)])
            out.append([_result(r) for r in res])
    con = sqlite3.connect(path)
    try:
        tables = {t: con.execute(f"SELECT * FROM {t} ORDER BY 1, 2").fetchall()
                  for t in TABLES}
    finally:
        con.close()
    return out, tables


def _result(r):
    if isinstance(r, IngestError):
        return (type(r).__name__, str(r))
    return (r.n_rows, r.n_duplicates, r.n_components, r.n_new_components,
            [(a.id, a.component, a.t, a.level, a.previous, a.rul, a.reason, a.raised)
             for a in r.alerts])


@pytest.mark.parametrize("block_rows", [None, 8])
def test_joined_batches_store_and_answer_as_one_by_one(tmp_path, monkeypatch, block_rows):
    applied = []
    real = ComponentStore._apply

    def counted(self, acq, *a, **k):
        applied.append(len(acq.names))
        return real(self, acq, *a, **k)

    monkeypatch.setattr(ComponentStore, "_apply", counted)
    joined = ingest_groups(tmp_path / "joined.db", True, block_rows)
    n_joined = len(applied)
    alone = ingest_groups(tmp_path / "alone.db", False, block_rows)
    assert n_joined < len(applied) - n_joined  # the runs were joined
    assert joined[0] == alone[0]
    for table in TABLES:
        assert joined[1][table] == alone[1][table], table
    results = joined[0]
    assert any(r[4] for g in results for r in g if isinstance(r[0], int))  # alerts raised
    assert results[2][0][:2] == (0, 50) and results[2][1][:2] == (6, 10)  # duplicates
    assert results[3][1][0] == "ConflictError" and results[3][2][0] == 2  # the others kept


def test_runs_cut_where_a_component_repeats_or_the_time_differs():
    def q(names, now=NOW):
        return (validate_acquisitions(frame(names, range(2)), CFG, None), "s", now)

    runs = list(disjoint_runs([q(["a", "b"]), q(["c"]), q(["b"]), q(["d"]),
                               q(["e"], now=None), q(["f"], now=None)]))
    assert [[n for acq, _, _ in r for n in acq.names] for r in runs] == [
        ["a", "b", "c"], ["b", "d"], ["e", "f"]]
    both = join([q(["a", "b"])[0], q(["c"])[0]])
    assert both.names == ["a", "b", "c"]
    assert [both.names[c] for c in both.codes] == ["a", "b", "a", "b", "c", "c"]


def test_a_wide_run_through_windows_of_ranks_as_one_by_one(tmp_path):
    """Batches joined past a block: windows of acquisition ranks with a staged history, each
    component's history row carrying its own batch's ingests row."""
    group = [frame([f"w{w}-{i}" for i in range(150)], range(2), rate=0.0) for w in range(3)]
    tables = []
    for join_batches in (True, False):
        path = tmp_path / f"{join_batches}.db"
        with ComponentStore(path, config=CFG) as store:
            store.JOIN_BATCHES = join_batches
            store.BLOCK_ROWS, store.WINDOW_ROWS = 100, 100
            staged = plan_pieces(order_of(group), 900, 100, 100, tmp_path)[3]
            assert staged is not None  # staged, if joined
            staged.__exit__()
            store.ingest_many([(validate_acquisitions(f, CFG, None), f"s{i}", NOW)
                               for i, f in enumerate(group)])
        con = sqlite3.connect(path)
        tables.append([con.execute(f"SELECT * FROM {t} ORDER BY 1, 2").fetchall()
                       for t in TABLES])
        con.close()
    assert tables[0] == tables[1]
    assert {r[4] for r in tables[0][1]} == {1, 2, 3}  # three batches' ingests rows


def order_of(frames):
    from rulkit.fleet.store.batch_order import order_by_component

    acq = join([validate_acquisitions(f, CFG, None) for f in frames])
    return order_by_component(acq.codes.astype(np.int32), acq.names)


@pytest.mark.parametrize("join_batches", [True, False])
@pytest.mark.parametrize("t_bad", [1e308, 2004.0])
def test_a_refused_batch_leaves_the_others_and_nothing_of_itself(tmp_path, join_batches,
                                                                 t_bad):
    """Refused alone, refused in a run: 2004 is a gap of 2000 after b's last acquisition,
    too far for the design life alone (the median spacing of that batch), not in the
    union with a's and c's gaps of 1."""
    db = tmp_path / "c.db"
    with ComponentStore(db, config=CFG) as store:
        store.JOIN_BATCHES = join_batches
        store.ingest(frame(["a", "b"], range(5)))
        bad = pd.DataFrame({"component": ["b"], "time": [t_bad], "hi": [0.5]})
        res = store.ingest_many([(validate_acquisitions(f, CFG, None), "s", NOW) for f in (
            frame(["a"], range(5, 9)), bad, frame(["c"], range(4)))])
        assert isinstance(res[1], IngestError) and "time units apart" in str(res[1])
        n = store.status().set_index("component")["n"].to_dict()
    assert n == {"a": 9, "b": 5, "c": 4}


class Refused(Exception):
    pass


@pytest.mark.parametrize("join_batches", [True, False])
def test_admitted_batches_store_and_answer_as_the_others_left_out(tmp_path, join_batches):
    """An admission that refuses every other batch of each group (read in the transaction,
    after the lock): the refused get their exception, nothing of them is stored, and the
    admitted, under the sources it gives, store and answer as groups without the refused."""
    queries = []

    def admission(group):
        def decide(rows):
            queries.append(rows)
            return [f"ok{i}" if i % 2 == 0 else Refused(i) for i in range(len(group))]

        return Admission("SELECT count(*) FROM components", decide)

    runs = []
    for admit in (True, False):
        path = tmp_path / f"{admit}.db"
        with ComponentStore(path, config=CFG) as store:
            store.JOIN_BATCHES = join_batches
            store.keep_states()
            out = []
            for group in GROUPS:
                batches = [(validate_acquisitions(f, CFG, None), f"ok{i}", NOW)
                           for i, f in enumerate(group)]
                res = (store.ingest_many(batches, admission(group)) if admit else
                       store.ingest_many(batches[::2]))
                out.append([r if isinstance(r, Refused) else _result(r) for r in res])
        con = sqlite3.connect(path)
        runs.append((out, [con.execute(f"SELECT * FROM {t} ORDER BY 1, 2").fetchall()
                           for t in TABLES]))
        con.close()
    (admitted, tables), (alone, tables_alone) = runs
    assert [[type(r) for r in g[1::2]] for g in admitted] == [
        [Refused] * (len(g) // 2) for g in GROUPS]
    assert [g[::2] for g in admitted] == alone
    assert tables == tables_alone
    # read in each group's transaction: the components the admitted batches stored before
    # (none; a, b; and e, f; and c, d, g)
    assert [rows[0][0] for rows in queries] == [0, 2, 4, 7]
