"""A SQLite connection of the service's own that only reads (docs/service-load.md, "The client,
the fixed cost of a request and the pollers' pages"): the tokens, and whether anything was
committed since it last looked.

``PRAGMA data_version`` of a connection changes whenever another connection, in this process
or another, has committed since this connection's previous read, and this connection never
writes (``query_only``): so two equal values mean no commit at all between the two reads, by
the service's own group commits, its pool, ``rulkit track`` or ``rulkit token revoke`` in
another process. :class:`~rulkit.fleet.service.page_cache.PageCache` keys its pages on it.

The token check reads ``api_tokens`` on this connection at every request (SHA-256 and one
indexed ``SELECT``, about 10 us): no token is remembered, so a revocation committed by any
process takes effect on the next request. Both reads take a few microseconds and never wait
for a writer (WAL), so the service runs them on its event loop instead of handing them to a
worker thread (a hand-off costs more CPU than the reads). A lock serialises the threads that
share the connection. PostgreSQL has no such counter and its reads are round trips to the
server: it has no watch (``ServiceDB.watch`` is ``None``).
"""

from __future__ import annotations

import threading
from pathlib import Path

from rulkit.fleet.store.database_file import StoreError, open_database

TIMEOUT = 5.0
"""Seconds a read may wait for SQLite's locks (a reader waits only while the write-ahead log's
index is rebuilt after a crash)."""


class CommitWatch:
    """The read-only connection of the module docstring to the SQLite database at ``path``
    (which must exist and be writable by this user: the service's own)."""

    def __init__(self, path: str | Path) -> None:
        opened = open_database(Path(path), timeout=TIMEOUT, readonly=True)
        if opened is None:
            raise StoreError(f"{path}: no database to watch")
        self._conn = opened[0]
        self._lock = threading.Lock()

    def version(self) -> int:
        """SQLite's ``PRAGMA data_version`` on this connection (module docstring)."""
        with self._lock:
            return int(self._conn.execute("PRAGMA data_version").fetchone()[0])

    def token_row(self, digest: str) -> tuple[int, str, str] | None:
        """(id, name, role) of the active token whose SHA-256 is ``digest``, or ``None``."""
        with self._lock:
            row = self._conn.execute(
                "SELECT id, name, role FROM api_tokens WHERE hash = ? AND revoked IS NULL",
                (digest,)).fetchone()
        return None if row is None else (int(row[0]), str(row[1]), str(row[2]))

    def close(self) -> None:
        """Close the connection."""
        with self._lock:
            self._conn.close()


__all__ = ["TIMEOUT", "CommitWatch"]
