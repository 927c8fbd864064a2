"""`rulkit motor damping FILE` and `rulkit reproduce motor-damping` (typer CliRunner)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from rulkit.cli import app
from rulkit.systems.motor_damping.motor import LifeTestConfig, simulate_life_test

runner = CliRunner()


@pytest.fixture(scope="module")
def pullup_csv(tmp_path_factory) -> tuple[Path, np.ndarray]:
    cfg = LifeTestConfig(n_cycles=6, duration=20.0, c0=6e-5, slope=1e-5, scatter_sd=1e-6)
    lt = simulate_life_test(cfg, np.random.default_rng(0))
    n, t = lt.speed.shape
    df = pd.DataFrame({
        "cycle": np.repeat(lt.cycle.astype(int), t), "time": np.tile(lt.time, n),
        "current": lt.current.ravel(), "speed": lt.speed.ravel(),
        "acceleration": lt.acceleration.ravel(),
    })
    p = tmp_path_factory.mktemp("pullup") / "test.csv"
    df.to_csv(p, index=False)
    return p, lt.damping


def test_motor_damping_on_a_file(pullup_csv, tmp_path: Path) -> None:
    path, truth = pullup_csv
    res = runner.invoke(app, ["motor", "damping", str(path), "--out", str(tmp_path),
                              "--mc-samples", "200"])
    assert res.exit_code == 0, res.output
    assert "6 cycles" in res.output and "measured (column 'acceleration')" in res.output
    assert "c_fail = 0.000147" in res.output
    table = pd.read_csv(tmp_path / "damping_per_cycle.csv")
    assert list(table["cycle"]) == [1, 2, 3, 4, 5, 6]
    np.testing.assert_allclose(table["damping"], truth, atol=5 * table["damping_sd"].max())
    assert np.isnan(table["rul_median"].iloc[1]) and np.isfinite(table["rul_median"].iloc[-1])
    # trend 6e-5 + 1e-5 n crosses 1.47e-4 at n = 8.7: about 2.7 cycles after cycle 6
    assert 1.0 < table["rul_median"].iloc[-1] < 5.0
    assert (tmp_path / "rul_last_cycle.json").exists()


def test_motor_damping_without_acceleration_says_how(pullup_csv, tmp_path: Path) -> None:
    path, _ = pullup_csv
    df = pd.read_csv(path).drop(columns=["acceleration"])
    p = tmp_path / "noacc.parquet"
    df.to_parquet(p)
    res = runner.invoke(app, ["motor", "damping", str(p), "--mc-samples", "100"])
    assert res.exit_code == 0, res.output
    assert "derived from speed by second-order central differences" in " ".join(res.output.split())
    assert "acceleration channel not used" in res.output


def test_motor_damping_bad_file_gives_specific_error(pullup_csv, tmp_path: Path) -> None:
    path, _ = pullup_csv
    df = pd.read_csv(path)
    df.loc[10, "speed"] = np.nan
    p = tmp_path / "bad.csv"
    df.to_csv(p, index=False)
    res = runner.invoke(app, ["motor", "damping", str(p)])
    assert res.exit_code == 1  # the input file was refused
    assert "column 'speed', row 11" in " ".join(res.output.split())
    res = runner.invoke(app, ["motor", "damping", str(tmp_path / "missing.csv")])
    assert res.exit_code == 1 and "file not found" in res.output


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--mc-samples", "0"], "--mc-samples = 0: outside its range, expected 1 <= mc_samples"),
        (["--sigma-w", "-1"], "--sigma-w = -1.0 (rad/s): outside its range, expected 0 <= "),
        (["--j", "-3e-3"], "--j = -0.003 (kg m^2): outside its range, expected 1e-07 <= J"),
        (["--q-a", "-1"], "--q-a = -1.0 ((N m s)^2/cycle^3): outside its range"),
        (["--min-samples", "2"], "--min-samples = 2: outside its range, expected 3 <="),
        (["--macro-model", "cubic"], "--macro-model = 'cubic': expected one of 'linear', "
                                     "'quadratic'"),
    ],
)
def test_motor_damping_bad_options_named_by_flag(pullup_csv, options, message) -> None:
    path, _ = pullup_csv
    res = runner.invoke(app, ["motor", "damping", str(path), *options])
    assert res.exit_code == 2
    assert message in " ".join(res.output.split())


def test_motor_damping_two_cycles_says_why_there_is_no_rul(pullup_csv, tmp_path: Path) -> None:
    path, _ = pullup_csv
    df = pd.read_csv(path)
    p = tmp_path / "two.csv"
    df[df["cycle"] <= 2].to_csv(p, index=False)
    res = runner.invoke(app, ["motor", "damping", str(p), "--mc-samples", "50"])
    assert res.exit_code == 0, res.output
    assert "no RUL: the first prediction needs 3 cycles" in " ".join(res.output.split())


def test_motor_damping_help_shows_units() -> None:
    # units in square brackets were swallowed as rich markup ("Inertia J ." in the help)
    res = runner.invoke(app, ["motor", "damping", "--help"])
    text = " ".join(res.output.split())
    for unit in ("(kg m^2)", "(rad/s)", "(N m/A)", "(rad/s^2;"):
        assert unit in text, unit


def test_analyse_pullup_refuses_non_positive_noise(pullup_csv) -> None:
    from rulkit.systems.motor_damping.analysis import analyse_pullup
    from rulkit.systems.motor_damping.pullup import read_pullup

    data = read_pullup(pullup_csv[0])
    with pytest.raises(ValueError, match="sigma_w: expected a positive finite value"):
        analyse_pullup(data, sigma_w=0.0, mc_samples=10)
    with pytest.raises(ValueError, match="mc_samples: expected a positive integer"):
        analyse_pullup(data, mc_samples=0)


def test_reproduce_motor_damping_help_lists_options() -> None:
    res = runner.invoke(app, ["reproduce", "motor-damping", "--help"])
    assert res.exit_code == 0
    for opt in ("--quick", "--runs", "--seed", "--out", "--macro-model"):
        assert opt in res.output


def test_reproduce_motor_damping_quick_small(tmp_path: Path, monkeypatch) -> None:
    # the real command with a reduced quick configuration (fewer cycles, shorter cycles)
    from rulkit.systems.motor_damping import reproduce as md

    small = md.MotorDampingConfig.quick

    def tiny(**kw):
        cfg = small(**kw)
        return md.replace(cfg, life=LifeTestConfig(n_cycles=30, duration=15.0), mc_samples=30,
                          variant_runs=1, qa_sweep_sd=(0.0,), q_a_grid=(0.0, 1e-14),
                          prediction_cycles=(10, 20, 30), j_prior_sweep_sd=(1e-7,))

    monkeypatch.setattr(md.MotorDampingConfig, "quick", staticmethod(tiny))
    res = runner.invoke(app, ["reproduce", "motor-damping", "--quick", "--runs", "2",
                              "--seed", "3", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    report = (tmp_path / "report.md").read_text()
    assert "rulkit reproduce motor-damping --quick --runs 2 --seed 3" in report
    assert "| failure damping c_fail [N m s] | 0.000147 | 0.000147 (algebra" in report
    assert (tmp_path / "rul_metrics.csv").exists()
    assert (tmp_path / "fig10_characteristic_curves.png").exists()
    # the quadratic law for the main scenarios: the linear law is then the comparison's extra
    res = runner.invoke(app, ["reproduce", "motor-damping", "--quick", "--runs", "2",
                              "--seed", "3", "--out", str(tmp_path / "q"),
                              "--macro-model", "quadratic"])
    assert res.exit_code == 0, res.output
    report = (tmp_path / "q" / "report.md").read_text()
    assert "--seed 3 --out" in report and "--macro-model quadratic" in report
    met = pd.read_csv(tmp_path / "q" / "rul_metrics.csv")
    assert set(met.loc[met["scenario"] == "linear", "macro_model"]) == {"quadratic"}
    assert set(met.loc[met["scenario"] == "linear-linear-macro", "macro_model"]) == {"linear"}
    res = runner.invoke(app, ["reproduce", "motor-damping", "--runs", "0"])
    assert res.exit_code != 0


def test_motor_damping_quadratic_macro_model(pullup_csv, tmp_path: Path) -> None:
    path, _ = pullup_csv
    res = runner.invoke(app, ["motor", "damping", str(path), "--macro-model", "quadratic",
                              "--mc-samples", "100", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert "quadratic" in res.output and "curv./cycle^2" in res.output
    table = pd.read_csv(tmp_path / "damping_per_cycle.csv")
    assert table["curvature_per_cycle2"].notna().all()
    # the analytic crossing of the last posterior-mean trend c + a m + j m^2/2 = c_fail
    last = table.iloc[-1]
    c, a, j = last["trend_damping"], last["slope_per_cycle"], last["curvature_per_cycle2"]
    m = last["trend_crossing"]
    c_at_m = c + a * m + 0.5 * j * m * m
    # c_fail from the design point with the file's measured steady current (~1.47e-4)
    assert c_at_m == pytest.approx(1.47e-4, rel=1e-4)
    res = runner.invoke(app, ["motor", "damping", str(path), "--mc-samples", "100",
                              "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    lin = pd.read_csv(tmp_path / "damping_per_cycle.csv")
    assert lin["curvature_per_cycle2"].isna().all()
    # the linear law's crossing reaches the same c_fail
    last = lin.iloc[-1]
    assert last["trend_damping"] + last["slope_per_cycle"] * last["trend_crossing"] == (
        pytest.approx(c_at_m, rel=1e-9))


def test_macro_model_bad_value_named_by_flag(pullup_csv) -> None:
    path, _ = pullup_csv
    res = runner.invoke(app, ["motor", "damping", str(path), "--macro-model", "cubic"])
    assert res.exit_code == 2
    assert "--macro-model" in res.output and "cubic" in res.output
    res = runner.invoke(app, ["reproduce", "motor-damping", "--macro-model", "cubic"])
    assert res.exit_code != 0
    assert "cubic" in res.output


def test_motor_damping_prints_brackets_as_written(pullup_csv) -> None:
    # rich markup swallowed "[c, a]": the line read "state )"
    path, _ = pullup_csv
    res = runner.invoke(app, ["motor", "damping", str(path), "--mc-samples", "50"])
    assert res.exit_code == 0, res.output
    assert "(seed eq. 4, state [c, a])" in res.output and "state )" not in res.output
    assert "Per-cycle damping [N m s]" in " ".join(res.output.split())
    res = runner.invoke(app, ["motor", "damping", str(path), "--mc-samples", "50",
                              "--macro-model", "quadratic"])
    assert "(state [c, a, j])" in res.output


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"speed": 60 / (2 * np.pi)}, "is beyond the plausible 1000 rad/s"),
        ({"current": 1000.0}, "current in mA?"),
        ({"time": 1000.0}, "time in ms?"),
    ],
)
def test_motor_damping_wrong_units_refused(pullup_csv, tmp_path: Path, change,
                                           message) -> None:
    path, _ = pullup_csv
    df = pd.read_csv(path)
    for col, f in change.items():
        df[col] = df[col] * f
    p = tmp_path / "units.csv"
    df.to_csv(p, index=False)
    res = runner.invoke(app, ["motor", "damping", str(p), "--out", str(tmp_path / "o")])
    assert res.exit_code == 1
    assert message in " ".join(res.output.split())
    assert not (tmp_path / "o").exists()  # nothing written


def test_motor_damping_rpm_within_the_range_is_a_negative_damping_error(
        pullup_csv, tmp_path: Path) -> None:
    path, _ = pullup_csv
    df = pd.read_csv(path)
    rpm = 60 / (2 * np.pi)
    df["speed"], df["acceleration"] = df["speed"] * rpm, df["acceleration"] * rpm
    p = tmp_path / "rpm.csv"
    df.to_csv(p, index=False)
    machine = tmp_path / "m.toml"
    machine.write_text("[limits]\nmax_speed = 10000\n")
    res = runner.invoke(app, ["motor", "damping", str(p), "--machine", str(machine)])
    assert res.exit_code == 1
    assert "is negative, which is physically impossible" in " ".join(res.output.split())


def test_motor_damping_refuses_colliding_and_boolean_columns(pullup_csv, tmp_path: Path) -> None:
    path, _ = pullup_csv
    df = pd.read_csv(path)
    df["Speed"] = df["speed"]
    p = tmp_path / "twice.csv"
    df.to_csv(p, index=False)
    res = runner.invoke(app, ["motor", "damping", str(p)])
    assert res.exit_code == 1 and "differ only in case" in res.output
    df = pd.read_csv(path)
    df["current"] = df["current"] > 2.5
    df.to_csv(p, index=False)
    res = runner.invoke(app, ["motor", "damping", str(p)])
    assert res.exit_code == 1 and "is a boolean (true/false), not a number" in res.output


def test_motor_damping_machine_file_and_print_machine(pullup_csv, tmp_path: Path) -> None:
    path, _ = pullup_csv
    machine = tmp_path / "m.toml"
    machine.write_text("[failure]\nc_fail = 2e-4\n[rul]\nmc_samples = 30\n")
    res = runner.invoke(app, ["motor", "damping", str(path), "--machine", str(machine)])
    assert res.exit_code == 0, res.output
    assert "c_fail = 0.0002 N m s (given)" in res.output and f"machine: {machine}" in res.output
    res = runner.invoke(app, ["motor", "damping", "--print-machine", "--machine", str(machine),
                              "--j", "0.002"])
    assert res.exit_code == 0, res.output
    assert "c_fail = 0.0002  # N m s" in res.output and "J = 0.002  # kg m^2" in res.output
    printed = tmp_path / "printed.toml"
    printed.write_text(res.output)
    from rulkit.systems.motor_damping.machine import read_motor_machine

    assert read_motor_machine(printed).constants.J == 0.002
    machine.write_text("[motor]\nJ = -1\n")
    res = runner.invoke(app, ["motor", "damping", str(path), "--machine", str(machine)])
    assert res.exit_code == 1 and "[motor] J = -1 (kg m^2): outside its range" in res.output
    res = runner.invoke(app, ["motor", "damping"])
    assert res.exit_code == 2 and "missing argument FILE" in res.output


def test_reproduce_motor_damping_refuses_a_bad_machine_file(tmp_path: Path) -> None:
    machine = tmp_path / "m.toml"
    machine.write_text("[motor]\nK = 0.001\n")  # too weak to reach the design point
    res = runner.invoke(app, ["reproduce", "motor-damping", "--machine", str(machine),
                              "--out", str(tmp_path / "o")])
    assert res.exit_code == 1
    assert "the design point (300.0 rad/s, 0.016 N m) is above the undamped curve" in res.output
    assert not (tmp_path / "o").exists()
