"""Steps 1-3 over a record of several files: the report and its files, a run stopped after a
file and continued gives the numbers of one uninterrupted run, a changed input refuses the
checkpoint, several wheels give the fleet table, and a record without losses runs step 1."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from rulkit.systems.reaction_wheel import pipeline
from rulkit.systems.reaction_wheel.pipeline import (
    PipelineError,
    PipelineOptions,
    find_record,
    run_fleet,
    run_pipeline,
)
from rulkit.systems.reaction_wheel.simulate import simulate_record


@pytest.fixture(scope="module")
def wheel_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """2 hours at 20 Hz in 4 files, 4-minute losses."""
    d = tmp_path_factory.mktemp("wheel")
    simulate_record(d, 1 / 12, np.random.default_rng(0), file_days=1 / 48)
    return d


OPTS = PipelineOptions(threshold_mL=0.5, chunk_rows=20_000)


@pytest.fixture(scope="module")
def full(wheel_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("full")
    run_pipeline(find_record(wheel_dir), out, OPTS)
    return out


def test_the_report_and_its_files(full: Path) -> None:
    names = {p.name for p in full.iterdir()}
    assert {"report.md", "summary.json", "temperature_hourly.csv", "tracks.csv", "posterior.csv",
            "rul_two_step.json", "rul.png", "tracks.png", "temperature.png"} <= names
    text = (full / "report.md").read_text()
    assert "144,000 telemetry rows" in text and "Step 3" in text
    tracks = pd.read_csv(full / "tracks.csv")
    assert len(tracks) == 30 and np.isfinite(tracks["b_two_step"]).all()
    hourly = pd.read_csv(full / "temperature_hourly.csv")
    assert hourly["T_mean"].between(20, 40).all()  # the scenario path stays near 30 C


def test_a_stopped_run_continues_with_the_same_numbers(wheel_dir: Path, full: Path,
                                                       tmp_path: Path, monkeypatch) -> None:
    real = pipeline.Step1Stream.run_file
    calls = {"n": 0}

    def stop_after_two(self, path, progress=None):
        if calls["n"] == 2:
            raise KeyboardInterrupt  # the run is killed between files
        calls["n"] += 1
        return real(self, path, progress)

    monkeypatch.setattr(pipeline.Step1Stream, "run_file", stop_after_two)
    with pytest.raises(KeyboardInterrupt):
        run_pipeline(find_record(wheel_dir), tmp_path, OPTS)
    monkeypatch.setattr(pipeline.Step1Stream, "run_file", real)
    res = run_pipeline(find_record(wheel_dir), tmp_path, OPTS)
    assert res.resumed_after == 2
    for name in ("tracks.csv", "temperature_hourly.csv", "posterior.csv"):
        pd.testing.assert_frame_equal(pd.read_csv(tmp_path / name), pd.read_csv(full / name),
                                      check_exact=True)


def test_a_changed_input_refuses_the_checkpoint(wheel_dir: Path, full: Path,
                                                tmp_path: Path) -> None:
    copy = tmp_path / "wheel"
    shutil.copytree(wheel_dir, copy)
    out = tmp_path / "out"
    run_pipeline(find_record(copy), out, OPTS)
    first = sorted((copy / "telemetry").iterdir())[0]
    pd.read_parquet(first).iloc[:-10].to_parquet(first)
    with pytest.raises(PipelineError, match="changed since the checkpoint"):
        run_pipeline(find_record(copy), out, OPTS)


def test_several_wheels_and_a_record_without_losses(wheel_dir: Path, tmp_path: Path) -> None:
    other = tmp_path / "other"
    shutil.copytree(wheel_dir, other)
    (other / "losses.csv").unlink()
    table = run_fleet([find_record(wheel_dir), find_record(other)], tmp_path / "fleet", OPTS)
    assert list(table["wheel"]) == [wheel_dir.name, "other"]
    assert np.isfinite(table["rul_median_days"].iloc[0])
    assert np.isnan(table["rul_median_days"].iloc[1])  # no losses: step 1 only
    assert (tmp_path / "fleet" / "fleet.csv").exists()
    assert "Not run: no loss measurements" in (tmp_path / "fleet" / "other" / "report.md"
                                               ).read_text()


def test_only_the_robust_methods_run_months(wheel_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(PipelineError, match="use --method imm"):
        run_pipeline(find_record(wheel_dir), tmp_path, PipelineOptions(method="adaptive"))
    with pytest.raises(PipelineError, match="no such file"):
        find_record(tmp_path / "nothing")


@pytest.mark.slow  # a local Dask cluster and two pipelines
def test_several_wheels_on_a_dask_cluster_equal_serial(wheel_dir: Path, tmp_path: Path) -> None:
    distributed = pytest.importorskip("distributed")
    other = tmp_path / "other"
    shutil.copytree(wheel_dir, other)
    recs = [find_record(wheel_dir), find_record(other)]
    serial = run_fleet(recs, tmp_path / "s", OPTS)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  protocol="tcp", host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        dask = run_fleet(recs, tmp_path / "d", OPTS, scheduler=cluster.scheduler_address)
    pd.testing.assert_frame_equal(serial, dask)
