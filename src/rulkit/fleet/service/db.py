"""The service's data layer over a component store (SQLite or PostgreSQL).

The service reads and writes the store's tables (:mod:`rulkit.fleet.store.schema`): tokens in
``api_tokens`` (the SHA-256 of each token, never the token; creation and revocation times) and
alerts in ``alerts`` (what every committed batch raised, and, once acknowledged, who
acknowledged it, why, when and with which token name).

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
import json
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

import numpy as np
import pandas as pd

from rulkit.fleet.store.acquisitions import (
    Alert,
    ConflictError,
    IngestResult,
    validate_acquisitions,
)
from rulkit.fleet.store.postgres import open_store, store_dialect
from rulkit.fleet.store.schema import migrate
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.tracking.tracker_chain import LEVEL_NAMES

ROLES = ("read", "write")
LEVEL_CODES = {name: code for code, name in LEVEL_NAMES.items()}
COMPONENT_FIELDS = ("component", "t", "n", "hi", "fhi", "dhi", "frul", "drul", "d2rul",
                    "valid", "level", "rul_low", "rul_high")
ALERT_FIELDS = ("id", "component", "t", "level", "previous", "hi", "fhi", "frul", "valid",
                "rul_low", "rul_high", "raised", "ack_by", "ack_reason", "ack_at", "ack_token")
SAME_HI_RTOL = 1e-12

class NotFound(LookupError):
    """No such component or alert (HTTP 404)."""


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


def _num(v: Any) -> Any:
    """JSON-safe number: NaN and infinities become None."""
    if v is None:
        return None
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    f = float(v)
    return f if math.isfinite(f) else None


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
        if not token or len(token) > 256:
            return None
        with self.store() as s:
            row = s._conn.execute(
                "SELECT id, name, role FROM api_tokens WHERE hash = ? AND revoked IS NULL",
                (hash_token(token),)).fetchone()
        return Token(int(row[0]), str(row[1]), str(row[2])) if row else None

    # ------------------------------------------------------------------ ingestion
    def ingest(self, df: pd.DataFrame, source: str) -> dict[str, Any]:
        """Validate and apply one batch through the store's one ingestion path
        (:meth:`~rulkit.fleet.store.sqlite.ComponentStore.ingest_many`: duplicates skipped,
        conflicts refused, alerts recorded), with group commit: batches that arrive while
        another is being written wait, then go together in one transaction (each under its
        own savepoint, so each is still all or nothing) with one commit. The call returns
        once its batch is committed (durable); JSON-ready result."""
        with self.store() as s:  # validation needs no lock: it runs beside the writer
            acq = validate_acquisitions(df, s.config, s.hi_model)
        req = _Pending(acq, source)
        with self._queue_lock:
            self._queue.append(req)
        with self._write_lock:
            if not req.done:
                with self._queue_lock:
                    group, self._queue = self._queue, []
                self._commit(group)
        if isinstance(req.outcome, BaseException):
            raise req.outcome
        res = req.outcome
        assert res is not None
        return {"ingested": res.n_rows, "duplicates": res.n_duplicates,
                "components": res.n_components, "new_components": res.n_new_components,
                "alerts": [alert_json(a) for a in res.alerts]}

    def _commit(self, group: list[_Pending]) -> None:
        """Write ``group`` in one transaction; every request gets its result or error."""
        try:
            with self.store() as s:
                outcomes: list[Any] = list(s.ingest_many([(r.acq, r.source) for r in group]))
            self._writes += 1
        except BaseException as err:  # the commit failed: nothing of the group is stored
            outcomes = [err] * len(group)
        for r, o in zip(group, outcomes, strict=True):
            r.outcome, r.done = o, True

    # ------------------------------------------------------------------ reading
    def components(self, *, limit: int, offset: int = 0, level: str | None = None,
                   sort: str = "worst", after: str | None = None
                   ) -> tuple[int, list[dict[str, Any]], str | None]:
        """(total matching, one page, the cursor of the next page or None).

        ``sort``: ``worst`` (level, then fHI descending, then id) or ``rul`` (filtered RUL
        ascending, then id). ``after`` (a cursor this method returned) continues after the
        previous page's last row by keyset (an index range scan: every page costs what the
        first does); ``offset`` skips rows (cost grows with it). ``total`` counts by level,
        from table ``level_counts``, which every ingestion keeps."""
        code = LEVEL_CODES[level] if level is not None else None
        key = _decode_cursor(after, sort) if after is not None else None
        sql, params = page_query(sort, code, key, limit, offset)
        with self.store() as s, s.snapshot() as conn:
            rows = conn.execute(sql, params).fetchall()
            counts = self._level_counts(conn)
        total = counts.get(LEVEL_CODES[level], 0) if level is not None else sum(counts.values())
        nxt = encode_cursor(rows[-1], sort) if len(rows) == limit else None
        return int(total), [_component_dict(r) for r in rows], nxt

    def _level_counts(self, conn: Any) -> dict[int, int]:
        """Components per level from table ``level_counts`` (kept by every ingestion)."""
        return {int(lv): int(n) for lv, n in conn.execute(
            "SELECT level, n FROM level_counts").fetchall()}

    def component(self, component: str) -> dict[str, Any]:
        with self.store() as s, s.snapshot() as conn:
            row = conn.execute(f"SELECT {', '.join(COMPONENT_FIELDS)} FROM components "
                               "WHERE component = ?", (component,)).fetchone()
            if row is None:
                raise NotFound(f"no component {component!r}")
            n_open = conn.execute("SELECT COUNT(*) FROM alerts WHERE component = ? AND "
                                  "ack_at IS NULL", (component,)).fetchone()[0]
        out = _component_dict(row)
        out["open_alerts"] = int(n_open)
        return out

    def history(self, component: str, *, limit: int) -> dict[str, Any]:
        """The last ``limit`` acquisitions (time ascending) and the component's alerts."""
        fields = ("t", "hi", "fhi", "frul", "rul_low", "rul_high", "valid", "level")
        with self.store() as s, s.snapshot() as conn:
            known = conn.execute("SELECT n FROM components WHERE component = ?",
                                 (component,)).fetchone()
            if known is None:
                raise NotFound(f"no component {component!r}")
            rows = conn.execute(
                f"SELECT {', '.join(fields)} FROM history WHERE component = ? "
                "ORDER BY t DESC LIMIT ?", (component, limit)).fetchall()
            alerts = conn.execute(f"SELECT {', '.join(ALERT_FIELDS)} FROM alerts WHERE "
                                  "component = ? ORDER BY t, id", (component,)).fetchall()
        rows.reverse()
        cols = {f: [_num(r[i]) for r in rows] for i, f in enumerate(fields)}
        cols["valid"] = [bool(v) for v in cols["valid"]]
        cols["level"] = [LEVEL_NAMES[int(v)] for v in cols["level"]]
        cols["rul"] = cols.pop("frul")  # the filtered RUL, named as in the components list
        return {"component": component, "n": int(known[0]), "returned": len(rows),
                "history": cols, "alerts": [_alert_dict(a) for a in alerts]}

    def alerts(self, *, state: str, component: str | None, limit: int, offset: int
               ) -> tuple[int, list[dict[str, Any]]]:
        conds, params = [], []
        if state == "open":
            conds.append("ack_at IS NULL")
        elif state == "acknowledged":
            conds.append("ack_at IS NOT NULL")
        if component is not None:
            conds.append("component = ?")
            params.append(component)
        where = (" WHERE " + " AND ".join(conds)) if conds else ""
        with self.store() as s, s.snapshot() as conn:
            total = conn.execute(f"SELECT COUNT(*) FROM alerts{where}", params).fetchone()[0]
            rows = conn.execute(
                f"SELECT {', '.join(ALERT_FIELDS)} FROM alerts{where} "
                "ORDER BY level DESC, id DESC LIMIT ? OFFSET ?",
                [*params, limit, offset]).fetchall()
        return int(total), [_alert_dict(r) for r in rows]

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
    """A validated batch waiting for its group's commit."""

    __slots__ = ("acq", "done", "outcome", "source")

    def __init__(self, acq: pd.DataFrame, source: str) -> None:
        self.acq, self.source = acq, source
        self.done = False
        self.outcome: IngestResult | BaseException | None = None


