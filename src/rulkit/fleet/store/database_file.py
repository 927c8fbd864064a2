"""The component database as a file: read-only probing, meta settings, durability.

Helpers of :mod:`rulkit.fleet.store.sqlite` that look at a database before it is opened for writing:
:func:`_probe` checks an existing file read-only (SQLite header, ``meta`` table, schema
version) so a foreign, empty or corrupt file keeps its bytes and gets a named
:class:`StoreError`; the tracker settings, HI model and learned
model are read from ``meta``; :func:`_fsync_dir` makes a published file durable.
"""

from __future__ import annotations

import json
import os
import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from rulkit.fleet.tracking.health_index import HealthIndexModel
from rulkit.fleet.tracking.tracker_chain import TrackerConfig
from rulkit.tables import safe_text

SCHEMA_VERSION = 1
SQLITE_HEADER = b"SQLite format 3\x00"


class StoreError(ValueError):
    """The database file cannot be used as a rulkit component database (missing directory,
    not a rulkit database, corrupt, other settings); the file is left as it was."""


class StoreBusyError(StoreError):
    """Another writer held the database longer than the timeout; nothing was written and the
    same call can be retried."""


def _uri(path: Path, mode: str) -> str:
    from urllib.parse import quote

    return f"file:{quote(str(path.absolute()))}?mode={mode}"


def _read_meta(conn: sqlite3.Connection) -> dict[str, str]:
    has_meta = conn.execute(
        "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'meta'").fetchone()
    return dict(conn.execute("SELECT key, value FROM meta").fetchall()) if has_meta else {}


def _probe(path: Path) -> dict[str, str] | None:
    """The ``meta`` of the rulkit database at ``path``, ``None`` if there is no file; anything
    else raises :class:`StoreError`. Read-only: the file's bytes never change."""
    if not path.exists():
        if not path.parent.is_dir():
            raise StoreError(f"{path}: the directory {path.parent} does not exist")
        return None
    if path.is_dir():
        raise StoreError(f"{path}: is a directory, expected a rulkit component database file")
    try:
        with open(path, "rb") as f:
            head = f.read(len(SQLITE_HEADER))
    except OSError as err:
        raise StoreError(f"{path}: cannot be read: {err.strerror or err}") from err
    if len(head) == 0:
        raise StoreError(f"{path}: empty file (0 bytes), not a rulkit component database; "
                         "refusing to write into it (remove it or choose another --db)")
    if head != SQLITE_HEADER:
        raise StoreError(f"{path}: not an SQLite database (no SQLite header), so not a rulkit "
                         "component database; left unchanged")
    try:
        # immutable: no lock, no -wal/-shm beside a file that may not be ours; the meta a
        # rulkit database is created with is in the main file (checkpointed before it is
        # linked into place), and an open store re-reads it through its own connection
        con = sqlite3.connect(_uri(path, "ro") + "&immutable=1", uri=True, timeout=5.0)
    except sqlite3.Error as err:
        raise StoreError(f"{path}: cannot be opened read-only: {err}") from err
    try:
        meta = _read_meta(con)
    except sqlite3.DatabaseError as err:
        raise StoreError(_db_error_message(path, err)) from err
    finally:
        con.close()
    if "schema_version" not in meta or "tracker_config" not in meta:
        raise StoreError(f"{path}: an SQLite database without rulkit's meta table, so not a "
                         "rulkit component database; left unchanged")
    if meta["schema_version"] != str(SCHEMA_VERSION):
        raise StoreError(f"{path}: schema version {safe_text(meta['schema_version'])}, this "
                         f"rulkit reads {SCHEMA_VERSION}")
    return meta


def _db_error_message(path: Path, err: sqlite3.Error) -> str:
    text = str(err)
    if isinstance(err, sqlite3.OperationalError) and ("locked" in text or "busy" in text):
        return (f"{path}: the database is busy (another process is writing to it); nothing "
                "was written, retry when it has finished")
    if isinstance(err, sqlite3.OperationalError) and "readonly" in text.replace("-", ""):
        return f"{path}: cannot be written (read-only file or directory): {text}"
    return (f"{path}: corrupt or truncated database ({text}); restore it from a backup "
            "(SQLite's .recover can salvage rows)")


