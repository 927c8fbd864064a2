"""CLI test of ``rulkit reproduce friction-drive`` on small settings."""

from __future__ import annotations

import numpy as np
import pandas as pd
from typer.testing import CliRunner

from rulkit.cli import app


def test_reproduce_friction_drive_small(tmp_path):
    out = tmp_path / "fd"
    res = CliRunner().invoke(
        app,
        ["reproduce", "friction-drive", "--runs", "1", "--seed", "7", "--n-rul", "20",
         "--duration", "3", "--out", str(out)],
    )
    assert res.exit_code == 0, res.output
    assert "seed: 106.09 h" in res.output
    rep = (out / "report.md").read_text()
    assert "106.09" in rep and "3.36" in rep and "93.9" in rep
    for name in ("consistency", "verdicts", "ellipsoid", "observability", "rul"):
        assert (out / f"{name}.csv").exists()
    for fig in ("fig3_estimates.png", "fig5_deterioration.png", "fig7_bundle_tuned.png",
                "fig8_rul_tuned.png"):
        assert (out / fig).stat().st_size > 1000
    rul = pd.read_csv(out / "rul.csv")
    assert set(rul["config"]) == {"tuned", "seed", "seed-f44"}
    assert (rul["N"] == 20).all()
    cons = pd.read_csv(out / "consistency.csv")
    assert len(cons) == 12  # twelve (filter, scenario) pairs, one run each
    # the NEES-cause sentence quotes this run's largest post-switch NEES of each group
    fixed = cons["config"].str.startswith("tuned-consistent")
    assert fixed.sum() == 3
    for name, sel in (("no speed noise", cons[~fixed]), ("tuned-consistent*", cons[fixed])):
        assert (f"{name}: largest NEES within 50 steps after a current switch "
                f"{sel['max_NEES_switch'].max():.3g}") in rep
    # the report's text describes this run, not the 20 s default: at t_pred = 3 s the jump of
    # m (at 10 s) has not happened, so the truth's RUL is computed with m = 0.01
    assert "(LSODA, m = 0.01, alpha = " in rep
    truth_h = float(res.output.split("from the truth state at 3 s: ")[1].split(" h")[0])
    assert f"**{truth_h:.2f} h**" in rep
    np.testing.assert_allclose(rul["true_rul_h"], truth_h, atol=0.005)
    assert truth_h > 250  # m = 0.01 from alpha ~ 9.7: ~290 h, not the ~105 h of m = 0.02
    n_steps = 3000
    assert f"{n_steps} steps make them sensitive" in rep
    # the LSODA check sentence quotes the measured maximum, in seconds
    worst_s = rul["lsoda_check_max_abs_h"].max() * 3600.0
    assert f"max |fast - LSODA| {worst_s:.1f} s over {rul['lsoda_check_n'].sum()} samples" in rep


def test_reproduce_friction_drive_rejects_bad_options(tmp_path):
    res = CliRunner().invoke(app, ["reproduce", "friction-drive", "--runs", "0",
                                   "--out", str(tmp_path)])
    assert res.exit_code != 0
    res = CliRunner().invoke(app, ["reproduce", "friction-drive", "--duration", "1",
                                   "--out", str(tmp_path)])
    assert res.exit_code != 0
    res = CliRunner().invoke(app, ["reproduce", "friction-drive", "--seed", "-1",
                                   "--out", str(tmp_path)])
    assert res.exit_code == 2 and "seed" in res.output.lower()


def _record(tmp_path, seconds: float = 2.0, name: str = "drive.csv"):
    from .conftest import simulate_record, square_wave

    cur = square_wave(seconds)
    frame, X = simulate_record(cur, np.full(cur.size, 0.01), seed=2)
    p = tmp_path / name
    frame.to_csv(p, index=False) if name.endswith(".csv") else frame.to_parquet(p)
    return p, frame, X


def test_drive_on_a_record_writes_estimates_rul_and_summary(tmp_path) -> None:
    import json

    path, _, X = _record(tmp_path)
    machine = tmp_path / "m.toml"
    machine.write_text("[rul]\nsamples = 30\nlsoda_checks = 1\n")
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["drive", str(path), "--machine", str(machine),
                                   "--out", str(out), "--seed", "4"])
    assert res.exit_code == 0, res.output
    text = " ".join(res.output.split())
    assert "2001 rows, sampling step 1 ms, 2 s" in text and f"machine: {machine}" in text
    assert "mean NIS" in text and "Ljung-Box" in text and "consistent:" in text
    assert "optimistic" in text and "pessimistic" in text and "LSODA" in text
    est = pd.read_csv(out / "estimates.csv")
    assert len(est) == 2001 and list(est.columns[:4]) == ["row", "t_s", "current_A", "w1_rad_s"]
    assert set(est["status"]) <= {"prior", "updated"}
    summary = json.loads((out / "summary.json").read_text())
    fin = summary["final"]["alpha"]
    assert fin["low"] <= X[-1, 2] <= fin["high"]  # the truth inside the printed 3-sd bounds
    assert f"{fin['mean']:.4g}" in text
    assert summary["rul_h"]["samples"] == 30 and summary["rul_h"]["lsoda_checks"] == 1
    from rulkit.systems.friction_drive.machine import read_drive_machine

    assert read_drive_machine(out / "machine.toml").values["rul"]["samples"] == 30


def test_drive_refusals_write_nothing(tmp_path) -> None:
    path, frame, _ = _record(tmp_path, 0.5)
    out = tmp_path / "out"
    bad = tmp_path / "rpm.parquet"
    frame.assign(w1_rad_s=frame["w1_rad_s"] * 9.549).to_parquet(bad)
    res = CliRunner().invoke(app, ["drive", str(bad), "--out", str(out)])
    # 0.5 s from rest: the speeds in rpm stay under the plausible range, the model refuses them
    assert res.exit_code == 1 and not out.exists()
    assert "the machine file does not describe this record" in " ".join(res.output.split())
    machine = tmp_path / "m.toml"
    machine.write_text("[drive]\nJ1 = -1\n")
    res = CliRunner().invoke(app, ["drive", str(path), "--machine", str(machine)])
    assert res.exit_code == 1 and "[drive] J1 = -1 (kg m^2): outside its range" in res.output
    res = CliRunner().invoke(app, ["drive", str(path), "--current", "-3"])
    assert res.exit_code == 2 and "--current = -3.0 (A): outside its range" in res.output
    res = CliRunner().invoke(app, ["drive"])
    assert res.exit_code == 2 and "missing argument FILE" in res.output


def test_drive_print_machine_reads_back(tmp_path) -> None:
    res = CliRunner().invoke(app, ["drive", "--print-machine", "--current", "15"])
    assert res.exit_code == 0, res.output
    assert "[filter]" in res.output and "q_m = 3e-08" in res.output
    p = tmp_path / "printed.toml"
    p.write_text(res.output)
    from rulkit.systems.friction_drive.machine import read_drive_machine

    assert read_drive_machine(p).values["rul"]["current"] == 15.0


def test_reproduce_friction_drive_refuses_a_bad_machine_file(tmp_path) -> None:
    machine = tmp_path / "m.toml"
    machine.write_text("[drive]\nr2 = 'big'\n")
    res = CliRunner().invoke(app, ["reproduce", "friction-drive", "--machine", str(machine),
                                   "--out", str(tmp_path / "o")])
    assert res.exit_code == 1 and "[drive] r2 = 'big' (m): expected a number" in res.output
    assert not (tmp_path / "o").exists()
