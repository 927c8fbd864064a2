"""The stored ``components`` rows a writing connection committed itself, kept in memory, so
that its next batch need not read them back (docs/systems/embedded-rul.md §4: a component's
state is read before each of its acquisitions is applied).

A :class:`StateCache` holds, per component, the row as the store's read of the batch's
stored rows returns it (``SELECT component, <columns> FROM components``: the values SQLite
gives back for what was written, NaN as ``None``, integers where the column is an integer).
It is trusted only while no other connection has committed: SQLite's ``PRAGMA
data_version`` changes for a connection whenever another connection, in this process or
another, commits to the database, and the cache is emptied when it does. Rows written in an
open transaction are kept apart (per batch, for the batch's savepoint) until the commit; a
rolled-back batch or a failed commit leaves nothing of theirs.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

_INT64 = 2.0**63


class StateCache:
    """``StateCache(columns, int_columns, limit)``: rows of ``columns`` (the read's order) per
    component; ``int_columns`` the columns of integer type; at most ``limit`` components
    (the least recently written are dropped first)."""

    def __init__(self, columns: Sequence[str], int_columns: Iterable[str], limit: int) -> None:
        self.columns = tuple(columns)
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

    def put(self, columns: Sequence[str], rows: Iterable[Sequence[Any]]) -> None:
        """Rows ``(component, *values)`` of ``columns`` (``columns[0]`` the component)
        written in the current batch, as the database returns them."""
        pos = {c: i for i, c in enumerate(columns)}
        take = [(pos[c], c in self._int) for c in self.columns]
        for row in rows:
            self._batch[row[0]] = tuple(_stored(row[i], as_int) for i, as_int in take)

    def release(self) -> None:
        """The batch was kept (its savepoint released)."""
        self._open.update(self._batch)
        self._batch.clear()

    def rollback(self) -> None:
        """The batch was rolled back to its savepoint."""
        self._batch.clear()

    def commit(self) -> None:
        """The transaction committed: its rows become the committed state."""
        for name, row in self._open.items():
            self._committed.pop(name, None)  # re-inserted last: the most recent
            self._committed[name] = row
        self._open.clear()
        excess = len(self._committed) - self.limit
        if excess > 0:
            for name in list(self._committed)[:excess]:
                del self._committed[name]

    def drop(self) -> None:
        """Forget everything (a failed commit, or a write this cache did not follow)."""
        self._committed.clear()
        self._open.clear()
        self._batch.clear()
        self.version = None


def _stored(v: Any, as_int: bool) -> Any:
    """``v`` as SQLite returns it from a column of integer (``as_int``) or real type: NaN
    as ``None`` (SQLite stores a NaN as NULL), a bool or a whole float of an integer
    column within 64 bits as ``int``, an int of a real column as ``float``, -0.0 as 0.0."""
    if v is None:
        return None
    if isinstance(v, bool):
        return int(v) if as_int else float(v)
    if isinstance(v, int):
        return v if as_int else float(v)
    if isinstance(v, float):
        if math.isnan(v):
            return None
        if as_int and v.is_integer() and -_INT64 <= v < _INT64:
            return int(v)
        return float(v) + 0.0  # -0.0 is stored as the integer 0: read back as 0.0
    return v


__all__ = ["StateCache"]