def _connect(path: Path, timeout: float, readonly: bool) -> sqlite3.Connection:
    """A connection to the rulkit database at ``path`` (already checked by :func:`_probe`);
    ``readonly``: SQLite's ``mode=ro`` when the file or its directory is not writable (it may
    leave -shm/-wal), ``query_only`` always. SQLite errors raise :class:`StoreError`."""
    try:
        writable = os.access(path, os.W_OK) and os.access(path.parent, os.W_OK)
        if readonly and not writable:  # SQLite's read-only mode (may leave -shm/-wal)
            conn = sqlite3.connect(_uri(path, "ro"), uri=True, timeout=timeout,
                                   isolation_level=None, check_same_thread=False)
        else:  # the last connection to close removes -wal/-shm
            conn = sqlite3.connect(str(path), timeout=timeout, isolation_level=None,
                                   check_same_thread=False)
            conn.execute("PRAGMA synchronous=FULL")
        if readonly:
            conn.execute("PRAGMA query_only=1")
    except sqlite3.Error as err:
        raise StoreError(_db_error_message(path, err)) from err
    return conn


def _store_error(path: Path, err: sqlite3.Error, timeout: float) -> StoreError:
    """``err`` as :class:`StoreBusyError` (another writer held the lock past ``timeout``) or
    :class:`StoreError`, with the path."""
    msg = _db_error_message(path, err)
    if isinstance(err, sqlite3.OperationalError) and (
            "locked" in str(err) or "busy" in str(err)):
        return StoreBusyError(f"{msg} (waited {timeout:g} s)")
    return StoreError(msg)


def _config_from_meta(path: Path, meta: dict[str, str]
                      ) -> tuple[TrackerConfig, HealthIndexModel | None]:
    try:
        cfg = TrackerConfig.from_dict(json.loads(meta["tracker_config"]))
        model = (HealthIndexModel.from_dict(json.loads(meta["hi_model"]))
                 if "hi_model" in meta else None)
    except (ValueError, TypeError, KeyError) as err:
        raise StoreError(f"{path}: unreadable stored settings in table meta: "
                         f"{safe_text(err)}") from err
    return cfg, model


def _degradation_from_meta(path: Path, meta: dict[str, str]) -> Any:
    """The learned degradation model stored by ``rulkit fit`` (None if there is none)."""
    if "degradation_model" not in meta:
        return None
    from rulkit.fleet.learned.degradation import DegradationModel

    try:
        return DegradationModel.from_dict(json.loads(meta["degradation_model"]))
    except (ValueError, TypeError, KeyError) as err:
        raise StoreError(f"{path}: unreadable learned model in table meta: "
                         f"{safe_text(err)}") from err


def _meta_rows(config: TrackerConfig, hi_model: HealthIndexModel | None) -> list[tuple[str, str]]:
    rows = [("schema_version", str(SCHEMA_VERSION)),
            ("tracker_config", json.dumps(config.to_dict()))]
    if hi_model is not None:
        rows.append(("hi_model", json.dumps(hi_model.to_dict())))
    return rows


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def rows_of_components(conn: Any, table: str, cols: tuple[str, ...], names: list[str]
                       ) -> Iterator[tuple[int, tuple]]:
    """(index into ``names``, the row's ``cols``) of each of ``names`` stored in ``table``,
    read in chunks of 500 ids (the SQL parameter limits)."""
    pos = {n: i for i, n in enumerate(names)}
    for i0 in range(0, len(names), 500):
        chunk = names[i0:i0 + 500]
        q = (f"SELECT component, {', '.join(cols)} FROM {table} WHERE component IN "
             f"({','.join('?' * len(chunk))})")
        for row in conn.execute(q, chunk).fetchall():
            yield pos[row[0]], tuple(row[1:])
