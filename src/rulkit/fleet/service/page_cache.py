"""The pages of components the service has answered, kept for as long as they are exactly
what a new read would answer (docs/service-load.md, "The client, the fixed cost of a request
and the pollers' pages").

A page (``GET /api/v1/components`` with its query) is a function of the committed database
and of the calendar time only through the stale rule: the stale flags, the stale filter and
the stale total, all set by the cutoff ``now - stale_after``. So a page's JSON text is served
again when both hold:

* nothing was committed since it was read: the
  :class:`~rulkit.fleet.service.commit_watch.CommitWatch`'s ``PRAGMA data_version``, read
  before the page was, is the same now (any commit in between, by any connection of any
  process, changes it; the page is then read again);
* the clock is in ``[now, until)``: ``now`` the time the page was read at and ``until`` the
  time the first component that was not stale then becomes stale
  (:meth:`~rulkit.fleet.service.db.ServiceDB.stale_horizon`), so the same components are
  stale; a clock set back misses.

Each entry is keyed on every query parameter of the page in canonical form. A newer
``data_version`` empties the cache, which holds at most :data:`MAX_BYTES` of JSON text.
"""

from __future__ import annotations

import threading
from collections.abc import Hashable

MAX_BYTES = 16 << 20
"""The JSON text kept at most (a page of 1,000 components is about 300 kB)."""


class PageCache:
    """The pages of the module docstring, by query key (thread-safe). ``hits`` counts the
    pages served from it."""

    def __init__(self, max_bytes: int = MAX_BYTES) -> None:
        self.max_bytes = max_bytes
        self.hits = 0
        self._lock = threading.Lock()
        self._version: int | None = None
        self._pages: dict[Hashable, tuple[float, float, bytes]] = {}
        self._bytes = 0

    def get(self, key: Hashable, version: int, now: float) -> bytes | None:
        """The page of ``key`` read at ``version`` and still valid at ``now``, or ``None``."""
        with self._lock:
            if self._version is None or version > self._version:
                self._pages.clear()  # committed since: every page may have changed
                self._version, self._bytes = version, 0
                return None
            if version < self._version:  # read before a commit another request saw
                return None
            found = self._pages.get(key)
            if found is None or not found[0] <= now < found[1]:
                return None
            self.hits += 1
            return found[2]

    def put(self, key: Hashable, version: int, now: float, until: float, body: bytes) -> None:
        """Keep ``body``, the page of ``key`` read after ``version`` was, at time ``now``,
        valid until ``until``."""
        with self._lock:
            if version != self._version or until <= now:
                return  # a commit since, seen by another request: the page may be older
            old = self._pages.pop(key, None)
            self._bytes -= 0 if old is None else len(old[2])
            if self._bytes + len(body) > self.max_bytes:
                self._pages.clear()
                self._bytes = 0
            self._pages[key] = (now, until, body)
            self._bytes += len(body)


__all__ = ["MAX_BYTES", "PageCache"]
