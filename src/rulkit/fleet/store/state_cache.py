"""The stored ``components`` rows a writing connection committed itself, kept in memory, so
that its next batch need not read them back (docs/systems/embedded-rul.md §4: a component's
state is read before each of its acquisitions is applied).

A :class:`StateCache` holds, per component, the row the store's read of the batch's stored
rows would return (``SELECT component, <columns> FROM components``), as the batch uses it
(:class:`~rulkit.fleet.store.tracker_rows.StoredRows`): every value the same float64 (NULL
as NaN, a bool or an int as the float64 of its value; -0.0 is made 0.0, as SQLite stores
it, unless ``signed_zeros``: PostgreSQL's float8 keeps it), kept in one array of rows, so
that a batch takes its components' rows with one index per name and one copy.
It is trusted only while no other connection has committed: SQLite's ``PRAGMA
data_version`` changes for a connection whenever another connection, in this process or
another, commits to the database, and the cache is emptied when it does (PostgreSQL: the
write counter of :mod:`rulkit.fleet.store.postgres`). Rows written in an
open transaction are kept apart (per batch, for the batch's savepoint) until the commit; a
rolled-back batch or a failed commit leaves nothing of theirs.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np

from rulkit.fleet.store.tracker_rows import StoredRows


class _Layer:
    """Rows written in the open transaction: ``pos[name]`` the row of ``name`` in the
    concatenation of ``chunks`` (the latest write of a name wins)."""

    def __init__(self) -> None:
        self.pos: dict[str, int] = {}
        self.chunks: list[np.ndarray] = []
        self.n = 0

    def add(self, names: Sequence[str], values: np.ndarray) -> None:
        self.pos.update(zip(names, range(self.n, self.n + len(names)), strict=True))
        self.chunks.append(values)
        self.n += len(names)

    def values(self) -> np.ndarray:
        if len(self.chunks) > 1:
            self.chunks = [np.concatenate(self.chunks)]
        return self.chunks[0]

    def latest(self) -> tuple[list[str], np.ndarray]:
        """Every name written, once, with its latest row."""
        return list(self.pos), self.values()[list(self.pos.values())]

    def clear(self) -> None:
        self.pos.clear()
        self.chunks.clear()
        self.n = 0


class StateCache:
    """``StateCache(columns, limit)``: rows of ``columns`` (the read's order) per component,
    at most ``limit`` components. ``signed_zeros``: -0.0 kept as given (the database stores
    it)."""

    def __init__(self, columns: Sequence[str], limit: int, signed_zeros: bool = False
                 ) -> None:
        self.columns = tuple(columns)
        self.signed_zeros = signed_zeros
        self.limit = limit
        self.version: int | None = None  # PRAGMA data_version when last trusted
        self._slot: dict[str, int] = {}  # committed: name -> row of _rows, oldest first
        self._rows = np.empty((0, len(self.columns)))
        self._free: list[int] = []  # rows of _rows no name holds
        self._open = _Layer()  # written by the transaction's released batches
        self._batch = _Layer()  # written by the batch under its savepoint

    def __len__(self) -> int:
        return len(self._slot)

    def begin(self, version: int) -> None:
        """At the start of a write transaction: ``version`` the connection's data version
        now; every row is dropped when another connection committed since the last commit."""
        if version != self.version:
            self._forget_committed()
        self.version = version
        self._open.clear()
        self._batch.clear()

    def split(self, names: Sequence[str]) -> tuple[StoredRows, list[str]]:
        """The rows of ``names`` known here (the open transaction's first), and the names
        to read from the database."""
        b = len(names)
        out = np.empty((b, len(self.columns)))
        found = np.zeros(b, dtype=bool)
        layers = ((self._slot, self._committed_rows), (self._open.pos, self._open.values),
                  (self._batch.pos, self._batch.values))
        for pos, values in layers:  # the later a layer, the newer its rows
            if not pos:
                continue
            idx = np.fromiter(map(pos.get, names, itertools.repeat(-1)), dtype=np.int64,
                              count=b)
            hit = idx >= 0
            out[hit] = values()[idx[hit]]
            found |= hit
        keep = np.flatnonzero(found).tolist()
        kept = StoredRows({names[k]: i for i, k in enumerate(keep)}, out[keep])
        return kept, [names[k] for k in np.flatnonzero(~found).tolist()]

    def put(self, names: Sequence[str], values: np.ndarray) -> None:
        """The rows of components ``names`` written in the current batch: ``values`` one row
        per name of :attr:`columns` (NaN for NULL), taken as float64 with -0.0 made 0.0, as
        SQLite stores it (kept as given with ``signed_zeros``)."""
        self._batch.add(names, np.array(values, dtype=np.float64) if self.signed_zeros
                        else np.asarray(values, dtype=np.float64) + 0.0)

    def release(self) -> None:
        """The batch was kept (its savepoint released)."""
        if self._batch.pos:
            self._open.add(*self._batch.latest())
        self._batch.clear()

    def rollback(self) -> None:
        """The batch was rolled back to its savepoint."""
        self._batch.clear()

    def commit(self) -> None:
        """The transaction committed: its rows become the committed state (over the limit,
        the components kept first are dropped first)."""
        if self._open.pos:
            names, values = self._open.latest()
            slots = [self._slot.get(n, -1) for n in names]
            new = [k for k, s in enumerate(slots) if s < 0]
            for k, s in zip(new, self._take_slots(len(new)), strict=True):
                slots[k] = s
                self._slot[names[k]] = s
            self._rows[slots] = values
        self._open.clear()
        excess = len(self._slot) - self.limit
        if excess > 0:
            for name in list(itertools.islice(self._slot, excess)):
                self._free.append(self._slot.pop(name))

    def _take_slots(self, k: int) -> list[int]:
        """``k`` rows of ``_rows`` no name holds (the array grown when needed)."""
        m = min(k, len(self._free))
        got = self._free[len(self._free) - m:]
        del self._free[len(self._free) - m:]
        short = k - m
        if short:
            used = self._rows.shape[0]
            grown = np.empty((max(2 * used, used + short), len(self.columns)))
            grown[:used] = self._rows
            self._rows = grown
            got += range(used, used + short)
            self._free += range(grown.shape[0] - 1, used + short - 1, -1)
        return got

    def _committed_rows(self) -> np.ndarray:
        return self._rows

    def _forget_committed(self) -> None:
        self._slot.clear()
        self._free.clear()
        self._rows = np.empty((0, len(self.columns)))

    def drop(self) -> None:
        """Forget everything (a failed commit, or a write this cache did not follow)."""
        self._forget_committed()
        self._open.clear()
        self._batch.clear()
        self.version = None


__all__ = ["StateCache"]
