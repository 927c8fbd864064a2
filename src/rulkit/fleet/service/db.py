"""The service's data layer over a component store (SQLite or PostgreSQL).

The service reads and writes the store's tables (:mod:`rulkit.fleet.store.schema`): tokens in
``api_tokens`` (the SHA-256 of each token, never the token; creation and revocation times) and
alerts in ``alerts`` (what every committed batch raised, and, once acknowledged, who
acknowledged it, why, when and with which token name).

* ``api_tokens``: id, name, role (``read`` | ``write``), the SHA-256 of the token (the token
  itself is never stored), creation and revocation times;
* ``alerts``: every alert the store reported for a committed batch (component, time, level,
  the level before, HI, the RUL median and interval then, the rule that raised it), when it
  was raised and, once acknowledged, who acknowledged it, why, when and with which token name.

What the reads return (one RUL per component, counts, the HI forecast) is
:mod:`rulkit.fleet.service.fleet_view`.

:meth:`ServiceDB.ingest` goes through the store's one ingestion path, the one ``rulkit track``
takes: rows already stored (same component and time, same HI within 1e-12 relative) are
skipped and counted as duplicates; a stored time with another HI, or a time before the
component's last acquisition that is not stored, raises
:class:`~rulkit.fleet.store.acquisitions.ConflictError` naming the row. Duplicate detection,
the store's update and the alerts' insertion run in one write transaction, so a batch is all
or nothing and two clients sending the same batch at once store it once.
"""

from __future__ import annotations

import hashlib
import math
import secrets
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from queue import Empty, LifoQueue
from typing import Any

import pandas as pd

from rulkit.fleet.monitoring.rules import unit_seconds
from rulkit.fleet.service import fleet_view
from rulkit.fleet.service.commit_watch import CommitWatch
from rulkit.fleet.service.fleet_view import num as _num
from rulkit.fleet.store import history_chunks
from rulkit.fleet.store.acquisitions import (
    Alert,
    Batch,
    Columns,
    ConflictError,
    IngestResult,
    validate_acquisitions,
)
from rulkit.fleet.store.batch_groups import Admission
from rulkit.fleet.store.postgres import open_store, store_dialect
from rulkit.fleet.store.prognosis import current_estimator
from rulkit.fleet.store.schema import migrate
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.tracking.tracker_chain import LEVEL_NAMES

ROLES = ("read", "write")
ALERT_FIELDS = ("id", "component", "t", "level", "previous", "hi", "fhi", "rul", "valid",
                "rul_low", "rul_high", "reason", "raised", "ack_by", "ack_reason", "ack_at",
                "ack_token")
_ALERT_NOW = ("level", "rul_median", "rul_low", "rul_high", "failed_at", "seen")
"""The alerted component's current columns, read with each alert (the table's values)."""

STALE_MARGIN = 1e-3
"""Seconds within which a component's last acquisition counts as at the stale cutoff
(:meth:`ServiceDB.stale_horizon`): far above the rounding of calendar times."""


INVALID_TOKEN = "invalid or revoked token"
"""The 401's message for a token that is unknown or revoked."""
READ_ONLY_TOKEN = ("this token is read-only; writes and acknowledgements need a write "
                   "token")
"""The 403's message for a read-only token where a write token is needed."""


class NotFound(LookupError):
    """No such component or alert (HTTP 404)."""


class TokenRefused(PermissionError):
    """A batch's token is not an active write token (``status`` 401: unknown or revoked;
    403: read-only); nothing of the batch is written."""

    def __init__(self, status: int) -> None:
        super().__init__(INVALID_TOKEN if status == 401 else READ_ONLY_TOKEN)
        self.status = status


@dataclass(frozen=True)
class Token:
    id: int
    name: str
    role: str

    @property
    def can_write(self) -> bool:
        return self.role == "write"


def hash_token(token: str) -> str:
    """SHA-256 hex of a token. Tokens carry 256 random bits, so a fast hash is enough."""
    return hashlib.sha256(token.encode("utf-8", "surrogatepass")).hexdigest()


def ensure_service_tables(store: ComponentStore) -> None:
    """Create the tables and indexes the service reads if missing (idempotent;
    :func:`rulkit.fleet.store.schema.migrate`)."""
    dialect = store_dialect(store)
    with store._transaction("IMMEDIATE") as conn:
        migrate(conn, dialect)


