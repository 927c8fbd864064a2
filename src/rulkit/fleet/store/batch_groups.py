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

import sqlite3
from collections.abc import Callable, Iterator, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from rulkit.fleet.store.acquisitions import Alert, Batch, IngestError, IngestResult
from rulkit.fleet.store.batch_order import (
    check_spacing,
    gaps_after_stored,
    order_by_component,
    split_duplicates,
)
from rulkit.fleet.store.tracker_rows import StoredRows

if TYPE_CHECKING:
    from rulkit.fleet.store.state_cache import StateCache
    from rulkit.fleet.tracking.tracker_chain import TrackerConfig

Queued = tuple[Batch, str, float | None]
"""A validated batch, its source and the calendar time it was received at (``None``: the
clock), as :meth:`~rulkit.fleet.store.sqlite.ComponentStore.ingest_many` takes them."""


@dataclass(frozen=True)
class Admission:
    """Which batches of a group commit may be written, decided inside its write transaction
    (the service's token check: a token revoked by a commit before the group's transaction
    is refused). ``sql``: one query without parameters, read once per group after the
    writers' lock is taken; ``decide(rows)``: per batch of the group, in order, its source
    (the batch is written under it) or the exception it gets instead (nothing of it
    written)."""

    sql: str
    decide: Callable[[list[tuple]], list[str | BaseException]]


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


