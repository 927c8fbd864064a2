"""Issue 13 items 6 and 7: messages instead of tracebacks, one exit-code rule, validated
options, help text kept verbatim (typer's CliRunner, in-process). Each test failed before."""

from __future__ import annotations

import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from rulkit.cli import app
from rulkit.cli.errors import EXIT_CORRUPT, EXIT_INPUT, EXIT_INTERNAL, EXIT_USAGE
from rulkit.fleet.store.ingest import ingest_into

runner = CliRunner()


def no_traceback(r) -> None:
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    assert "Traceback" not in r.output


def acq_csv(path: Path, n: int = 6) -> Path:
    pd.DataFrame({"component": ["a"] * n, "time": np.arange(n, dtype=float),
                  "hi": np.linspace(0.1, 0.2, n)}).to_csv(path, index=False)
    return path


@pytest.fixture(scope="module")
def pullup(tmp_path_factory) -> Path:
    from rulkit.systems.motor_damping.motor import LifeTestConfig, simulate_life_test

    cfg = LifeTestConfig(n_cycles=4, duration=10.0, c0=6e-5, slope=1e-5, scatter_sd=1e-6)
    lt = simulate_life_test(cfg, np.random.default_rng(0))
    n, t = lt.speed.shape
    df = pd.DataFrame({"cycle": np.repeat(lt.cycle.astype(int), t), "time": np.tile(lt.time, n),
                       "current": lt.current.ravel(), "speed": lt.speed.ravel()})
    p = tmp_path_factory.mktemp("pullup") / "pull.csv"
    df.to_csv(p, index=False)
    return p


# ------------------------------------------------------------------ item 6: --db
@pytest.mark.parametrize("kind", ["csv", "directory", "missing-directory"])
@pytest.mark.parametrize("command", ["track", "status"])
def test_db_that_cannot_be_a_database(tmp_path, kind, command):
    db = {"csv": acq_csv(tmp_path / "x.csv"), "directory": tmp_path,
          "missing-directory": tmp_path / "nope" / "f.db"}[kind]
    args = (["track", "--db", str(db), str(acq_csv(tmp_path / "a.csv"))] if command == "track"
            else ["status", "--db", str(db)])
    r = runner.invoke(app, args)
    no_traceback(r)
    assert r.exit_code == EXIT_INPUT
    assert f"error: {db}" in r.output
    assert not (tmp_path / "nope").exists()


