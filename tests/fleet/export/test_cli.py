"""`rulkit export c` end to end: from a database the commands build, from a configuration
file, and its refusals."""

import subprocess
from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from rulkit.cli import app
from rulkit.fleet.learned.datasets import fatigue_histories

runner = CliRunner()


def _run(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture
def fleet_db(tmp_path):
    csv = tmp_path / "fatigue.csv"
    fatigue_histories().to_frame().drop(columns="failed").to_csv(csv, index=False)
    db = tmp_path / "fleet.db"
    assert _run("fit", csv, "--db", tmp_path / "t.db", "--model", "tracker").exit_code == 0
    assert _run("track", "--db", db, csv).exit_code == 0
    res = _run("fit", csv, "--db", db, "--model", "linear", "--time-unit", "kcycles")
    assert res.exit_code == 0, res.output
    return db


def test_export_from_a_database_compiles(cc, tmp_path, fleet_db):
    out = tmp_path / "c"
    res = _run("export", "c", "--db", fleet_db, "--out", out, "--prefix", "crack",
               "--number", "float")
    assert res.exit_code == 0, res.output
    assert "learned linear model (RUL of the first measured crossing) (float)" in res.output
    header = (out / "crack.h").read_text()
    assert "int crack_update(crack_state *s, crack_time t, crack_real hi, crack_output *out);" \
        in header
    cmd = [cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2", "-c",
           str(out / "crack.c"), "-o", str(tmp_path / "crack.o")]
    assert subprocess.run(cmd, capture_output=True, check=False).returncode == 0


def test_refusals_write_nothing(tmp_path, fleet_db):
    out = tmp_path / "c"
    res = _run("export", "c", "--db", fleet_db, "--out", out, "--number", "fixed")
    assert res.exit_code == 1 and "learned linear model" in res.output
    assert not out.exists()
    assert _run("export", "c", "--db", fleet_db, "--out", out, "--number", "fixed",
                "--no-learned").exit_code == 0
    assert _run("export", "c", "--db", fleet_db, "--out", out, "--number", "half"
                ).exit_code == 2
    assert _run("export", "c", "--out", out).exit_code == 2  # neither --db nor --config
    assert _run("export", "c", "--db", fleet_db, "--out", out, "--prefix", "Bad").exit_code == 2
    missing = _run("export", "c", "--db", tmp_path / "none.db", "--out", out)
    assert missing.exit_code == 1 and "no such database" in missing.output


def test_a_learned_type_without_c_export_is_refused_by_name(tmp_path):
    from rulkit.fleet.export.learned_device import EXPORTERS
    from rulkit.fleet.learned.onset import OnsetModel
    from rulkit.fleet.store.sqlite import ComponentStore

    csv = tmp_path / "fatigue.csv"
    fatigue_histories().to_frame().to_csv(csv, index=False)
    growth = {"shape": 0.0, "mean": (-2.3, 1.5), "cov": (0.01, 0.0, 0.2), "hi_noise_sd": 0.02,
              "log_noise_sd": 0.0, "walk_sd": 0.05, "time_scale": 300.0}
    stored = {"onset": OnsetModel(noise="additive", grid=(0.0, 0.5), onset_mean=0.4,
                                  onset_sd=0.3, **growth)}
    for name in ("regression", *stored):
        db, out = tmp_path / f"{name}.db", tmp_path / f"c-{name}"
        if name in stored:
            with ComponentStore(db) as s:
                s.set_degradation_model(stored[name])
        else:  # a model rulkit fit chose
            fit = _run("fit", csv, "--db", db, "--model", name, "--time-unit", "kcycles")
            assert fit.exit_code == 0, fit.output
        res = _run("export", "c", "--db", db, "--out", out)
        assert res.exit_code == 1, res.output
        assert f"learned model type {name!r}" in res.output
        # the refusal names every exported type (the -iid variant is paris-additive's entry)
        listed = res.output.split("runs the learned types ")[1].split(" (rulkit fit")[0]
        assert set(listed.replace("\n", " ").split(", ")) == set(EXPORTERS) - {
            "paris-additive-iid"}
        assert "--no-learned" in res.output and not out.exists()


def test_export_of_a_paris_mixed_fit_runs_as_its_database(cc, tmp_path):
    """rulkit fit --model paris-mixed, rulkit track, rulkit export c: the C compiled from the
    export's files (as written) over the tracked acquisitions gives the learned RUL median and
    interval the database holds (tolerance: tests/fleet/export/test_learned_device.py)."""
    from rulkit.fleet.export.device_spec import spec_from_database
    from rulkit.fleet.export.generator import generate_c
    from rulkit.fleet.export.verify import build, python_reference, relative_error, segments
    from rulkit.fleet.learned.datasets import goal_fleet
    from rulkit.fleet.store.sqlite import ComponentStore

    frame, _ = goal_fleet("mixed", np.random.default_rng(11), 6)
    csv, db, out = tmp_path / "mixed.csv", tmp_path / "fleet.db", tmp_path / "c"
    frame.to_csv(csv, index=False)
    fit = _run("fit", csv, "--db", db, "--model", "paris-mixed", "--time-unit", "h")
    assert fit.exit_code == 0, fit.output
    assert _run("track", "--db", db, csv).exit_code == 0
    res = _run("export", "c", "--db", db, "--out", out, "--prefix", "rk")
    assert res.exit_code == 0, res.output
    assert "learned paris-mixed model (RUL of the first measured crossing) (double)" in res.output
    spec = spec_from_database(db)
    assert generate_c(spec)["rk.c"] == (out / "rk.c").read_text()
    with ComponentStore(db, readonly=True) as store:
        hist = store.history()
    start, df = segments(hist.rename(columns={"t": "time"}))
    got = build(spec, tmp_path / "lib").run(start, df["time"], df["hi"], through_bytes=True)
    # the server's event (the first measured crossing, eq. (5b)): what the database holds
    # (the learned median and interval in rul_median, rul_low, rul_high)
    for col, db_col in (("rul_median", "rul_median"), ("rul_p05", "rul_low"),
                        ("rul_p95", "rul_high")):
        assert relative_error(got[col], df[db_col]).max() <= 1e-6, col
    assert np.isfinite(df["rul_median"]).mean() > 0.8
    # --rul-one-measurement: eq. (5) of one measurement, the database's replayed with that
    # event, and not the server's
    one = _run("export", "c", "--db", db, "--out", out, "--prefix", "rk",
               "--rul-one-measurement")
    assert "learned paris-mixed model (RUL of one measurement) (double)" in one.output
    spec = replace(spec, one_measurement=True)
    assert generate_c(spec)["rk.c"] == (out / "rk.c").read_text()
    got = build(spec, tmp_path / "lib1").run(start, df["time"], df["hi"], through_bytes=True)
    ref = python_reference(spec, start, df["time"].to_numpy(), df["hi"].to_numpy())
    for col in ("rul_median", "rul_p05", "rul_p95"):
        assert relative_error(got[col], ref[col]).max() <= 1e-6, col
    assert relative_error(got["rul_median"], df["rul_median"]).max() > 1e-3


def test_export_from_a_configuration_file(tmp_path):
    cfg = tmp_path / "bearing.toml"
    cfg.write_text('[component]\nname = "bearing"\n[tracker]\ndt = 1.0\ndesign_life = 2e4\n'
                   'initiation = "measured"\nrul_clip = true\n'
                   '[learned]\nkind = "exponential"\nshape = -0.1\nmean_a = -1.5\n'
                   'mean_b = 1.0\ncov_aa = 0.1\ncov_bb = 0.2\nnoise_sd = 0.02\n'
                   'time_scale = 500.0\ntime_unit = "h"\n')
    out = tmp_path / "c"
    res = _run("export", "c", "--config", cfg, "--out", out)
    assert res.exit_code == 0, res.output
    text = (out / "rk.c").read_text()
    assert 'component type "bearing"' in text and "static const double L_TAU = 500.0;" in text
    cfg.write_text("[tracker]\ndesing_life = 2e4\n")
    res = _run("export", "c", "--config", cfg, "--out", out)
    assert res.exit_code == 1 and "[tracker] unknown key(s) 'desing_life'" in res.output
