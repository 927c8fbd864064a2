"""The component database as a file: opening it through SQLite, meta settings, durability.

docs/systems/embedded-rul.md §4. Helpers of :mod:`rulkit.fleet.store.sqlite` that open a database
and look at it before it is used for writing.

**The file is only ever opened through SQLite.** On Linux, closing *any* descriptor of a file
drops every POSIX lock the process holds on it, SQLite's included; a process that read the
database header with a plain ``open()`` while it held SQLite connections lost their locks, and
another process then deleted the write-ahead log the first one was still writing to
(acknowledged rows lost). So :func:`open_database` learns everything (no file, a directory, an
empty file, not an SQLite file, not a rulkit database, corrupt) from ``os.stat`` and from
SQLite's own answers, and reads ``meta`` through the write-ahead log (a database killed during
a checkpoint has a main file that only the log makes whole).

**Each failure has its own class, message and exit code** (docs/file-formats.md):
:class:`StoreBusyError` (another writer; retry, 75), :class:`StoreCorruptError` (SQLite
itself finds the file damaged, write-ahead log included; 65), :class:`StoreFullError` (no
space left; nothing written, 74), :class:`StoreReadOnlyError` (the file or its directory
cannot be written; 77), and :class:`StoreError` for the rest (not a rulkit database, other
settings; 1). :func:`store_error` maps an ``sqlite3.Error`` by its SQLite result code.

**Readers who cannot write** (another user's database, a read-only directory): when no
writer is active (no ``-wal`` file) the file is read as SQLite's ``immutable`` (no lock, no
``-wal``/``-shm`` created, which would otherwise be left behind owned by the reader and block
the owner's next write); when a writer is active its log is read through SQLite's read-only
mode. :func:`read_verified` repeats a read whose file changed meanwhile.
"""

from __future__ import annotations

import glob
import json
import os
import sqlite3
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

from rulkit.fleet.tracking.health_index import HealthIndexModel
from rulkit.fleet.tracking.tracker_chain import TrackerConfig
from rulkit.tables import safe_text

SCHEMA_VERSION = 1
T = TypeVar("T")
PG_SCHEMES = ("postgresql://", "postgres://")
"""How a ``--db`` that names a PostgreSQL database begins (a libpq URL)."""


def is_postgres_url(db: str | Path) -> bool:
    """Whether ``db`` (what ``--db`` gives) is a PostgreSQL URL rather than a SQLite file
    (decided without importing the PostgreSQL store: ``rulkit status`` stays light)."""
    return isinstance(db, str) and db.startswith(PG_SCHEMES)

class StoreError(ValueError):
    """The database cannot be used as a rulkit component database (missing directory, not a
    rulkit database, other settings); the file is left as it was. ``exit_code``: what a
    command exits with (the codes of :mod:`rulkit.cli.errors`)."""

    exit_code = 1


class StoreBusyError(StoreError):
    """Another writer held the database longer than the timeout; nothing was written and the
    same call can be retried."""

    exit_code = 75  # EXIT_BUSY


class StoreCorruptError(StoreError):
    """SQLite reports the database damaged (read through its write-ahead log)."""

    exit_code = 65  # EXIT_CORRUPT


class StoreFullError(StoreError):
    """The disk (or a size limit) is full, or the device failed; nothing was written."""

    exit_code = 74  # EXIT_IO


class StoreReadOnlyError(StoreError):
    """The database file or its directory cannot be written by this user."""

    exit_code = 77  # EXIT_NOPERM


_BUSY = ("SQLITE_BUSY", "SQLITE_LOCKED")
_READONLY = ("SQLITE_READONLY", "SQLITE_CANTOPEN", "SQLITE_PERM", "SQLITE_AUTH")