def test_truncated_database_and_a_bad_row(tmp_path):
    db = tmp_path / "t.db"
    ingest_into(db, pd.DataFrame({"component": [f"c{i}" for i in range(3000)], "time": 1.0,
                                  "hi": 0.2}))
    con = sqlite3.connect(db)
    con.execute("UPDATE components SET level = 7 WHERE component = 'c5'")
    con.commit()
    con.close()
    r = runner.invoke(app, ["status", "--db", str(db)])
    no_traceback(r)
    assert r.exit_code == EXIT_INPUT
    assert "table components, component 'c5': column 'level' holds 7" in r.output
    data = db.read_bytes()
    db.write_bytes(data[: len(data) // 2])
    for args in (["status", "--db", str(db)],
                 ["track", "--db", str(db), str(acq_csv(tmp_path / "a.csv"))]):
        r = runner.invoke(app, args)
        no_traceback(r)
        assert r.exit_code == EXIT_CORRUPT  # damaged: its own exit code
        assert "reports the database damaged" in r.output and str(db) in r.output


# ------------------------------------------------------------------ item 6: motor
def test_motor_damping_huge_speed_names_file_and_column(pullup, tmp_path):
    df = pd.read_csv(pullup)
    df.assign(speed=df.speed * 1e300).to_csv(tmp_path / "big.csv", index=False)
    r = runner.invoke(app, ["motor", "damping", str(tmp_path / "big.csv")])
    no_traceback(r)
    assert r.exit_code == EXIT_INPUT
    assert f"{tmp_path / 'big.csv'}: column 'speed', cycle 1, sample 1" in " ".join(
        r.output.split())


def test_motor_damping_out_an_existing_file_is_refused_before_work(pullup, tmp_path):
    target = tmp_path / "existing.txt"
    target.write_text("keep me")
    r = runner.invoke(app, ["motor", "damping", str(pullup), "--out", str(target)])
    no_traceback(r)
    assert r.exit_code == EXIT_USAGE and "--out" in r.output
    assert target.read_text() == "keep me"


def test_paths_with_brackets_are_printed_verbatim(pullup, tmp_path):
    d = tmp_path / "run[1]" / "[bold]"
    d.mkdir(parents=True)
    src = d / "pull[a].csv"
    src.write_bytes(pullup.read_bytes())
    r = runner.invoke(app, ["motor", "damping", str(src), "--out", str(d / "out[x]"),
                            "--mc-samples", "20"])
    no_traceback(r)
    assert r.exit_code == 0, r.output
    flat = "".join(r.output.split())
    assert "".join(str(src).split()) in flat
    assert "".join(str(d / "out[x]" / "damping_per_cycle.csv").split()) in flat


@pytest.mark.parametrize(
    ("option", "value"), [("--tl", "-5"), ("--design-torque", "-1"), ("--design-torque", "nan")])
def test_motor_options_validated(pullup, option, value):
    r = runner.invoke(app, ["motor", "damping", str(pullup), option, value])
    no_traceback(r)
    assert r.exit_code == EXIT_USAGE and option in r.output


# ------------------------------------------------------------------ item 6: seeds, scheduler
@pytest.mark.parametrize("command", [
    ["reproduce", "rw-lubrication", "--quick"], ["reproduce", "motor-damping", "--quick"],
    ["reproduce", "friction-drive", "--quick"], ["reproduce", "embedded-rul"],
    ["demo"], ["example"], ["motor", "damping", "x.csv"], ["rw", "estimate-temperature", "x.csv"],
])
def test_negative_seed_is_a_usage_error_before_any_work(tmp_path, command):
    out = tmp_path / "out"
    extra = ["--out", str(out)] if command[0] in ("reproduce", "demo") else []
    r = runner.invoke(app, [*command, "--seed", "-1", *extra])
    no_traceback(r)
    assert r.exit_code == EXIT_USAGE, r.output
    assert "--seed" in r.output
    assert not out.exists()


def test_unreachable_scheduler_fails_fast_with_a_message(tmp_path):
    import socket

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens on this port now
    r = runner.invoke(app, ["reproduce", "rw-lubrication", "--quick", "--scheduler",
                            f"tcp://127.0.0.1:{port}", "--out", str(tmp_path / "o")])
    no_traceback(r)
    assert r.exit_code == EXIT_INPUT
    assert "cannot reach the Dask scheduler" in r.output
    assert not (tmp_path / "o").exists()
    r = runner.invoke(app, ["reproduce", "rw-lubrication", "--scheduler", "not an address",
                            "--out", str(tmp_path / "o")])
    assert r.exit_code == EXIT_USAGE


# ------------------------------------------------------------------ item 7
@pytest.mark.parametrize("option", [["--dt", "-1"], ["--lambda-hi", "0"], ["--offset", "x"],
                                    ["--initiation", "later"], ["--warn-rul", "inf"]])
def test_track_option_values_are_usage_errors(tmp_path, option):
    r = runner.invoke(app, ["track", "--db", str(tmp_path / "f.db"),
                            str(acq_csv(tmp_path / "a.csv")), *option])
    no_traceback(r)
    assert r.exit_code == EXIT_USAGE and option[0] in r.output
    assert not (tmp_path / "f.db").exists()


def test_status_format_json_and_csv_for_scripts(tmp_path):
    db = tmp_path / "s.db"
    ingest_into(db, pd.read_csv(acq_csv(tmp_path / "a.csv")))
    r = runner.invoke(app, ["status", "--db", str(db), "--format", "json"])
    assert r.exit_code == 0, r.output
    rows = pd.read_json(__import__("io").StringIO(r.output))
    assert rows["component"].tolist() == ["a"] and rows["n"].tolist() == [6]
    r = runner.invoke(app, ["status", "--db", str(db), "--format", "yaml"])
    assert r.exit_code == EXIT_USAGE


def test_help_text_is_not_eaten_by_markup():
    r = runner.invoke(app, ["motor", "damping", "--help"])
    assert "linear (seed eq. 4, [c, a])" in " ".join(r.output.split())


def test_an_unexpected_exception_is_exit_70_without_traceback(tmp_path):
    code = ("import sys, rulkit.fleet.store.status_view as s\n"  # what `rulkit status` reads with
            "def boom(*a, **k): raise RuntimeError('injected bug')\n"
            "s.read_status = boom\n"
            "from rulkit.cli import main\n"
            f"sys.argv = ['rulkit', 'status', '--db', {str(tmp_path / 'x.db')!r}]\n"
            "main()\n")
    ingest_into(tmp_path / "x.db", pd.read_csv(acq_csv(tmp_path / "a.csv")))
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == EXIT_INTERNAL, p.stderr
    assert "internal error" in p.stderr and "injected bug" in p.stderr
    assert "Traceback" not in p.stderr
