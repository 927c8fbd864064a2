"""One acquisition's stored row: the field names of a component's tracker state and outputs in
``components`` and ``history``, the trackers' state from those rows and the refusal of a block
whose tracker outputs are not finite (docs/systems/embedded-rul.md §4)."""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from rulkit.fleet.store.acquisitions import IngestError
from rulkit.fleet.store.schema import COMPONENTS
from rulkit.fleet.tracking.tracker_chain import TrackerState
from rulkit.tables import cell_repr as _fmt

STATE_FIELDS = ("t", "n", "hi", "fhi", "dhi", "rul", "frul", "drul", "d2rul")
OUTPUT_FIELDS = ("valid", "level", "rul_low", "rul_high")
ROW_FIELDS = (*STATE_FIELDS, *OUTPUT_FIELDS)
HISTORY_FIELDS = tuple(f for f in ROW_FIELDS if f != "n")


_WHOLE = {c.name: bool if c.kind == "bool" else np.int64
          for c in COMPONENTS.columns if c.kind in ("int", "small", "bool")}
"""The columns of ``components`` that hold integers (or bools), and their type."""

TRACKER_OUT = tuple(f for f in HISTORY_FIELDS if f not in ("t", "hi", "valid", "level"))
"""The tracker's outputs per acquisition that the history stores as they are."""


@dataclass(frozen=True)
class StoredRows:
    """The stored ``components`` rows of some components, as a batch starts from them:
    ``values[pos[name]]`` the row of ``name``, float64 (NULL as NaN; an integer or a bool as
    the float64 of its value), its columns the store's state columns (:data:`ROW_FIELDS`
    first)."""

    pos: dict[str, int]
    values: np.ndarray

    @classmethod
    def of_tuples(cls, rows: Sequence[tuple], ncols: int) -> StoredRows:
        """From rows ``(component, *columns)`` as a query returns them."""
        if not rows:
            return cls({}, np.empty((0, ncols)))
        return cls({r[0]: i for i, r in enumerate(rows)},
                   np.array([r[1:] for r in rows], dtype=np.float64))

    @classmethod
    def joined(cls, parts: Sequence[StoredRows]) -> StoredRows:
        """The rows of ``parts`` (no component in two of them), in one."""
        parts = [p for p in parts if p.pos] or list(parts[:1])
        if len(parts) == 1:
            return parts[0]
        offsets = itertools.accumulate([len(p.pos) for p in parts[:-1]], initial=0)
        pos: dict[str, int] = {}
        for p, off in zip(parts, offsets, strict=True):
            pos.update(zip(p.pos, (i + off for i in p.pos.values()), strict=True))
        return cls(pos, np.concatenate([p.values for p in parts]))

    def __len__(self) -> int:
        return len(self.pos)

    def __contains__(self, name: object) -> bool:
        return name in self.pos

    def rows_of(self, names: Iterable[str]) -> tuple[np.ndarray, np.ndarray]:
        """The indices into ``names`` of the stored ones, and their rows."""
        idx = np.fromiter(map(self.pos.get, names, itertools.repeat(-1)), dtype=np.int64)
        known = np.flatnonzero(idx >= 0)
        return known, self.values[idx[known]]

    def last_t(self) -> dict[str, float]:
        """Each stored component's time of its last acquisition."""
        return dict(zip(self.pos, self.values[list(self.pos.values()), 0].tolist(),
                        strict=True))


def stored_state(names: list[str], stored: StoredRows
                 ) -> tuple[TrackerState, np.ndarray, np.ndarray]:
    """The trackers' state of ``names`` (empty for a new one) from their ``stored`` rows, the
    indices of the stored ones and their rows."""
    state = TrackerState.empty(len(names))
    known, vals = stored.rows_of(names)
    if known.size:
        col = {f: vals[:, j] for j, f in enumerate(ROW_FIELDS)}
        state.t[known], state.n[known] = col["t"], col["n"]
        state.hi[known], state.rul[known] = col["hi"], col["rul"]
        state.ab[known] = np.column_stack([col["fhi"], col["dhi"]])
        state.abg[known] = np.column_stack([col["frul"], col["drul"], col["d2rul"]])
    return state, known, vals


def component_rows(names: Sequence[str], values: np.ndarray, columns: Sequence[str],
                   nullable: Iterable[str] = (), key_last: bool = False) -> list[list]:
    """The ``components`` rows ``[component, *columns]`` (``[*columns, component]`` with
    ``key_last``) of ``names`` for SQL, from ``values`` (one float64 row per name, a column
    per name of ``columns``): Python floats, ints in the integer columns and bools in the
    boolean ones, NaN as ``None`` (NULL) in the ``nullable`` columns. A NaN in an integer or
    boolean column that is not nullable raises ``ValueError`` (it has no value to write). One
    conversion of the whole array, no loop over its rows."""
    b, k = values.shape
    obj = np.empty((b, k + 1), dtype=object)
    key, first = (k, 0) if key_last else (0, 1)
    obj[:, key] = names
    obj[:, first:first + k] = values
    nulls = set(nullable)
    null_cols = [j for j, c in enumerate(columns) if c in nulls]
    for j, c in enumerate(columns):
        kind = _WHOLE.get(c)
        if kind is None:
            continue
        if c not in nulls and np.isnan(values[:, j]).any():
            raise ValueError(f"components column {c}: NaN where an integer is required")
        obj[:, first + j] = np.nan_to_num(values[:, j]).astype(kind)
    if null_cols:
        rows, cols = np.nonzero(np.isnan(values[:, null_cols]))
        obj[rows, np.asarray(null_cols, dtype=np.intp)[cols] + first] = None
    return list(obj.tolist())


def refuse_non_finite(out: dict[str, np.ndarray], rank: np.ndarray, row: np.ndarray,
                       comp: np.ndarray, t: np.ndarray) -> None:
    """:class:`IngestError` for the first row of a block (by acquisition rank, then key
    order) whose tracker output is not finite, named by its batch ``row``, ``comp`` and
    ``t``."""
    finite = np.ones(rank.size, dtype=bool)
    for f in TRACKER_OUT:
        finite &= np.isfinite(out[f])
    if finite.all():
        return
    bad = np.flatnonzero(~finite)
    q = int(bad[np.argsort(rank[bad], kind="stable")[0]])
    f = next(f for f in TRACKER_OUT if not np.isfinite(out[f][q]))
    raise IngestError(
        f"row {row[q]} (component {comp[q]!r}), column 'time' = {_fmt(t[q])}: the tracker's "
        f"{f} is not finite (the interval since the previous "
        "acquisition or the time itself is too large for float64 arithmetic); use a smaller "
        "time unit or offset")


__all__ = ["HISTORY_FIELDS", "OUTPUT_FIELDS", "ROW_FIELDS", "STATE_FIELDS", "TRACKER_OUT",
           "StoredRows", "component_rows", "refuse_non_finite", "stored_state"]
