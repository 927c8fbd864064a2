"""A validated batch grouped by component in the store's key order, and the checks of its
times against the stored last acquisitions (docs/systems/embedded-rul.md §4).

The store writes history sorted by (component, t), so SQLite appends to its B-tree; components
are ordered by SQLite's BINARY collation (UTF-8 byte order = code point order = Python's
``str`` order) and processed in blocks of consecutive components.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rulkit.fleet.store.acquisitions import Batch, ConflictError, IngestError
from rulkit.fleet.store.history_chunks import field, read_range
from rulkit.fleet.tracking.tracker_chain import TrackerConfig
from rulkit.fleet.tracking.tracker_settings import check_intervals
from rulkit.tables import cell_repr as _fmt

IntArray = NDArray[np.int64]
SAME_HI_RTOL = 1e-12
"""Relative tolerance under which a re-sent acquisition's HI equals the stored one."""


@dataclass(frozen=True)
class ComponentOrder:
    """Rows of a batch grouped by component. ``sorted_pos[k]``: the component (index into the
    batch's names) at key-order position ``k``; ``by_comp``: batch positions grouped by
    component in key order, batch (= time) order inside; ``counts[k]``: acquisitions of the
    component at position ``k``; ``start``: offsets into ``by_comp`` (length b + 1)."""

    sorted_pos: IntArray
    by_comp: IntArray
    counts: IntArray
    start: IntArray


def order_by_component(codes: NDArray[np.int32], names: list[str]) -> ComponentOrder:
    """The :class:`ComponentOrder` of rows whose component is ``names[codes[i]]``."""
    b = len(names)
    sorted_pos = np.argsort(np.array(names, dtype=object), kind="stable")
    name_order = np.empty(b, dtype=np.int32)
    name_order[sorted_pos] = np.arange(b, dtype=np.int32)
    key = name_order[codes]
    by_comp = np.argsort(key, kind="stable")
    counts = np.bincount(key, minlength=b)
    start = np.concatenate([[0], np.cumsum(counts)])
    return ComponentOrder(sorted_pos, by_comp, counts, start)


def gaps_after_stored(order: ComponentOrder, t: np.ndarray, rows: np.ndarray,
                      names: list[str], last_t: np.ndarray) -> np.ndarray:
    """Each acquisition's interval since the previous one of its component (NaN for a
    component's first ever), in key order (``order.by_comp``'s). ``last_t``: the stored last
    time of each component in key order (NaN: new). A component's first acquisition of the
    batch that is not after its stored last, or whose interval overflows float64, raises
    :class:`IngestError` naming the first such row in batch order."""
    n = t.size
    first = order.by_comp[order.start[:-1]]  # batch position of each component's first row
    with np.errstate(over="ignore", invalid="ignore"):
        huge = np.isfinite(last_t) & ~np.isfinite(t[first] - last_t)
    back = np.isfinite(last_t) & ~(t[first] > last_t)
    for bad, what in ((huge, "huge"), (back, "back")):
        if bad.any():
            k = int(np.argmin(np.where(bad, first, n)))  # first in batch order
            i, g = int(first[k]), int(order.sorted_pos[k])
            raise IngestError(
                f"row {rows[i]} (component {names[g]!r}), column 'time': the interval "
                f"from the last stored acquisition at {_fmt(last_t[k])} to {_fmt(t[i])} "
                "overflows float64; use a smaller time unit or offset" if what == "huge"
                else f"row {rows[i]} (component {names[g]!r}): time {_fmt(t[i])} is "
                f"not after the component's last stored acquisition at {_fmt(last_t[k])}")
    ts = t[order.by_comp]
    gaps = np.empty(n)
    np.subtract(ts[1:], ts[:-1], out=gaps[1:])
    head = order.start[:-1][order.counts > 0]
    gaps[head] = ts[head] - last_t[order.counts > 0]
    return gaps


def check_spacing(config: TrackerConfig, gaps: np.ndarray) -> None:
    """The batch's acquisition spacing against ``design_life`` (time-unit check,
    :func:`rulkit.fleet.tracking.tracker_settings.check_intervals`), as an
    :class:`IngestError`. ``gaps``: as :func:`gaps_after_stored` gives them."""
    try:
        check_intervals(config, gaps[np.isfinite(gaps) & (gaps > 0)], source="time column")
    except ValueError as err:
        raise IngestError(str(err)) from err


def component_blocks(order: ComponentOrder, block_rows: int) -> list[tuple[int, int]]:
    """Blocks ``(k0, k1)`` of consecutive components (key order) holding at most
    ``block_rows`` acquisitions each (a component with more is a block of its own); one block
    for a batch of at most ``block_rows`` rows."""
    b = order.counts.size
    if order.start[-1] <= block_rows:
        return [(0, b)]
    blocks, k0 = [], 0
    while k0 < b:
        k1 = k0 + 1
        while k1 < b and order.start[k1 + 1] - order.start[k0] <= block_rows:
            k1 += 1
        blocks.append((k0, k1))
        k0 = k1
    return blocks


