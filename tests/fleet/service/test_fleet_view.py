"""Pages of the component list by keyset cursor, on both backends: walking the cursors visits
every component once, in the order a Python sort of the whole table gives, for every sort and
level filter the API offers; each part of a page's query is an index range of one level; the
totals kept in ``level_counts`` and ``seen_counts`` equal a count of the table."""

import itertools
import re

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.monitoring.rules import MonitoringRules, due_time
from rulkit.fleet.service import fleet_view
from rulkit.fleet.service.fleet_view import SORTS, CursorError, page_query, stale_page_query
from rulkit.fleet.store.prognosis import current_estimator

NOW = 1.8e9  # calendar time of the second batch (seconds since 1970)


def fleet(sdb, n=90):
    """``n`` components with every level, unknown RULs and failed ones (ties on the key), two
    ingestion times (the first batch's components stale at ``NOW``), hours as the time
    unit."""
    with sdb.store() as s:
        s.set_rules(MonitoringRules(time_unit="h", lead_time=30.0, alarm_hi=0.9,
                                    stale_after=3600.0))
    rng = np.random.default_rng(5)
    t = np.arange(12.0)
    rate = rng.uniform(0.0, 0.2, n)
    hi = np.minimum(0.2 + np.outer(rate, t), 1.2)
    names = [f"c{i:03d}" for i in range(n)]
    df = pd.DataFrame({"component": np.repeat(names, t.size), "time": np.tile(t, n),
                       "hi": hi.ravel()})
    df = df[~df["component"].isin(names[3::11]) | (df["time"] == 0.0)]  # one: RUL unknown
    half = df["component"] < f"c{n // 2:03d}"
    sdb.ingest(df[half], "old", now=NOW - 7200.0)
    sdb.ingest(df[~half], "new", now=NOW)


def table(sdb):
    with sdb.store() as s, s.snapshot() as conn:
        cols = ["component", "level", "rul_median", "seen", "due"]
        rows = conn.execute(f"SELECT {', '.join(cols)} FROM components").fetchall()
        return pd.DataFrame(rows, columns=cols), current_estimator(s)


def expected(df, sort, level):
    """The order by a Python sort of every row (unknown keys last, then the id)."""
    if level == "stale":
        df = df[df["seen"] < NOW - 3600.0]
    elif level is not None:
        df = df[df["level"] == {"ok": 0, "warning": 1, "alarm": 2}[level]]
    due = due_time(df["seen"].to_numpy(), df["rul_median"].to_numpy(dtype=float), "h")
    rul = df["rul_median"].to_numpy(dtype=float)
    rows = list(zip(df["level"], np.where(np.isnan(rul), np.inf, rul),
                    np.where(np.isnan(due), np.inf, due), df["component"], strict=True))
    if sort == "worst":
        rows.sort(key=lambda r: (-r[0], r[1], r[3]))
    else:
        rows.sort(key=lambda r: (r[1] if sort == "rul" else r[2], r[3]))
    return [r[3] for r in rows]


def walk(sdb, limit, level, sort, total):
    """The components of every page by cursor from the first, each page's total checked."""
    got, after = [], None
    while True:
        n, items, after = sdb.components(limit=limit, level=level, sort=sort, after=after,
                                         now=NOW)
        assert n == total
        got += [i["component"] for i in items]
        if after is None:
            return got


@pytest.mark.parametrize("level", [None, "ok", "alarm", "stale", "stale by level"])
def test_walking_the_cursors_visits_every_component_once_in_order(sdb, level, monkeypatch):
    """(``stale by level``: the stale filter as many stale components are read, each level's
    order filtered by ``seen``, instead of a sort of the few.)"""
    if level == "stale by level":
        monkeypatch.setattr(fleet_view, "STALE_BY_SEEN", 0)
        level = "stale"
    fleet(sdb)
    df, _ = table(sdb)
    assert set(df["level"]) == {0, 1, 2} and df["rul_median"].isna().any()
    assert np.array_equal(df["due"].isna(), df["rul_median"].isna())  # the stored due
    for sort in SORTS:
        want = expected(df, sort, level)
        assert walk(sdb, 8, level, sort, len(want)) == want, (sort, level)
        # offset after a cursor skips rows of the same order
        _, _, cur = sdb.components(limit=3, level=level, sort=sort, now=NOW)
        if cur is not None:
            _, skipped, _ = sdb.components(limit=2, offset=2, level=level, sort=sort,
                                           after=cur, now=NOW)
            assert [i["component"] for i in skipped] == want[5:7]
        # offset from the start: across the levels' ranges, in ties, at and past the end
        for off in sorted({1, 7, len(want) // 3, len(want) // 2, len(want) - 1, len(want),
                           len(want) + 5}):
            _, items, nxt = sdb.components(limit=4, offset=off, level=level, sort=sort,
                                           now=NOW)
            assert [i["component"] for i in items] == want[off:off + 4], (sort, level, off)
            assert (nxt is None) == (len(want[off:off + 4]) < 4)


