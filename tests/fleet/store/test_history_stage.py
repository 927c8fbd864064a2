"""The rank windows' history staged in a temporary file and given back per block of
components (rulkit.fleet.store.history_stage) against the records laid out by component."""

import itertools
import tempfile

import numpy as np
import pytest

from rulkit.fleet.store.batch_order import order_by_component, rank_windows, window_piece
from rulkit.fleet.store.database_file import StoreError
from rulkit.fleet.store.history_chunks import WIDTH, chunk_rows
from rulkit.fleet.store.history_stage import HistoryStage


@pytest.mark.parametrize("window_rows,block_rows,max_chunk",
                         [(1, 1, 4096), (7, 10, 4096), (1000, 4, 4096), (7, 10, 3), (20, 30, 1),
                          (1000, 4, 2)])
def test_blocks_give_each_components_chunks_in_time_order(tmp_path, window_rows, block_rows,
                                                          max_chunk, monkeypatch):
    """Against the chunks of the records laid out by component (history_chunks.chunk_rows):
    the same rows, blobs byte for byte, also when a window's run crosses a chunk's bound and
    when a read is split over several calls."""
    import rulkit.fleet.store.history_stage as stage_module

    monkeypatch.setattr(stage_module, "_IOV_MAX", 3)  # scattered reads of 3 buffers at most
    rng = np.random.default_rng(8)
    b = 9
    counts = rng.integers(0, 15, b)
    codes = rng.permutation(np.repeat(np.arange(b), counts)).astype(np.int32)
    order = order_by_component(codes, [f"c{int(k)}" for k in rng.permutation(b)])
    values = rng.normal(size=(codes.size, WIDTH))  # a record per batch row
    names = np.array([f"k{k}" for k in range(b)], dtype=object)  # by key-order position
    with HistoryStage(order, tmp_path) as stage:
        for r0, r1 in rank_windows(order, window_rows):
            piece = window_piece(order, r0, r1)
            stage.add(piece, values[piece.rows])
        got = [(k0, k1, chunks.rows(names[k0:k1], 5))
               for k0, k1, chunks in stage.blocks(block_rows, max_chunk)]
    assert got[0][0] == 0 and got[-1][1] == b  # consecutive blocks, every component once
    assert all(a[1] == c[0] for a, c in itertools.pairwise(got))
    for k0, k1, rows in got:
        # brute force: the rows of the block's components, by component, in batch order
        expect = values[order.by_comp[order.start[k0]:order.start[k1]]]
        ref = chunk_rows(names[k0:k1], order.start[k0:k1 + 1] - order.start[k0], expect, 5,
                         max_chunk)
        assert [(*r[:5], bytes(r[5])) for r in rows] == [(*r[:5], bytes(r[5])) for r in ref]
        assert max(r[3] for r in rows) <= max_chunk
    assert list(tmp_path.iterdir()) == []  # the temporary file has no name


def test_a_short_read_continues_where_it_stopped(tmp_path, monkeypatch):
    """A scattered read that returns fewer bytes than asked (as a read may) goes on from
    the byte after the last it got."""
    import os

    import rulkit.fleet.store.history_stage as stage_module

    data = np.arange(40, dtype="<f8")
    f = tmp_path / "f"
    f.write_bytes(data.tobytes())
    out = np.zeros(40)
    raw = out.data.cast("B")
    real = os.preadv
    monkeypatch.setattr(stage_module.os, "preadv",  # at most 12 bytes a call
                        lambda fd, bufs, off: real(fd, [bufs[0][:12]], off))
    with open(f, "rb") as fh:
        stage_module._read_scattered(fh.fileno(), [raw[0:80], raw[80:200], raw[200:320]], 0)
    assert out.tobytes() == data.tobytes()


def test_the_system_temporary_directory_when_the_databases_cannot_hold_the_stage(
        tmp_path, monkeypatch):
    order = order_by_component(np.zeros(3, dtype=np.int32), ["a"])
    with HistoryStage(order, tmp_path / "missing") as stage:  # a directory it cannot write
        assert stage.directory is None
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "missing-too"))
    with pytest.raises(StoreError, match="cannot stage the batch's history"):
        HistoryStage(order, tmp_path / "missing")


def test_a_failed_write_of_the_stage_is_the_stores_error(tmp_path, monkeypatch):
    """A write of the worker that fails (a full disk) raises the store's error for it when
    the batch next stages or reads back, naming the directory; nothing is given back."""
    import errno
    import os

    import rulkit.fleet.store.history_stage as stage_module
    from rulkit.fleet.store.database_file import StoreFullError

    def full(fd, data, offset):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(stage_module.os, "pwrite", full)
    codes = np.repeat(np.arange(3, dtype=np.int32), 4)
    order = order_by_component(codes, ["a", "b", "c"])
    values = np.ones((codes.size, WIDTH))
    with HistoryStage(order, tmp_path) as stage:
        (r0, r1), *_ = rank_windows(order, 6)
        piece = window_piece(order, r0, r1)
        stage.add(piece, values[piece.rows])
        with pytest.raises(StoreFullError, match=f"{tmp_path}: cannot stage the batch's "
                           "history in a temporary file: .*No space left"):
            list(stage.blocks(10))


@pytest.mark.parametrize("failure", [None, "EOPNOTSUPP", "ENOSPC"])
def test_the_stage_reserves_its_bytes_at_once(tmp_path, monkeypatch, failure):
    """The stage reserves the batch's records (104 bytes a row) on the disk before its first
    write; a file system that cannot reserve gives the same blocks; a full disk raises the
    store's error for it."""
    import errno
    import os

    import rulkit.fleet.store.history_stage as stage_module
    from rulkit.fleet.store.database_file import StoreFullError

    calls = []

    def reserve(fd, offset, size):
        calls.append((offset, size, os.fstat(fd).st_size))
        if failure is not None:
            code = getattr(errno, failure)
            raise OSError(code, os.strerror(code))

    monkeypatch.setattr(stage_module.os, "posix_fallocate", reserve, raising=False)
    codes = np.repeat(np.arange(3, dtype=np.int32), 4)
    order = order_by_component(codes, ["a", "b", "c"])
    values = np.arange(codes.size * WIDTH, dtype=np.float64).reshape(-1, WIDTH)
    with HistoryStage(order, tmp_path) as stage:
        windows = [window_piece(order, r0, r1) for r0, r1 in rank_windows(order, 6)]
        if failure == "ENOSPC":
            with pytest.raises(StoreFullError, match="No space left"):
                stage.add(windows[0], values[windows[0].rows])
            return
        for piece in windows:
            stage.add(piece, values[piece.rows])
        got = [bytes(b) for _, _, chunks in stage.blocks(10) for b in chunks.blobs()]
    assert calls == [(0, codes.size * WIDTH * 8, 0)]  # before any write
    want = [bytes(r[5]) for r in chunk_rows(np.array(["a", "b", "c"], dtype=object),
                                            order.start, values[order.by_comp], 1)]
    assert got == want