@dataclass(frozen=True)
class Piece:
    """Rows of a batch run together: ``keys`` the key-order positions of its components,
    ``seg`` offsets (length ``keys.size + 1``) of each one's rows in ``rows`` (batch
    positions, component by component, time order inside) and ``rank0`` the acquisition rank
    (within the batch) of every component's first row of the piece."""

    keys: IntArray
    seg: IntArray
    rows: IntArray
    rank0: int


def block_pieces(order: ComponentOrder, blocks: list[tuple[int, int]]) -> list[Piece]:
    """The :class:`Piece` of each block ``(k0, k1)`` of consecutive components
    (:func:`component_blocks`): all their rows."""
    st = order.start
    return [Piece(np.arange(k0, k1), st[k0:k1 + 1] - st[k0], order.by_comp[st[k0]:st[k1]], 0)
            for k0, k1 in blocks]


def rank_windows(order: ComponentOrder, window_rows: int) -> list[tuple[int, int]]:
    """Windows ``(r0, r1)`` of consecutive acquisition ranks holding at most ``window_rows``
    rows of all components together (a rank with more is a window of its own): a wide batch
    run rank by rank across every unit, as a time-ordered feed delivers it, holding one
    window's outputs."""
    width = np.cumsum(np.bincount(order.counts)[::-1])[::-1][1:]  # rows at each rank
    cum = np.cumsum(width)
    windows, r0, done = [], 0, 0
    while r0 < width.size:
        r1 = max(r0 + 1, int(np.searchsorted(cum, done + window_rows, side="right")))
        windows.append((r0, r1))
        done, r0 = int(cum[r1 - 1]), r1
    return windows


def window_piece(order: ComponentOrder, r0: int, r1: int) -> Piece:
    """The :class:`Piece` of the rows of ranks ``r0`` to ``r1 - 1`` of every component."""
    cw = np.clip(order.counts - r0, 0, r1 - r0)
    keys = np.flatnonzero(cw)
    cw = cw[keys]
    seg = np.concatenate([[0], np.cumsum(cw)])
    pos = np.repeat(order.start[keys] + r0 - seg[:-1], cw) + np.arange(int(seg[-1]))
    return Piece(keys, seg, order.by_comp[pos], r0)


def split_duplicates(conn: Any, acq: Batch, last: dict[str, float]) -> tuple[Batch, int]:
    """Split off rows at or before a component's stored last time (inside the write
    transaction on ``conn``, a DB-API connection): rows stored with the same HI (to
    :data:`SAME_HI_RTOL`) are duplicates, skipped and counted; anything else raises
    :class:`ConflictError` naming the row (acquisitions are appended in time order).
    ``last``: the stored last time of each stored component of the batch."""
    if not last:
        return acq, 0
    last_t = np.array([last.get(c, np.nan) for c in acq.names])[acq.codes]  # NaN: new
    old = np.flatnonzero(acq.t <= last_t)
    if old.size == 0:
        return acq, 0
    old_codes = acq.codes[old]
    _, first = np.unique(old_codes, return_index=True)
    for code in old_codes[np.sort(first)].tolist():  # by first appearance in the batch
        idx = old[old_codes == code]
        _check_stored(conn, acq.names[code], acq.row[idx].tolist(), acq.t[idx].tolist(),
                      acq.hi[idx].tolist(), last[acq.names[code]])
    keep = np.ones(len(acq), dtype=bool)
    keep[old] = False
    return acq.take(keep), int(old.size)


def _check_stored(conn: Any, name: str, rows: list[int], ts: list[float], his: list[float],
                  last: float) -> None:
    """One component's rows at or before its stored ``last`` time: each stored with the same
    HI, or :class:`ConflictError`."""
    rec = read_range(conn, name, min(ts), max(ts))
    stored = dict(zip(field(rec, "t").tolist(), field(rec, "hi").tolist(), strict=True))
    for row, t, hi in zip(rows, ts, his, strict=True):
        if float(t) not in stored:
            raise ConflictError(
                f"row {row} (component {name!r}): time {_fmt(t)} is before the "
                f"component's last stored acquisition at {_fmt(last)} and "
                "is not stored (acquisitions are appended in time order)")
        h = float(stored[float(t)])
        if abs(h - hi) > SAME_HI_RTOL * max(1.0, abs(h), abs(hi)):
            raise ConflictError(
                f"row {row} (component {name!r}): time {_fmt(t)} is already "
                f"stored with hi = {_fmt(h)}; this batch gives {_fmt(hi)}")


__all__ = ["SAME_HI_RTOL", "ComponentOrder", "Piece", "block_pieces", "check_spacing",
           "component_blocks", "gaps_after_stored", "order_by_component", "rank_windows",
           "split_duplicates", "window_piece"]