def test_a_cursor_of_another_sort_or_forged_is_refused(sdb):
    fleet(sdb, 20)
    _, _, cur = sdb.components(limit=5, sort="rul", now=NOW)
    for bad in (cur, "bm90IGEgY3Vyc29y", "!!", ""):
        with pytest.raises(CursorError, match="cursor"):
            sdb.components(limit=5, sort="due", after=bad, now=NOW)


def test_a_cursor_past_the_filters_levels_gives_an_empty_page(sdb):
    """In ``worst`` order every alarm precedes every ok component: after an ok one's cursor
    no alarm is left, by cursor or by offset."""
    fleet(sdb, 30)
    _, _, cur = sdb.components(limit=2, level="ok", sort="worst", now=NOW)
    alarms, _, _ = sdb.components(limit=1, level="alarm", now=NOW)
    assert alarms > 0 and cur is not None
    for offset in (0, 1):
        total, items, nxt = sdb.components(limit=5, offset=offset, level="alarm",
                                           sort="worst", after=cur, now=NOW)
        assert (total, items, nxt) == (alarms, [], None)


@pytest.mark.parametrize("level", [None, "ok", "stale"])
@pytest.mark.parametrize("sort", list(SORTS))
def test_a_keyset_page_seeks_an_index(sdb, sort, level):
    """Every part of a page's query reads an index range in its order (SQLite: SEARCH, or a
    walk of an order's index that stops after the page; PostgreSQL: an index scan), never a
    sort of the table nor of a tie of the sort key (the cursor's key with later ids)."""
    fleet(sdb, 30)
    _, est = table(sdb)
    sql, params = page_query(sort, level, est, NOW, [1, 5.0, "c010"], 50, sdb.dialect)
    with sdb.store() as s, s.snapshot() as conn:
        if sdb.dialect == "sqlite":
            plan = [r[3] for r in conn.execute("EXPLAIN QUERY PLAN " + sql, params)]
            reads = [p for p in plan if p.startswith(("SCAN components", "SEARCH components"))]
            assert reads and all("INDEX" in p for p in reads), plan
            assert level == "stale" or all(p.startswith("SEARCH") for p in reads), plan
            # each range comes out of its index in order: only the merge of the ranges sorts
            sorts = [p for p in plan if "TEMP B-TREE" in p]
            assert len(sorts) <= ("SCAN page" in plan), plan
        else:
            conn.execute("SET LOCAL enable_seqscan = off")
            plan = " ".join(r[0] for r in conn.execute("EXPLAIN " + sql, params).fetchall())
            assert "Index" in plan and "Seq Scan" not in plan, plan


def test_a_tie_that_fills_the_page_is_not_followed_past_it(sdb):
    """A cursor inside a tie of the sort key that holds the next page (stale alarms that all
    failed at one time: one due date), followed in the level's order by many rows the filter
    skips (fresh alarms): the page after it reads what the first page reads, not every fresh
    alarm (SQLite: the tie's range, then the keys after it only for a short page; counted in
    the virtual machine's steps), and both pages are the Python sort's."""
    with sdb.store() as s:
        s.set_rules(MonitoringRules(time_unit="h", lead_time=30.0, alarm_hi=0.9,
                                    stale_after=3600.0))
    names = [f"c{i:04d}" for i in range(3000)]
    df = pd.DataFrame({"component": np.repeat(names, 2), "time": np.tile([0.0, 1.0], 3000),
                       "hi": np.tile([0.5, 1.1], 3000)})  # failed: RUL 0, due at the time seen
    stale = df["component"] < "c0200"
    sdb.ingest(df[stale], "old", now=NOW - 7200.0)
    sdb.ingest(df[~stale], "new", now=NOW)
    rows, est = table(sdb)
    want = expected(rows, "due", "stale")
    assert len(want) == 200 and rows["level"].eq(2).all()
    _, first, cur = sdb.components(limit=50, level="stale", sort="due", now=NOW)
    _, second, _ = sdb.components(limit=50, level="stale", sort="due", after=cur, now=NOW)
    assert [i["component"] for i in first + second] == want[:100]
    if sdb.dialect != "sqlite":
        return
    steps = {}
    with sdb.store() as s, s.snapshot() as conn:
        for name, key in (("first", None), ("second", fleet_view.decode_cursor(cur, "due"))):
            count = [0]

            def step(count=count):
                count[0] += 1
                return 0

            sql, params = page_query("due", "stale", est, NOW, key, 50)
            conn.set_progress_handler(step, 100)
            try:
                conn.execute(sql, params).fetchall()
            finally:
                conn.set_progress_handler(None, 0)
            steps[name] = count[0]
    assert steps["second"] < 3 * steps["first"] + 10, steps


