"""A wide batch's history records staged by rank window in a temporary file, then given back
per block of consecutive components in the order of the per-component path, so that the
history holds one chunk per component and ingestion whatever the windows
(docs/systems/embedded-rul.md §4; docs/service-load.md, "Where track's 2M rows go").

A batch run in windows of acquisition ranks (:func:`~rulkit.fleet.store.batch_order.
rank_windows`) has each component's records spread over the windows; holding them until the
last window would hold the file's (104 bytes an acquisition). The stage appends each window's
records to an unlinked temporary file (the operating system's page cache holds them, not the
process) and reads a block's back with one read per window: a block of consecutive components
is one contiguous range of each window's records (both are in key order).

The file's writes and reads run on one worker thread beside the batch's: a window's records
are written while the next window is computed (one write in flight at most: its records are
held until written), and the next block is read back while the caller writes the current one
into the database (the file's and SQLite's calls release the interpreter's lock). The bytes,
their order and the blocks given back are those of writing and reading in line.
"""

from __future__ import annotations

import errno
import os
import tempfile
from bisect import bisect_left
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np

from rulkit.fleet.monitoring.unit_trend import trend_strategy
from rulkit.fleet.store.batch_order import (
    ComponentOrder,
    Piece,
    block_pieces,
    component_blocks,
    rank_windows,
    window_piece,
)
from rulkit.fleet.store.database_file import StoreError, StoreFullError, StoreReadOnlyError
from rulkit.fleet.store.history_chunks import MAX_CHUNK, WIDTH, Chunks, layout
from rulkit.fleet.tracking.tracker_run import tracker_strategy
from rulkit.tables import safe_text


class HistoryStage:
    """The records of the rank windows of one batch, with ``order`` its
    :class:`~rulkit.fleet.store.batch_order.ComponentOrder`, in a temporary file in
    ``directory`` (the database's: room for the history it will hold), else in the system's
    temporary directory; use as a context manager."""

    def __init__(self, order: ComponentOrder, directory: Path | None = None) -> None:
        self.order = order
        self.directory = directory
        try:
            self._file = tempfile.TemporaryFile(dir=directory)
        except OSError as err:
            if directory is None:
                raise self._error(err) from err
            self.directory = None  # e.g. a database file writable in a directory that is not
            try:
                self._file = tempfile.TemporaryFile()
            except OSError as err2:
                raise self._error(err2) from err2
        # per window: its components' key-order positions (array and list), their records'
        # offsets and counts, its first batch rank and its records' file offset
        self._windows: list[tuple[np.ndarray, list[int], np.ndarray, np.ndarray, int, int]] = []
        self._size = 0
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rulkit-stage")
        self._written: Future[None] | None = self._worker.submit(
            _reserve, self._file.fileno(), int(order.start[-1]) * WIDTH * 8)

    def __enter__(self) -> HistoryStage:
        return self

    def __exit__(self, *exc: object) -> None:
        self._worker.shutdown(wait=True, cancel_futures=True)
        self._file.close()

    def add(self, piece: Piece, rec: np.ndarray) -> None:
        """Stage the records ``rec`` of the window ``piece`` (its rows' order): written by
        the worker once the previous window's are."""
        rec = np.ascontiguousarray(rec, dtype="<f8")
        self._wait_written()
        self._written = self._worker.submit(_write_at, self._file.fileno(), rec, self._size)
        self._windows.append((piece.keys, piece.keys.tolist(), piece.seg, np.diff(piece.seg),
                              piece.rank0, self._size))
        self._size += rec.nbytes

    def _wait_written(self) -> None:
        """Wait for the window in flight; a failed write raises the store's error."""
        if self._written is not None:
            done, self._written = self._written, None
            try:
                done.result()
            except OSError as err:
                raise self._error(err) from err

    def blocks(self, block_rows: int, max_chunk: int = MAX_CHUNK
               ) -> Iterator[tuple[int, int, Chunks]]:
        """``(k0, k1, chunks)`` per block of consecutive components (at most ``block_rows``
        acquisitions, :func:`~rulkit.fleet.store.batch_order.component_blocks`): the
        history chunks (:func:`~rulkit.fleet.store.history_chunks.layout`, at most
        ``max_chunk`` acquisitions each) of the components at key-order positions ``k0`` to
        ``k1 - 1``, ``owner`` counted from ``k0``. Each window's records of the block are
        read straight into their places beside the chunks' headers: one scattered read per
        window (a component's run of ranks is one contiguous stretch of its chunk); the next
        block is read while the caller has this one."""
        self._wait_written()
        bounds = component_blocks(self.order, block_rows)
        ahead = [self._worker.submit(self._chunks, *bounds[0], max_chunk)] if bounds else []
        for i, (k0, k1) in enumerate(bounds):
            chunks = ahead.pop().result()
            if i + 1 < len(bounds):
                ahead.append(self._worker.submit(self._chunks, *bounds[i + 1], max_chunk))
                if i + 2 == len(bounds):  # the file's pages freed once the last block is read
                    self._worker.submit(os.ftruncate, self._file.fileno(), 0)
            yield k0, k1, chunks

    def _chunks(self, k0: int, k1: int, max_chunk: int) -> Chunks:
        """The chunks of the components at key-order positions ``k0`` to ``k1 - 1``
        (:meth:`blocks`)."""
        st = self.order.start
        chunks = layout(st[k0:k1 + 1] - st[k0], max_chunk)
        first = np.searchsorted(chunks.owner, np.arange(k1 - k0))  # each one's first chunk
        raw = chunks.words.data.cast("B")
        for keys, key_list, seg, counts, rank0, offset in self._windows:
            a, b = bisect_left(key_list, k0), bisect_left(key_list, k1)
            if a < b:
                at, size = _runs(keys[a:b] - k0, counts[a:b], rank0, max_chunk, first,
                                 chunks.start)
                _read_scattered(self._file.fileno(), [
                    raw[8 * w:8 * (w + m)] for w, m in zip(at, size, strict=True)],
                    offset + int(seg[a]) * WIDTH * 8)
        return chunks

    def _error(self, err: OSError) -> StoreError:
        """The store's error for a failed write of the temporary file (nothing is stored)."""
        where = self.directory or tempfile.gettempdir()
        msg = (f"{where}: cannot stage the batch's history in a temporary file: "
               f"{safe_text(err)}; nothing was written")
        if err.errno == errno.ENOSPC:
            return StoreFullError(msg)
        if err.errno in (errno.EACCES, errno.EROFS, errno.EPERM):
            return StoreReadOnlyError(msg)
        return StoreError(msg)



