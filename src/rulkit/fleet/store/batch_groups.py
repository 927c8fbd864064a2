"""The batches of one group commit that can be applied in one pass
(docs/systems/embedded-rul.md §4): consecutive batches with no component in common, received
at the same calendar time ``now`` and read on the same time axis, joined into one
:class:`Batch`.

A component's acquisitions are applied in time order, batch after batch; batches that share
no component do not depend on each other, so the trackers, the estimator and the rules run
over their union as over each of them, and the union's rows are written in one pass of the
store's writes instead of one per batch.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np

from rulkit.fleet.store.acquisitions import Batch

Queued = tuple[Batch, str, float | None]
"""A validated batch, its source and the calendar time it was received at (``None``: the
clock), as :meth:`~rulkit.fleet.store.sqlite.ComponentStore.ingest_many` takes them."""


def disjoint_runs(batches: Sequence[Queued]) -> Iterator[list[Queued]]:
    """``batches`` in order, cut into runs of consecutive batches that share no component,
    have the same ``now``, the same time axis (``calendar``, ``seconds_per_unit``) and no
    ``installed`` column (each run of one batch or more)."""
    run: list[Queued] = []
    seen: set[str] = set()
    for item in batches:
        if run and not _joins(run[0], item, seen):
            yield run
            run, seen = [], set()
        run.append(item)
        seen.update(item[0].names)
    if run:
        yield run


def _joins(first: Queued, item: Queued, seen: set[str]) -> bool:
    a, b = first[0], item[0]
    return (first[2] == item[2] and a.calendar == b.calendar
            and a.seconds_per_unit == b.seconds_per_unit
            and a.installed is None and b.installed is None
            and seen.isdisjoint(b.names))


def join(batches: Sequence[Batch]) -> Batch:
    """One batch of the rows of ``batches`` (no component in common), in order: each
    batch's component codes shifted past the components of the batches before it."""
    offsets = np.cumsum([0] + [len(b.names) for b in batches[:-1]])
    first = batches[0]
    return Batch(
        codes=np.concatenate([b.codes + off for b, off in zip(batches, offsets, strict=True)]),
        names=[n for b in batches for n in b.names],
        t=np.concatenate([b.t for b in batches]),
        hi=np.concatenate([b.hi for b in batches]),
        row=np.concatenate([b.row for b in batches]),
        installed=None, calendar=first.calendar, seconds_per_unit=first.seconds_per_unit)


__all__ = ["Queued", "disjoint_runs", "join"]