SORTS = {"worst": ("level DESC, fhi DESC, component", ("level", "fhi", "component")),
         "rul": ("frul, component", ("frul", "component"))}
"""Orders of the component list: ``(ORDER BY, the key columns a cursor holds)``."""

def page_query(sort: str, level: int | None, key: list[Any] | None, limit: int,
               offset: int = 0) -> tuple[str, list[Any]]:
    """SQL and parameters of one page of components in ``sort`` order (:data:`SORTS`),
    optionally of one ``level`` code, after the row whose key is ``key`` (keyset). Every part
    is an index range scan on either backend: ``rul`` compares the row value (frul,
    component); ``worst`` mixes directions, so it is the union of three ranges (same level
    and fHI with a later id, same level with a lower fHI, a lower level), each limited."""
    cols = ", ".join(COMPONENT_FIELDS)
    order = SORTS[sort][0]
    lv, lvp = ("level = ? AND ", [level]) if level is not None else ("", [])
    n = limit + offset
    if key is None:
        return (f"SELECT {cols} FROM components WHERE {lv}1 = 1 ORDER BY {order} "
                "LIMIT ? OFFSET ?", [*lvp, limit, offset])
    if sort == "rul":
        return (f"SELECT {cols} FROM components WHERE {lv}(frul, component) > (?, ?) "
                f"ORDER BY {order} LIMIT ? OFFSET ?", [*lvp, *key, limit, offset])
    lvl, fhi, comp = key
    parts = [("level = ? AND fhi = ? AND component > ?", [lvl, fhi, comp]),
             ("level = ? AND fhi < ?", [lvl, fhi]), ("level < ?", [lvl])]
    sql = " UNION ALL ".join(
        f"SELECT {cols} FROM (SELECT {cols} FROM components WHERE {lv}{cond} ORDER BY "
        f"{order} LIMIT {n}) AS p{i}" for i, (cond, _) in enumerate(parts))
    params = [v for _, ps in parts for v in (*lvp, *ps)]
    return (f"SELECT {cols} FROM ({sql}) AS page ORDER BY {order} LIMIT ? OFFSET ?",
            [*params, limit, offset])