class ServiceDB:
    """A pool of store connections to one database, plus the service's operations.

    ``ServiceDB(db, pool_size=8)``: ``db`` is a SQLite path or a ``postgresql://`` URL; a new
    SQLite database is created with the default tracker configuration (create it first with
    ``rulkit track --db`` to choose other settings). Each request checks a connection out of
    the pool (:meth:`store`). On SQLite, writers additionally queue on an in-process lock
    rather than polling SQLite's busy handler.

    The ingestion's group commits go through one connection of their own, opened with the
    first of them: SQLite drops a connection's page cache whenever another connection has
    written since its last transaction, so with the groups spread over the pool every
    commit read the tables' and indexes' pages afresh from the file (PostgreSQL's server
    keeps the statements that connection prepared). On SQLite that connection keeps the
    component rows it committed and starts the next batches from them while no other
    connection has written (:meth:`~rulkit.fleet.store.sqlite.ComponentStore.keep_states`).

    On SQLite, ``watch`` is a read-only connection of its own
    (:class:`~rulkit.fleet.service.commit_watch.CommitWatch`): the token check and the
    commit counter the page cache is keyed on; ``None`` on PostgreSQL.
    """

    def __init__(self, db: str | Path, *, pool_size: int = 8, create: bool = True) -> None:
        self.db = db
        self.pool_size = pool_size
        first = open_store(db, create=create)
        try:
            ensure_service_tables(first)
        except BaseException:
            first.close()
            raise
        self.dialect = store_dialect(first)
        self._pool: LifoQueue[ComponentStore] = LifoQueue()
        self._pool.put(first)
        self._opened = 1
        self._lock = threading.Lock()
        self._write_lock = threading.Lock()  # one group being written at a time
        self._queue_lock = threading.Lock()
        self._queue: list[_Pending] = []
        self._writes = 0  # committed groups (tests count them)
        self._writers_seen: set[str] = set()  # hashes of tokens writer_token last passed
        self._writer: ComponentStore | None = None  # the group commits' own connection
        self.watch: CommitWatch | None = None
        if self.dialect == "sqlite":
            try:
                self.watch = CommitWatch(db)
            except BaseException:
                first.close()
                raise

    @contextmanager
    def store(self) -> Iterator[ComponentStore]:
        """Check a store connection out of the pool for the duration of the block."""
        try:
            s = self._pool.get_nowait()
        except Empty:
            with self._lock:
                grow = self._opened < self.pool_size
                if grow:
                    self._opened += 1
            if grow:
                try:
                    s = open_store(self.db, create=False)
                except BaseException:
                    with self._lock:
                        self._opened -= 1
                    raise
            else:
                s = self._pool.get()
        try:
            yield s
        except BaseException:
            # a connection in an unknown state is not reused
            if _in_transaction(s):
                s.close()
                with self._lock:
                    self._opened -= 1
                raise
            self._pool.put(s)
            raise
        else:
            self._pool.put(s)

    @contextmanager
    def writing(self) -> Iterator[ComponentStore]:
        with self.store() as s:
            if self.dialect == "sqlite":
                with self._write_lock:
                    yield s
            else:
                yield s

    def close(self) -> None:
        """Close every connection (the pool's, the group commits' and the watch's)."""
        if self.watch is not None:
            self.watch.close()
        with self._write_lock:
            if self._writer is not None:
                self._writer.close()
                self._writer = None
        while True:
            try:
                self._pool.get_nowait().close()
            except Empty:
                break

    # ------------------------------------------------------------------ tokens
    def create_token(self, role: str, name: str) -> tuple[int, str]:
        """A new token for ``role``; returns (id, token). Only its hash is stored."""
        if role not in ROLES:
            raise ValueError(f"role must be one of {ROLES}, got {role!r}")
        token = "rk_" + secrets.token_urlsafe(32)
        with self.writing() as s, s._transaction("IMMEDIATE") as conn:
            row = conn.execute(
                "INSERT INTO api_tokens (name, role, hash, created) VALUES (?, ?, ?, ?) "
                "RETURNING id", (name, role, hash_token(token), time.time())).fetchone()
        return int(row[0]), token

    def revoke_token(self, *, token_id: int | None = None, name: str | None = None) -> int:
        """Revoke by id or by name (all active tokens of that name); returns how many."""
        if (token_id is None) == (name is None):
            raise ValueError("give exactly one of a token id or a name")
        with self.writing() as s, s._transaction("IMMEDIATE") as conn:
            if token_id is not None:
                cur = conn.execute("UPDATE api_tokens SET revoked = ? WHERE id = ? AND "
                                   "revoked IS NULL", (time.time(), token_id))
            else:
                cur = conn.execute("UPDATE api_tokens SET revoked = ? WHERE name = ? AND "
                                   "revoked IS NULL", (time.time(), name))
            return int(cur.rowcount)

    def list_tokens(self) -> list[dict[str, Any]]:
        with self.store() as s, s.snapshot() as conn:
            rows = conn.execute("SELECT id, name, role, created, revoked FROM api_tokens "
                                "ORDER BY id").fetchall()
        return [dict(zip(("id", "name", "role", "created", "revoked"), r, strict=True))
                for r in rows]

    def check_token(self, token: str) -> Token | None:
        """The active token with this value, or None."""
        if not plausible_token(token):
            return None
        if self.watch is not None:  # SQLite: read on the watch's connection, every time
            found = self.watch.token_row(hash_token(token))
            return None if found is None else Token(*found)
        with self.store() as s:
            row = s._conn.execute(
                "SELECT id, name, role FROM api_tokens WHERE hash = ? AND revoked IS NULL",
                (hash_token(token),)).fetchone()
        return Token(int(row[0]), str(row[1]), str(row[2])) if row else None

    def writer_token(self, token: str) -> Token:
        """The active write token with this value (:meth:`check_token`), else
        :class:`TokenRefused` (401 or 403). The outcome is remembered for
        :meth:`known_writer`."""
        tok = self.check_token(token)
        if tok is None or not tok.can_write:
            self._writers_seen.discard(hash_token(token))
            raise TokenRefused(401 if tok is None else 403)
        self._writers_seen.add(hash_token(token))
        return tok

    def known_writer(self, token: str) -> bool:
        """Whether ``token`` passed :meth:`writer_token` the last time it was checked there.
        Not a check: a token may have been revoked since; the ingest on PostgreSQL uses it
        to check a token at the door the first time it is seen (an unknown token is refused
        before its body is read), and only inside the group's transaction after that. The
        set holds only tokens that were in ``api_tokens``, so it stays as small as that
        table."""
        return hash_token(token) in self._writers_seen

    # ------------------------------------------------------------------ ingestion
    def ingest(self, df: pd.DataFrame | Columns, source: str, *, now: float | None = None,
               token: str | None = None) -> dict[str, Any]:
        """Validate and apply one batch through the store's one ingestion path
        (:meth:`~rulkit.fleet.store.sqlite.ComponentStore.ingest_many`: duplicates skipped,
        conflicts refused, alerts recorded), with group commit: batches that arrive while
        another is being written wait, then go together in one transaction (each under its
        own savepoint, so each is still all or nothing) with one commit. The call returns
        once its batch is committed (durable); JSON-ready result. ``now``: the calendar time
        of the ingestion (seconds since 1970; default the clock), the time a batch of ages
        was acquired at.

        ``token``: a bearer token, checked inside the group's transaction, after the
        writers' lock (one query for the group's tokens): the batch is written, under the
        source ``source`` followed by the token's name, only if it is an active write token
        then; else :class:`TokenRefused` and nothing of it is written. A revocation
        committed before the group's transaction is seen. A batch that fails before it is
        checked (invalid, or its group's transaction failed) has its token checked first
        (:meth:`writer_token`), so a bad token is refused before anything else, as a check
        before the body gives it."""
        try:
            with self.store() as s:  # validation needs no lock: it runs beside the writer
                acq = validate_acquisitions(df, s.config, s.hi_model, s.time_axis)
        except BaseException:
            if token is not None:
                self.writer_token(token)
            raise
        req = _Pending(acq, source, now, None if token is None else hash_token(token))
        with self._queue_lock:
            self._queue.append(req)
        with self._write_lock:
            if not req.done:
                with self._queue_lock:
                    group, self._queue = self._queue, []
                self._commit(group)
        if isinstance(req.outcome, BaseException):
            if token is not None and not req.admitted:
                self.writer_token(token)
            raise req.outcome
        res = req.outcome
        assert res is not None
        return {"ingested": res.n_rows, "duplicates": res.n_duplicates,
                "components": res.n_components, "new_components": res.n_new_components,
                "alerts": [alert_json(a) for a in res.alerts]}

    def _commit(self, group: list[_Pending]) -> None:
        """Write ``group`` in one transaction; every request gets its result or error."""
        try:
            if self._writer is None:
                self._writer = open_store(self.db, create=False)
                self._writer.keep_states()
            outcomes: list[Any] = list(self._writer.ingest_many(
                [(r.acq, r.source, r.now) for r in group], _admission(group)))
            self._writes += 1
        except BaseException as err:  # the commit failed: nothing of the group is stored
            outcomes = [err] * len(group)
            if self._writer is not None and _in_transaction(self._writer):
                self._writer.close()  # a connection in an unknown state is not reused
                self._writer = None
        for r, o in zip(group, outcomes, strict=True):
            r.outcome, r.done = o, True

    # ------------------------------------------------------------------ reading
    def summary(self, *, now: float | None = None) -> dict[str, Any]:
        """Counts per level and of stale components, the estimator, the rules
        (:func:`rulkit.fleet.service.fleet_view.summary`)."""
        now = time.time() if now is None else now
        with self.store() as s, s.snapshot() as conn:
            return fleet_view.summary(conn, current_estimator(s), now)

    def components(self, *, limit: int, offset: int = 0, level: str | None = None,
                   sort: str = "worst", after: str | None = None, now: float | None = None
                   ) -> tuple[int, list[dict[str, Any]], str | None]:
        """(total matching, one page: worst first (level, then RUL median ascending,
        unknown last, then id), or by ``sort`` rul or due, the next page's cursor;
        :func:`rulkit.fleet.service.fleet_view.list_components`)."""
        now = time.time() if now is None else now
        with self.store() as s, s.snapshot() as conn:
            return fleet_view.list_components(conn, current_estimator(s), limit=limit,
                                              offset=offset, level=level, sort=sort, now=now,
                                              after=after)

    def stale_horizon(self, now: float) -> float:
        """The calendar time until which the components stale at ``now`` are exactly the
        stale ones: the first component not stale at ``now`` turns stale ``stale_after``
        after its last acquisition (less :data:`STALE_MARGIN`; one within it of the cutoff
        gives ``now`` or less: nothing is certain). ``inf`` without a stale rule or without
        a component that is not stale. Later clocks stale more components; none turns fresh
        without a commit."""
        with self.store() as s, s.snapshot() as conn:
            after = current_estimator(s).rules.stale_after
            if after is None:
                return math.inf
            row = conn.execute("SELECT MIN(seen) FROM components WHERE seen >= ?",
                               (now - after - STALE_MARGIN,)).fetchone()
        return math.inf if row[0] is None else float(row[0]) + after - STALE_MARGIN

    def component(self, component: str, *, now: float | None = None) -> dict[str, Any]:
        now = time.time() if now is None else now
        with self.store() as s, s.snapshot() as conn:
            row = conn.execute(f"SELECT {', '.join(fleet_view.FIELDS)} FROM components "
                               "WHERE component = ?", (component,)).fetchone()
            if row is None:
                raise NotFound(f"no component {component!r}")
            n_open = conn.execute("SELECT COUNT(*) FROM alerts WHERE component = ? AND "
                                  "ack_at IS NULL", (component,)).fetchone()[0]
            out = fleet_view.component_item(row, current_estimator(s), now)
        out["open_alerts"] = int(n_open)
        return out

    def history(self, component: str, *, limit: int, now: float | None = None
                ) -> dict[str, Any]:
        """The last ``limit`` acquisitions (time ascending: HI, fHI, the RUL median and
        interval, level), the component now, its HI forecast to the threshold and its
        alerts."""
        fields = ("t", "hi", "fhi", "rul_median", "rul_low", "rul_high", "valid", "level")
        now = time.time() if now is None else now
        with self.store() as s, s.snapshot() as conn:
            est = current_estimator(s)
            row = conn.execute(f"SELECT {', '.join(fleet_view.FIELDS)} FROM components "
                               "WHERE component = ?", (component,)).fetchone()
            if row is None:
                raise NotFound(f"no component {component!r}")
            item = fleet_view.component_item(row, est, now)
            rec = history_chunks.read_last(conn, component, limit)
            t = history_chunks.field(rec, "t")
            fc = fleet_view.forecast(conn, est, component, item,
                                     float(t[0]) if t.size else math.nan)
            alerts = self._alert_rows(conn, " WHERE a.component = ?", [component],
                                      "a.t, a.id")
        cols = {f: [_num(v) for v in history_chunks.field(rec, f).tolist()] for f in fields}
        cols["valid"] = [bool(v) for v in cols["valid"]]
        cols["level"] = [LEVEL_NAMES[int(v)] for v in cols["level"]]
        cols["rul"] = cols.pop("rul_median")  # the RUL median, as in the components list
        return {"component": component, "n": item["n"], "returned": len(t),
                "now": item, "history": cols, "forecast": fc, "threshold": 1.0,
                "alarm_hi": est.rules.alarm_hi, "time_unit": est.time_unit,
                "unit_seconds": unit_seconds(est.time_unit),
                "time_origin": fleet_view.time_origin(item, est),
                "alerts": [_alert_dict(a, est, now) for a in alerts]}

    def _alert_rows(self, conn: Any, where: str, params: list[Any], order: str,
                    limit: int | None = None, offset: int = 0) -> list[tuple]:
        cols = ", ".join([f"a.{f}" for f in ALERT_FIELDS] + [f"c.{f}" for f in _ALERT_NOW])
        tail = "" if limit is None else " LIMIT ? OFFSET ?"
        return list(conn.execute(
            f"SELECT {cols} FROM alerts a LEFT JOIN components c ON c.component = a.component"
            f"{where} ORDER BY {order}{tail}",
            [*params, *([] if limit is None else [limit, offset])]).fetchall())

    def alerts(self, *, state: str, component: str | None, limit: int, offset: int,
               now: float | None = None) -> tuple[int, list[dict[str, Any]]]:
        """Alerts, highest level then newest first, each with its component's current level
        and RUL (as the fleet table shows them)."""
        conds, params = [], []
        if state == "open":
            conds.append("a.ack_at IS NULL")
        elif state == "acknowledged":
            conds.append("a.ack_at IS NOT NULL")
        if component is not None:
            conds.append("a.component = ?")
            params.append(component)
        where = (" WHERE " + " AND ".join(conds)) if conds else ""
        now = time.time() if now is None else now
        with self.store() as s, s.snapshot() as conn:
            total = conn.execute(f"SELECT COUNT(*) FROM alerts a{where}", params).fetchone()[0]
            rows = self._alert_rows(conn, where, params, "a.level DESC, a.id DESC", limit,
                                    offset)
            est = current_estimator(s)
        return int(total), [_alert_dict(r, est, now) for r in rows]

    def ack(self, alert_id: int, *, by: str, reason: str, token_name: str) -> dict[str, Any]:
        """Acknowledge an open alert; raises NotFound, or ConflictError if already done."""
        with self.writing() as s, s._transaction("IMMEDIATE") as conn:
            row = conn.execute(f"SELECT {', '.join(ALERT_FIELDS)} FROM alerts WHERE id = ?",
                               (alert_id,)).fetchone()
            if row is None:
                raise NotFound(f"no alert {alert_id}")
            if row[ALERT_FIELDS.index("ack_at")] is not None:
                raise ConflictError(
                    f"alert {alert_id} was already acknowledged by "
                    f"{row[ALERT_FIELDS.index('ack_by')]!r}")
            conn.execute("UPDATE alerts SET ack_by = ?, ack_reason = ?, ack_at = ?, "
                         "ack_token = ? WHERE id = ?",
                         (by, reason, time.time(), token_name, alert_id))
            row = conn.execute(f"SELECT {', '.join(ALERT_FIELDS)} FROM alerts WHERE id = ?",
                               (alert_id,)).fetchone()
        return _alert_dict(row)


