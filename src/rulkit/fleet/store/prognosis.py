"""One RUL per component in the store: the estimator in force and the alert rules over a
batch, the columns that hold them, and their replay (docs/systems/embedded-rul.md §6-7).

The store keeps, beside the tracker chain's state (its 7 numbers, unchanged):

* ``components``: ``rul_median`` and, in ``rul_low`` / ``rul_high``, the interval of the same
  estimator (:mod:`rulkit.fleet.monitoring.estimators`); ``level`` / ``max_level`` from the
  alert rules (:mod:`rulkit.fleet.monitoring.rules`); ``hits`` (crossings of the last
  acquisitions), ``failed_at``, ``seen`` (calendar time of the last acquisition, seconds since
  1970) and the trend estimator's 7 sums ``tr_*``;
* ``history``: per acquisition ``rul_median``, ``rul_low``, ``rul_high`` and ``level`` as the
  estimator in force and the rules gave them;
* ``meta`` key ``monitoring``: the :class:`~rulkit.fleet.monitoring.rules.MonitoringRules` and
  the :class:`~rulkit.fleet.monitoring.unit_trend.TrendConfig`.

A RUL not estimated yet is stored as median NULL with the vacuous interval [0, inf) (the
columns ``rul_low`` / ``rul_high`` are NOT NULL); a failed component as 0 [0, 0].

The columns are defined with every other in :mod:`rulkit.fleet.store.schema`
(``RUL_COLUMNS``); a database written before them gains them in one transaction, with the
RUL columns of every component and history row replayed from the stored acquisitions
(:func:`upgrade`, :func:`replay`); :func:`replay` also runs when a model is fitted or the rules
change, so the table, the history and the charts always show one estimator.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from rulkit.fleet.monitoring.estimators import Estimator, estimator_in_force
from rulkit.fleet.monitoring.rules import (
    MonitoringRules,
    RuleRows,
    RuleState,
    apply_rules,
    due_time,
)
from rulkit.fleet.monitoring.unit_trend import (
    SUM_NAMES,
    TrendConfig,
    TrendState,
    rul_quantiles,
    trend_posterior,
    trend_run,
)
from rulkit.fleet.store import history_chunks
from rulkit.fleet.store.database_file import rows_of_components
from rulkit.fleet.store.schema import (
    RUL_COLUMNS,
    TREND_COLUMNS,
    migrate,
    recount_totals,
    table_columns,
)
from rulkit.fleet.tracking.tracker_chain import LEVEL_ALARM, tracker_rul_interval

if TYPE_CHECKING:
    from rulkit.fleet.store.acquisitions import Alert

FloatArray = NDArray[np.float64]
META_KEY = "monitoring"
PROGNOSIS_COLUMNS = ("hits", "failed_at", "max_level", "seen", *TREND_COLUMNS)
"""The columns of ``components`` a batch's prognosis starts from (the store reads them with
the tracker state, in one query: :class:`BatchPrognosis` ``stored``)."""
REPLAY_ROWS = 200_000
"""History rows replayed at once (bounds the memory of :func:`replay`)."""
QUANTILE_ROWS = 25_000
"""Rows whose trend RUL quantiles are computed at once (their temporaries: some 45 arrays of
a row each at three levels)."""


# ----------------------------------------------------------------------------- schema
def _dialect(conn: Any) -> str:
    return str(getattr(conn, "dialect", "sqlite"))


def read_monitoring(meta: dict[str, str]) -> tuple[MonitoringRules, TrendConfig]:
    """The rules and trend settings stored in ``meta`` (defaults when absent)."""
    raw = meta.get(META_KEY)
    if raw is None:
        return MonitoringRules(), TrendConfig()
    d = json.loads(raw)
    return MonitoringRules.from_dict(d["rules"]), TrendConfig.from_dict(d["trend"])


def monitoring_meta(rules: MonitoringRules, trend: TrendConfig) -> tuple[str, str]:
    """The ``meta`` row of the rules and trend settings."""
    return META_KEY, json.dumps({"rules": rules.to_dict(), "trend": trend.to_dict()})


def write_monitoring(conn: Any, rules: MonitoringRules, trend: TrendConfig) -> None:
    """Store the rules (inside the caller's transaction)."""
    key, value = monitoring_meta(rules, trend)
    conn.execute("DELETE FROM meta WHERE key = ?", (key,))
    conn.execute("INSERT INTO meta VALUES (?, ?)", (key, value))


def needs_upgrade(conn: Any) -> bool:
    """Whether the database lacks a column of one RUL per component
    (:data:`~rulkit.fleet.store.schema.RUL_COLUMNS`; read, no lock taken)."""
    have = set(table_columns(conn, "components"))
    return any(c.name not in have for c in RUL_COLUMNS)


def upgrade(store: Any) -> bool:
    """Inside the caller's transaction: bring the database to the schema
    (:func:`~rulkit.fleet.store.schema.migrate`); when that added the columns of one RUL per
    component, store the rules in force (the defaults) and replay them (:func:`replay`).
    Returns whether it replayed."""
    conn = store._conn
    added = needs_upgrade(conn)
    migrate(conn, _dialect(conn))
    if added:
        if conn.execute("SELECT 1 FROM meta WHERE key = ?", (META_KEY,)).fetchone() is None:
            write_monitoring(conn, store.rules, store.trend)
        replay(store)
    return bool(added)


# ----------------------------------------------------------------------------- one batch
def current_estimator(store: Any) -> Estimator:
    """The estimator in force as the database says now (another process may have fitted a
    model or changed the rules since ``store`` was opened); the store's ``rules``, ``trend``
    and ``degradation`` are brought up to date."""
    rows = dict(store._conn.execute(
        "SELECT key, value FROM meta WHERE key IN (?, 'degradation_model')",
        (META_KEY,)).fetchall())
    store.rules, store.trend = read_monitoring(rows)
    if "degradation_model" in rows and getattr(store, "dialect", "sqlite") == "sqlite":
        from rulkit.fleet.learned.candidates import model_from_dict

        store.degradation = model_from_dict(json.loads(rows["degradation_model"]))
    return estimator_in_force(store.rules, store.config, store.degradation, store.trend)


@dataclass(frozen=True)
class BlockRows:
    """One block of a batch's rows (time order per component): the rules' rows, and the
    tracker's fHI per row (for the alerts)."""

    rules: RuleRows
    fhi: FloatArray


class BatchPrognosis:
    """The estimators and rules of one ingestion (inside its transaction): load the stored
    state of the batch's components ``names`` (or take it as ``stored``: the indices into
    ``names`` of the stored ones and their :data:`PROGNOSIS_COLUMNS`, float64 rows with NULL
    as NaN), run :meth:`block` over each block of components, :meth:`finish` gives the final
    columns and stores the model states."""

    def __init__(self, store: Any, names: list[str], t_last: FloatArray, hi_last: FloatArray,
                 n_last: NDArray[np.int64], calendar: bool, now: float | None = None,
                 seconds_per_unit: float = 1.0, installed: dict[str, float] | None = None,
                 stored: tuple[Any, np.ndarray] | None = None) -> None:
        self.store, self.names = store, names
        self.est = current_estimator(store)
        self.calendar = calendar
        self.seconds_per_unit = seconds_per_unit  # a calendar t in this many seconds
        self.now = time.time() if now is None else float(now)
        b = len(names)
        self.trend = TrendState(t=np.array(t_last, dtype=np.float64),
                                hi=np.array(hi_last, dtype=np.float64),
                                n=np.array(n_last, dtype=np.int64),
                                s=np.zeros((b, len(SUM_NAMES))))
        self.rule_state = RuleState.empty(b)
        self.seen = np.full(b, np.nan)
        if stored is None:
            stored = self._read(names)
        self._set_stored(*stored)
        self.learned = None
        if getattr(store, "degradation", None) is not None:
            from rulkit.fleet.store.learned_state import LearnedPass

            self.learned = LearnedPass(store._conn, store.degradation, names, installed)
        self.final = {k: np.full(b, np.nan) for k in ("rul_median", "rul_low", "rul_high")}
        self.level = np.zeros(b, dtype=np.int8)
        self.strategy: str | None = None  # trend_run's way (None: the cheapest per block)

    def _read(self, names: list[str]) -> tuple[list[int], np.ndarray]:
        """The stored :data:`PROGNOSIS_COLUMNS` of those of ``names`` in ``components``:
        (indices into ``names``, their rows as float64, NULL as NaN)."""
        got = list(rows_of_components(self.store._conn, "components", PROGNOSIS_COLUMNS,
                                      names))
        return [i for i, _ in got], np.array([row for _, row in got], dtype=np.float64
                                             ).reshape(len(got), len(PROGNOSIS_COLUMNS))

    def _set_stored(self, idx: Any, vals: np.ndarray) -> None:
        """Start components ``idx`` from their stored :data:`PROGNOSIS_COLUMNS` ``vals``
        (float64 rows, NULL as NaN; a NULL ``hits`` is 0)."""
        if not len(idx):
            return
        pos = np.asarray(idx, dtype=np.intp)
        self.rule_state.hits[pos] = np.nan_to_num(vals[:, 0], nan=0.0)
        self.rule_state.failed_at[pos] = vals[:, 1]
        self.rule_state.max_level[pos] = vals[:, 2]
        self.seen[pos] = vals[:, 3]
        self.trend.s[pos] = vals[:, 4:]

    def block(self, comps: np.ndarray, seg: np.ndarray, t: FloatArray, hi: FloatArray,
              tracker_rows: dict[str, np.ndarray]) -> BlockRows:
        """The rows of components ``comps`` (indices into ``names``; rows
        ``seg[c]:seg[c + 1]`` of each, in time order): the estimator's RUL per row, then the
        rules (RUL 0 once failed)."""
        est, levels = self.est, self.est.rules.levels
        new, rows = trend_run(self.trend.take(comps), seg, t, hi, est.trend,
                              strategy=self.strategy)
        for f in ("t", "hi", "n", "s"):
            getattr(self.trend, f)[comps] = getattr(new, f)
        learned = None
        if self.learned is not None:
            learned = self.learned.run(comps, seg, t, hi, levels)
        if est.kind == "model":
            assert learned is not None
            med, low, high = learned
        elif est.kind == "trend":
            med, low, high = _trend_quantiles(rows, est.trend, levels)
        else:
            med, low, high = tracker_rul_interval(tracker_rows["fhi"], tracker_rows["frul"],
                                                  est.tracker)
        sub = RuleState(hits=self.rule_state.hits[comps],
                        failed_at=self.rule_state.failed_at[comps],
                        max_level=self.rule_state.max_level[comps])
        new_rules, out = apply_rules(est.rules, seg, t, hi, med, low, high, sub)
        self.rule_state.hits[comps] = new_rules.hits
        self.rule_state.failed_at[comps] = new_rules.failed_at
        self.rule_state.max_level[comps] = new_rules.max_level
        last = seg[1:] - 1
        for k, v in (("rul_median", out.median), ("rul_low", out.low), ("rul_high", out.high)):
            self.final[k][comps] = v[last]
        self.level[comps] = out.level[last]
        self.seen[comps] = t[last] * self.seconds_per_unit if self.calendar else self.now
        return BlockRows(rules=out, fhi=np.asarray(tracker_rows["fhi"]))

    def finish(self, seen: FloatArray | None = None) -> dict[str, Any]:
        """:meth:`finish_arrays` as lists, NaN as None, ready for SQL."""
        return {k: _sql_list(v) for k, v in self.finish_arrays(seen).items()}

    def finish_arrays(self, seen: FloatArray | None = None) -> dict[str, np.ndarray]:
        """The columns of :data:`~rulkit.fleet.store.schema.RUL_COLUMNS` plus ``rul_low``,
        ``rul_high``, ``level`` and ``max_level`` per component of the batch (arrays, NaN
        where NULL); stores the fitted model's states. ``seen``: the calendar times of the
        last acquisitions (default: this batch's)."""
        if self.learned is not None:
            self.learned.finish()
        med, low, high = stored_interval(self.final["rul_median"], self.final["rul_low"],
                                         self.final["rul_high"])
        seen = self.seen if seen is None else seen
        cols: dict[str, Any] = {"rul_median": med, "rul_low": low, "rul_high": high,
                                "level": self.level, "max_level": self.rule_state.max_level,
                                "hits": self.rule_state.hits,
                                "failed_at": self.rule_state.failed_at, "seen": seen,
                                "due": due_time(seen, med, self.est.time_unit)}
        for j, c in enumerate(TREND_COLUMNS):
            cols[c] = self.trend.s[:, j]
        return cols


def _trend_quantiles(rows: TrendState, config: TrendConfig, levels: tuple[float, ...]
                     ) -> tuple[FloatArray, ...]:
    """The trend's RUL quantiles of every row of ``rows``, :data:`QUANTILE_ROWS` rows at a time
    (the same element-wise operations: the quantiles' temporaries of a slice, not of all)."""
    m = len(rows)
    out = tuple(np.empty(m) for _ in levels)
    for a in range(0, m, QUANTILE_ROWS):
        sl = slice(a, a + QUANTILE_ROWS)
        part = TrendState(t=rows.t[sl], hi=rows.hi[sl], n=rows.n[sl], s=rows.s[sl])
        for o, q in zip(out, rul_quantiles(trend_posterior(part, config), levels), strict=True):
            o[a:a + QUANTILE_ROWS] = q
    return out


def block_alerts(got: BlockRows, rules: MonitoringRules, unit: str, comps: list[str],
                 seg: np.ndarray, rank: np.ndarray, rows: np.ndarray, t: FloatArray,
                 hi: FloatArray) -> list[tuple[int, int, Alert]]:
    """The alerts of a block: rows whose level passes the highest the component reached
    before, as (acquisition rank, batch row, :class:`Alert`) for sorting."""
    from rulkit.fleet.store.acquisitions import Alert  # pandas: not for rulkit status

    r = got.rules
    out = []
    unit_of = np.repeat(np.arange(len(comps)), np.diff(seg))
    for q in np.flatnonzero(r.level > r.previous).tolist():
        level = int(r.level[q])
        out.append((int(rank[q]), int(rows[q]), Alert(
            component=comps[unit_of[q]], t=float(t[q]), level=level,
            previous=int(r.previous[q]), hi=float(hi[q]), rul=float(r.median[q]),
            rul_low=float(r.low[q]), rul_high=float(r.high[q]),
            reason=rules.alarm_text() if level == LEVEL_ALARM else rules.warning_text(unit),
            fhi=float(got.fhi[q]))))
    return out


def stored_interval(median: FloatArray, low: FloatArray, high: FloatArray
                    ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The RUL as stored: where there is no estimate (NaN median), the vacuous [0, inf)."""
    none = np.isnan(median)
    return median, np.where(none, 0.0, low), np.where(none, np.inf, high)


def _sql_list(v: np.ndarray) -> list[Any]:
    """Values for SQL: Python numbers, NaN as None (SQLite stores a bound NaN as NULL)."""
    a = np.asarray(v)
    out = a.tolist()
    if a.dtype.kind == "f":
        for i in np.flatnonzero(np.isnan(a)).tolist():
            out[i] = None
    return list(out)


# ----------------------------------------------------------------------------- replay
def _replay_names(conn: Any) -> list[tuple[str, int]]:
    rows = conn.execute("SELECT component, n FROM components ORDER BY component").fetchall()
    return [(str(c), int(n)) for c, n in rows]


def _chunks(names: list[tuple[str, int]]) -> list[list[str]]:
    out: list[list[str]] = [[]]
    size = 0
    for name, n in names:
        if out[-1] and size + n > REPLAY_ROWS:
            out.append([])
            size = 0
        out[-1].append(name)
        size += n
    return [c for c in out if c]


def replay(store: Any) -> int:
    """Inside the caller's transaction: every component's RUL columns and levels, in
    ``history`` and ``components``, and the trend and model states, recomputed by replaying
    its stored acquisitions through the estimator in force and the rules (alerts are not
    raised again). Returns the number of components replayed."""
    conn = store._conn
    names = _replay_names(conn)
    if store.degradation is not None:
        from rulkit.fleet.store.learned_state import ensure_model_state

        ensure_model_state(conn, store.degradation)
    for chunk in _chunks(names):
        _replay_chunk(store, chunk)
    recount_totals(conn)
    return len(names)


def _replay_chunk(store: Any, names: list[str]) -> None:
    conn = store._conn
    chunks, rec = history_chunks.read_components(conn, names)
    t, hi, fhi, frul = (np.ascontiguousarray(history_chunks.field(rec, f))
                        for f in ("t", "hi", "fhi", "frul"))
    pos = {n: i for i, n in enumerate(names)}
    counts = np.bincount([pos[c] for c, _, _ in chunks], weights=[k for _, _, k in chunks],
                         minlength=len(names)).astype(np.int64) if chunks else \
        np.zeros(len(names), dtype=np.int64)
    seg = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    b = len(names)
    empty = np.full(b, np.nan)
    prog = BatchPrognosis(store, names, empty, empty, np.zeros(b, dtype=np.int64),
                          calendar=False)
    prog.trend = TrendState.empty(b)
    prog.rule_state = RuleState(hits=np.zeros(b, dtype=np.int64), failed_at=np.full(b, np.nan),
                                max_level=np.zeros(b, dtype=np.int8))
    if prog.learned is not None:
        prog.learned.reset()
    seen = prog.seen.copy()
    out = prog.block(np.arange(b), seg, t, hi, {"fhi": fhi, "frul": frul}).rules
    final = prog.finish(seen)
    # the history's chunks rewritten with the new RUL columns and levels
    for f, v in zip(("rul_median", "rul_low", "rul_high"),
                    stored_interval(out.median, out.low, out.high), strict=True):
        history_chunks.field(rec, f)[:] = v
    history_chunks.field(rec, "level")[:] = out.level
    history_chunks.rewrite(conn, chunks, rec)
    cols = list(final)
    conn.executemany(
        f"UPDATE components SET {', '.join(f'{c} = ?' for c in cols)} WHERE component = ?",
        zip(*(final[c] for c in cols), names, strict=True))


__all__ = [
    "META_KEY",
    "PROGNOSIS_COLUMNS",
    "BatchPrognosis",
    "BlockRows",
    "block_alerts",
    "current_estimator",
    "monitoring_meta",
    "needs_upgrade",
    "read_monitoring",
    "replay",
    "stored_interval",
    "upgrade",
    "write_monitoring",
]
