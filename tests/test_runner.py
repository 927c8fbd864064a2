"""Independent-runs runner: identical results serially, with local worker processes and on a
Dask cluster (loopback LocalCluster), seeds from SeedSequence.spawn by run index."""

from __future__ import annotations

import numpy as np
import pytest

from rulkit.runner import run_independent, run_seeds, sample_task


def test_serial_results_use_spawned_seeds_by_index() -> None:
    out = run_independent(sample_task, [3, 5, 2], seed=7)
    kids = np.random.SeedSequence(7).spawn(3)
    for o, k, n in zip(out, kids, [3, 5, 2], strict=True):
        assert np.array_equal(o, np.random.default_rng(k).standard_normal(n))
    assert [s.spawn_key for s in run_seeds(7, 3)] == [(0,), (1,), (2,)]


def test_processes_and_dask_equal_serial() -> None:
    distributed = pytest.importorskip("distributed")
    tasks = [4, 1, 6, 2, 3]
    serial = run_independent(sample_task, tasks, seed=11)
    procs = run_independent(sample_task, tasks, seed=11, workers=2)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  protocol="tcp",
                                  host="127.0.0.1", dashboard_address=None) as cluster:
        dask = run_independent(sample_task, tasks, seed=11, scheduler=cluster.scheduler_address)
        with distributed.Client(cluster) as client:  # an existing Client is accepted too
            dask2 = run_independent(sample_task, tasks, seed=11, scheduler=client)
    for a, b, c, d in zip(serial, procs, dask, dask2, strict=True):
        assert np.array_equal(a, b) and np.array_equal(a, c) and np.array_equal(a, d)
    other = run_independent(sample_task, tasks, seed=12)
    assert not np.array_equal(serial[0], other[0])


def test_table5_runs_identical_on_dask_and_serial() -> None:
    distributed = pytest.importorskip("distributed")
    from rulkit.systems.reaction_wheel.temperature.study import run_table5

    kw = dict(runs=2, seed=3, methods=[("apf_eq28", "F1")], n_particles=(50,), ekf=False)
    serial = run_table5(**kw)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  protocol="tcp",
                                  host="127.0.0.1", dashboard_address=None) as cluster:
        dask = run_table5(scheduler=cluster.scheduler_address, **kw)
    assert serial.equals(dask)


def test_progress_callback_and_rich_bar() -> None:
    calls: list[tuple[int, int]] = []
    run_independent(sample_task, [1, 1, 1], progress=lambda d, n: calls.append((d, n)))
    assert calls == [(1, 3), (2, 3), (3, 3)]
    calls.clear()
    run_independent(sample_task, [1, 1, 1], workers=2, progress=lambda d, n: calls.append((d, n)))
    assert sorted(calls) == [(1, 3), (2, 3), (3, 3)]
    assert len(run_independent(sample_task, [2, 2], progress=True)) == 2


def _boom(task: int, rng: np.random.Generator) -> int:
    raise RuntimeError(f"run {task} failed")


def test_errors() -> None:
    with pytest.raises(ValueError, match="workers"):
        run_independent(sample_task, [1], workers=0)
    with pytest.raises(ValueError, match="not both"):
        run_independent(sample_task, [1], workers=2, scheduler="tcp://127.0.0.1:1")
    with pytest.raises(TypeError, match="progress"):
        run_independent(sample_task, [1], progress="yes")  # type: ignore[arg-type]
    with pytest.raises(RuntimeError, match="run 5 failed"):
        run_independent(_boom, [5])
    assert run_independent(sample_task, []) == []
