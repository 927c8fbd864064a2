"""One acquisition's stored row: the field names of a component's tracker state and outputs in
``components`` and ``history``, the trackers' state from those rows and the refusal of a block
whose tracker outputs are not finite (docs/systems/embedded-rul.md §4)."""

from __future__ import annotations

import numpy as np

from rulkit.fleet.store.acquisitions import IngestError
from rulkit.fleet.tracking.tracker_chain import TrackerState
from rulkit.tables import cell_repr as _fmt

STATE_FIELDS = ("t", "n", "hi", "fhi", "dhi", "rul", "frul", "drul", "d2rul")
OUTPUT_FIELDS = ("valid", "level", "rul_low", "rul_high")
ROW_FIELDS = (*STATE_FIELDS, *OUTPUT_FIELDS)
HISTORY_FIELDS = tuple(f for f in ROW_FIELDS if f != "n")


TRACKER_OUT = tuple(f for f in HISTORY_FIELDS if f not in ("t", "hi", "valid", "level"))
"""The tracker's outputs per acquisition that the history stores as they are."""


def stored_state(names: list[str], stored: dict[str, tuple]
                  ) -> tuple[TrackerState, list[int]]:
    """The trackers' state of ``names`` (empty for a new one) from their ``stored`` rows
    (:data:`ROW_FIELDS` first), and the indices of the stored ones."""
    state = TrackerState.empty(len(names))
    known = [i for i, name in enumerate(names) if name in stored]
    if known:  # one array of the stored rows' ROW_FIELDS
        vals = np.array([stored[names[i]][:len(ROW_FIELDS)] for i in known], dtype=np.float64)
        col = {f: vals[:, j] for j, f in enumerate(ROW_FIELDS)}
        state.t[known], state.n[known] = col["t"], col["n"]
        state.hi[known], state.rul[known] = col["hi"], col["rul"]
        state.ab[known] = np.column_stack([col["fhi"], col["dhi"]])
        state.abg[known] = np.column_stack([col["frul"], col["drul"], col["d2rul"]])
    return state, known


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
           "refuse_non_finite", "stored_state"]