class _Pending:
    """A validated batch waiting for its group's commit; ``token``: the SHA-256 of its
    bearer token, checked in the group's transaction (``admitted`` once it passed)."""

    __slots__ = ("acq", "admitted", "done", "now", "outcome", "source", "token")

    def __init__(self, acq: Batch, source: str, now: float | None,
                 token: str | None = None) -> None:
        self.acq, self.source, self.now, self.token = acq, source, now, token
        self.done = self.admitted = False
        self.outcome: IngestResult | BaseException | None = None


def plausible_token(token: str) -> bool:
    """Whether ``token`` could be a token at all (the others are refused unread)."""
    return bool(token) and len(token) <= 256


def _admission(group: list[_Pending]) -> Admission | None:
    """The check of the group's tokens in its transaction (:class:`Admission`): one query of
    the active tokens among the group's hashes (hex digests, so the query carries them as
    literals); a batch whose token is active and may write gets the source ``source``
    followed by the token's name, the others :class:`TokenRefused`. ``None`` when no batch
    of the group has a token."""
    hashes = sorted({r.token for r in group if r.token is not None})
    if not hashes:
        return None
    assert all(len(h) == 64 and h.isalnum() and h.isascii() for h in hashes)  # hex digests

    def decide(rows: list[tuple]) -> list[str | BaseException]:
        found = {str(h): (str(name), str(role)) for h, name, role in rows}
        out: list[str | BaseException] = []
        for r in group:
            if r.token is None:
                out.append(r.source)
            elif r.token not in found or found[r.token][1] != "write":
                out.append(TokenRefused(401 if r.token not in found else 403))
            else:
                r.admitted = True
                out.append(r.source + found[r.token][0])
        return out

    return Admission(
        "SELECT hash, name, role FROM api_tokens WHERE revoked IS NULL AND hash IN ("
        + ", ".join(f"'{h}'" for h in hashes) + ")", decide)


