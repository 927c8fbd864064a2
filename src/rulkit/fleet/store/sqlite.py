"""Persistent component state in SQLite: tracker state per component, history per acquisition.

docs/systems/embedded-rul.md §4 (the seed's "component state file" and "HI/RUL file"). One database
file holds

* ``meta``: schema version, the :class:`~rulkit.fleet.tracking.tracker_chain.TrackerConfig`
  (JSON) the database was created with and, optionally, the
  :class:`~rulkit.fleet.tracking.health_index.HealthIndexModel`
  that maps condition indicators (CIs) to HI;
* ``components``: one row per component with its tracker state (the seed's 7 numbers HI, fHI,
  dHI, RUL, fRUL, dRUL, d2RUL, plus the time of the last acquisition, the number of
  acquisitions and validity), and the one RUL of the estimator in force with the alert
  rules' level (:mod:`rulkit.fleet.store.prognosis`, docs/systems/embedded-rul.md §6-7);
* ``history``: the acquisitions (same fields), one row per component and write chunk, packed
  (:mod:`rulkit.fleet.store.history_chunks`), primary key (component, t_first);
* ``ingests``: one row per committed ingestion (audit).

Guarantees (tested in tests/fleet/store/test_sqlite.py):

* **Validation first.** A batch is validated completely (columns, NaN/inf, HI range, time
  order per component within the batch and against the stored state) before anything is
  written; a bad batch raises :class:`IngestError` naming the row, component and field, and the
  database stays as it was.
* **Transactional ingestion.** The whole batch is applied in one transaction
  (``BEGIN IMMEDIATE`` ... ``COMMIT``); any exception rolls it back, and a process killed
  mid-transaction leaves the last committed state (SQLite's write-ahead log is replayed or
  discarded on the next open). ``synchronous=FULL`` makes a commit durable.
* **Consistent readers.** The database runs in WAL mode: a reader inside a read transaction
  (:meth:`ComponentStore.snapshot`) sees one committed state, never a half-applied batch,
  while a writer proceeds.
* **Nothing created on rejection, atomic creation.** :func:`~rulkit.fleet.store.ingest.ingest_into`
  validates a batch before touching the database; a new database is built beside its final name
  (schema, settings and first batch in a temporary file) and linked into place only once complete,
  so a rejected batch creates nothing and concurrent first ingests never see a half-made file (the
  loser of the race applies its batch to the winner's database). The private temporary file is
  written without the write-ahead log and without syncs (one ``fsync`` before it is linked; WAL mode
  is switched on last), which nothing can observe.
* **Foreign files are never modified.** An existing file is checked read-only (SQLite header,
  ``meta`` table, schema version) before it is opened for writing; a 0-byte file, a
  non-SQLite file or an SQLite file of another application raises :class:`StoreError` and
  keeps its bytes. ``readonly=True`` (``rulkit status``) opens with SQLite's ``mode=ro``.
* **Busy, not broken.** A writer waits up to ``timeout`` seconds for another one to commit,
  then raises :class:`StoreBusyError` (nothing written; retry), never a raw ``sqlite3`` error.

Component ids (:func:`rulkit.fleet.rows.check_component_ids`): 1 to 128 printable
characters (:meth:`str.isprintable`: no control characters such as ESC, newline, tab, no
Unicode format characters such as bidirectional overrides), surrounding blanks stripped.
Anything else raises :class:`ComponentIdError` naming the row, so a crafted id cannot forge
terminal output; printing still goes through :func:`rulkit.tables.safe_text`.
"""

from __future__ import annotations

import json
import math
import sqlite3
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, nullcontext
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rulkit.fleet.monitoring.rules import MonitoringRules
from rulkit.fleet.monitoring.unit_trend import TrendConfig
from rulkit.fleet.store import history_chunks
from rulkit.fleet.store.acquisitions import (
    Alert,
    Batch,
    IngestResult,
    read_acquisitions,
    validate_acquisitions,
)
from rulkit.fleet.store.batch_groups import GroupCommits
from rulkit.fleet.store.batch_order import (
    ComponentOrder,
    check_spacing,
    gaps_after_stored,
    order_by_component,
    split_duplicates,
)
from rulkit.fleet.store.database_file import (
    StoreError,
    _config_from_meta,
    _degradation_from_meta,
    _meta_rows,
    creation_path,
    link_into_place,
    open_database,
    store_error,
    time_axis_from_meta,
)
from rulkit.fleet.store.history_stage import plan_pieces
from rulkit.fleet.store.prognosis import (
    PROGNOSIS_COLUMNS,
    BatchPrognosis,
    block_alerts,
    monitoring_meta,
    read_monitoring,
    stored_interval,
    upgrade,
)
from rulkit.fleet.store.schema import (
    add_level_counts,
    add_seen_counts,
    create_schema,
    needs_migration,
    table_columns,
)
from rulkit.fleet.store.state_cache import StateCache
from rulkit.fleet.store.store_settings import StoreSettings
from rulkit.fleet.store.tracker_rows import (
    HISTORY_FIELDS,
    ROW_FIELDS,
    TRACKER_OUT,
    StoredRows,
    component_rows,
    refuse_non_finite,
    stored_state,
)
from rulkit.fleet.store.writeback import EarlyWriteback
from rulkit.fleet.tracking.health_index import HealthIndexModel
from rulkit.fleet.tracking.tracker_chain import (
    LEVEL_NAMES,
    TrackerConfig,
    TrackerState,
    tracker_outputs,
)
from rulkit.fleet.tracking.tracker_run import tracker_run
from rulkit.tables import cell_repr as _fmt
from rulkit.tables import safe_text