def test_first_done_answers_with_the_plan_that_ends_and_leaves_the_connection_clean(tmp_path):
    """A plan that would run for seconds is stopped within its budget and the other plan's
    rows are returned; an error of a plan's own is raised; no progress handler is left."""
    import sqlite3

    conn = sqlite3.connect(tmp_path / "x.db")
    endless = "WITH RECURSIVE c(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM c " \
              "WHERE i < 100000000) SELECT count(*) FROM c"

    def slow():
        return conn.execute(endless).fetchall()

    def quick():
        return conn.execute("SELECT 7").fetchall()

    assert fleet_view.first_done(conn, [slow, quick], budget=1e-4) == [(7,)]
    assert fleet_view.first_done(conn, [quick, slow], budget=1e-4) == [(7,)]
    with pytest.raises(sqlite3.OperationalError, match="no such table"):
        fleet_view.first_done(conn, [lambda: conn.execute("SELECT * FROM absent").fetchall(),
                                     quick])
    assert conn.execute("WITH RECURSIVE c(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM c "
                        "WHERE i < 200000) SELECT count(*) FROM c").fetchone() == (200000,)


@pytest.mark.parametrize("level", ["stale"])
def test_stale_pages_by_either_plan_are_the_python_sort(sdb, level, monkeypatch):
    """Beyond ``STALE_BY_SEEN`` the stale pages on SQLite come from whichever plan ends first
    (:func:`fleet_view.first_done`); with budgets so small that every plan is stopped many
    times before one ends, and with each plan alone, every page is still the Python sort's
    (on PostgreSQL the variants are not called and the pages are checked as they are)."""
    monkeypatch.setattr(fleet_view, "STALE_BY_SEEN", 0)
    monkeypatch.setattr(fleet_view, "HANDLER_STEPS", 100)
    fleet(sdb)
    df, _ = table(sdb)
    runs, pages = [0], [0]

    def tiny(conn, plans):  # every plan run counted: the stopped ones too
        pages[0] += 1
        counted = [lambda p=p: (runs.__setitem__(0, runs[0] + 1), p())[1] for p in plans]
        return real(conn, counted, budget=1e-7)

    variants = {"tiny budgets": tiny,
                "by order": lambda conn, plans: plans[0](),
                "by seen": lambda conn, plans: plans[1]()}
    real = fleet_view.first_done
    for name, variant in variants.items():
        monkeypatch.setattr(fleet_view, "first_done", variant)
        for sort in SORTS:
            want = expected(df, sort, level)
            assert walk(sdb, 7, level, sort, len(want)) == want, (name, sort)
            _, items, _ = sdb.components(limit=4, offset=5, level=level, sort=sort, now=NOW)
            assert [i["component"] for i in items] == want[5:9], (name, sort)
    if sdb.dialect == "sqlite":  # the tiny budgets stopped plans, many times a page
        assert runs[0] > 3 * pages[0] > 0
    else:  # PostgreSQL's planner chooses: no race
        assert pages[0] == 0


