"""Independent-runs runner: serial, local worker processes, or an existing Dask cluster.

Every run ``i`` gets its own ``numpy.random.Generator`` built from child ``i`` of
``numpy.random.SeedSequence(seed).spawn(n_runs)``, so a run's result depends only on
``(seed, i, task)``, never on which process or machine executes it or in which order: the
serial, ``workers=N`` and ``scheduler="tcp://..."`` paths return identical results (tested).

    results = run_independent(fn, tasks, seed=0, workers=2)

``fn(task, rng)`` must be a picklable (module-level) function for the parallel paths. Results
come back in task order. ``progress`` is a callable ``progress(done, total)``, ``True`` for a
rich progress bar, or ``None``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any, TypeVar

import numpy as np

R = TypeVar("R")
ProgressArg = Callable[[int, int], None] | bool | None


def run_seeds(seed: int, n_runs: int) -> list[np.random.SeedSequence]:
    """Child seed sequences of ``SeedSequence(seed)``, one per run index."""
    if n_runs < 0:
        raise ValueError(f"n_runs: must be >= 0, got {n_runs}")
    return np.random.SeedSequence(seed).spawn(n_runs)


def sample_task(task: Any, rng: np.random.Generator) -> Any:
    """A tiny picklable run function (``task`` = number of normals to draw): for smoke tests
    of the execution paths and for checking a cluster (``rng.standard_normal(task)``)."""
    return rng.standard_normal(int(task))


def _call(fn: Callable[[Any, np.random.Generator], R], task: Any, ss: np.random.SeedSequence) -> R:
    return fn(task, np.random.default_rng(ss))


class _RichProgress:
    """``progress=True``: a rich progress bar (rich is a core dependency)."""

    def __init__(self, total: int, description: str) -> None:
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self._p = Progress(
            TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
            TimeElapsedColumn(), TimeRemainingColumn(), transient=False,
        )
        self._p.start()
        self._task = self._p.add_task(description, total=total)

    def __call__(self, done: int, total: int) -> None:
        self._p.update(self._task, completed=done)

    def close(self) -> None:
        self._p.stop()


def run_independent(
    fn: Callable[[Any, np.random.Generator], R],
    tasks: Sequence[Any],
    *,
    seed: int = 0,
    workers: int = 1,
    scheduler: str | None = None,
    progress: ProgressArg = None,
    description: str = "runs",
) -> list[R]:
    """Run ``fn(task, rng_i)`` for every task and return the results in task order.

    ``workers=1`` and no ``scheduler``: serial in this process. ``workers > 1``: a
    ``concurrent.futures.ProcessPoolExecutor`` with that many local processes. ``scheduler``:
    the address of an existing Dask scheduler (``"tcp://host:port"``) or a
    ``distributed.Client``; needs the optional ``distributed`` package. Run ``i`` always uses
    ``default_rng(SeedSequence(seed).spawn(n)[i])``.
    """
    tasks = list(tasks)
    n = len(tasks)
    if workers < 1:
        raise ValueError(f"workers: must be >= 1, got {workers}")
    if scheduler is not None and workers != 1:
        raise ValueError("give either workers > 1 or scheduler, not both")
    seeds = run_seeds(seed, n)
    bar: _RichProgress | None = None
    if progress is True:
        bar = _RichProgress(n, description)
        report: Callable[[int, int], None] | None = bar
    elif progress is False or progress is None:
        report = None
    elif callable(progress):
        report = progress
    else:
        raise TypeError("progress: expected a callable(done, total), True, False or None")
    try:
        if scheduler is not None:
            return _run_dask(fn, tasks, seeds, scheduler, report)
        if workers == 1 or n <= 1:
            out: list[R] = []
            for i, (task, ss) in enumerate(zip(tasks, seeds, strict=True)):
                out.append(_call(fn, task, ss))
                if report:
                    report(i + 1, n)
            return out
        return _run_processes(fn, tasks, seeds, workers, report)
    finally:
        if bar is not None:
            bar.close()


def _run_processes(
    fn: Callable[[Any, np.random.Generator], R], tasks: list[Any],
    seeds: list[np.random.SeedSequence], workers: int, report: Callable[[int, int], None] | None,
) -> list[R]:
    n = len(tasks)
    results: list[Any] = [None] * n
    pool = ProcessPoolExecutor(max_workers=min(workers, n))
    try:
        futs = {pool.submit(_call, fn, t, s): i for i, (t, s) in enumerate(zip(tasks, seeds,
                                                                                strict=True))}
        pending = set(futs)
        done_count = 0
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                results[futs[f]] = f.result()  # re-raises a run's exception here
                done_count += 1
                if report:
                    report(done_count, n)
    except BaseException:
        pool.shutdown(wait=True, cancel_futures=True)  # do not run the remaining tasks
        raise
    pool.shutdown(wait=True)
    return results


def _run_dask(
    fn: Callable[[Any, np.random.Generator], R], tasks: list[Any],
    seeds: list[np.random.SeedSequence], scheduler: Any, report: Callable[[int, int], None] | None,
) -> list[R]:
    try:
        from distributed import Client, as_completed
    except ImportError as e:  # pragma: no cover - optional dependency
        raise ImportError(
            "scheduler= needs the optional 'distributed' package (pip install rulkit[dask])"
        ) from e
    own = not isinstance(scheduler, Client)
    client = Client(scheduler) if own else scheduler
    try:
        n = len(tasks)
        futs = [client.submit(_call, fn, t, s, pure=False) for t, s in zip(tasks, seeds,
                                                                          strict=True)]
        index = {f.key: i for i, f in enumerate(futs)}
        results: list[Any] = [None] * n
        for k, f in enumerate(as_completed(futs), start=1):
            results[index[f.key]] = f.result()
            if report:
                report(k, n)
        return results
    finally:
        if own:
            client.close()