if TYPE_CHECKING:  # pandas is imported by the reads that return frames, not by track
    import pandas as pd


def _return_freed_memory() -> None:
    """Give the C heap's free pages back to the system (glibc's ``malloc_trim``; nothing
    elsewhere). A batch's checks free arrays of 8 bytes per row that glibc keeps in its heap
    once its mmap threshold has grown; without this they stay resident through the blocks
    (docs/service-load.md, "Where track's 2M rows go")."""
    import ctypes

    try:
        ctypes.CDLL(None).malloc_trim(0)  # the process's own symbols
    except (OSError, AttributeError, TypeError):  # not glibc
        pass


def _of_components(ingest_id: Any, comps: np.ndarray) -> Any:
    """The ``ingests`` row of components ``comps``: the batch's one, or theirs of one per
    component (joined batches)."""
    return ingest_id if np.ndim(ingest_id) == 0 else ingest_id[comps]


ALERT_COLUMNS = ("component", "t", "level", "previous", "hi", "fhi", "rul", "valid", "rul_low",
                 "rul_high", "reason", "raised")
"""The columns of table ``alerts`` a new alert's row fills (:meth:`ComponentStore.
_record_alerts`)."""
_INSERT_ALERT = (f"INSERT INTO alerts ({', '.join(ALERT_COLUMNS)}) "
                 f"VALUES ({', '.join('?' * len(ALERT_COLUMNS))})")


def _finite(v: float) -> float | None:
    """``v``, or ``None`` (SQL NULL) when it is NaN or infinite."""
    return v if math.isfinite(v) else None



def _build_and_publish(path: Path, config: TrackerConfig, hi_model: HealthIndexModel | None,
                       acq: Batch | None, source: str,
                       rules: MonitoringRules | None = None) -> IngestResult | None:
    """Create the database in a temporary file beside ``path`` (schema, settings and, when
    given, the validated batch ``acq``), then hard-link it to ``path``, which fails if
    ``path`` appeared meanwhile. Returns the batch's result, or ``None`` when another process
    created ``path`` first (then nothing of ours is kept and the caller applies the batch to
    that database)."""
    tmp = creation_path(path)
    result: IngestResult | None = None
    writeback: EarlyWriteback | None = None
    try:
        try:
            conn = sqlite3.connect(str(tmp), isolation_level=None)
        except sqlite3.Error as err:
            raise StoreError(f"{path}: cannot create the database in {path.parent}: {err}"
                             ) from err
        try:
            # The file is private until linked into place (and deleted on any failure), so
            # it is built without a write-ahead log or syncs: an in-memory rollback journal
            # (ROLLBACK still works) and one fsync below. Writing the first batch through the
            # WAL wrote every page twice (log, then checkpoint): 1.1 s of 2M rows.
            # 16 KB pages, not SQLite's 4 KB: a batch's history is blobs of up to
            # HISTORY_CHUNK records, written and read in a quarter of the page calls
            conn.execute("PRAGMA page_size=16384")
            conn.execute("PRAGMA journal_mode=MEMORY")
            conn.execute("PRAGMA synchronous=OFF")
            # a page cache of 8 MB, not SQLite's 2 MB: a block's history (BLOCK_ROWS records
            # in overflow pages) is spilled to the file once, not in many small spills
            conn.execute("PRAGMA cache_size=-8192")
            conn.execute("BEGIN IMMEDIATE")
            create_schema(conn, "sqlite")
            conn.executemany("INSERT INTO meta VALUES (?, ?)", _meta_rows(config, hi_model))
            conn.execute("INSERT INTO meta VALUES (?, ?)",
                         monitoring_meta(rules or MonitoringRules(), TrendConfig()))
            conn.execute("COMMIT")
            if acq is not None:
                writeback = EarlyWriteback(tmp)  # the file's pages written while it grows
                writeback.start()
                store = ComponentStore.__new__(ComponentStore)
                store._attach(tmp, conn, config, hi_model, timeout=0.0)
                store.rules, store.trend = rules or MonitoringRules(), TrendConfig()
                with store._transaction("IMMEDIATE"):
                    result = store._ingest_in_transaction(acq, source)
            # WAL mode is recorded in the file: every later connection uses the log
            if conn.execute("PRAGMA journal_mode=WAL").fetchone()[0] != "wal":
                raise sqlite3.OperationalError("cannot switch the new database to WAL mode")
        except sqlite3.OperationalError as err:
            raise StoreError(f"{path}: cannot create the database in {path.parent}: {err}"
                             ) from err
        finally:
            conn.close()
            if writeback is not None:  # closed after SQLite's connection: its locks kept
                writeback.close()
        for side in ("-wal", "-shm"):
            Path(f"{tmp}{side}").unlink(missing_ok=True)
        return result if link_into_place(tmp, path) else None
    finally:
        for p in (tmp, Path(f"{tmp}-wal"), Path(f"{tmp}-shm"), Path(f"{tmp}-journal")):
            p.unlink(missing_ok=True)


