"""A new database's pages sent to the disk while it is still being written, so that the one
``fsync`` before it is published (:func:`~rulkit.fleet.store.database_file.link_into_place`)
waits for little (docs/systems/embedded-rul.md §4; docs/service-load.md, "Track's wall time").

A new database is built without syncs and synced once at the end; of a large batch's file
(some 100 bytes an acquisition) the operating system would start writing nothing before that
sync, which then waits for all of it. :class:`EarlyWriteback` asks the kernel, from a thread of
its own, to start writing the file's dirty pages every :data:`PERIOD` seconds
(``sync_file_range(SYNC_FILE_RANGE_WRITE)``: start, do not wait), so the disk works while the
process computes. It changes when bytes reach the disk, never which: the final ``fsync`` is
what makes the file durable. Where ``sync_file_range`` is missing (not Linux), it does nothing.

The file is opened once and closed only after SQLite's connection to it is closed: closing a
descriptor of a file drops every POSIX lock the process holds on it, SQLite's included.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import threading
from pathlib import Path
from typing import Any

PERIOD = 0.05
"""Seconds between two requests to start writing the file's dirty pages."""

_SYNC_FILE_RANGE_WRITE = 2


def _sync_file_range() -> Any:
    """libc's ``sync_file_range`` (it releases the GIL while it runs), or ``None``."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        fn = libc.sync_file_range
    except (OSError, AttributeError, TypeError):  # no C library by that name, or no call
        return None
    fn.argtypes = (ctypes.c_int, ctypes.c_longlong, ctypes.c_longlong, ctypes.c_uint)
    fn.restype = ctypes.c_int
    return fn


class EarlyWriteback:
    """The file at ``path`` (existing), its dirty pages written out while :meth:`start` ..
    :meth:`stop` runs; :attr:`fd` its descriptor, open until :meth:`close` (``None``, and
    nothing done, when it cannot be opened: the final ``fsync`` does the work)."""

    def __init__(self, path: Path) -> None:
        try:
            self.fd: int | None = os.open(path, os.O_RDWR)
        except OSError:
            self.fd = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Start the thread that asks for the file's pages to be written (none where the
        call is missing)."""
        fn = _sync_file_range()
        if fn is None or self.fd is None or self._thread is not None:
            return
        self._thread = threading.Thread(target=self._run, args=(fn,), daemon=True,
                                        name="rulkit-writeback")
        self._thread.start()

    def _run(self, fn: Any) -> None:
        fd = self.fd
        while not self._stop.wait(PERIOD):
            if fn(fd, 0, 0, _SYNC_FILE_RANGE_WRITE) != 0:
                return  # e.g. a file system without it: the final fsync does the work

    def stop(self) -> None:
        """Stop the thread (after its current request)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None

    def close(self) -> None:
        """Stop, and close the descriptor (only once no SQLite connection holds the file)."""
        self.stop()
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None