def store_error(path: Path | str, err: sqlite3.Error, timeout: float | None = None
                ) -> StoreError:
    """``err`` as the :class:`StoreError` subclass of its SQLite result code, with a message
    naming ``path`` and what to do (``timeout``: how long a busy writer was waited for)."""
    name = getattr(err, "sqlite_errorname", "") or ""
    text = safe_text(str(err))
    if name.startswith(_BUSY) or (not name and ("locked" in text or "busy" in text)):
        waited = "" if timeout is None else f" (waited {timeout:g} s)"
        return StoreBusyError(f"{path}: the database is busy (another process is writing to "
                              f"it); nothing was written, retry when it has finished{waited}")
    if name.startswith("SQLITE_FULL"):
        return StoreFullError(f"{path}: the disk is full ({text}); nothing was written, free "
                              "space and retry (the database is intact)")
    if name.startswith("SQLITE_IOERR"):
        return StoreFullError(f"{path}: input/output error ({text}; {name}); nothing was "
                              "written: check the disk and free space, then retry")
    if name.startswith(_READONLY) or "readonly" in text.replace("-", ""):
        return StoreReadOnlyError(f"{path}: cannot be written by this user (read-only file, "
                                  f"directory or file system: {text})")
    if name.startswith("SQLITE_NOTADB"):
        return StoreError(f"{path}: not an SQLite database (no SQLite header), so not a rulkit "
                          "component database; left unchanged")
    if name.startswith("SQLITE_CORRUPT"):
        return StoreCorruptError(
            f"{path}: SQLite reports the database damaged ({text}), reading it with its "
            "write-ahead log; keep the file and its -wal beside it, check it with sqlite3 "
            "'PRAGMA integrity_check', and restore it from a backup (SQLite's .recover can "
            "salvage rows)")
    return StoreError(f"{path}: cannot be used ({text}; {name or type(err).__name__})")


def _uri(path: Path, params: str) -> str:
    from urllib.parse import quote

    return f"file:{quote(str(path.absolute()))}?{params}"


def _read_meta(conn: sqlite3.Connection) -> dict[str, str]:
    has_meta = conn.execute(
        "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'meta'").fetchone()
    return dict(conn.execute("SELECT key, value FROM meta").fetchall()) if has_meta else {}


def _file_state(path: Path) -> tuple[int, int, int, bool]:
    """What changes when a writer touches the database: inode, size, modification time of the
    main file, and whether a write-ahead log exists (``os.stat`` only, never ``open``)."""
    st = os.stat(path)
    return st.st_ino, st.st_size, st.st_mtime_ns, os.path.exists(f"{path}-wal")


def _writable(path: Path) -> bool:
    return os.access(path, os.W_OK) and os.access(path.parent, os.W_OK)


def _check_file(path: Path) -> bool:
    """``False`` if there is no file at ``path``; :class:`StoreError` for a missing directory,
    a directory or an empty file (``os.stat`` only)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        if not path.parent.is_dir():
            raise StoreError(f"{path}: the directory {path.parent} does not exist") from None
        return False
    except OSError as err:
        raise StoreReadOnlyError(f"{path}: cannot be read: {err.strerror or err}") from err
    if os.path.isdir(path):
        raise StoreError(f"{path}: is a directory, expected a rulkit component database file")
    if st.st_size == 0:
        raise StoreError(f"{path}: empty file (0 bytes), not a rulkit component database; "
                         "refusing to write into it (remove it or choose another --db)")
    return True


def _connect(path: Path, timeout: float, readonly: bool) -> tuple[sqlite3.Connection, bool]:
    """A connection to the existing file ``path`` and whether it is SQLite's ``immutable``
    read (module docstring). Writable by this user: a normal connection (``query_only`` when
    ``readonly``; the last connection to close checkpoints and removes ``-wal``/``-shm``).
    Otherwise, ``readonly`` only: ``immutable`` when no writer is active, else ``mode=ro``
    over the writer's log."""
    kw: dict[str, Any] = {"timeout": timeout, "isolation_level": None,
                          "check_same_thread": False}
    immutable = False
    try:
        if _writable(path) or not readonly:
            conn = sqlite3.connect(str(path), **kw)
            conn.execute("PRAGMA synchronous=FULL")
        elif not os.path.exists(f"{path}-wal"):
            conn = sqlite3.connect(_uri(path, "mode=ro&immutable=1"), uri=True, **kw)
            immutable = True
        else:
            conn = sqlite3.connect(_uri(path, "mode=ro"), uri=True, **kw)
        if readonly:
            conn.execute("PRAGMA query_only=1")
    except sqlite3.Error as err:
        raise store_error(path, err) from err
    return conn, immutable


def _checked_meta(path: Path, conn: sqlite3.Connection) -> dict[str, str]:
    """``meta`` read through ``conn`` (write-ahead log included), checked to be rulkit's."""
    try:
        meta = _read_meta(conn)
    except sqlite3.Error as err:
        raise store_error(path, err) from err
    if "schema_version" not in meta or "tracker_config" not in meta:
        raise StoreError(f"{path}: an SQLite database without rulkit's meta table, so not a "
                         "rulkit component database; left unchanged")
    if meta["schema_version"] != str(SCHEMA_VERSION):
        raise StoreError(f"{path}: schema version {safe_text(meta['schema_version'])}, this "
                         f"rulkit reads {SCHEMA_VERSION}")
    return meta