class ComponentStore(GroupCommits, StoreSettings):
    """SQLite store of component tracker state and acquisition history (see module docstring).

    ``ComponentStore(path, config=None, hi_model=None)`` opens (creating if needed, atomically)
    the database. A new database stores ``config`` (default ``TrackerConfig()``) and
    ``hi_model``; opening an existing one with a different ``config`` or ``hi_model`` raises
    :class:`StoreError` (a ``ValueError``; the trackers' gains and state are only meaningful
    with the configuration they were run with). ``create=False`` refuses to create a missing
    database (``FileNotFoundError``); ``readonly=True`` opens an existing one read-only
    (implies ``create=False``). A file that is not a rulkit database raises
    :class:`StoreError` and is not modified. Use as a context manager or call :meth:`close`.
    """

    HISTORY_CHUNK = history_chunks.MAX_CHUNK
    """Acquisitions per history row at most (:mod:`rulkit.fleet.store.history_chunks`)."""
    BLOCK_ROWS = 25_000
    """Acquisitions per block of components run together: bounds the per-acquisition outputs
    and the RUL quantiles' temporaries held at once (about 500 bytes an acquisition at the peak of
    a block: the RUL quantiles of three levels hold some 15 arrays of every row)."""
    STATE_COLUMNS = (*ROW_FIELDS, *PROGNOSIS_COLUMNS)
    """The columns of a component's stored row a batch starts from (:meth:`_load_states`)."""
    WINDOW_ROWS = 100_000
    """Acquisitions per window of acquisition ranks of a wide batch
    (:func:`~rulkit.fleet.store.history_stage.plan_pieces`): the same bound, wider because its
    numpy steps cost per rank."""
    hi_model: HealthIndexModel | None
    _states: StateCache | None = None  # the rows this connection committed (keep_states)
    _ingesting = False  # inside ingest_many, which keeps _states up to date

    def __init__(
        self,
        path: str | Path,
        *,
        config: TrackerConfig | None = None,
        hi_model: HealthIndexModel | None = None,
        timeout: float = 30.0,
        create: bool = True,
        readonly: bool = False,
        rules: MonitoringRules | None = None,
    ) -> None:
        self.path = Path(path)
        create = create and not readonly
        opened = open_database(self.path, timeout=timeout, readonly=readonly)
        if opened is None:
            if not create:
                raise FileNotFoundError(f"{self.path}: no such database")
            _build_and_publish(self.path, config or TrackerConfig(), hi_model, None, "", rules)
            opened = open_database(self.path, timeout=timeout, readonly=readonly)
            assert opened is not None
        conn, meta = opened  # meta read through this connection: sees the write-ahead log
        try:
            stored_cfg, stored_model = _config_from_meta(self.path, meta)
            if config is not None and config != stored_cfg:
                raise StoreError(
                    f"{self.path} was created with tracker config {stored_cfg.to_dict()}; "
                    f"refusing to continue with a different one {config.to_dict()}"
                )
            if hi_model is not None and stored_model is not None and (
                    hi_model.to_dict() != stored_model.to_dict()):
                raise StoreError(f"{self.path} already holds a different HI model")
        except BaseException:
            conn.close()
            raise
        self._attach(self.path, conn, stored_cfg, stored_model, timeout)
        self.readonly = readonly
        try:
            self.degradation = _degradation_from_meta(self.path, meta)
            self.time_axis = time_axis_from_meta(self.path, meta)
            self.rules, self.trend = read_monitoring(meta)
        except (ValueError, TypeError, KeyError) as err:
            conn.close()
            raise StoreError(f"{self.path}: unreadable monitoring rules in table meta: "
                             f"{safe_text(err)}") from err
        except BaseException:
            conn.close()
            raise
        if not readonly and needs_migration(conn, "sqlite"):
            try:  # a database written by an older rulkit: new tables, columns, replayed RULs
                with self._transaction("IMMEDIATE"):
                    upgrade(self)
            except BaseException:
                conn.close()
                raise
        if rules is not None and rules != self.rules and not readonly:
            self.set_rules(rules)
        if hi_model is not None and stored_model is None:
            try:
                with self._transaction():
                    self._conn.execute("INSERT INTO meta VALUES ('hi_model', ?)",
                                       (json.dumps(hi_model.to_dict()),))
            except BaseException:
                self._conn.close()
                raise
            self.hi_model = hi_model

    def _attach(self, path: Path, conn: sqlite3.Connection, config: TrackerConfig,
                hi_model: HealthIndexModel | None, timeout: float) -> None:
        self.path = path
        self._conn = conn
        self.config = config
        self.hi_model = hi_model
        self.timeout = timeout
        self.readonly = False
        self.gains = config.gains()
        self.degradation = None  # learned model (rulkit fit), set from meta by __init__
        self.time_axis = None  # the time axis rulkit fit stored, set from meta by __init__
        self.rules, self.trend = MonitoringRules(), TrendConfig()  # set from meta by __init__
        self.now: float | None = None  # the calendar time of ingestion (None: the clock)
        self._states = None

    def keep_states(self, limit: int = 25_000) -> None:
        """Keep the ``components`` rows of the batches :meth:`ingest_many` commits in memory
        (at most ``limit`` components, a float64 row of :attr:`STATE_COLUMNS` and the name
        each, about 0.4 KB with the array's spare rows: 11 MB at the default; a fleet
        writing more components than that between two batches of a component reads them
        back, as without it) and start each next batch from them
        instead of reading them back, for as long as no other connection commits to the
        database (:class:`~rulkit.fleet.store.state_cache.StateCache`). Any other write
        through this store forgets them."""
        self._states = StateCache(self.STATE_COLUMNS, limit)

    def _data_version(self) -> int:
        """SQLite's ``PRAGMA data_version``: changes whenever another connection commits."""
        return int(self._conn.execute("PRAGMA data_version").fetchone()[0])

    @contextmanager
    def _group_transaction(self, keep: bool, sql: str | None
                           ) -> Iterator[tuple[int | None, list[tuple]]]:
        """A group commit's write transaction (:meth:`ingest_many`), yielding what is read at
        its start: the version the kept rows are checked against (``keep``; else ``None``)
        and the rows of the admission's query ``sql`` (none without it)."""
        with self._transaction("IMMEDIATE"):
            version = self._data_version() if keep else None
            yield version, ([] if sql is None else self._conn.execute(sql).fetchall())

    # -- plumbing
    def close(self) -> None:
        self._conn.close()

    def __enter__(self) -> ComponentStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextmanager
    def _transaction(self, mode: str = "IMMEDIATE") -> Iterator[sqlite3.Connection]:
        """``BEGIN mode`` ... ``COMMIT``, rolled back on any exception. SQLite errors become
        :class:`StoreBusyError` (another writer held the lock past the timeout) or
        :class:`StoreError` (corrupt file, disk full, read-only), with the path."""
        if self._states is not None and mode != "DEFERRED" and not self._ingesting:
            self._states.drop()  # a write the kept rows do not follow
        try:
            self._conn.execute(f"BEGIN {mode}")
        except sqlite3.Error as err:
            raise self._error(err) from err
        try:
            yield self._conn
        except BaseException as exc:
            if self._conn.in_transaction:
                self._conn.execute("ROLLBACK")
            if isinstance(exc, sqlite3.Error):
                raise self._error(exc) from exc
            raise
        else:
            try:
                self._conn.execute("COMMIT")
            except sqlite3.Error as err:
                if self._conn.in_transaction:
                    self._conn.execute("ROLLBACK")
                raise self._error(err) from err

    def _error(self, err: sqlite3.Error) -> StoreError:
        return store_error(self.path, err, self.timeout)

    @contextmanager
    def snapshot(self) -> Iterator[sqlite3.Connection]:
        """A read transaction: every query inside sees the same committed state."""
        with self._transaction("DEFERRED") as conn:
            yield conn

    # -- reading
    def _load_states(self, names: list[str]) -> StoredRows:
        """The stored rows (:attr:`STATE_COLUMNS`) of the components ``names`` that are
        stored: those :meth:`keep_states` kept, the others read."""
        parts = []
        if self._states is not None:
            kept, names = self._states.split(names)
            parts.append(kept)
        cols = ", ".join(("component", *self.STATE_COLUMNS))
        read: list[tuple] = []
        for i in range(0, len(names), 500):
            chunk = names[i : i + 500]
            q = f"SELECT {cols} FROM components WHERE component IN ({','.join('?' * len(chunk))})"
            read += self._conn.execute(q, chunk).fetchall()
        parts.append(StoredRows.of_tuples(read, len(self.STATE_COLUMNS)))
        return StoredRows.joined(parts)

    def _query(self, sql: str, params: tuple = ()) -> pd.DataFrame:
        import pandas as pd

        with self.snapshot() as conn:
            try:
                return pd.read_sql_query(sql, conn, params=params)
            except sqlite3.Error as err:
                raise self._error(err) from err
            except Exception as err:  # pandas wraps the driver's errors
                cause = err.__cause__ if isinstance(err.__cause__, sqlite3.Error) else None
                if cause is not None:
                    raise self._error(cause) from err
                raise StoreError(f"{self.path}: cannot be read: {safe_text(err)}") from err

    def _checked(self, df: pd.DataFrame, table: str) -> pd.DataFrame:
        """Refuse rows rulkit cannot have written (text in a number column, an unknown alert
        level), naming the table, component and column, instead of failing later."""
        import pandas as pd

        for col in df.columns:
            if col == "component":
                continue
            num = df[col]
            if num.dtype.kind not in "fiub":  # text or NULL among numbers: coerce and flag
                num = pd.to_numeric(num, errors="coerce")
            bad = num.isna().to_numpy().copy()
            if col == "level":
                bad |= ~num.isin(list(LEVEL_NAMES)).to_numpy()
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise StoreError(
                    f"{self.path}: table {table}, component "
                    f"{safe_text(df['component'].iloc[i], 60)!r}: column {col!r} holds "
                    f"{_fmt(df[col].iloc[i])}, not "
                    + ("an alert level 0, 1 or 2" if col == "level" else "a number")
                    + f" ({int(bad.sum())} such row(s); not written by rulkit?)")
            df[col] = num
        df["component"] = df["component"].astype(str)
        df["valid"] = df["valid"].astype(bool)
        if "level" in df:
            df["level"] = df["level"].astype(np.int64)
        return df

    def status(self) -> pd.DataFrame:
        """All components, worst first (alert level, then RUL median ascending, one not
        estimated yet as 1e308, then id): the tracker chain's columns and the RUL and rules' columns
        ``rul_median``, ``failed_at``, ``seen`` (NaN where NULL; docs/systems/embedded-rul.md
        §6-7)."""
        import pandas as pd

        nullable = ("rul_median", "failed_at", "seen")
        df = self._query("SELECT component, " + ", ".join((*ROW_FIELDS, *nullable))
                         + " FROM components")
        extra = {c: pd.to_numeric(df.pop(c), errors="coerce") for c in nullable}
        df = self._checked(df, "components").assign(**extra)
        return df.assign(_key=df["rul_median"].fillna(1e308)).sort_values(
            ["level", "_key", "component"], ascending=[False, True, True],
            kind="stable").drop(columns="_key").reset_index(drop=True)

    def history(self, component: str | None = None) -> pd.DataFrame:
        """History rows (all components, or one), ordered by component and time: the tracker
        chain's columns, and the RUL of the estimator in force, ``rul_median`` (NaN: not
        estimated yet) in ``rul_low``/``rul_high``, with the rules' ``level``
        (docs/systems/embedded-rul.md §6-7)."""
        import pandas as pd

        with self.snapshot() as conn:
            if history_chunks.is_row_history(table_columns(conn, "history")):
                raise StoreError(f"{self.path}: its history has one row per acquisition, the "
                                 "layout of an older rulkit; open it for writing once (e.g. "
                                 "'rulkit track' or 'rulkit serve') to convert it")
            try:
                comp, ingest, rec = history_chunks.read_all(conn, component)
            except history_chunks.LayoutError as err:
                raise StoreError(f"{self.path}: table history: {err}") from err
            except sqlite3.Error as err:
                raise self._error(err) from err
        df = pd.DataFrame({"component": comp, **{
            f: history_chunks.field(rec, f) for f in HISTORY_FIELDS}, "ingest": ingest})
        df = self._checked(df, "history")
        df["rul_median"] = history_chunks.field(rec, "rul_median")
        return df

    def counts(self) -> tuple[int, int, int]:
        """(components, sum of their acquisition counts, history rows), in one snapshot."""
        with self.snapshot() as conn:
            n_comp, n_sum = conn.execute(
                "SELECT COUNT(*), COALESCE(SUM(n), 0) FROM components").fetchone()
            n_hist = history_chunks.count(conn)
        return int(n_comp), int(n_sum), n_hist

    # -- writing
    def ingest_file(self, path: str | Path) -> IngestResult:
        """Read a CSV/Parquet batch and :meth:`ingest` it."""
        return self.ingest(read_acquisitions(path), source=str(path))

    def ingest(self, df: pd.DataFrame, source: str = "<dataframe>") -> IngestResult:
        """Validate and apply a batch of acquisitions in one transaction.

        Acquisitions of the same component are applied in time order
        (:func:`~rulkit.fleet.tracking.tracker_run.tracker_run`: the same numbers as one
        :func:`~rulkit.fleet.tracking.tracker_chain.tracker_update` per acquisition). Returns the
        committed result with the new alerts (:class:`Alert`). Raises :class:`IngestError`
        (database unchanged) on bad input.
        """
        acq = validate_acquisitions(df, self.config, self.hi_model, self.time_axis)
        return self._ingest_validated(acq, source)

    def _ingest_validated(self, acq: Batch, source: str,
                          new_model: HealthIndexModel | None = None) -> IngestResult:
        """The one ingestion path (``rulkit track`` and the service): one validated batch in
        one write transaction (:meth:`_ingest_in_transaction`)."""
        with self._transaction("IMMEDIATE"):
            if new_model is not None:
                self._conn.execute("INSERT INTO meta VALUES ('hi_model', ?)",
                                   (json.dumps(new_model.to_dict()),))
            res = self._ingest_in_transaction(acq, source)
        if new_model is not None:
            self.hi_model = new_model
        return res

    def _ingest_in_transaction(self, acq: Batch, source: str) -> IngestResult:
        """Inside the caller's write transaction: skip the rows already stored
        (:func:`~rulkit.fleet.store.batch_order.split_duplicates`; a contradiction raises
        :class:`ConflictError`), run and store the trackers (:meth:`_apply`) and record the new
        alerts in table ``alerts`` with their ids."""
        stored = self._load_states(acq.names)
        acq, n_dup = split_duplicates(self._conn, acq, stored.last_t())
        if len(acq):
            res = self._apply(acq, source, stored)
        else:
            res = IngestResult(n_rows=0, n_components=0, n_new_components=0)
        alerts = self._record_alerts(res.alerts)
        return replace(res, alerts=alerts, n_duplicates=n_dup)

    def _record_alerts(self, alerts: list[Alert]) -> list[Alert]:
        """Insert ``alerts`` into table ``alerts`` (inside the caller's transaction); the
        same alerts with their ids and the time they were raised (the ingestion's calendar
        time ``now``, default the clock)."""
        now = time.time() if self.now is None else self.now
        rows = [(a.component, a.t, a.level, a.previous, _finite(a.hi), _finite(a.fhi),
                 _finite(a.rul), math.isfinite(a.rul), _finite(a.rul_low),
                 _finite(a.rul_high), a.reason, now) for a in alerts]
        ids = self._insert_alerts(rows) if rows else []
        return [replace(a, id=i, raised=now) for a, i in zip(alerts, ids, strict=True)]

    def _insert_alerts(self, rows: list[tuple]) -> list[int]:
        """Insert alert rows ``ALERT_COLUMNS``; their ids, in order (backend hook). SQLite
        numbers a row one above the table's largest id while that stays below the largest
        integer: the rows of one statement take consecutive ids; past it, one insert each."""
        top = self._conn.execute("SELECT max(id) FROM alerts").fetchone()[0] or 0
        if top + len(rows) < 2**63 - 1:
            self._conn.executemany(_INSERT_ALERT, rows)
            return list(range(top + 1, top + 1 + len(rows)))
        return [int(self._conn.execute(f"{_INSERT_ALERT} RETURNING id", r).fetchone()[0])
                for r in rows]

    def _apply(self, acq: Batch, source: str, stored: StoredRows | None = None,
               ingest_ids: np.ndarray | None = None) -> IngestResult:
        """Run the trackers over a validated batch and write history and states (inside the
        caller's transaction). ``stored``: the batch's stored component rows
        (:meth:`_load_states`), read here when not given.

        The rows are processed in pieces
        (:func:`~rulkit.fleet.store.history_stage.plan_pieces`): blocks of consecutive components
        in SQLite's key order (BINARY collation: UTF-8 byte order = code point order =
        Python's str order) of at most :attr:`BLOCK_ROWS` acquisitions, or, for a wide
        batch, windows of consecutive acquisition ranks of every component. Each piece runs
        :func:`~rulkit.fleet.tracking.tracker_run.tracker_run` over its components' rows
        (equal to one vectorised update per acquisition rank), the state carried from piece
        to piece, and writes its history in key order, a chunk of at most
        :attr:`HISTORY_CHUNK` rows per component and piece (appended to the table's rowids;
        its key index takes the order), so only one piece's outputs are held. Memory and
        time are linear in the batch.
        """
        codes = acq.codes.astype(np.int32, copy=False)  # 4 bytes less per acquisition
        names = acq.names
        if stored is None:
            stored = self._load_states(names)
        state, known, stored_vals = stored_state(names, stored)
        t, rows_all = acq.t, acq.row
        n, b = len(acq), len(names)
        # rows grouped by component in key order, batch order (= time order) inside; the
        # spacing check sees every interval, in batch order
        order = order_by_component(codes, names)
        sorted_pos = order.sorted_pos
        check_spacing(self.config, gaps_after_stored(order, t, rows_all, names,
                                                     state.t[sorted_pos]))
        ingest_id: Any = ingest_ids  # per component (joined batches), or this batch's row
        if ingest_ids is None:
            ingest_id = self._insert_ingest(source, n, b)
        # the RUL of the estimator in force and the alert rules (rulkit.fleet.monitoring), per
        # block below; the history holds them in rul_median / rul_low / rul_high and level
        inst = None
        if acq.installed is not None:  # each component's install time (its first row's)
            inst = dict(zip(names, acq.installed[acq.first_rows()].tolist(), strict=True))
        k_row = len(ROW_FIELDS)
        prog = BatchPrognosis(self, names, state.t, state.hi, state.n,
                              calendar=acq.calendar, now=self.now,
                              seconds_per_unit=acq.seconds_per_unit, installed=inst,
                              stored=(known, stored_vals[:, k_row:]))
        del codes
        if n > self.BLOCK_ROWS:
            _return_freed_memory()  # the checks' arrays, before the pieces
        alerts = self._run_pieces(acq, order, state, prog, ingest_id)
        alerts.sort(key=lambda a: (a[0], a[1]))  # by acquisition rank, then batch position
        self._write_final(names, state, prog, known, stored_vals)
        return IngestResult(n_rows=n, n_components=b, n_new_components=b - len(known),
                            alerts=[a for _, _, a in alerts])

    def _write_final(self, names: list[str], state: TrackerState, prog: BatchPrognosis,
                     known: np.ndarray, stored_vals: np.ndarray) -> None:
        """The batch's ``components`` rows from the trackers' final ``state`` and ``prog``'s
        final columns: an ``UPDATE`` of the stored ones (``known``, indices into ``names``,
        their stored rows ``stored_vals``), the upsert of the new ones, kept by
        :meth:`keep_states` and counted by level and last-seen window."""
        fin = tracker_outputs(state, self.config)
        prog_cols = prog.finish_arrays()
        cols = {**state.columns(), "valid": fin.valid, **prog_cols}
        write = (*ROW_FIELDS, "max_level", *(c for c in prog_cols if c not in ROW_FIELDS
                                             and c != "max_level"))
        values = np.column_stack([cols[c] for c in write]).astype(np.float64, copy=False)
        if self._states is not None and self._ingesting:
            self._states.put(names, values[:, [write.index(c) for c in self.STATE_COLUMNS]])
        self._write_components(names, values, write, tuple(prog_cols), known)
        add_level_counts(self._conn, stored_vals[:, ROW_FIELDS.index("level")], cols["level"])
        add_seen_counts(self._conn, stored_vals[:, len(ROW_FIELDS) + PROGNOSIS_COLUMNS.index(
            "seen")], cols["seen"])

    def _write_components(self, names: list[str], values: np.ndarray, columns: tuple[str, ...],
                          nullable: tuple[str, ...], known: np.ndarray) -> None:
        """The batch's ``components`` rows ``values`` (a float64 row per name, a column per
        name of ``columns``, ``ROW_FIELDS`` and ``max_level`` first; NaN is NULL in the
        ``nullable`` ones): an ``UPDATE`` of the stored ones (``known``, indices into
        ``names``) first, so the new ones' rowids follow batch order, then the upsert of the
        new ones (backend hook; :func:`~rulkit.fleet.store.tracker_rows.component_rows`)."""
        extra = columns[len(ROW_FIELDS) + 1:]
        if known.size:
            self._update_states(component_rows([names[i] for i in known.tolist()],
                                               values[known], columns, nullable,
                                               key_last=True), extra)
        fresh = np.ones(len(names), dtype=bool)
        fresh[known] = False
        new = np.flatnonzero(fresh)  # np.setdiff1d's, without its import of numpy.ma
        if new.size:
            self._write_states(component_rows([names[i] for i in new.tolist()], values[new],
                                              columns, nullable), extra)

    def _run_pieces(self, acq: Batch, order: ComponentOrder, state: TrackerState,
                    prog: BatchPrognosis, ingest_id: Any) -> list[tuple[int, int, Alert]]:
        """The trackers, the estimator, the rules and the history of every piece of the
        batch (:func:`~rulkit.fleet.store.history_stage.plan_pieces`), the trackers' ``state``
        (and ``prog``'s) carried from piece to piece; the alerts as (acquisition rank, batch
        row, :class:`Alert`). ``ingest_id``: the batch's ``ingests`` row, or one per component
        (joined batches)."""
        t, hi, rows_all, names = acq.t, acq.hi, acq.row, acq.names
        names_arr = np.array(names, dtype=object)
        sorted_pos = order.sorted_pos
        alerts: list[tuple[int, int, Alert]] = []
        pieces, strategy, prog.strategy, stage = plan_pieces(
            order, len(acq), self.BLOCK_ROWS, self.WINDOW_ROWS,
            self.path.parent if isinstance(self.path, Path) else None)
        with stage if stage is not None else nullcontext():
            for piece in pieces:
                comps = sorted_pos[piece.keys]  # component indices (into names / state)
                seg, rows_b = piece.seg, piece.rows
                cidx = np.repeat(np.arange(comps.size), np.diff(seg))  # piece-local component
                t_b, hi_b = t[rows_b], hi[rows_b]
                sub, out = tracker_run(state.take(comps), seg, t_b, hi_b, self.config,
                                       self.gains, strategy=strategy)
                rank_b = np.arange(rows_b.size) - seg[cidx] + piece.rank0
                comp_b = names_arr[comps][cidx]
                refuse_non_finite(out, rank_b, rows_all[rows_b], comp_b, t_b)
                # the RUL and the rules' level per row; alerts where the level passes the
                # highest the component reached before (latched)
                got = prog.block(comps, seg, t_b, hi_b, out)
                alerts += block_alerts(got, self.rules, prog.est.time_unit,
                                       [names[c] for c in comps], seg, rank_b, rows_b, t_b, hi_b)
                for f in ("t", "n", "hi", "ab", "rul", "abg"):
                    getattr(state, f)[comps] = getattr(sub, f)
                rec = self._block_records(t_b, hi_b, out, got)
                if stage is None:
                    self._write_block_history(names_arr[comps], seg, rec,
                                              _of_components(ingest_id, comps))
                else:
                    stage.add(piece, rec)
                del rank_b, cidx, comp_b, out, t_b, hi_b, got, rows_b, seg, piece, rec
            if stage is not None:  # the windows' history, one chunk per component
                for k0, k1, chunks in stage.blocks(self.BLOCK_ROWS, self.HISTORY_CHUNK):
                    self._write_history(chunks.rows(
                        names_arr[sorted_pos[k0:k1]], _of_components(ingest_id,
                                                                     sorted_pos[k0:k1])))
        return alerts

    @staticmethod
    def _block_records(t: np.ndarray, hi: np.ndarray, out: dict[str, np.ndarray],
                       got: Any) -> np.ndarray:
        """The history records of a piece's rows: the tracker's ``out``, the rules' level and
        the stored RUL interval of ``got`` (:func:`history_chunks.records`)."""
        med, low, high = stored_interval(got.rules.median, got.rules.low, got.rules.high)
        return history_chunks.records({
            "t": t, "hi": hi, **{f: out[f] for f in TRACKER_OUT[:6]}, "valid": out["valid"],
            "level": got.rules.level, "rul_low": low, "rul_high": high, "rul_median": med},
            t.size)

    def _write_block_history(self, names: np.ndarray, seg: np.ndarray, rec: np.ndarray,
                             ingest_id: Any) -> None:
        """The history of one block (component ``names[i]`` owns records
        ``rec[seg[i]:seg[i + 1]]``, key order, time order inside), packed in rows of at most
        :attr:`HISTORY_CHUNK` acquisitions."""
        self._write_history(history_chunks.chunk_rows(names, seg, rec, ingest_id,
                                                      self.HISTORY_CHUNK))

    def _insert_ingests(self, rows: list[tuple[str, int, int]]) -> list[int]:
        """Record ingestions ``(source, n_rows, n_components)`` (audit rows); their ids, in
        order (backend hook)."""
        return [self._insert_ingest(*r) for r in rows]

    def _insert_ingest(self, source: str, n_rows: int, n_components: int) -> int:
        """Record one ingestion (audit row) and return its id (backend hook)."""
        cur = self._conn.execute(
            "INSERT INTO ingests (source, n_rows, n_components) VALUES (?, ?, ?)",
            (source, n_rows, n_components),
        )
        assert cur.lastrowid is not None
        return int(cur.lastrowid)

    def _write_history(self, rows: list[tuple]) -> None:
        """Insert packed history rows ``(component, t_first, t_last, n, ingest, data)``
        (backend hook)."""
        history_chunks.write_chunks(self._conn, rows)

    def _update_states(self, rows: Sequence[Sequence[Any]], extra_cols: tuple[str, ...] = ()
                       ) -> None:
        """Update stored component rows ``(*ROW_FIELDS, max_level, *extra_cols, component)``
        (cheaper than the upsert: no insert tried first; backend hook). A row that is not
        stored raises :class:`StoreError` (the write transaction is then rolled back), never
        a row lost in silence."""
        sets = ", ".join(f"{c} = ?" for c in (*ROW_FIELDS, "max_level", *extra_cols))
        cur = self._conn.executemany(f"UPDATE components SET {sets} WHERE component = ?", rows)
        if isinstance(self._conn, sqlite3.Connection) and cur.rowcount != len(rows):
            raise StoreError(f"{self.path}: {len(rows) - cur.rowcount} of the batch's "
                             "components read as stored are not in table components")

    def _write_states(self, rows: Sequence[Sequence[Any]], extra_cols: tuple[str, ...] = ()
                      ) -> None:
        """Upsert component rows ``(component, *ROW_FIELDS, max_level, *extra_cols)``."""
        cols = ("component", *ROW_FIELDS, "max_level", *extra_cols)
        updates = ", ".join(f"{c} = excluded.{c}" for c in cols[1:])
        self._conn.executemany(
            f"INSERT INTO components ({', '.join(cols)}) VALUES ({', '.join('?' * len(cols))}) "
            f"ON CONFLICT(component) DO UPDATE SET {updates}",
            rows,
        )

    def meta(self) -> dict[str, Any]:
        """The stored configuration (tracker config and HI model as dicts)."""
        return {"tracker_config": self.config.to_dict(),
                "hi_model": self.hi_model.to_dict() if self.hi_model else None}
