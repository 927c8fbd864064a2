"""Second storage backend of the component store: PostgreSQL, and :func:`open_store`.

docs/systems/embedded-rul.md §4 (the component state and history store). :class:`PgComponentStore`
is :class:`~rulkit.fleet.store.sqlite.ComponentStore` with its plumbing (connection, schema,
transactions, queries that used pandas' SQLite reader) replaced for PostgreSQL; the
validation, the vectorised tracker update and the alert logic are the SQLite store's own code,
so both backends give the same numbers and the same errors.

Guarantees, as for SQLite (tested against both in tests/fleet/store/test_postgres.py):

* **Validation first**: :func:`~rulkit.fleet.store.sqlite.validate_acquisitions` runs before any
  statement is sent.
* **One transaction per batch**: ``BEGIN`` ... ``COMMIT``; any exception (or a dropped
  connection: PostgreSQL aborts a transaction whose client went away) rolls it back.
* **Concurrent writers**: each write transaction first takes one transaction-level advisory
  lock, so writers queue like SQLite's ``BEGIN IMMEDIATE`` and a batch always sees the state
  the previous batch committed (no lost update, no duplicated history row; the history primary
  key (component, t) is the backstop).
* **Consistent readers**: :meth:`snapshot` is a ``REPEATABLE READ READ ONLY`` transaction.
* **Kept rows** (:meth:`PgComponentStore.keep_states`, the service's writer): trusted only
  while nobody else wrote ``components``. A statement-level trigger on ``components`` counts
  every statement that writes it, whoever runs it, in the one row of :data:`WRITES`; the
  writer locks that row (``FOR UPDATE``) at the start of each write transaction, so the
  count it reads is final until its commit, and compares it with the count it read back
  before its own last commit: any difference, and the kept rows are dropped.

``psycopg`` (the ``service`` extra) is imported only when a ``postgresql://`` URL is opened.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from rulkit.fleet.monitoring.rules import MonitoringRules
from rulkit.fleet.monitoring.unit_trend import TrendConfig
from rulkit.fleet.store import history_chunks
from rulkit.fleet.store.database_file import (
    SCHEMA_VERSION,
    StoreError,
    _degradation_from_meta,
    is_postgres_url,
    time_axis_from_meta,
)
from rulkit.fleet.store.pg_copy import binary_rows, binary_tuples
from rulkit.fleet.store.prognosis import monitoring_meta, read_monitoring, upgrade
from rulkit.fleet.store.schema import (
    ALERTS,
    COMPONENTS,
    HISTORY,
    INGESTS,
    create_schema,
    needs_migration,
)
from rulkit.fleet.store.sqlite import ALERT_COLUMNS, ComponentStore
from rulkit.fleet.store.state_cache import StateCache
from rulkit.fleet.store.tracker_rows import ROW_FIELDS, StoredRows
from rulkit.fleet.tracking.health_index import HealthIndexModel
from rulkit.fleet.tracking.tracker_chain import TrackerConfig

# Key of the advisory lock that serialises writers (any fixed 64-bit number; "rulkit" in ASCII).
WRITE_LOCK_KEY = 0x72756C6B6974
_BINARY_TYPES = {"key": "text", "text": "text", "real": "float8", "int": "int8",
                 "small": "int2", "bool": "bool", "blob": "bytea"}
"""PostgreSQL's type of each column kind of :mod:`rulkit.fleet.store.schema`, as binary COPY
sends it (the column's own type: binary COPY converts nothing)."""
WRITES = "rulkit_writes"
"""The table of one row ``n``: the statements that wrote ``components`` so far (counted by
the trigger ``components_written``; made by :meth:`PgComponentStore.keep_states`)."""
STAGING = "components_in"
"""The temporary table a write's ``components`` rows are copied into before their upsert
(one per connection, made before its first write transaction; emptied at every commit, and
before a second write of the same transaction)."""


@lru_cache(maxsize=256)
def _pg_sql(sql: str) -> str:
    """The store's qmark SQL in psycopg's format style (the store's SQL has no literals)."""
    return sql.replace("%", "%%").replace("?", "%s")


class PgConnection:
    """The slice of ``sqlite3.Connection`` the store uses, over a psycopg connection."""

    dialect = "postgresql"

    def __init__(self, raw: Any) -> None:
        self.raw = raw
        self.staging = False  # STAGING made on this connection
        self.staged = False  # rows copied into STAGING since the last commit or rollback

    def execute(self, sql: str, params: Any = ()) -> Any:
        cur = self.raw.cursor()
        cur.execute(_pg_sql(sql), tuple(params) if params else None)
        return cur

    def executemany(self, sql: str, rows: Any) -> Any:
        cur = self.raw.cursor()
        cur.executemany(_pg_sql(sql), rows)
        return cur

    def copy_binary(self, table: str, columns: tuple[str, ...], types: list[str],
                    rows: Any) -> None:
        """``rows`` into ``table``'s ``columns`` by one ``COPY ... FROM STDIN (FORMAT
        BINARY)``: every value sent as the bits of its column's type (a float8 as its 8 bytes,
        so stored exactly as given), no statement per row."""
        with self.raw.cursor() as cur, cur.copy(
                f"COPY {table} ({', '.join(columns)}) FROM STDIN (FORMAT BINARY)") as copy:
            copy.set_types(types)
            for row in rows:
                copy.write_row(row)

    def copy_data(self, table: str, columns: tuple[str, ...], data: bytes) -> None:
        """Binary ``COPY`` data ``data`` (header and trailer included:
        :func:`~rulkit.fleet.store.pg_copy.binary_rows`) into ``table``'s ``columns``."""
        with self.raw.cursor() as cur, cur.copy(
                f"COPY {table} ({', '.join(columns)}) FROM STDIN (FORMAT BINARY)") as copy:
            copy.write(data)

    def close(self) -> None:
        self.raw.close()


def _connect_pg(url: str, timeout: float) -> PgConnection:
    try:
        import psycopg
    except ImportError as err:  # pragma: no cover - depends on the installed extras
        raise RuntimeError("PostgreSQL needs psycopg: pip install 'rulkit[service]'") from err
    try:
        raw = psycopg.connect(url, autocommit=True, connect_timeout=max(1, int(timeout)))
    except psycopg.OperationalError as err:
        # the message names host and port, never the password (libpq does not echo it)
        raise ConnectionError(f"cannot connect to PostgreSQL: {str(err).strip()}") from None
    return PgConnection(raw)


class PgComponentStore(ComponentStore):
    """:class:`~rulkit.fleet.store.sqlite.ComponentStore` on PostgreSQL (see module docstring).

    ``PgComponentStore(url, config=None, hi_model=None, create=True)``: same contract as the
    SQLite store; ``url`` is a libpq URL ``postgresql://user@host:port/dbname``.
    """

    dialect = "postgresql"

    _conn: Any  # a PgConnection: sqlite3-like execute/executemany/close over psycopg
    _opened: list[list[tuple]]  # the rows of the reads begun with the write transaction

    def __init__(
        self,
        url: str,
        *,
        config: TrackerConfig | None = None,
        hi_model: HealthIndexModel | None = None,
        timeout: float = 30.0,
        create: bool = True,
        rules: MonitoringRules | None = None,
    ) -> None:
        # for messages only (never holds a password); a str, since Path would fold the "//"
        self.path = _redact(url)  # type: ignore[assignment]
        self.url = url
        self.timeout = timeout
        self.readonly = False
        self._conn = _connect_pg(url, timeout)  # type: ignore[assignment]
        try:
            with self._transaction("IMMEDIATE"):  # creation under the writers' lock: atomic
                meta = self._read_meta()
                if "schema_version" not in meta:
                    if not create:
                        raise FileNotFoundError(f"{self.path}: not a rulkit component database")
                    create_schema(self._conn, "postgresql")
                    cfg = config or TrackerConfig()
                    rows = [("schema_version", str(SCHEMA_VERSION)),
                            ("tracker_config", json.dumps(cfg.to_dict())),
                            monitoring_meta(rules or MonitoringRules(), TrendConfig())]
                    if hi_model is not None:
                        rows.append(("hi_model", json.dumps(hi_model.to_dict())))
                    self._conn.executemany("INSERT INTO meta VALUES (?, ?)", rows)
                    meta = dict(rows)
            if int(meta["schema_version"]) != SCHEMA_VERSION:
                raise StoreError(f"{self.path}: schema version {meta['schema_version']}, "
                                 f"this rulkit reads {SCHEMA_VERSION}")
            self.config = TrackerConfig.from_dict(json.loads(meta["tracker_config"]))
            self.hi_model = (HealthIndexModel.from_dict(json.loads(meta["hi_model"]))
                             if "hi_model" in meta else None)
            self.degradation = _degradation_from_meta(self.path, meta)  # type: ignore[arg-type]
            self.time_axis = time_axis_from_meta(self.path, meta)  # type: ignore[arg-type]
            self.rules, self.trend = read_monitoring(meta)
            self.now: float | None = None
            if config is not None and config != self.config:
                raise StoreError(
                    f"{self.path} was created with tracker config {self.config.to_dict()}; "
                    f"refusing to continue with a different one {config.to_dict()}"
                )
            if hi_model is not None and (
                self.hi_model is None or hi_model.to_dict() != self.hi_model.to_dict()
            ):
                if self.hi_model is not None:
                    raise StoreError(f"{self.path} already holds a different HI model")
                with self._transaction():
                    self._conn.execute("INSERT INTO meta VALUES ('hi_model', ?)",
                                       (json.dumps(hi_model.to_dict()),))
                self.hi_model = hi_model
            self.gains = self.config.gains()
            if needs_migration(self._conn, "postgresql"):  # written by an older rulkit
                with self._transaction():
                    upgrade(self)
            if rules is not None and rules != self.rules:
                self.set_rules(rules)
        except BaseException:
            self._conn.close()
            raise

    def keep_states(self, limit: int = 25_000) -> None:
        """Keep the ``components`` rows of the batches :meth:`ingest_many` commits, as on
        SQLite (:meth:`ComponentStore.keep_states`), for as long as the write counter
        (:data:`WRITES`, made here when missing) says that nobody else wrote ``components``
        since this connection's last commit (module docstring). A role that may not make the
        counter (not the owner of ``components``) keeps nothing: every batch reads its rows."""
        import psycopg

        try:
            with self._transaction("IMMEDIATE"):
                _count_writes(self._conn)
        except psycopg.errors.InsufficientPrivilege:
            return
        self._states = StateCache(self.STATE_COLUMNS, limit, signed_zeros=True)  # float8 -0.0

    @contextmanager
    def _group_transaction(self, keep: bool, sql: str | None
                           ) -> Iterator[tuple[int | None, list[tuple]]]:
        """:meth:`ComponentStore._group_transaction` in one round trip: ``BEGIN``, the
        writers' lock, the write counter (:data:`WRITES`, its row locked until this
        transaction ends: nobody else's write to ``components`` can commit meanwhile) and the
        admission's query, sent as one string."""
        reads = ([f"SELECT n FROM {WRITES} FOR UPDATE"] if keep else []) + (
            [sql] if sql is not None else [])
        with self._transaction("IMMEDIATE", reads):
            got = self._opened
            yield (int(got[0][0][0]) if keep else None), (got[-1] if sql is not None else [])

    def _load_states(self, names: list[str]) -> StoredRows:
        """The stored rows of ``names`` (:meth:`ComponentStore._load_states`): those kept,
        the others read in one query of an array parameter (``= ANY``: no statement text
        of one placeholder per name to parse), results in binary."""
        parts = []
        if self._states is not None:
            kept, names = self._states.split(names)
            parts.append(kept)
        read: list[tuple] = []
        if names:
            cols = ", ".join(("component", *self.STATE_COLUMNS))
            with self._conn.raw.cursor(binary=True) as cur:
                cur.execute(f"SELECT {cols} FROM components WHERE component = ANY(%s)",
                            (names,))
                read = cur.fetchall()
        parts.append(StoredRows.of_tuples(read, len(self.STATE_COLUMNS)))
        return StoredRows.joined(parts)

    def _read_meta(self) -> dict[str, str]:
        if self._conn.execute("SELECT to_regclass('meta')").fetchone()[0] is None:
            return {}
        return dict(self._conn.execute("SELECT key, value FROM meta").fetchall())

    @contextmanager
    def _transaction(self, mode: str = "IMMEDIATE", reads: Sequence[str] = ()
                     ) -> Iterator[Any]:
        """A transaction: ``DEFERRED``, a read-only snapshot (``REPEATABLE READ``); else a
        write transaction under the writers' advisory lock, begun in one round trip with the
        queries ``reads`` (without parameters; their rows in :attr:`_opened`)."""
        if self._states is not None and mode != "DEFERRED" and not self._ingesting:
            self._states.drop()  # a write the kept rows do not follow
        if mode == "DEFERRED":
            self._conn.execute("BEGIN ISOLATION LEVEL REPEATABLE READ READ ONLY")
        elif not self._conn.staging:  # outside any transaction: no rollback undoes it
            self._conn.execute(_staging_sql())
            self._conn.staging = True
        try:
            if mode != "DEFERRED":  # one string of statements: one round trip
                cur = self._conn.execute("; ".join(
                    [f"BEGIN; SELECT pg_advisory_xact_lock({WRITE_LOCK_KEY})", *reads]))
                cur.nextset()  # past BEGIN's result: the lock's
                self._opened = [list(cur.fetchall()) for _ in reads if cur.nextset()]
            yield self._conn
        except BaseException:
            if not self._conn.raw.closed:
                self._conn.execute("ROLLBACK")
                self._conn.staged = False
            raise
        else:
            if self._states is not None and self._ingesting:  # the count after our writes,
                self._states.version = int(  # read and committed in one round trip
                    self._conn.execute(f"SELECT n FROM {WRITES}; COMMIT").fetchone()[0])
            else:
                self._conn.execute("COMMIT")
            self._conn.staged = False

    def _query(self, sql: str, params: tuple = ()) -> pd.DataFrame:
        """A query in one read snapshot as a DataFrame (the base class's reads and checks,
        :meth:`status`, :meth:`history`, run on it unchanged)."""
        with self.snapshot():
            cur = self._conn.execute(sql, params)
            cols = [d.name for d in cur.description]
            rows = cur.fetchall()
        return pd.DataFrame(rows, columns=cols) if rows else pd.DataFrame(
            {c: pd.Series(dtype=object if c == "component" else float) for c in cols})

    def _write_history(self, rows: list[tuple]) -> None:
        """Packed history rows (:mod:`rulkit.fleet.store.history_chunks`) by binary ``COPY``
        (the blobs as raw bytes, not hex text; the server parses no statement per row; the
        data made by :func:`~rulkit.fleet.store.pg_copy.binary_tuples`). The cheapest of the
        ways measured by benchmarks/bench_pg_writes.py (docs/service-load.md, "PostgreSQL
        ingest")."""
        self._conn.copy_data("history", history_chunks.COLUMNS, binary_tuples(
            rows, _column_types(HISTORY, history_chunks.COLUMNS)))

    def _write_states(self, rows: Sequence[Sequence[Any]], extra_cols: tuple[str, ...] = ()
                      ) -> None:
        """Upsert component rows ``(component, *ROW_FIELDS, max_level, *extra_cols)``: binary
        ``COPY`` into the connection's temporary table :data:`STAGING`, then one statement
        that empties it into ``components`` (:meth:`_upsert_staged`), instead of one upsert
        per row: the same stored values (float8 bits as sent), the same conflict handling.
        The cheapest of the ways measured by benchmarks/bench_pg_writes.py (docs/service-load.md,
        "PostgreSQL ingest")."""
        cols = ("component", *ROW_FIELDS, "max_level", *extra_cols)
        self._stage(cols, rows)
        self._upsert_staged(cols)

    def _update_states(self, rows: Sequence[Sequence[Any]], extra_cols: tuple[str, ...] = ()
                       ) -> None:
        """Update stored component rows ``(*ROW_FIELDS, max_level, *extra_cols, component)``
        (:meth:`ComponentStore._update_states`): binary ``COPY`` into :data:`STAGING`, then
        one ``UPDATE ... FROM`` it (:meth:`_update_staged`)."""
        cols = (*ROW_FIELDS, "max_level", *extra_cols, "component")
        self._stage(cols, rows)
        self._update_staged(cols, len(rows))

    def _write_components(self, names: list[str], values: np.ndarray, columns: tuple[str, ...],
                          nullable: tuple[str, ...], known: np.ndarray) -> None:
        """:meth:`ComponentStore._write_components` with the rows' binary ``COPY`` data made
        from ``values`` by :func:`~rulkit.fleet.store.pg_copy.binary_rows` (the bytes
        ``COPY`` of the rows of :func:`~rulkit.fleet.store.tracker_rows.component_rows`
        sends, without a Python object per value), then :meth:`_update_staged` and
        :meth:`_upsert_staged`."""
        types = _column_types(COMPONENTS, columns)
        nulls = [c in nullable for c in columns]
        if known.size:
            cols = (*columns, "component")
            self._stage_data(cols, binary_rows([names[i] for i in known.tolist()],
                                               values[known], columns, types, nulls,
                                               key_last=True))
            self._update_staged(cols, known.size)
        new = np.setdiff1d(np.arange(len(names)), known)
        if new.size:
            cols = ("component", *columns)
            self._stage_data(cols, binary_rows([names[i] for i in new.tolist()],
                                               values[new], columns, types, nulls))
            self._upsert_staged(cols)

    def _update_staged(self, cols: tuple[str, ...], n_rows: int) -> None:
        """``components`` updated from the ``n_rows`` rows of :data:`STAGING` (columns ``cols``,
        the key last) by one ``UPDATE ... FROM``; a row that is not stored raises
        :class:`StoreError` (the write transaction is then rolled back)."""
        sets = ", ".join(f"{c} = s.{c}" for c in cols[:-1])
        n = self._conn.execute(f"UPDATE components AS c SET {sets} FROM {STAGING} AS s "
                               "WHERE c.component = s.component").rowcount
        if n != n_rows:
            raise StoreError(f"{self.path}: {n_rows - n} of the batch's components read "
                             "as stored are not in table components")

    def _upsert_staged(self, cols: tuple[str, ...]) -> None:
        """The rows of :data:`STAGING` (columns ``cols``, the key first) into ``components``
        (``INSERT ... SELECT ... ON CONFLICT (component) DO UPDATE``). The commit empties the
        table (``ON COMMIT DELETE ROWS``, in place); a second write in one transaction
        (group commits whose batches share components) empties it first."""
        names = ", ".join(cols)
        updates = ", ".join(f"{c} = excluded.{c}" for c in cols[1:])
        self._conn.execute(
            f"INSERT INTO components ({names}) SELECT {names} FROM {STAGING} "
            f"ON CONFLICT (component) DO UPDATE SET {updates}")

    def _stage(self, cols: tuple[str, ...], rows: Sequence[Sequence[Any]]) -> None:
        """``rows`` of columns ``cols`` into the empty :data:`STAGING` (emptied first when an
        earlier write of this transaction used it)."""
        self._empty_staging()
        self._conn.copy_binary(STAGING, cols, _column_types(COMPONENTS, cols), rows)

    def _stage_data(self, cols: tuple[str, ...], data: bytes) -> None:
        """Binary ``COPY`` data ``data`` of columns ``cols`` into the empty :data:`STAGING`."""
        self._empty_staging()
        self._conn.copy_data(STAGING, cols, data)

    def _empty_staging(self) -> None:
        if self._conn.staged:
            self._conn.execute(f"DELETE FROM {STAGING}")
        self._conn.staged = True

    def _insert_ingest(self, source: str, n_rows: int, n_components: int) -> int:
        return self._insert_ingests([(source, n_rows, n_components)])[0]

    def _insert_ingests(self, rows: list[tuple[str, int, int]]) -> list[int]:
        """:meth:`ComponentStore._insert_ingests` in one statement (:func:`_insert_rows`)."""
        return _insert_rows(self._conn, INGESTS, ("source", "n_rows", "n_components"), rows)

    def _insert_alerts(self, rows: list[tuple]) -> list[int]:
        """:meth:`ComponentStore._insert_alerts` in one statement (:func:`_insert_rows`)."""
        return _insert_rows(self._conn, ALERTS, ALERT_COLUMNS, rows)


def _insert_rows(conn: PgConnection, table: Any, columns: Sequence[str],
                 rows: Sequence[Sequence[Any]]) -> list[int]:
    """``rows`` of ``columns`` into ``table`` (a :class:`~rulkit.fleet.store.schema.Table`
    whose key ``id`` PostgreSQL numbers) by one statement from an array parameter per column;
    their ids, in the rows' order. Each position takes its id from the key's sequence in a
    ``WITH`` query of its own (one that calls ``nextval`` is evaluated once, however often it
    is read), the rows are inserted with those ids, and the ids are returned by position:
    nothing depends on the order in which PostgreSQL inserts or returns rows."""
    if not rows:
        return []
    cols = ", ".join(columns)
    arrays = ", ".join(f"%s::{t}[]" for t in _column_types(table, tuple(columns)))
    with conn.raw.cursor() as cur:
        cur.execute(
            f"WITH k AS (SELECT o, nextval(pg_get_serial_sequence('{table.name}', 'id')) "
            f"AS id FROM generate_series(1, %s) AS o), "
            f"ins AS (INSERT INTO {table.name} (id, {cols}) SELECT k.id, {cols} "
            f"FROM unnest({arrays}) WITH ORDINALITY AS u({cols}, o) JOIN k USING (o)) "
            f"SELECT id FROM k ORDER BY o",
            [len(rows), *(list(col) for col in zip(*rows, strict=True))])
        return [int(r[0]) for r in cur.fetchall()]


def _count_writes(conn: PgConnection) -> None:
    """Inside a write transaction: the write counter :data:`WRITES` and the trigger that
    counts every statement writing ``components`` (each made when missing), then a lock of
    the counter's row, as each write transaction of the kept rows takes it. The function
    names the table with its schema (a writer with another ``search_path`` counts in the same
    row) and runs as its owner (a role that may write ``components`` but not the counter
    still counts). Raises ``InsufficientPrivilege`` for a role that may not make them or lock
    the row."""
    if conn.execute("SELECT 1 FROM pg_trigger WHERE tgrelid = 'components'::regclass AND "
                    "tgname = 'components_written'").fetchone() is None:
        schema = conn.execute("SELECT quote_ident(current_schema())").fetchone()[0]
        conn.execute(f"CREATE TABLE IF NOT EXISTS {WRITES} (n BIGINT NOT NULL)")
        conn.execute(f"INSERT INTO {WRITES} SELECT 0 WHERE NOT EXISTS (SELECT 1 FROM {WRITES})")
        conn.execute("CREATE OR REPLACE FUNCTION rulkit_count_write() RETURNS trigger LANGUAGE "
                     "plpgsql SECURITY DEFINER SET search_path = pg_catalog AS $$ BEGIN UPDATE "
                     f"{schema}.{WRITES} SET n = n + 1; RETURN NULL; END $$")
        conn.execute("CREATE TRIGGER components_written AFTER INSERT OR UPDATE OR DELETE OR "
                     "TRUNCATE ON components FOR EACH STATEMENT EXECUTE FUNCTION "
                     "rulkit_count_write()")
    conn.execute(f"SELECT n FROM {WRITES} FOR UPDATE")


_TYPES: dict[tuple[str, tuple[str, ...]], list[str]] = {}


def _column_types(table: Any, names: tuple[str, ...]) -> list[str]:
    """PostgreSQL's types of columns ``names`` of ``table`` (a :class:`~rulkit.fleet.store.
    schema.Table`), as binary COPY sends them; kept by the table's name (hashing the table
    itself hashes every column of it, at every call)."""
    key = (table.name, names)
    got = _TYPES.get(key)
    if got is None:
        kinds = {c.name: c.kind for c in table.columns}
        got = _TYPES[key] = [_BINARY_TYPES[kinds[n]] for n in names]
    return got


@lru_cache(maxsize=1)
def _staging_sql() -> str:
    """The temporary table :data:`STAGING`: the columns of ``components``, no key, no index;
    PostgreSQL empties it at every commit too."""
    cols = ", ".join(c.sql("postgresql") for c in COMPONENTS.columns)
    return f"CREATE TEMP TABLE IF NOT EXISTS {STAGING} ({cols}) ON COMMIT DELETE ROWS"


def _redact(url: str) -> str:
    """``url`` without its password (for messages)."""
    from urllib.parse import urlsplit, urlunsplit

    parts = urlsplit(url)
    if parts.password is None:
        return url
    netloc = parts.netloc.rsplit("@", 1)
    user = netloc[0].split(":", 1)[0]
    return urlunsplit(parts._replace(netloc=f"{user}:***@{netloc[1]}"))


def open_store(db: str | Path, **kwargs: Any) -> ComponentStore:
    """Open the component store at ``db``: a ``postgresql://`` URL or a SQLite path."""
    if is_postgres_url(db):
        return PgComponentStore(str(db), **kwargs)
    return ComponentStore(db, **kwargs)


def store_dialect(store: ComponentStore) -> str:
    """``"postgresql"`` or ``"sqlite"``."""
    return getattr(store, "dialect", "sqlite")
