"""What the API and the dashboard read: one RUL per component, the counts per level, the HI
forecast (docs/service.md; docs/systems/embedded-rul.md §6-7).

Every reader takes a connection inside one read snapshot and the estimator in force
(:func:`rulkit.fleet.store.prognosis.current_estimator`), so the fleet table, a component's
page, its chart and the alerts list show the same RUL (the median and the interval of one
estimator) and the same level. Numbers that are not finite are ``null`` in JSON; ``rul_state``
says what a ``null`` RUL means (``pending``: too few acquisitions; ``failed``; ``estimated``:
then a ``null`` quantile is unbounded, it lies in the never-failing mass).
"""

from __future__ import annotations

import math
import sqlite3
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from rulkit.fleet.monitoring.estimators import (
    ComponentStates,
    Estimator,
    forecast_horizons,
    hi_forecast,
)
from rulkit.fleet.monitoring.rules import due_time, stale, unit_seconds
from rulkit.fleet.monitoring.unit_trend import TrendState
from rulkit.fleet.store.schema import DUE_KEY, RUL_KEY, SEEN_BUCKET, TREND_COLUMNS
from rulkit.fleet.tracking.tracker_chain import LEVEL_NAMES

FIELDS = ("component", "t", "n", "hi", "fhi", "frul", "valid", "level", "rul_median",
          "rul_low", "rul_high", "failed_at", "seen")
"""The ``components`` columns a component item is made of."""
LEVEL_CODES = {name: code for code, name in LEVEL_NAMES.items()}
SORTS = {"worst": (RUL_KEY, "component"), "rul": (RUL_KEY, "component"),
         "due": (DUE_KEY, "component")}
"""The list's orders: the key after the level (``worst``: level first, descending; unknown
RULs and due dates last, as 1e308). Within one level each order is a range of one index of
:data:`rulkit.fleet.store.schema.COMPONENTS`."""


def num(v: Any) -> Any:
    """JSON-safe number: NaN, infinities and None become None."""
    if type(v) is float:  # the common case first: a column value of SQLite or psycopg
        return v if math.isfinite(v) else None
    if v is None:
        return None
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    f = float(v)
    return f if math.isfinite(f) else None


def _float(v: Any) -> float:
    return math.nan if v is None else float(v)


_SEEN, _MEDIAN, _FAILED = FIELDS.index("seen"), FIELDS.index("rul_median"), \
    FIELDS.index("failed_at")


def component_items(rows: list[tuple], est: Estimator, now: float) -> list[dict[str, Any]]:
    """The components as the API returns them (rows of :data:`FIELDS`): the due dates and
    stale flags of the whole page in one array operation each (docs/systems/embedded-rul.md
    §7), the rest copied per row."""
    if not rows:
        return []
    seen = np.array([r[_SEEN] for r in rows], dtype=np.float64)  # None -> NaN
    med = np.array([r[_MEDIAN] for r in rows], dtype=np.float64)
    failed = np.array([r[_FAILED] is not None for r in rows])
    due = np.where(failed, np.nan, due_time(seen, med, est.time_unit)).tolist()
    stale_flags = stale(seen, now, est.rules).tolist()
    out = []
    for r, d, st in zip(rows, due, stale_flags, strict=True):
        (component, t, n, hi, fhi, _frul, _valid, level, rul_median, rul_low, rul_high,
         failed_at, last_seen) = r
        is_failed = failed_at is not None
        rul = num(rul_median)
        out.append({
            "component": component, "level": LEVEL_NAMES[int(level)], "failed": is_failed,
            "failed_at": num(failed_at), "stale": st,
            "rul_state": "failed" if is_failed else ("pending" if rul_median is None
                                                     or rul_median != rul_median
                                                     else "estimated"),
            "rul": rul, "rul_low": num(rul_low), "rul_high": num(rul_high), "due": num(d),
            "hi": num(hi), "fhi": num(fhi), "last_time": num(t), "last_seen": num(last_seen),
            "n": int(n)})
    return out


def component_item(row: tuple, est: Estimator, now: float) -> dict[str, Any]:
    """One component as the API returns it (a row of :data:`FIELDS`)."""
    return component_items([row], est, now)[0]


def _stale_filter(level: str | None, est: Estimator, now: float) -> tuple[str, list[Any]]:
    """The condition of the ``stale`` filter (no acquisition for ``stale_after``), or none."""
    if level != "stale":
        return "1 = 1", []
    after = est.rules.stale_after
    return ("1 = 0", []) if after is None else ("seen < ?", [now - after])