def _in_transaction(store: ComponentStore) -> bool:
    conn = store._conn
    if hasattr(conn, "in_transaction"):
        return bool(conn.in_transaction)
    raw = getattr(conn, "raw", None)
    if raw is None or raw.closed:
        return True
    import psycopg

    return bool(raw.info.transaction_status != psycopg.pq.TransactionStatus.IDLE)


def alert_json(a: Alert) -> dict[str, Any]:
    """A newly recorded alert as the API returns it."""
    valid = a.rul == a.rul and abs(a.rul) != float("inf")  # the RUL is estimated
    return _alert_dict((a.id, a.component, a.t, a.level, a.previous, a.hi, a.fhi, a.rul,
                        valid, a.rul_low, a.rul_high, a.reason, a.raised, None, None, None,
                        None))


def _alert_dict(r: tuple, est: Any = None, now: float = 0.0) -> dict[str, Any]:
    """An alert as the API returns it; with the estimator, the row's trailing
    current-component columns become ``current`` (level and RUL as the fleet table shows)."""
    d = dict(zip(ALERT_FIELDS, r[:len(ALERT_FIELDS)], strict=True))
    ack = None
    if d["ack_at"] is not None:
        ack = {"by": d["ack_by"], "reason": d["ack_reason"], "at": _num(d["ack_at"]),
               "token_name": d["ack_token"]}
    out = {"id": int(d["id"]), "component": d["component"], "time": _num(d["t"]),
           "level": LEVEL_NAMES[int(d["level"])], "previous": LEVEL_NAMES[int(d["previous"])],
           "hi": _num(d["hi"]), "fhi": _num(d["fhi"]), "rul": _num(d["rul"]),
           "rul_low": _num(d["rul_low"]), "rul_high": _num(d["rul_high"]),
           "reason": d["reason"], "valid": bool(d["valid"]), "raised": _num(d["raised"]),
           "acknowledged": ack}
    now_cols = dict(zip(_ALERT_NOW, r[len(ALERT_FIELDS):], strict=False))
    if est is not None and now_cols.get("level") is not None:
        row = tuple({"component": d["component"], "t": None, "n": 0, "hi": None, "fhi": None,
                     "frul": None, "valid": 0, **now_cols}[f] for f in fleet_view.FIELDS)
        cur = fleet_view.component_item(row, est, now)
        out["current"] = {k: cur[k] for k in ("level", "rul_state", "rul", "rul_low",
                                              "rul_high", "due", "failed", "stale")}
    return out