def _reserve(fd: int, size: int) -> None:
    """Reserve the file's ``size`` bytes on the disk at once: its writes then fill blocks the
    file system has already allocated (less of the kernel's work per write). A file system
    that cannot reserve leaves it to the writes; a full disk raises as a write would."""
    if size and hasattr(os, "posix_fallocate"):
        try:
            os.posix_fallocate(fd, 0, size)
        except OSError as err:
            if err.errno not in (errno.EOPNOTSUPP, errno.EINVAL, errno.ENOSYS):
                raise


def _write_at(fd: int, rec: np.ndarray, offset: int) -> None:
    """Write the bytes of ``rec`` (contiguous) to the file ``fd`` at ``offset``."""
    view = rec.data.cast("B")
    done = 0
    while done < view.nbytes:
        done += os.pwrite(fd, view[done:], offset + done)


def _runs(comp: np.ndarray, length: np.ndarray, rank0: int, max_chunk: int,
          first: np.ndarray, start: np.ndarray) -> tuple[list[int], list[int]]:
    """Where a window's records of a block go: components ``comp`` (block-local, ascending)
    have ``length`` records each, of ranks ``rank0`` on; each run split at its component's
    chunk bounds (ranks at multiples of ``max_chunk``). Returns the word offset of each
    piece in the chunks' buffer and its length in words, in the window's record order."""
    end = rank0 + length
    q = rank0 // max_chunk
    if int(end.max()) <= (q + 1) * max_chunk:  # every run inside its component's chunk q
        at = start[first[comp] + q] + 1 + (rank0 - q * max_chunk) * WIDTH
        return at.tolist(), (length * WIDTH).tolist()
    parts = []
    for q in range(rank0 // max_chunk, int(end.max() - 1) // max_chunk + 1):
        lo = max(rank0, q * max_chunk)
        hi = np.minimum(end, (q + 1) * max_chunk)
        keep = np.flatnonzero(hi > lo)
        at = start[first[comp[keep]] + q] + 1 + (lo - q * max_chunk) * WIDTH
        parts.append((keep, at, (hi[keep] - lo) * WIDTH))
    keep, at, size = (np.concatenate(x) for x in zip(*parts, strict=True))
    order = np.argsort(keep, kind="stable")  # by component, then rank
    return at[order].tolist(), size[order].tolist()


_IOV_MAX = os.sysconf("SC_IOV_MAX") if "SC_IOV_MAX" in os.sysconf_names else 16
"""Buffers per scattered read at most (the system's limit)."""


def _read_scattered(fd: int, views: list[memoryview], offset: int) -> None:
    """Fill ``views`` in turn from the file ``fd``'s bytes from ``offset`` on."""
    i = 0
    while i < len(views):
        group = views[i:i + _IOV_MAX]
        got = os.preadv(fd, group, offset)
        if got <= 0:
            raise StoreError("the batch's staged history ended early (its temporary file was "
                             "truncated)")
        offset += got
        for v in group:
            if got < v.nbytes:  # the rest of a view filled in part
                views[i] = v[got:]
                break
            got -= v.nbytes
            i += 1


def plan_pieces(order: ComponentOrder, n: int, block_rows: int, window_rows: int,
                directory: Path | None) -> tuple[Iterator[Piece], str, str, HistoryStage | None]:
    """How a store runs a batch of ``n`` rows: its pieces, the trackers' and the trend's
    strategy, and the stage of its history (or ``None``). A batch wider than long by the
    trackers' cost rule (:func:`~rulkit.fleet.tracking.tracker_run.tracker_strategy` of its
    longest series: ``"ranks"``) and larger than a block runs in windows of consecutive
    acquisition ranks of every component (:func:`~rulkit.fleet.store.batch_order.
    rank_windows`, at most ``window_rows`` rows each: one numpy step per rank across all
    units, no compiled pass to load); any other in blocks of consecutive components of at
    most ``block_rows`` rows, each way the cheapest for the rank loops of all blocks against
    loading the compiled passes once. The windows' history is staged (a
    :class:`HistoryStage` in ``directory``) and written per block of components after the
    last window: one chunk per component, as in blocks."""
    longest = int(order.counts.max(initial=0))
    if n > block_rows and tracker_strategy(longest, n) == "ranks":
        windows = rank_windows(order, window_rows)
        return ((window_piece(order, r0, r1) for r0, r1 in windows), "ranks", "ranks",
                HistoryStage(order, directory))
    blocks = component_blocks(order, block_rows)
    n_ranks = sum(int(order.counts[k0:k1].max()) for k0, k1 in blocks)
    return (iter(block_pieces(order, blocks)), tracker_strategy(n_ranks, n),
            trend_strategy(n_ranks, n), None)


__all__ = ["HistoryStage", "plan_pieces"]