def _ranges(sort: str, level: str | None, est: Estimator, now: float,
            key: list[Any] | None, dialect: str) -> list[list[tuple[str, list[Any], str]]]:
    """The ranges of a page in ``sort`` order after ``key`` (:func:`page_query`), one group
    per level, each range (condition, parameters, order) and a group's ranges in the order
    of its rows; for ``worst`` the groups in the page's order."""
    cond, params = _stale_filter(level, est, now)
    k, order = SORTS[sort][0], ", ".join(SORTS[sort])
    levels = [LEVEL_CODES[level]] if level in LEVEL_CODES else [2, 1, 0]
    groups: list[list[tuple[str, list[Any], str]]] = []
    for lv in levels:
        where, p = f"{cond} AND level = ?", [*params, lv]
        if key is None or (sort == "worst" and lv < key[0]):
            groups.append([(where, p, order)])
        elif dialect == "postgresql" and (sort != "worst" or lv == key[0]):
            groups.append([(f"{where} AND ({k}, component) > (?, ?)",
                            [*p, key[1], key[2]], order)])
        elif sort != "worst" or lv == key[0]:  # ordered by id alone: the key is fixed
            groups.append([(f"{where} AND {k} = ? AND component > ?", [*p, key[1], key[2]],
                            "component"),
                           (f"{where} AND {k} > ?", [*p, key[1]], order)])
    return groups


def _ranges_query(cols: str, outer_order: str,
                  groups: list[list[tuple[str, list[Any], str]]], sort: str, n: int,
                  skip: int = 0) -> tuple[str, list[Any]]:
    """SQL and parameters of rows ``skip`` to ``skip + n`` of the union of the ranges of
    ``groups`` (:func:`_ranges`), selecting ``cols``, merged by ``outer_order``. Each range
    stops after ``skip + n`` rows, and so does each group: its ranges are read in turn, a
    later one only while the earlier ones gave fewer rows (the rest of a tie on the cursor's
    key first: when that holds a page, the keys after it in a level with a filter that
    skips most of them are not walked). This takes a compound's rows in the order of its
    arms, as SQLite reads them (every page is checked against a Python sort of the table in
    tests/fleet/service/test_fleet_view.py)."""
    m = int(n + skip)
    tail = f"LIMIT {int(n)}" + (f" OFFSET {int(skip)}" if skip else "")
    args = [v for g in groups for _, p, _ in g for v in p]
    if sum(map(len, groups)) <= 1:  # none: a cursor of a level before the filter's (worst)
        w, _, o = groups[0][0] if groups else ("1 = 0", [], "component")
        return f"SELECT {cols} FROM components WHERE {w} ORDER BY {o} {tail}", args

    def group_sql(i: int, g: list[tuple[str, list[Any], str]], limit: str) -> str:
        """A group's rows in its order: its ranges in turn (a compound stops reading its
        arms at its limit)."""
        arms = [f"SELECT {cols} FROM components WHERE {w} ORDER BY {o} LIMIT {m}"
                for w, _, o in g]
        if len(arms) == 1:
            return arms[0]
        return " UNION ALL ".join(f"SELECT * FROM ({a}) AS r{i}_{j}"
                                  for j, a in enumerate(arms)) + f" {limit}"

    if len(groups) == 1:  # one level: its ranges in turn are the page's order
        return group_sql(0, groups[0], tail), args
    parts = [group_sql(i, g, f"LIMIT {m}") for i, g in enumerate(groups)]
    union = " UNION ALL ".join(f"SELECT * FROM ({q}) AS p{i}" for i, q in enumerate(parts))
    lead = "level DESC, " if sort == "worst" else ""
    return f"SELECT * FROM ({union}) AS page ORDER BY {lead}{outer_order} {tail}", args


def page_query(sort: str, level: str | None, est: Estimator, now: float,
               key: list[Any] | None, n: int, dialect: str = "sqlite"
               ) -> tuple[str, list[Any]]:
    """SQL and parameters of the first ``n`` components in ``sort`` order (:data:`SORTS`)
    after the row whose key is ``key`` (keyset: ``[level, sort key, id]``; ``None`` from the
    start), under the ``level`` filter. The page is the union of index ranges that each stop
    after ``n`` rows, so a deep page costs what the first does. Every range is of one level
    (an equality on the level heads each order's index): ``worst`` is level descending, then
    the key; ``rul`` and ``due`` merge the levels' ranges. A range after the cursor's key is
    one row comparison ``(key, id) > (?, ?)`` on PostgreSQL (an index condition there); on
    SQLite, which seeks only the level with it, two: the rest of the key's tie (later ids)
    and the keys after it, read in turn (:func:`_ranges_query`).

    One level per range, and the row comparison, keep the plan right on PostgreSQL: the
    levels follow the RUL (the alarms hold the shortest; the pending RULs are rarely
    alarms), which the planner's estimates take as independent, so with an index of the key
    alone it reads the ``ok`` rows of a key order past every alarm, and for a tie of an
    unknown RUL it walks the primary key past every later id, filtering them one by one."""
    ranges = _ranges(sort, level, est, now, key, dialect)
    return _ranges_query(", ".join((*FIELDS, "due")), ", ".join(SORTS[sort]), ranges, sort, n)