class GroupCommits:
    """The group commits of :class:`~rulkit.fleet.store.sqlite.ComponentStore`: queued
    batches in one write transaction, each under its own savepoint, and runs of batches with
    no component in common (:func:`disjoint_runs`) applied in one pass."""

    JOIN_BATCHES = True
    """:meth:`ingest_many` applies consecutive batches with no component in common in one
    pass (:meth:`_ingest_joined`)."""
    if TYPE_CHECKING:  # the store's, which this class is a part of
        _conn: sqlite3.Connection
        _states: StateCache | None
        _ingesting: bool
        now: float | None
        config: TrackerConfig

        def _transaction(self, mode: str = "IMMEDIATE"
                         ) -> AbstractContextManager[sqlite3.Connection]: ...
        def _group_transaction(self, keep: bool, sql: str | None
                               ) -> AbstractContextManager[tuple[int | None, list[tuple]]]: ...
        def _load_states(self, names: list[str]) -> StoredRows: ...
        def _insert_ingests(self, rows: list[tuple[str, int, int]]) -> list[int]: ...
        def _apply(self, acq: Batch, source: str, stored: StoredRows | None = None,
                   ingest_ids: Any = None) -> IngestResult: ...
        def _record_alerts(self, alerts: list[Alert]) -> list[Alert]: ...
        def _ingest_in_transaction(self, acq: Batch, source: str) -> IngestResult: ...

    def ingest_many(self, batches: list[tuple[Batch, str, float | None]],
                    admit: Admission | None = None) -> list[IngestResult | BaseException]:
        """Validated batches (:func:`validate_acquisitions`' :class:`Batch`, their sources and the
        calendar times ``now`` they were received at, ``None``: the clock) in one write
        transaction, each under its own savepoint: a batch that fails (conflict, a
        non-finite tracker output) is rolled back alone and gets its error, the others are
        committed together (one commit, one sync: group commit). A failing commit raises
        for all of them; nothing is then stored. ``admit``: which batches may be written and
        under which source, read in the transaction (:class:`Admission`); a batch it refuses
        gets its exception and nothing of it is written."""
        states = self._states
        self._ingesting = True
        try:
            with self._group_transaction(states is not None,
                                         None if admit is None else admit.sql) as (version, rows):
                if states is not None:
                    states.begin(version)  # type: ignore[arg-type]
                verdicts: list[str | BaseException] = (
                    [b[1] for b in batches] if admit is None else admit.decide(rows))
                out = self._ingest_admitted(batches, verdicts)
        except BaseException:
            if states is not None:
                states.drop()
            raise
        finally:
            self._ingesting = False
        if states is not None:
            states.commit()
        return out

    def _ingest_admitted(self, batches: list[Queued], verdicts: list[str | BaseException]
                         ) -> list[IngestResult | BaseException]:
        """The batches whose verdict is a source applied under it (runs of them with no
        component in common in one pass); the others get their verdict."""
        live = [(acq, v, now) for (acq, _, now), v in zip(batches, verdicts, strict=True)
                if isinstance(v, str)]
        done: list[IngestResult | IngestError] = []
        runs = disjoint_runs(live) if self.JOIN_BATCHES else ([b] for b in live)
        for run in runs:
            joined = self._ingest_joined(run) if len(run) > 1 else None
            done += joined if joined is not None else [
                self._ingest_savepoint(acq, source, now) for acq, source, now in run]
        it = iter(done)
        return [next(it) if isinstance(v, str) else v for v in verdicts]

    def _ingest_savepoint(self, acq: Batch, source: str, now: float | None
                          ) -> IngestResult | IngestError:
        """One batch of :meth:`ingest_many` under its own savepoint: its result, or its
        error with the batch rolled back."""
        self._conn.execute("SAVEPOINT batch")
        self.now = now
        try:
            res: IngestResult | IngestError = self._ingest_in_transaction(acq, source)
        except IngestError as err:
            self._roll_back("batch")
            res = err
        finally:
            self.now = None
        self._release("batch")
        return res

    def _ingest_joined(self, run: list[Queued]) -> list[IngestResult | IngestError] | None:
        """Batches of :meth:`ingest_many` with no component in common
        (:func:`~rulkit.fleet.store.batch_groups.disjoint_runs`) applied in one pass under one
        savepoint: each batch's duplicates split off, its spacing checked and its ``ingests``
        row inserted as alone, their rows joined (:func:`~rulkit.fleet.store.batch_groups.
        join`) and applied once (:meth:`_apply`), each batch's alerts recorded in turn. The
        results are those of the batches applied one by one (tests/fleet/store/
        test_batch_groups.py). ``None``, with nothing applied, when any of them is refused:
        the caller then applies them one by one, each with its own error."""
        self._conn.execute("SAVEPOINT joined")
        self.now = run[0][2]
        try:
            parts, stored = [], []
            for acq, source, _ in run:
                mine = self._load_states(acq.names)
                acq, n_dup = split_duplicates(self._conn, acq, mine.last_t())
                known, rows = mine.rows_of(acq.names)
                if len(acq):  # the batch's own spacing (a median: not the union's)
                    order = order_by_component(acq.codes.astype(np.int32), acq.names)
                    last = np.full(len(acq.names), np.nan)
                    last[known] = rows[:, 0]
                    check_spacing(self.config, gaps_after_stored(
                        order, acq.t, acq.row, acq.names, last[order.sorted_pos]))
                parts.append((acq, source, n_dup, len(acq.names) - known.size))
                stored.append(mine)
            live = [p for p in parts if len(p[0])]
            ids = self._insert_ingests([(source, len(acq), len(acq.names))
                                        for acq, source, _, _ in live])
            alerts: list[list[Alert]] = [[] for _ in parts]
            if live:
                counts = [len(p[0].names) for p in live]
                res = self._apply(join([p[0] for p in live]), "", StoredRows.joined(stored),
                                  ingest_ids=np.repeat(np.asarray(ids, np.int64), counts))
                batch_of = {n: i for i, p in enumerate(parts) for n in p[0].names}
                for a in res.alerts:  # in the order each batch alone gives them
                    alerts[batch_of[a.component]].append(a)
            out: list[IngestResult | IngestError] = []
            for (acq, _, n_dup, n_new), mine_alerts in zip(parts, alerts, strict=True):
                out.append(IngestResult(
                    n_rows=len(acq), n_components=len(acq.names) if len(acq) else 0,
                    n_new_components=n_new if len(acq) else 0,
                    alerts=self._record_alerts(mine_alerts), n_duplicates=n_dup))
        except IngestError:
            self._roll_back("joined")
            self._conn.execute("RELEASE SAVEPOINT joined")
            return None
        finally:
            self.now = None
        self._release("joined")
        return out

    def _roll_back(self, savepoint: str) -> None:
        """Undo the writes since ``savepoint`` and the component rows kept under it."""
        self._conn.execute(f"ROLLBACK TO SAVEPOINT {savepoint}")
        if self._states is not None:
            self._states.rollback()

    def _release(self, savepoint: str) -> None:
        """Keep the writes since ``savepoint`` in the transaction, and the rows kept under it."""
        self._conn.execute(f"RELEASE SAVEPOINT {savepoint}")
        if self._states is not None:
            self._states.release()



__all__ = ["Admission", "GroupCommits", "Queued", "disjoint_runs", "join"]
