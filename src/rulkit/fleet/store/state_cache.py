"""The stored ``components`` rows a writing connection committed itself, kept in memory, so
that its next batch need not read them back (docs/systems/embedded-rul.md §4: a component's
state is read before each of its acquisitions is applied).

A :class:`StateCache` holds, per component, the row the store's read of the batch's stored
rows would return (``SELECT component, <columns> FROM components``), as the batch uses it:
every value the same float64 (the batch builds its arrays from the rows with
``dtype=float64``: ``None`` and NaN alike, a bool or an int of the same value alike; -0.0 is
made 0.0, as SQLite stores it, unless ``signed_zeros``: PostgreSQL's float8 keeps it).
It is trusted only while no other connection has committed: SQLite's ``PRAGMA
data_version`` changes for a connection whenever another connection, in this process or
another, commits to the database, and the cache is emptied when it does (PostgreSQL: the
write counter of :mod:`rulkit.fleet.store.postgres`). Rows written in an
open transaction are kept apart (per batch, for the batch's savepoint) until the commit; a
rolled-back batch or a failed commit leaves nothing of theirs.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np


class StateCache:
    """``StateCache(columns, int_columns, limit)``: rows of ``columns`` (the read's order) per
    component; ``int_columns`` the columns of integer type; at most ``limit`` components.
    ``signed_zeros``: a real column's -0.0 kept as given (the database stores it)."""

    def __init__(self, columns: Sequence[str], int_columns: Iterable[str], limit: int,
                 signed_zeros: bool = False) -> None:
        self.columns = tuple(columns)
        self.signed_zeros = signed_zeros
        self._int = frozenset(int_columns)
        self.limit = limit
        self.version: int | None = None  # PRAGMA data_version when last trusted
        self._committed: dict[str, tuple] = {}
        self._open: dict[str, tuple] = {}  # written by the transaction's released batches
        self._batch: dict[str, tuple] = {}  # written by the batch under its savepoint

    def __len__(self) -> int:
        return len(self._committed)

    def begin(self, version: int) -> None:
        """At the start of a write transaction: ``version`` the connection's data version
        now; every row is dropped when another connection committed since the last commit."""
        if version != self.version:
            self._committed.clear()
        self.version = version
        self._open.clear()
        self._batch.clear()

    def split(self, names: Iterable[str]) -> tuple[dict[str, tuple], list[str]]:
        """The rows of ``names`` known here (the open transaction's first), and the names
        to read from the database."""
        found: dict[str, tuple] = {}
        missing: list[str] = []
        for name in names:
            row = self._batch.get(name) or self._open.get(name) or self._committed.get(name)
            if row is None:
                missing.append(name)
            else:
                found[name] = row
        return found, missing

    def put(self, names: Sequence[str], columns: Mapping[str, Sequence[Any]]) -> None:
        """The rows of components ``names`` written in the current batch: ``columns`` maps
        each column to its values (in the order of ``names``; ``None`` or NaN for NULL). A
        column of reals holding a zero is taken through float64 with -0.0 made 0.0, as
        SQLite stores it; the others are kept as given (a bool of an integer column reads
        as the same float64 as SQLite's integer)."""
        cols = []
        for c in self.columns:
            v = columns[c]
            if not self.signed_zeros and c not in self._int and 0.0 in v:  # -0.0 == 0.0
                v = (np.asarray(v, dtype=np.float64) + 0.0).tolist()
            cols.append(v)
        self._batch.update(zip(names, zip(*cols, strict=True), strict=True))

    def release(self) -> None:
        """The batch was kept (its savepoint released)."""
        self._open.update(self._batch)
        self._batch.clear()

    def rollback(self) -> None:
        """The batch was rolled back to its savepoint."""
        self._batch.clear()

    def commit(self) -> None:
        """The transaction committed: its rows become the committed state (over the limit,
        the components kept first are dropped first)."""
        self._committed.update(self._open)
        self._open.clear()
        excess = len(self._committed) - self.limit
        if excess > 0:
            for name in list(itertools.islice(self._committed, excess)):
                del self._committed[name]

    def drop(self) -> None:
        """Forget everything (a failed commit, or a write this cache did not follow)."""
        self._committed.clear()
        self._open.clear()
        self._batch.clear()
        self.version = None


__all__ = ["StateCache"]