def skip_query(sort: str, level: str | None, est: Estimator, now: float,
               key: list[Any] | None, offset: int, dialect: str = "sqlite"
               ) -> tuple[str, list[Any]]:
    """SQL and parameters of the key ``[level, sort key, id]`` of the ``offset``-th
    component (from 1) in ``sort`` order after ``key``, as :func:`page_query` orders them:
    the same ranges, each reading only the columns of its order's index (on SQLite a walk of
    that index alone, without the table's rows), so that a page by ``offset`` is the page
    after that key."""
    k = SORTS[sort][0]
    ranges = _ranges(sort, level, est, now, key, dialect)
    return _ranges_query(f"level, {k} AS k, component", "k, component", ranges, sort, 1,
                         offset - 1)


STALE_BY_SEEN = 2000
"""Up to this many stale components, a page of the stale filter reads them all in the
``seen`` index and sorts them (:func:`stale_page_query`: a cost of the stale ones, the usual
few); beyond, :func:`page_query` reads each level's order and skips the fresh ones (pages of
50 come soon when many are stale; with few, that would read whole levels)."""


FIRST_BUDGET = 0.002
"""Seconds of this thread's CPU time each plan of :func:`first_done` is given in its first
round (a page that comes soon takes a fraction of it); every further round doubles it."""
HANDLER_STEPS = 10_000
"""SQLite virtual machine steps between two calls of :func:`first_done`'s progress handler
(each call takes the interpreter's lock, which the query otherwise runs without)."""


def first_done(conn: Any, plans: list[Callable[[], list[Any]]],
               budget: float | None = None) -> list[Any]:
    """The rows of whichever of ``plans`` (the same rows read by different plans) ends first
    within a budget of this thread's CPU time: each tried in turn, stopped by SQLite's
    progress handler once its budget is spent, the budget doubled after every round, so the
    time spent is at most about 4 times that of the cheaper plan (and the rows are the same
    whichever answers). For the stale filter beyond :data:`STALE_BY_SEEN`: each level's
    order read past the fresh components is cheap while stale ones come soon in every level
    and dear where a level holds few of them before its end; the ``seen`` index read whole
    is dear when many are stale. SQLite, without statistics, cannot tell which."""
    budget = FIRST_BUDGET if budget is None else budget
    while True:
        for plan in plans:
            stop = time.thread_time() + budget
            over = [False]

            def spent(over: list[bool] = over, stop: float = stop) -> bool:
                over[0] = time.thread_time() > stop
                return over[0]

            conn.set_progress_handler(spent, HANDLER_STEPS)
            try:
                return plan()
            except sqlite3.OperationalError:
                if not over[0]:  # not the handler's interruption
                    raise
            finally:
                conn.set_progress_handler(None, 0)
        budget *= 2


def stale_page_query(sort: str, cutoff: float, key: list[Any] | None, n: int
                     ) -> tuple[str, list[Any]]:
    """SQL and parameters of the first ``n`` components seen before ``cutoff`` in ``sort``
    order after the row whose key is ``key`` (as :func:`page_query`): one range of the
    ``seen`` index, the cursor's key a filter and the order a sort of that range. The level is
    written ``+level`` (the same value) so that SQLite, which has no statistics, can neither
    seek nor walk the level's index instead."""
    cols = ", ".join((*FIELDS, "due"))
    k, order = SORTS[sort][0], ", ".join(SORTS[sort])
    where, params = "seen < ?", [cutoff]
    if key is not None:
        after = f"({k} > ? OR ({k} = ? AND component > ?))"
        args = [key[1], key[1], key[2]]
        if sort == "worst":
            after, args = f"(+level < ? OR (+level = ? AND {after}))", [key[0], key[0], *args]
        where, params = f"{where} AND {after}", [*params, *args]
    lead = "+level DESC, " if sort == "worst" else ""
    return (f"SELECT {cols} FROM components WHERE {where} ORDER BY {lead}{order} "
            f"LIMIT {int(n)}", params)