def open_database(path: Path, *, timeout: float = 30.0, readonly: bool = False
                  ) -> tuple[sqlite3.Connection, dict[str, str]] | None:
    """An open connection to the rulkit database at ``path`` and its checked ``meta``, or
    ``None`` if there is no file. Everything is learned through ``os.stat`` and SQLite
    (module docstring); the file's bytes never change when it is refused."""
    if not _check_file(path):
        return None
    conn, _ = _connect(path, timeout, readonly)
    try:
        return conn, _checked_meta(path, conn)
    except BaseException:
        conn.close()
        raise


def read_verified(path: Path, timeout: float, read: Callable[[sqlite3.Connection], T]) -> T:
    """``read(conn)`` on a read-only connection to ``path`` (checked rulkit database), with
    ``meta`` checked first. An ``immutable`` read (module docstring) is repeated through the
    writer's log when the file changed while it ran, so a reader never returns, or reports as
    corrupt, a state a concurrent checkpoint was rewriting."""
    if not _check_file(path):
        raise FileNotFoundError(f"{path}: no such database")
    for _attempt in range(3):
        before = _file_state(path)
        conn, immutable = _connect(path, timeout, readonly=True)
        try:
            try:
                _checked_meta(path, conn)
                out = read(conn)
            except StoreError:
                if immutable and _file_state(path) != before:
                    continue
                raise
            if immutable and _file_state(path) != before:
                continue
            return out
        finally:
            conn.close()
    raise StoreBusyError(f"{path}: the database kept changing while it was read; retry")


def _probe(path: Path, timeout: float = 30.0) -> dict[str, str] | None:
    """The checked ``meta`` of the rulkit database at ``path``, ``None`` if there is no file
    (:func:`read_verified`: read-only, through SQLite; waits up to ``timeout`` seconds for a
    writer's lock)."""
    try:
        return read_verified(path, timeout, _read_meta)
    except FileNotFoundError:
        return None


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
    """The learned model stored by ``rulkit fit`` (None if there is none)."""
    if "degradation_model" not in meta:
        return None
    from rulkit.fleet.learned.candidates import model_from_dict

    try:
        return model_from_dict(json.loads(meta["degradation_model"]))
    except (ValueError, TypeError, KeyError) as err:
        raise StoreError(f"{path}: unreadable learned model in table meta: "
                         f"{safe_text(err)}") from err


def time_axis_from_meta(path: Path, meta: dict[str, str]) -> Any:
    """The :class:`~rulkit.fleet.time_axis.TimeAxis` stored by ``rulkit fit`` (None: a
    database from before, whose time column is read as it always was)."""
    if "time_axis" not in meta:
        return None
    from rulkit.fleet.time_axis import TimeAxis

    try:
        return TimeAxis.from_dict(json.loads(meta["time_axis"]))
    except (ValueError, TypeError, KeyError) as err:
        raise StoreError(f"{path}: unreadable time axis in table meta: "
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


def creation_path(path: Path) -> Path:
    """A private file beside ``path`` in which a new database is built before it is linked
    into place (:func:`link_into_place`); creations of ``path`` left by dead processes are
    removed first (:func:`remove_stale_creations`)."""
    remove_stale_creations(path)
    return path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.creating")


def link_into_place(tmp: Path, path: Path) -> bool:
    """Publish the finished private database ``tmp`` (no SQLite connection holds it) as
    ``path``: synced, then hard-linked, which fails if ``path`` appeared meanwhile (then
    ``False``: another process created it first); on a file system without hard links
    renamed, with a small race window. The directory is synced after."""
    fd = os.open(tmp, os.O_RDWR)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    try:
        os.link(tmp, path)
    except FileExistsError:
        return False
    except OSError:  # a file system without hard links: rename, a small race window
        if path.exists():
            return False
        os.replace(tmp, path)
    _fsync_dir(path.parent)
    return True


def remove_stale_creations(path: Path) -> None:
    """Delete the temporary files of creations of ``path`` whose process is gone (a first
    ingest killed before it published its database leaves ``.NAME.PID.XXXXXXXX.creating``
    and its journals; the PID in the name tells whether it is still running)."""
    for tmp in path.parent.glob(f".{glob.escape(path.name)}.*.creating*"):
        parts = tmp.name[len(path.name) + 2:].split(".")
        if len(parts) < 3 or not parts[0].isdigit():
            continue
        pid = int(parts[0])
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            tmp.unlink(missing_ok=True)
        except PermissionError:  # another user's process: alive
            continue