def encode_cursor(row: tuple, sort: str) -> str:
    """The cursor of the page after ``row`` (a row of :data:`COMPONENT_FIELDS`)."""
    import base64

    key = [row[COMPONENT_FIELDS.index(c)] for c in SORTS[sort][1]]
    return base64.urlsafe_b64encode(json.dumps(key).encode()).decode().rstrip("=")


def _decode_cursor(cursor: str, sort: str) -> list[Any]:
    """The key of a cursor of ``sort``; ValueError if it is not one."""
    import base64

    try:
        key = json.loads(base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4)))
    except (ValueError, TypeError):
        raise ValueError("after: not a cursor returned by this API") from None
    want = [str if c == "component" else int if c == "level" else (int, float)
            for c in SORTS[sort][1]]
    if not isinstance(key, list) or len(key) != len(want) or not all(
            isinstance(v, t) and not isinstance(v, bool)
            for v, t in zip(key, want, strict=True)):
        raise ValueError(f"after: not a cursor of sort={sort}")
    return key


def _in_transaction(store: ComponentStore) -> bool:
    conn = store._conn
    if hasattr(conn, "in_transaction"):
        return bool(conn.in_transaction)
    raw = getattr(conn, "raw", None)
    if raw is None or raw.closed:
        return True
    import psycopg

    return bool(raw.info.transaction_status != psycopg.pq.TransactionStatus.IDLE)


def _component_dict(r: tuple) -> dict[str, Any]:
    d = dict(zip(COMPONENT_FIELDS, r, strict=True))
    out: dict[str, Any] = {"component": d["component"], "level": LEVEL_NAMES[int(d["level"])]}
    for k in ("hi", "fhi", "dhi"):
        out[k] = _num(d[k])
    out["rul"] = _num(d["frul"])
    out["rul_low"] = _num(d["rul_low"])
    out["rul_high"] = _num(d["rul_high"])
    out["drul"] = _num(d["drul"])
    out["d2rul"] = _num(d["d2rul"])
    out["valid"] = bool(d["valid"])
    out["last_time"] = _num(d["t"])
    out["n"] = int(d["n"])
    return out


def alert_json(a: Alert) -> dict[str, Any]:
    """A newly recorded alert as the API returns it."""
    return _alert_dict((a.id, a.component, a.t, a.level, a.previous, a.hi, a.fhi, a.frul,
                        a.valid, a.rul_low, a.rul_high, a.raised, None, None, None, None))


def _alert_dict(r: tuple) -> dict[str, Any]:
    d = dict(zip(ALERT_FIELDS, r, strict=True))
    ack = None
    if d["ack_at"] is not None:
        ack = {"by": d["ack_by"], "reason": d["ack_reason"], "at": _num(d["ack_at"]),
               "token_name": d["ack_token"]}
    return {"id": int(d["id"]), "component": d["component"], "time": _num(d["t"]),
            "level": LEVEL_NAMES[int(d["level"])], "previous": LEVEL_NAMES[int(d["previous"])],
            "hi": _num(d["hi"]), "fhi": _num(d["fhi"]), "rul": _num(d["frul"]),
            "rul_low": _num(d["rul_low"]), "rul_high": _num(d["rul_high"]),
            "valid": bool(d["valid"]), "raised": _num(d["raised"]), "acknowledged": ack}