def cursor_of(row: tuple, sort: str) -> str:
    """The cursor of the page after ``row`` (a row of :func:`page_query`)."""
    import base64
    import json

    d = dict(zip((*FIELDS, "due"), row, strict=True))
    k = d["due"] if sort == "due" else d["rul_median"]
    key = [sort, int(d["level"]), 1e308 if k is None else float(k), d["component"]]
    return base64.urlsafe_b64encode(json.dumps(key).encode()).decode().rstrip("=")


class CursorError(ValueError):
    """``after`` is not a cursor of this sort returned by the API."""


def decode_cursor(cursor: str, sort: str) -> list[Any]:
    """``[level, sort key, id]`` of a cursor of ``sort``; :class:`CursorError` if it is not
    one."""
    import base64
    import binascii
    import json

    try:
        key = json.loads(base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4)))
    except (ValueError, TypeError, binascii.Error, RecursionError):
        raise CursorError("after: not a cursor returned by this API") from None
    ok = (isinstance(key, list) and len(key) == 4 and key[0] == sort
          and type(key[1]) is int and key[1] in LEVEL_NAMES
          and type(key[2]) in (int, float) and math.isfinite(key[2])
          and isinstance(key[3], str))
    if not ok:
        raise CursorError(f"after: not a cursor of sort={sort} returned by this API")
    return [key[1], float(key[2]), key[3]]


def level_total(conn: Any, level: str | None, est: Estimator, now: float) -> int:
    """Components under the ``level`` filter: from table ``level_counts`` (kept by every
    write), stale ones by :func:`stale_total`."""
    if level == "stale":
        after = est.rules.stale_after
        return 0 if after is None else stale_total(conn, now - after)
    counts = dict(conn.execute("SELECT level, n FROM level_counts").fetchall())
    if level is None:
        return int(sum(counts.values()))
    return int(counts.get(LEVEL_CODES[level], 0))


def stale_total(conn: Any, cutoff: float) -> int:
    """Components whose last acquisition is before ``cutoff`` (``seen < cutoff``), inside the
    caller's snapshot: the windows of ``seen_counts`` wholly on one side of the cutoff
    (:data:`rulkit.fleet.store.schema.SEEN_COUNTS`, kept by every write) and, counted in the
    ``seen`` index, the components of the cutoff's own window between the cutoff and that
    window's nearer edge. The cost is of the windows, not of the components before the
    cutoff."""
    b = math.floor(cutoff / SEEN_BUCKET)
    lo, hi = b * SEEN_BUCKET, (b + 1) * SEEN_BUCKET
    if cutoff - lo <= hi - cutoff:  # the windows before b, plus [lo, cutoff)
        whole, edge, sign = "bucket < ?", (lo, cutoff), 1
    else:  # the windows up to b, less [cutoff, hi)
        whole, edge, sign = "bucket <= ?", (cutoff, hi), -1
    n = conn.execute(f"SELECT COALESCE(SUM(n), 0) FROM seen_counts WHERE {whole}",
                     (b,)).fetchone()[0]
    m = conn.execute("SELECT COUNT(*) FROM components WHERE seen >= ? AND seen < ?",
                     edge).fetchone()[0]
    return int(n) + sign * int(m)


def list_components(conn: Any, est: Estimator, *, limit: int, offset: int,
                    level: str | None, sort: str, now: float, after: str | None = None
                    ) -> tuple[int, list[dict[str, Any]], str | None]:
    """(total matching, one page in the order ``sort`` of :data:`SORTS`, the cursor of the
    next page or ``None`` after the last); ``level`` one of ok, warning, alarm or stale
    (``None``: all). ``after``: a cursor this function returned (keyset: any page costs what
    the first does); ``offset`` then skips rows: read in their order's index alone
    (:func:`skip_query`), then the page after the last one skipped, so its cost grows with
    the offset but no skipped row is fetched into Python."""
    key = None if after is None else decode_cursor(after, sort)
    total = level_total(conn, level, est, now)
    stale_after = est.rules.stale_after
    dialect = getattr(conn, "dialect", "sqlite")

    def by_seen() -> list[Any]:
        assert stale_after is not None
        sql, params = stale_page_query(sort, now - stale_after, key, offset + limit)
        return list(conn.execute(sql, params).fetchall()[offset:])

    def by_order() -> list[Any]:
        at = key
        if offset:  # the rows skipped read in their order's index alone, then a page after
            row = conn.execute(*skip_query(sort, level, est, now, at, offset, dialect)
                               ).fetchone()
            at = None if row is None else [int(row[0]), float(row[1]), row[2]]
        sql, params = page_query(sort, level, est, now, at, limit, dialect)
        return [] if offset and at is None else list(conn.execute(sql, params).fetchall())

    if level == "stale" and stale_after is not None and total <= STALE_BY_SEEN:
        rows = by_seen()
    elif level == "stale" and stale_after is not None and dialect == "sqlite":
        rows = first_done(conn, [by_order, by_seen])
    else:
        rows = by_order()
    nxt = cursor_of(rows[-1], sort) if len(rows) == limit else None
    items = component_items([r[:len(FIELDS)] for r in rows], est, now)
    return total, items, nxt