def test_a_page_of_few_stale_components_reads_the_seen_index(sdb):
    """With few stale components, their page is one range of the ``seen`` index (a cursor's
    key a filter, the order a sort of the few), never a walk of an order's index that reads
    every fresh component of a level (SQLite has no statistics to see that)."""
    fleet(sdb, 30)
    with sdb.store() as s, s.snapshot() as conn:
        if sdb.dialect == "postgresql":
            conn.execute("SET LOCAL enable_seqscan = off")
        for sort in SORTS:
            sql, params = stale_page_query(sort, NOW - 3600.0, [1, 5.0, "c010"], 50)
            if sdb.dialect == "sqlite":
                plan = [r[3] for r in conn.execute("EXPLAIN QUERY PLAN " + sql, params)]
                reads = [p for p in plan if "components" in p]
                assert len(reads) == 1 and "INDEX components_seen (seen<?)" in reads[0], plan
            else:
                plan = " ".join(r[0] for r in conn.execute("EXPLAIN " + sql, params))
                assert "components_seen" in plan and plan.count("Index") == 2, plan


def test_level_counts_follow_every_write(sdb):
    fleet(sdb, 40)

    def counts():
        with sdb.store() as s, s.snapshot() as conn:
            kept = dict(conn.execute("SELECT level, n FROM level_counts").fetchall())
            real = dict(conn.execute("SELECT level, COUNT(*) FROM components "
                                     "GROUP BY level").fetchall())
        return {k: v for k, v in kept.items() if v}, real

    kept, real = counts()
    assert kept == real and len(real) == 3
    # more acquisitions move components between levels; a rules change replays them all
    more = pd.DataFrame({"component": [f"c{i:03d}" for i in range(40)], "time": 20.0,
                         "hi": np.linspace(0.1, 1.1, 40)})
    sdb.ingest(more, "more", now=NOW)
    kept2, real2 = counts()
    assert kept2 == real2 and real2 != real
    with sdb.store() as s:
        s.set_rules(MonitoringRules(time_unit="h", alarm_hi=0.5))
    kept3, real3 = counts()
    assert kept3 == real3 and real3 != real2


def test_the_stale_total_equals_a_count_whatever_the_clock_and_the_writes(sdb, tmp_path):
    """The stale total (windows of ``seen_counts`` and the edge of the cutoff's window)
    against a count of the table at every step, with the clock moving forth and back, writes
    through the service's own connections and through another process's connection."""
    from rulkit.fleet.store.postgres import open_store

    fleet(sdb, 60)

    def brute(now):
        with sdb.store() as s, s.snapshot() as conn:
            return conn.execute("SELECT COUNT(*) FROM components WHERE seen < ?",
                                (now - 3600.0,)).fetchone()[0]

    def check(now):
        total = sdb.components(limit=1, level="stale", now=now)[0]
        assert total == sdb.summary(now=now)["counts"]["stale"] == brute(now), now

    steps = [NOW, NOW + 10.0, NOW + 7200.0, NOW - 3600.0, NOW + 3600.0 - 1.0, NOW + 3600.0]
    for now in steps:
        check(now)
    assert brute(NOW + 3600.0 + 1.0) == 60 > brute(NOW) > 0  # the range moved the total
    late = pd.DataFrame({"component": ["c001", "c002", "new"], "time": 30.0, "hi": 0.3})
    sdb.ingest(late, "late", now=NOW + 5000.0)  # through the service: seen moves
    for now in steps:
        check(now)
    with open_store(sdb.db) as other:  # another connection, as another process has
        other.now = NOW + 9000.0
        other.ingest(pd.DataFrame({"component": ["c003", "c004"], "time": 40.0, "hi": 0.3}),
                     "elsewhere")
    for now in steps:
        check(now)


