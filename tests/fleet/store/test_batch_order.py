"""The pieces a batch is run in (rulkit.fleet.store.batch_order): rank windows against a
brute-force split of every component's rows by acquisition rank."""

import itertools

import numpy as np
import pytest

from rulkit.fleet.store.batch_order import (
    block_pieces,
    component_blocks,
    order_by_component,
    rank_windows,
    window_piece,
)


def _order(rng, b=7, max_k=12):
    counts = rng.integers(0, max_k + 1, b)
    codes = rng.permutation(np.repeat(np.arange(b), counts)).astype(np.int32)
    names = [f"c{int(k)}" for k in rng.permutation(b)]
    return order_by_component(codes, names), codes, names


@pytest.mark.parametrize("window_rows", [1, 4, 9, 1000])
def test_rank_windows_split_every_row_once_by_rank(window_rows):
    rng = np.random.default_rng(3)
    order, codes, _ = _order(rng)
    windows = rank_windows(order, window_rows)
    assert windows[0][0] == 0 and windows[-1][1] == order.counts.max()
    assert all(a[1] == b[0] for a, b in itertools.pairwise(windows))
    seen = []
    for r0, r1 in windows:
        piece = window_piece(order, r0, r1)
        rows = piece.rows
        # at most window_rows rows, unless a single rank holds more
        assert rows.size <= window_rows or r1 - r0 == 1
        for j, k in enumerate(piece.keys.tolist()):
            mine = rows[piece.seg[j]:piece.seg[j + 1]]
            every = np.flatnonzero(codes == order.sorted_pos[k])  # the component's rows
            np.testing.assert_array_equal(mine, every[r0:r1])  # brute force: by rank
        assert piece.rank0 == r0 and np.all(np.diff(piece.keys) > 0)  # key order
        seen.append(rows)
    np.testing.assert_array_equal(np.sort(np.concatenate(seen)), np.arange(codes.size))


def test_block_pieces_hold_whole_components():
    rng = np.random.default_rng(4)
    order, _, _ = _order(rng)
    pieces = block_pieces(order, component_blocks(order, 10))
    np.testing.assert_array_equal(np.concatenate([p.rows for p in pieces]), order.by_comp)
    for p in pieces:
        assert p.rank0 == 0
        np.testing.assert_array_equal(np.diff(p.seg), order.counts[p.keys])
