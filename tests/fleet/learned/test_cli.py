"""rulkit fit / track / evaluate end to end from files (issue 11)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from rulkit.cli import app
from rulkit.fleet.learned.datasets import synthetic_linear_fleet
from rulkit.fleet.store.sqlite import ComponentStore

runner = CliRunner()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("fleet")
    df, _ = synthetic_linear_fleet(np.random.default_rng(0), 10, n_acq=6)
    df.to_csv(d / "hist.csv", index=False)
    new, _ = synthetic_linear_fleet(np.random.default_rng(1), 2, n_acq=6, censor_frac=0.0)
    new = new.groupby("component").head(4)
    new["component"] = "new-" + new["component"]
    new.to_csv(d / "acq.csv", index=False)
    return d


def test_fit_then_track_writes_the_learned_rul(files):
    db = files / "a.db"
    r = runner.invoke(app, ["fit", "--db", str(db), str(files / "hist.csv"), "--model",
                            "linear", "--time-unit", "h"])
    assert r.exit_code == 0, r.output
    assert "linear model" in r.output and "per h" in r.output
    r = runner.invoke(app, ["track", "--db", str(db), str(files / "acq.csv")])
    assert r.exit_code == 0, r.output
    with ComponentStore(db, readonly=True) as s:
        h = s.history()
    assert len(h) == 8
    assert (h["rul_low"] <= h["rul_median"]).all() and (h["rul_median"] <= h["rul_high"]).all()
    assert (h["rul_median"] >= 0).all() and np.isfinite(h["rul_median"]).any()


def test_fit_into_a_database_with_history_replays_it(files):
    """A model fitted into a database that already holds acquisitions replays them: the
    RUL of every history row then equals what the model gives when fitted first (replay and
    ingestion, two paths)."""
    more = pd.read_csv(files / "acq.csv").assign(time=lambda d: d["time"] + 1000.0)
    more.to_csv(files / "more.csv", index=False)
    late, first = files / "late.db", files / "first.db"
    assert runner.invoke(app, ["track", "--db", str(late), str(files / "acq.csv")]).exit_code == 0
    r = runner.invoke(app, ["fit", "--db", str(late), str(files / "hist.csv"), "--model",
                            "linear"])
    assert r.exit_code == 0, r.output
    assert "2 components' state rebuilt" in r.output
    assert runner.invoke(app, ["fit", "--db", str(first), str(files / "hist.csv"), "--model",
                               "linear"]).exit_code == 0
    for db, f in ((late, "more.csv"), (first, "acq.csv"), (first, "more.csv")):
        r = runner.invoke(app, ["track", "--db", str(db), str(files / f)])
        assert r.exit_code == 0, r.output
    with ComponentStore(late, readonly=True) as s, ComponentStore(first, readonly=True) as f:
        h, ref = s.history(), f.history()
        assert s.status()["rul_median"].notna().all()
    assert len(h) == 16 and h["rul_median"].notna().all()
    for c in ("rul_median", "rul_low", "rul_high", "level"):
        np.testing.assert_allclose(h[c], ref[c], rtol=1e-12, err_msg=c)


def test_evaluate_prints_and_writes_the_table(files, tmp_path):
    out = tmp_path / "ev"
    r = runner.invoke(app, ["evaluate", str(files / "hist.csv"), "--model", "linear",
                            "--out", str(out), "--folds", "3"])
    assert r.exit_code == 0, r.output
    for name in ("summary.csv", "predictions.csv", "alpha_lambda.png", "summary.md"):
        assert (out / name).exists()
    s = pd.read_csv(out / "summary.csv")
    assert list(s["method"]) == ["linear", "origin", "last2"]
    assert "90 % coverage" in r.output and "median rel. error" in r.output
    assert "coverage_90_last_half" in s.columns


@pytest.mark.parametrize(("edit", "match"), [
    (lambda d: d[d["component"] == d["component"].iloc[0]], "1 unit"),
    (lambda d: d.assign(hi=d["hi"].clip(upper=0.5)), "no unit has failed"),
    (lambda d: d.assign(hi=-d["hi"]), "< 0"),
])
def test_bad_histories_are_named(files, tmp_path, edit, match):
    bad = edit(pd.read_csv(files / "hist.csv"))
    bad.to_csv(tmp_path / "bad.csv", index=False)
    for cmd in (["fit", "--db", str(tmp_path / "x.db")], ["evaluate"]):
        r = runner.invoke(app, [*cmd, str(tmp_path / "bad.csv"), "--model", "linear"])
        assert r.exit_code == 1
        assert match in r.output and "bad.csv" in r.output
    assert not (tmp_path / "x.db").exists()


def test_fit_tracker_and_model_in_either_order_or_one_command(files, tmp_path):
    hist = str(files / "hist.csv")
    tracker = ["--model", "tracker"]
    model = ["--model", "linear", "--folds", "2"]
    for order in ((tracker, model), (model, tracker)):
        db = tmp_path / f"{len(order[0])}{order[0][1]}.db"
        for args in order:
            r = runner.invoke(app, ["fit", "--db", str(db), hist, *args])
            assert r.exit_code == 0, r.output
        with ComponentStore(db, readonly=True) as s:
            assert s.config.initiation == "measured" and s.config.rul_clip
            assert s.degradation is not None and s.degradation.name == "linear"
    db = tmp_path / "one.db"
    r = runner.invoke(app, ["fit", "--db", str(db), hist, *model, "--tracker"])
    assert r.exit_code == 0, r.output
    assert "fitted tracker settings" in r.output
    with ComponentStore(db, readonly=True) as s:
        assert s.config.rul_clip and s.degradation is not None
    r = runner.invoke(app, ["track", "--db", str(db), str(files / "acq.csv")])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["fit", "--db", str(db), hist, *tracker])
    assert r.exit_code == 1 and "fixed once a component is tracked" in r.output


def test_fit_prints_the_candidates_table_choice_and_unit(files, tmp_path):
    db = tmp_path / "auto.db"
    r = runner.invoke(app, ["fit", "--db", str(db), str(files / "hist.csv"), "--candidates",
                            "linear,regression", "--folds", "3", "--time-unit", "kcycles"])
    assert r.exit_code == 0, r.output
    for text in ("candidate", "held-out rel. error", "90 % coverage", "score", "<- chosen",
                 "chosen: ", "RUL in kcycles"):
        assert text in r.output
    with ComponentStore(db, readonly=True) as s:
        assert s.degradation.time_unit == "kcycles"
    r = runner.invoke(app, ["fit", "--db", str(db), str(files / "hist.csv"), "--candidates",
                            "linear,arima"])
    assert r.exit_code == 2 and "--candidates" in r.output


def test_warnings_are_printed_and_stored(files, tmp_path):
    epoch = pd.read_csv(files / "hist.csv").assign(time=lambda d: d["time"] + 1.7e9)
    epoch.to_csv(tmp_path / "epoch.csv", index=False)
    db = tmp_path / "w.db"
    r = runner.invoke(app, ["fit", "--db", str(db), str(tmp_path / "epoch.csv"), "--model",
                            "linear", "--folds", "2"])
    assert r.exit_code == 0, r.output
    assert "warning: time: every unit starts at an age above" in r.output
    with ComponentStore(db, readonly=True) as s:
        assert any("epoch timestamps" in w for w in s.degradation.warnings)


def test_date_times_in_fit_track_and_evaluate(files, tmp_path):
    def stamped(name):
        d = pd.read_csv(files / name)
        d["time"] = (pd.Timestamp("2024-03-01") + pd.to_timedelta(d["time"], unit="h")
                     ).dt.strftime("%Y-%m-%dT%H:%M:%S")
        d.to_csv(tmp_path / name, index=False)
        return str(tmp_path / name)

    hist, acq = stamped("hist.csv"), stamped("acq.csv")
    db = tmp_path / "ts.db"
    r = runner.invoke(app, ["fit", "--db", str(db), hist, "--model", "linear", "--folds", "2",
                            "--time-unit", "h", "--tracker"])
    assert r.exit_code == 0, r.output
    assert "date-times, converted to h; age since each unit's first acquisition" in r.output
    r = runner.invoke(app, ["track", "--db", str(db), acq])
    assert r.exit_code == 0, r.output
    with ComponentStore(db, readonly=True) as s:
        h = s.history()
    assert np.isfinite(h["rul_median"]).all() and (h["rul_low"] <= h["rul_median"]).all()
    r = runner.invoke(app, ["track", "--db", str(db), str(files / "acq.csv")])
    assert r.exit_code == 1 and "holds numbers, but the time axis is date-times" in r.output
    num = tmp_path / "num.db"
    r = runner.invoke(app, ["fit", "--db", str(num), str(files / "hist.csv"), "--model",
                            "linear", "--folds", "2"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["track", "--db", str(num), acq])
    assert r.exit_code == 1 and "holds date-times" in r.output
    assert "design_life" not in r.output
    r = runner.invoke(app, ["evaluate", hist, "--model", "linear", "--folds", "3", "--out",
                            str(tmp_path / "ev")])
    assert r.exit_code == 0, r.output
    assert "RUL and CRPS in h" in r.output


@pytest.mark.slow
def test_evaluate_on_a_local_dask_cluster_from_partitioned_parquet(tmp_path):
    r = runner.invoke(app, ["fleet-data", str(tmp_path), "--units", "12"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["evaluate", str(tmp_path / "synthetic_paris_parquet"), "--model",
                            "linear", "--scheduler", "local", "--out", str(tmp_path / "ev")])
    assert r.exit_code == 0, r.output
    local = pd.read_csv(tmp_path / "ev" / "summary.csv")
    r = runner.invoke(app, ["evaluate", str(tmp_path / "synthetic_paris_parquet"), "--model",
                            "linear", "--out", str(tmp_path / "ev1")])
    one = pd.read_csv(tmp_path / "ev1" / "summary.csv")
    pd.testing.assert_frame_equal(local, one)  # same numbers in-process and on Dask
