"""CLI of the reaction-wheel lubrication system: estimate-temperature on tiny files (good and
bad), and the quick reproduction at a reduced size writing the expected files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from rulkit.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def telemetry(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from rulkit.systems.reaction_wheel.wheel import simulate_table3

    run = simulate_table3(np.random.default_rng(0), "low", t_end=30.0)
    df = pd.DataFrame({"time_s": run.t, "v_comm_V": run.V, "speed_rad_s": run.y[:, 0],
                       "current_A": run.y[:, 1]})
    p = tmp_path_factory.mktemp("tele") / "wheel.csv"
    df.to_csv(p, index=False)
    return p


def _err(res) -> str:
    return (res.stderr if hasattr(res, "stderr") and res.stderr else "") + res.output


def test_estimate_temperature_writes_estimate_with_interval(telemetry: Path, tmp_path: Path):
    out = tmp_path / "est.csv"
    res = runner.invoke(app, ["rw", "estimate-temperature", str(telemetry), "--out", str(out),
                              "--particles", "40", "--seed", "1"])
    assert res.exit_code == 0, _err(res)
    est = pd.read_csv(out)
    assert list(est.columns) == ["time_s", "T_mean", "T_lo", "T_hi", "untrusted", "flags"]
    assert len(est) == 601
    num = est[["time_s", "T_mean", "T_lo", "T_hi"]].to_numpy()
    assert np.isfinite(num).all() and (est["T_lo"] <= est["T_hi"]).all()
    # the weighted mean may leave a quantile interval of a skewed particle set, but rarely
    inside = (est["T_lo"] <= est["T_mean"]) & (est["T_mean"] <= est["T_hi"])
    assert inside.mean() > 0.9
    # same seed, same numbers; parquet output too
    out2 = tmp_path / "est.parquet"
    res = runner.invoke(app, ["rw", "estimate-temperature", str(telemetry), "--out", str(out2),
                              "--particles", "40", "--seed", "1"])
    assert res.exit_code == 0, _err(res)
    np.testing.assert_array_equal(pd.read_parquet(out2)["T_mean"], est["T_mean"])


@pytest.mark.parametrize("case, expect", [
    ("missing", "no such file"),
    ("empty", "empty file"),
    ("column", "speed_rad_s"),
    ("nan", "row"),
    ("suffix", "unknown file type"),
])
def test_bad_telemetry_gives_specific_error_and_exit_code_2(telemetry: Path, tmp_path: Path,
                                                            case: str, expect: str) -> None:
    df = pd.read_csv(telemetry)
    p = tmp_path / "bad.csv"
    if case == "missing":
        p = tmp_path / "nope.csv"
    elif case == "empty":
        p.write_text("")
    elif case == "column":
        df.drop(columns="speed_rad_s").to_csv(p, index=False)
    elif case == "nan":
        df.loc[7, "current_A"] = np.nan
        df.to_csv(p, index=False)
    else:
        p = tmp_path / "bad.xlsx"
        p.write_text("x")
    # a particle filter needs every cell (the default 'imm' takes an empty cell as a dropout)
    res = runner.invoke(app, ["rw", "estimate-temperature", str(p), "--method", "pf",
                              "--particles", "20"])
    assert res.exit_code == 1  # the input file was refused (docs/guide.md, exit codes)
    msg = _err(res)
    assert "error:" in msg and expect in msg
    assert "Traceback" not in msg
    assert res.exception is None or isinstance(res.exception, SystemExit)


def test_bad_options_exit_code_2(telemetry: Path) -> None:
    res = runner.invoke(app, ["rw", "estimate-temperature", str(telemetry), "--method", "magic"])
    assert res.exit_code == 2 and "--method" in _err(res)
    res = runner.invoke(app, ["rw", "estimate-temperature", str(telemetry), "--particles", "1"])
    assert res.exit_code == 2 and "--particles" in _err(res)


def test_quick_reproduction_at_reduced_size_writes_files(tmp_path: Path, monkeypatch) -> None:
    from rulkit.systems.reaction_wheel.degradation.trackers import DegradationConfig
    from rulkit.systems.reaction_wheel.reproduce import ReproductionConfig
    from rulkit.systems.reaction_wheel.rul.forecast import RULConfig

    tiny = ReproductionConfig(
        quick=True, n_runs=2, seed=3,
        step2=DegradationConfig(n_particles=30, horizon_days=1.0),
        step3=RULConfig(failure_day=20.0, prediction_days=(0.5, 1.0), table7_day=1.0,
                            forecast_horizon_days=40.0),
        table5_particles=(20,), table5_ekf=False, step1_error_runs=1, step1_particles=30,
        error_hours=0.1, table6_alt=False,
        validation_hours=0.0, sensitivity_runs=0, eq28_seconds=5.0, real_step1_runs=0)
    monkeypatch.setattr(ReproductionConfig, "quick_config",
                        classmethod(lambda cls, seed=0, n_runs=None, **kw: tiny))
    out = tmp_path / "rwq"
    res = runner.invoke(app, ["reproduce", "rw-lubrication", "--quick", "--out", str(out)])
    assert res.exit_code == 0, _err(res)
    for name in ("table5.csv", "table6.csv", "table7.csv", "report.md", "rul_density.png",
                 "forecast_scenario1.png", "forecast_scenario2.png",
                 "step2_tracking_scenario1.png", "prognostic_metrics.csv", "settings.json"):
        assert (out / name).exists(), name
    t6 = pd.read_csv(out / "table6.csv")
    assert t6["runs"].iloc[0] == 2 and "S1 b paper" in t6
    new = ["RBPF + two-step PF (ours)", "RBPF + RB-PF (ours)"]  # RBPF step-1 source rows
    t7 = pd.read_csv(out / "table7.csv")
    for tab, cols in ((t6, [f"S{s} {p} ours" for s in (1, 2) for p in ("b", "beta")]),
                      (t7, [f"S{s} {k} ours" for s in (1, 2) for k in ("LB", "UB", "mean")])):
        rows = tab.set_index("method").loc[new, cols].to_numpy()
        assert np.isfinite(rows).all(), tab
    report = (out / "report.md").read_text()
    assert "Table 6" in report and "[R]" in report and "not validated" in report
    assert "| RBPF | rbpf RBJ |" in report and "RBPF step-1 source (ours)" in report
    assert "Table 6: RMSPE" in res.output  # the tables are printed
    # the seeds' filters complete, eq. 28 explained, one-step against two-step on every T^
    for name in ("table5_seed_filters.csv", "eq28_weights.csv", "table6_one_vs_two_step.csv"):
        assert (out / name).exists(), name
    assert "### Why eq. 28 fails" in report and "### One-step against two-step" in report
    filters = pd.read_csv(out / "table5_seed_filters.csv")
    assert {"pf", "apf", "apf_eq28", "apf_tempered", "adaptive"} == set(filters["method"])
    assert set(filters["design"]) == {"F1", "F2"}
    assert set(pd.read_csv(out / "table6_one_vs_two_step.csv")["T^ source"]) >= {"APF", "IMM"}


def test_reproduce_rejects_bad_options(tmp_path: Path) -> None:
    res = runner.invoke(app, ["reproduce", "rw-lubrication", "--runs", "0", "--out",
                              str(tmp_path)])
    assert res.exit_code == 2
    res = runner.invoke(app, ["reproduce", "rw-lubrication", "--workers", "2", "--scheduler",
                              "tcp://x:1", "--out", str(tmp_path)])
    assert res.exit_code == 2


@pytest.mark.parametrize("method", ["ekf", "rbpf"])
def test_estimate_temperature_other_methods(telemetry: Path, tmp_path: Path, method: str) -> None:
    out = tmp_path / f"{method}.csv"
    res = runner.invoke(app, ["rw", "estimate-temperature", str(telemetry), "--out", str(out),
                              "--method", method, "--particles", "30"])
    assert res.exit_code == 0, _err(res)
    est = pd.read_csv(out)
    assert len(est) == 601 and (est["T_lo"] <= est["T_hi"]).all()


def test_estimate_temperature_refuses_to_overwrite_its_input(tmp_path) -> None:
    """Issue 13: ``--out f.csv`` on input f.csv overwrote the input; now refused, unchanged."""
    from rulkit.systems.reaction_wheel.telemetry import table3_telemetry

    f = tmp_path / "f.csv"
    table3_telemetry(np.random.default_rng(0), "low", t_end=2.0).to_csv(f, index=False)
    before = f.read_bytes()
    res = runner.invoke(app, ["rw", "estimate-temperature", str(f), "--out", str(f)])
    assert res.exit_code != 0 and "overwrite" in _err(res)
    assert f.read_bytes() == before


def test_estimate_below_absolute_zero_is_refused() -> None:
    from rulkit.systems.reaction_wheel.temperature.estimator import (
        ImplausibleEstimateError,
        TemperatureEstimator,
    )

    est = pd.DataFrame({"time_s": [0.0, 0.05], "T_mean": [20.0, -300.0], "T_lo": [19, -301],
                        "T_hi": [21, -299], "untrusted": [False, False]})
    check = TemperatureEstimator("ekf", dt=0.05, source="f.csv")
    with pytest.raises(ImplausibleEstimateError, match=r"f.csv: .*row 11.*absolute zero"):
        check._check(est, 10)
    check._check(est.assign(T_mean=[20.0, 250.0]), 0)
    check._check(est.assign(T_mean=[-40.0, 20.0]), 2)
    assert check.warning is not None
    assert "2 estimates outside -30..215 C" in check.warning and "first: 250 C" in check.warning


@pytest.fixture(scope="module")
def wheel_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from rulkit.systems.reaction_wheel.simulate import simulate_record

    d = tmp_path_factory.mktemp("wheel-07")
    simulate_record(d, 1 / 24, np.random.default_rng(3), file_days=1 / 48)
    return d


def test_pipeline_then_rul_then_degradation_commands(wheel_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "p"
    res = runner.invoke(app, ["rw", "pipeline", str(wheel_dir), "--out", str(out),
                              "--threshold", "0.2"])
    assert res.exit_code == 0, res.output
    assert "RUL" in res.output and (out / "report.md").exists()
    res = runner.invoke(app, ["rw", "rul", str(out), "--threshold", "0.3", "--repeat-days",
                              "0.02"])
    assert res.exit_code == 0, res.output
    assert "two_step: RUL median" in res.output and (out / "rul_two_step.json").exists()
    est = tmp_path / "T.parquet"
    files = sorted((wheel_dir / "telemetry").iterdir())
    assert runner.invoke(app, ["rw", "estimate-temperature", str(files[0]), "--out",
                               str(est)]).exit_code == 0
    res = runner.invoke(app, ["rw", "degradation", "--losses", str(wheel_dir / "losses.csv"),
                              "--temperature", str(est), "--out", str(tmp_path / "d")])
    assert res.exit_code == 0, res.output
    # the windows the half hour of estimate reaches: 7 whole and the one it ends in
    assert pd.read_csv(tmp_path / "d" / "tracks.csv").shape[0] == 8


@pytest.mark.parametrize(("args", "code", "match"), [
    (["rw", "pipeline", "NOWHERE"], 2, "no such file"),
    (["rw", "pipeline", "WHEEL", "--threshold", "-1"], 2, "--threshold"),
    (["rw", "pipeline", "WHEEL", "--method", "adaptive"], 2, "--method"),
    (["rw", "pipeline", "WHEEL", "WHEEL", "--losses", "x.csv"], 2, "go with one record"),
    (["rw", "degradation", "--losses", "L"], 2, "exactly one of"),
    (["rw", "rul", "NOWHERE", "--threshold", "1"], 1, "not the output of step 2"),
    (["rw", "pipeline", "WHEEL", "--wheel", "BADWHEEL"], 1, r"\[wheel\] J"),
])
def test_record_commands_refuse_bad_input(wheel_dir: Path, tmp_path: Path, args, code,
                                          match) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[wheel]\nJ = -1.0\n")
    subs = {"WHEEL": str(wheel_dir), "NOWHERE": str(tmp_path / "nowhere"),
            "L": str(wheel_dir / "losses.csv"), "BADWHEEL": str(bad)}
    res = runner.invoke(app, [subs.get(a, a) for a in args] + ["--out", str(tmp_path / "o")]
                        if args[1] != "rul" else [subs.get(a, a) for a in args])
    assert res.exit_code == code, res.output
    assert __import__("re").search(match, _err(res)), _err(res)


def test_wheel_template_command_writes_a_readable_file(tmp_path: Path) -> None:
    from rulkit.systems.reaction_wheel.wheel_file import read_wheel_file

    f = tmp_path / "w.toml"
    assert runner.invoke(app, ["rw", "wheel-template", "--out", str(f)]).exit_code == 0
    assert read_wheel_file(f).params.J == 0.0077


def test_pipeline_refuses_an_unreachable_scheduler_before_any_work(wheel_dir: Path,
                                                                    tmp_path: Path) -> None:
    res = runner.invoke(app, ["rw", "pipeline", str(wheel_dir), str(wheel_dir), "--out",
                              str(tmp_path / "o"), "--scheduler", "tcp://127.0.0.1:1"])
    assert res.exit_code == 1 and "cannot reach the Dask scheduler" in _err(res)
    assert not (tmp_path / "o").exists()