def test_postgresql_reads_are_index_ranges_by_the_planners_own_choice(pg_server, monkeypatch):
    """After ANALYZE of a filled database, with no planner setting forced: every query the
    pages, the summary and a history read send reads ``components`` and ``history`` through
    their indexes (never a sequential scan), and a single-range page or the history needs no
    sort (the index gives the order). Plans, not timings."""
    from rulkit.fleet.service.db import ServiceDB
    from rulkit.fleet.store.postgres import PgConnection

    sdb = ServiceDB(pg_server.create_schema())
    try:
        n = 3000
        with sdb.store() as s:
            s.set_rules(MonitoringRules(time_unit="h", lead_time=30.0, alarm_hi=0.9,
                                        stale_after=3600.0))
        rng = np.random.default_rng(9)
        names = [f"c{i:05d}" for i in range(n)]
        hi = rng.uniform(0.1, 1.0, n)
        df = pd.DataFrame({"component": np.repeat(names, 2), "time": np.tile([0.0, 1.0], n),
                           "hi": np.repeat(hi, 2) + np.tile([0.0, 0.02], n)})
        sdb.ingest(df[df["component"] < "c00150"], "old", now=NOW - 7200.0)  # 5 % stale
        sdb.ingest(df[df["component"] >= "c00150"], "new", now=NOW)
        t = np.arange(2.0, 1500.0)
        sdb.ingest(pd.DataFrame({"component": "c00200", "time": t, "hi": 0.2 + t * 1e-4}),
                   "long", now=NOW)
        with sdb.store() as s:
            s._conn.execute("ANALYZE")
        sent: list[tuple[str, tuple]] = []
        execute = PgConnection.execute

        def recording(self, sql, params=()):
            if sql.lstrip().upper().startswith("SELECT"):
                sent.append((sql, tuple(params)))
            return execute(self, sql, params)

        monkeypatch.setattr(PgConnection, "execute", recording)
        for sort in SORTS:
            for level in (None, "ok", "alarm", "stale"):
                _, _, nxt = sdb.components(limit=50, sort=sort, level=level, now=NOW)
                if nxt is not None:
                    sdb.components(limit=50, sort=sort, level=level, after=nxt, now=NOW)
        sdb.summary(now=NOW)
        sdb.summary(now=NOW + 60.0)  # the stale total moved by a range
        sdb.history("c00200", limit=100, now=NOW)  # 100 of its 1500 rows
        monkeypatch.setattr(PgConnection, "execute", execute)
        with sdb.store() as s, s.snapshot() as conn:
            for sql, params in sent:
                if " components" not in sql and " history" not in sql:
                    continue
                plan = "\n".join(r[0] for r in conn.execute("EXPLAIN " + sql, params))
                assert "Seq Scan on components" not in plan, (sql, plan)
                assert "Seq Scan on history" not in plan, (sql, plan)
                # a page of one range, or the history's last rows (a component's few
                # alerts may be sorted)
                single = "UNION ALL" not in sql and "seen <" not in sql and "alerts" not in sql
                if single and "LIMIT" in sql:
                    assert "Sort" not in plan, (sql, plan)
        assert any("FROM history" in q and "ORDER BY t_first DESC" in q for q, _ in sent)
    finally:
        sdb.close()


def _correlated_fleet(conn, n):
    """``n`` components straight into ``components`` (PostgreSQL), in the order of their
    ids: the first 6 % alarms with the shortest RULs and due dates, the rest ok, every other
    one of the second half pending (RUL unknown), every column a constant otherwise."""
    from rulkit.fleet.store.schema import COMPONENTS

    consts = {"real": "0.0", "int": "1", "small": "0", "bool": "true"}
    exprs = {"component": "'c' || lpad(i::text, 7, '0')",
             "level": f"CASE WHEN i < {n * 6 // 100} THEN 2 ELSE 0 END",
             "rul_median": f"CASE WHEN i >= {n // 2} AND mod(i, 2) = 0 THEN NULL ELSE i END",
             "seen": str(NOW), "due": f"{NOW} + i * 3600.0"}
    cols = [c for c in COMPONENTS.columns if not c.null or c.name in exprs]
    sel = ", ".join(exprs.get(c.name, consts.get(c.kind, "NULL")) for c in cols)
    conn.execute(f"INSERT INTO components ({', '.join(c.name for c in cols)}) "
                 f"SELECT {sel} FROM generate_series(0, {n - 1}) AS i")
    conn.execute("ANALYZE components")