def summary(conn: Any, est: Estimator, now: float) -> dict[str, Any]:
    """Counts per level (and of stale components), what gives the RUL, the rules, the fitted
    model's warnings and the calendar time ``now`` the staleness is judged at."""
    counts = {name: 0 for name in LEVEL_NAMES.values()}
    for level, n in conn.execute("SELECT level, n FROM level_counts"):
        counts[LEVEL_NAMES[int(level)]] = int(n)
    counts["stale"] = level_total(conn, "stale", est, now)
    rules = est.rules
    return {"total": sum(counts[n] for n in LEVEL_NAMES.values()), "counts": counts,
            "estimator": est.kind, "estimator_label": est.label, "time_unit": est.time_unit,
            "calendar": unit_seconds(est.time_unit) is not None, "interval": rules.interval,
            "rules": {"alarm": rules.alarm_text(), "warning": rules.warning_text(est.time_unit),
                      "alarm_hi": rules.alarm_hi, "lead_time": rules.lead_time,
                      "stale_after": rules.stale_after},
            "model_warnings": list(est.warnings), "now": now}


def _states(conn: Any, est: Estimator, component: str, row: dict[str, Any]
            ) -> ComponentStates:
    """The one component's estimator states (trend sums, fitted model state, tracker)."""
    sums = conn.execute(f"SELECT {', '.join(TREND_COLUMNS)} FROM components WHERE "
                        "component = ?", (component,)).fetchone()
    trend = TrendState(t=np.array([_float(row["t"])]), hi=np.array([_float(row["hi"])]),
                       n=np.array([int(row["n"])]),
                       s=np.array([[_float(v) for v in sums]]))
    model = None
    if est.kind == "model":
        from rulkit.fleet.store.learned_state import model_states

        model = model_states(conn, est.model, [component])
    return ComponentStates(trend=trend, model=model, fhi=np.array([_float(row["fhi"])]),
                           frul=np.array([_float(row["frul"])]))


def forecast(conn: Any, est: Estimator, component: str, item: dict[str, Any],
             t_first: float) -> dict[str, Any] | None:
    """The HI forecast from the last acquisition to the end of the RUL interval: times, the
    median path and the band (``None`` once failed, while pending, or when the estimator
    offers none)."""
    if item["rul_state"] != "estimated":
        return None
    row = dict(zip(FIELDS, conn.execute(f"SELECT {', '.join(FIELDS)} FROM components WHERE "
                                        "component = ?", (component,)).fetchone(),
                   strict=True))
    states = _states(conn, est, component, row)
    t_last = _float(row["t"])
    span = np.array([max(t_last - t_first, 1.0)])
    hz = forecast_horizons(np.array([_float(row["rul_median"])]),
                           np.array([_float(row["rul_low"])]),
                           np.array([_float(row["rul_high"])]), span)
    got = hi_forecast(est, states, hz)
    if got is None:
        return None
    med, low, high = (np.asarray(g)[0] for g in got)
    return {"t": (t_last + hz[0]).tolist(), "hi": [num(v) for v in med],
            "hi_low": [num(v) for v in low], "hi_high": [num(v) for v in high]}


def time_origin(item: dict[str, Any], est: Estimator) -> float | None:
    """The calendar time (seconds since 1970) of t = 0 for this component, when its time unit
    is a duration and its last acquisition has a calendar time; ``None`` otherwise."""
    scale = unit_seconds(est.time_unit)
    if scale is None or item["last_seen"] is None or item["last_time"] is None:
        return None
    return float(item["last_seen"] - item["last_time"] * scale)


__all__ = ["FIELDS", "SORTS", "STALE_BY_SEEN", "CursorError", "component_item",
           "component_items", "cursor_of", "decode_cursor", "forecast", "level_total",
           "list_components", "num", "page_query", "skip_query", "stale_page_query", "stale_total",
           "summary", "time_origin"]
