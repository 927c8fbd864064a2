"""The rank windows' history staged in a temporary file and given back per block of
components (rulkit.fleet.store.history_stage) against the records laid out by component."""

import itertools
import tempfile

import numpy as np
import pytest

from rulkit.fleet.store.batch_order import order_by_component, rank_windows, window_piece
from rulkit.fleet.store.database_file import StoreError
from rulkit.fleet.store.history_chunks import WIDTH
from rulkit.fleet.store.history_stage import HistoryStage


@pytest.mark.parametrize("window_rows,block_rows", [(1, 1), (7, 10), (1000, 4)])
def test_blocks_give_each_components_records_in_time_order(tmp_path, window_rows, block_rows):
    rng = np.random.default_rng(8)
    b = 9
    counts = rng.integers(0, 15, b)
    codes = rng.permutation(np.repeat(np.arange(b), counts)).astype(np.int32)
    order = order_by_component(codes, [f"c{int(k)}" for k in rng.permutation(b)])
    values = rng.normal(size=(codes.size, WIDTH))  # a record per batch row
    with HistoryStage(order, tmp_path) as stage:
        for r0, r1 in rank_windows(order, window_rows):
            piece = window_piece(order, r0, r1)
            stage.add(piece, values[piece.rows])
        got = list(stage.blocks(block_rows))
    assert got[0][0] == 0 and got[-1][1] == b  # consecutive blocks, every component once
    assert all(a[1] == c[0] for a, c in itertools.pairwise(got))
    for k0, k1, rec in got:
        # brute force: the rows of the block's components, by component, in batch order
        expect = values[order.by_comp[order.start[k0]:order.start[k1]]]
        assert rec.tobytes() == expect.tobytes()
    assert list(tmp_path.iterdir()) == []  # the temporary file has no name


def test_the_system_temporary_directory_when_the_databases_cannot_hold_the_stage(
        tmp_path, monkeypatch):
    order = order_by_component(np.zeros(3, dtype=np.int32), ["a"])
    with HistoryStage(order, tmp_path / "missing") as stage:  # a directory it cannot write
        assert stage.directory is None
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "missing-too"))
    with pytest.raises(StoreError, match="cannot stage the batch's history"):
        HistoryStage(order, tmp_path / "missing")