def test_a_level_filtered_page_seeks_its_level_on_postgresql(pg_server):
    """The levels follow the RUL (alarms hold the shortest), which the planner's estimates
    take as independent: each range of a page under a level filter must seek the level in
    its index (an index condition), never read the key's order and filter the level row by
    row (past every alarm, for an ``ok`` page), nor, after a cursor in a tie of unknown
    RULs, walk the ids (no alarm is pending). After ANALYZE, no planner setting forced."""
    from rulkit.fleet.service.db import ServiceDB

    sdb = ServiceDB(pg_server.create_schema())
    try:
        with sdb.store() as s:
            s.set_rules(MonitoringRules(time_unit="h", lead_time=30.0, alarm_hi=0.9,
                                        stale_after=3600.0))
            _correlated_fleet(s._conn, 50_000)
        with sdb.store() as s, s.snapshot() as conn:
            est = current_estimator(s)
            keys = (None, [0, 1e308, "c0030000"], [2, 5.0, "c0000005"])  # a tie of pending
            for sort, level, key in itertools.product(SORTS, ("ok", "alarm", "stale", None),
                                                      keys):
                if key is not None and {"ok": 0, "alarm": 2}.get(level, key[0]) != key[0]:
                    continue  # not a cursor of this filter
                sql, params = page_query(sort, level, est, NOW + 7200.0, key, 50,
                                         "postgresql")
                plan = "\n".join(r[0] for r in conn.execute("EXPLAIN " + sql, params))
                scans = plan.count("Index Scan")
                assert scans and len(re.findall(r"Index Cond: \(+level = ", plan)) == scans, plan
                assert "Filter: (level" not in plan and "AND (level" not in plan, plan
    finally:
        sdb.close()


def test_seen_counts_follow_every_write(sdb):
    """Table ``seen_counts`` equals a count of ``components`` per window of ``seen``
    (floor(seen / SEEN_BUCKET)) after ingestion, a replay (a rules change) and the creation
    of the table in an older database; only windows holding components are kept."""
    from rulkit.fleet.store.schema import SEEN_BUCKET

    fleet(sdb, 40)

    def counts():
        with sdb.store() as s, s.snapshot() as conn:
            kept = dict(conn.execute("SELECT bucket, n FROM seen_counts").fetchall())
            seen = [r[0] for r in conn.execute("SELECT seen FROM components").fetchall()]
        real: dict[int, int] = {}
        for v in seen:
            b = int(np.floor(v / SEEN_BUCKET))
            real[b] = real.get(b, 0) + 1
        return kept, real

    kept, real = counts()
    assert kept == real and len(real) == 2
    # the old batch's components seen again, some of them in another window
    again = pd.DataFrame({"component": [f"c{i:03d}" for i in range(0, 20, 2)], "time": 20.0,
                         "hi": 0.3})
    sdb.ingest(again, "again", now=NOW + 3 * SEEN_BUCKET)
    kept2, real2 = counts()
    assert kept2 == real2 and real2 != real and len(real2) == 3
    sdb.ingest(pd.DataFrame({"component": [f"c{i:03d}" for i in range(0, 40, 2)],
                             "time": 30.0, "hi": 0.3}), "all old", now=NOW + 9 * SEEN_BUCKET)
    kept3, real3 = counts()
    assert kept3 == real3 and 0 not in kept3.values()  # an emptied window is removed
    with sdb.store() as s:
        s.set_rules(MonitoringRules(time_unit="h", alarm_hi=0.5, stale_after=3600.0))
    assert counts()[0] == real3
    with sdb.store() as s:
        with s._transaction("IMMEDIATE") as conn:
            conn.execute("DROP TABLE seen_counts")
    from rulkit.fleet.service.db import ServiceDB

    ServiceDB(sdb.db).close()  # opening the database migrates it
    assert counts()[0] == real3


def test_the_stale_total_equals_a_count_at_any_cutoff_within_a_window(sdb):
    """Against a count of the table: cutoffs at fractions of the windows of ``seen`` (either
    edge of the cutoff's window is counted from) and at the components' own times, with
    components seen in many windows, some on a window's edge."""
    from rulkit.fleet.service.fleet_view import stale_total
    from rulkit.fleet.store.schema import SEEN_BUCKET, recount_totals

    fleet(sdb, 30)
    w0 = 4e5 * SEEN_BUCKET
    seen = w0 + SEEN_BUCKET * np.array([2 * (i // 5) + (i % 5) / 5 for i in range(30)])
    with sdb.store() as s, s._transaction("IMMEDIATE") as conn:  # 5 per window, 6 windows
        conn.executemany("UPDATE components SET seen = ? WHERE component = ?",
                         [(float(v), f"c{i:03d}") for i, v in enumerate(seen)])
        recount_totals(conn)
    cutoffs = [w0 + (b + f) * SEEN_BUCKET for b in range(-1, 14)
               for f in (0.0, 0.1, 0.5, 0.9, 0.999)]
    with sdb.store() as s, s.snapshot() as conn:
        for cutoff in [*cutoffs, *seen.tolist()]:
            assert stale_total(conn, cutoff) == int((seen < cutoff).sum()), cutoff
