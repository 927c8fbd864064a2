"""Commands of the reaction-wheel motor damping system (seed 002; docs/systems/motor-damping.md).

- ``rulkit reproduce motor-damping [--quick] [--runs N] [--seed S] [--out DIR]
  [--macro-model linear|quadratic]``: the seed reproduction (tables, report.md with the seed's
  values beside ours, figures); the macro law of the main scenarios (the comparison table
  always has both).
- ``rulkit motor damping FILE``: multi-scale EKF on a user's pull-up test data (CSV/Parquet:
  cycle, time, current, speed, optionally acceleration): per-cycle damping, trend, RUL
  (``--macro-model quadratic`` for a constant-acceleration trend).

Heavy imports stay inside the command functions (``rulkit --help`` stays fast).
"""

from __future__ import annotations

import math
import shlex
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

if TYPE_CHECKING:
    from rulkit.systems.motor_damping.machine import MotorMachine


def _fmt(v: float, spec: str = ".4g") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, float) and math.isinf(v):
        return "> horizon"
    return format(v, spec)


def _check_macro_model(value: str) -> str:
    from rulkit.systems.motor_damping.macro import MACRO_MODELS

    if value not in MACRO_MODELS:
        raise typer.BadParameter(
            f"expected one of {', '.join(MACRO_MODELS)}, got {value!r}", param_hint="--macro-model"
        )
    return value


def reproduce_motor_damping(
    out: Path, runs: int | None, seed: int, quick: bool, command: str = "",
    macro_model: str = "linear", machine: MotorMachine | None = None,
) -> Path:
    """Run the reproduction and write its outputs; returns the report path. With ``machine``
    the synthetic motor is replaced by the machine's constants (its damping trend scaled to
    its failure damping: :func:`rulkit.systems.motor_damping.reproduce.study_for_motor`)."""
    from rich.console import Console
    from rich.markup import escape

    from rulkit.systems.motor_damping.macro import MacroSettings
    from rulkit.systems.motor_damping.report import write_report
    from rulkit.systems.motor_damping.reproduce import MotorDampingConfig, run, study_for_motor

    console = Console()
    kw: dict = {"seed": seed, "macro": MacroSettings(model=_check_macro_model(macro_model))}
    if machine is not None:
        kw.update(study_for_motor(machine.constants))
    if runs is not None:
        if runs < 1:
            raise typer.BadParameter(f"--runs: expected >= 1, got {runs}")
        kw["runs"] = runs
    cfg = MotorDampingConfig.quick(**kw) if quick else MotorDampingConfig(**kw)
    t0 = time.perf_counter()

    def progress(msg: str) -> None:
        console.print(f"[dim]{time.perf_counter() - t0:6.1f} s[/dim] {escape(msg)}")

    res = run(cfg, progress=progress)
    report = write_report(res, out, command=command)
    lin = res.scenarios["linear"]
    n_ref = min(58, cfg.life.n_cycles)
    k58 = int((lin.cycles == n_ref).nonzero()[0][0])
    a58 = lin.track.x[k58, :, 1]
    console.print(f"[bold]Seed 002 vs ours[/bold] ({cfg.runs} runs, seed {cfg.seed}):")
    _say(console, f"  slope per cycle after cycle {n_ref}: seed 2.67e-6, ours {a58.mean():.4g} "
                  f"(true {cfg.life.slope:.3g}, synthetic motor)")
    _say(console, f"  failure damping c_fail: seed 0.000147, ours {res.c_fail:.4g} (design-point "
                  f"algebra), {res.c_fail_from_curves:.4g} (from characteristic curves)")
    met = res.tables["rul_metrics"]
    for _, row in met.iterrows():
        _say(console, f"  {row['scenario']:<22} {row['method']:<11} cover90 "
                      f"{row['coverage_90']:.3f} a-l(0.5) {row['alpha_lambda_pass_0.5']:.2f}")
    console.print("[bold]Macro law comparison[/bold] (coverage of 90 % intervals, alpha-lambda "
                  "pass at lambda 0.5, RA, median interval width in cycles):")
    for _, row in res.tables["macro_models"].iterrows():
        _say(console,
             f"  truth {row['truth']:<12} model {row['macro_model']:<9} {row['method']:<11} "
             f"cover90 {row['coverage_90']:.3f} (1st half {row['coverage_90_first_half']:.3f}, "
             f"2nd {row['coverage_90_second_half']:.3f}) a-l(0.5) "
             f"{row['alpha_lambda_pass_0.5']:.2f} RA {row['ra_0.5_median']:.3f} width "
             f"{_fmt(float(row['median_width']), '.3g')}")
    _say(console, f"wrote tables, figures and {report} ({time.perf_counter() - t0:.1f} s)")
    return report


def _say(console: Any, text: str, **kw: Any) -> None:
    """Print plain text: no rich markup (``[c, a]`` stays as written), no highlighting."""
    console.print(text, markup=False, highlight=False, soft_wrap=True, **kw)


def analyse_file(
    file: Path,
    out: Path | None = None,
    machine: MotorMachine | None = None,
    *,
    seed: int = 0,
) -> object:
    """Read, validate and analyse a pull-up file with the motor of ``machine`` (default: the
    defaults of :data:`rulkit.systems.motor_damping.machine.MOTOR_SCHEMA`); print the
    per-cycle table; write CSV/JSON into ``out``."""
    import numpy as np
    from rich.console import Console
    from rich.table import Table
    from rich.text import Text

    from rulkit.prognosis.rul import RULDistribution
    from rulkit.systems.motor_damping.analysis import analyse_pullup
    from rulkit.systems.motor_damping.machine import read_motor_machine
    from rulkit.systems.motor_damping.pullup import check_plausible, read_pullup

    console = Console(width=150)
    machine = machine or read_motor_machine()
    limits = machine.limits
    data = read_pullup(file, min_samples=limits.min_samples)
    check_plausible(data, limits)
    consts = machine.constants
    kw = machine.analysis_kwargs()
    res = analyse_pullup(data, consts, rng=np.random.default_rng(seed), **kw)
    n_s = int(data.n_samples.sum())
    console.print(Text(f"{file}", style="bold") + f": {data.n_cycles} cycles, {n_s} samples")
    _say(console, f"machine: {machine.source}")
    _say(console, f"acceleration: {res.acceleration_source}")
    note = (" (defaults: the synthetic motor; give yours in a machine file)"
            if machine.source == "defaults" else "")
    _say(console, f"motor constants K={consts.K:g} N m/A, J={consts.J:g} kg m^2, "
                  f"T_L={consts.T_L:g} N m{note}")
    acc_sd = (f"acceleration {res.sigma_dw:.4g} rad/s^2" if data.acceleration_measured
              else "acceleration channel not used")
    given = kw["sigma_w"] is not None
    _say(console,
         f"noise sd: speed {res.sigma_w:.4g} rad/s, {acc_sd} "
         f"({'given' if given else 'estimated from second differences'}); "
         f"steady current {res.steady_current:.4g} A")
    design = (f"design point {kw['design_speed']:g} rad/s, {kw['design_torque'] * 1e3:g} mN m"
              if kw["c_fail"] is None else "given")
    _say(console, f"failure damping c_fail = {res.c_fail:.4g} N m s ({design})")
    gated = int(res.table["gated"].sum())
    if gated:
        cycles = ", ".join(f"{c:g}" for c in res.table.loc[res.table["gated"] > 0, "cycle"])
        _say(console, f"{gated} sample(s) outside the gate (NIS > {machine.micro.gate:g}; not "
                      f"used for the damping) in cycle(s) {cycles}")
    quad = kw["macro_model"] == "quadratic"
    _say(console, "macro law: " + ("quadratic c + a n + j n^2/2 (state [c, a, j])" if quad
                                   else "linear c + a n (seed eq. 4, state [c, a])"))
    tab = Table(title=Text("Per-cycle damping [N m s], trend and RUL in cycles (90 % interval)"))
    cols = ["cycle", "damping", "+-sd", "trend", "slope/cycle"]
    cols += ["curv./cycle^2"] if quad else []
    for c in (*cols, "RUL median", "RUL 90 %", "MC median", "MC 90 %"):
        tab.add_column(Text(c), justify="right")
    for _, r in res.table.iterrows():
        curv = [_fmt(r["curvature_per_cycle2"], ".3g")] if quad else []
        cells = [
            str(int(r["cycle"])), _fmt(r["damping"]), _fmt(r["damping_sd"], ".2g"),
            _fmt(r["trend_damping"]), _fmt(r["slope_per_cycle"], ".3g"), *curv,
            _fmt(r["rul_median"], ".1f"),
            f"[{_fmt(r['rul_p05'], '.1f')}, {_fmt(r['rul_p95'], '.1f')}]",
            _fmt(r["rul_mc_median"], ".1f"),
            f"[{_fmt(r['rul_mc_p05'], '.1f')}, {_fmt(r['rul_mc_p95'], '.1f')}]",
        ]
        tab.add_row(*(Text(c) for c in cells))
    console.print(tab)
    n_rul = int(np.isfinite(res.table["rul_median"]).sum())
    if n_rul == 0:
        _say(console,
             f"no RUL: the first prediction needs 3 cycles (the damping's scatter about its "
             f"trend is estimated from the residuals of a line); this file has "
             f"{data.n_cycles} cycle(s)")
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        res.table.to_csv(out / "damping_per_cycle.csv", index=False)
        if res.last_rul_samples.size:
            RULDistribution(
                res.last_rul_samples, censored=res.last_rul_censored, horizon=res.horizon
            ).to_json(out / "rul_last_cycle.json")
        _say(console, f"wrote {out / 'damping_per_cycle.csv'}")
    return res


def register(app: typer.Typer, reproduce: typer.Typer) -> None:
    """Add ``rulkit motor damping`` and ``rulkit reproduce motor-damping``."""
    motor = typer.Typer(help="Reaction-wheel motor (seed 002): damping and life from pull-ups.",
                        no_args_is_help=True)
    app.add_typer(motor, name="motor")
    _register_reproduce(reproduce)
    _register_damping(motor)


def _register_reproduce(reproduce: typer.Typer) -> None:
    """``rulkit reproduce motor-damping``."""

    @reproduce.command("motor-damping")
    def _reproduce(
        quick: Annotated[bool, typer.Option("--quick", help="Short run (< 1 min).")] = False,
        runs: Annotated[int | None, typer.Option(help="Seeded runs per scenario.")] = None,
        seed: Annotated[int, typer.Option(min=0, help="Master seed of the runs.")] = 0,
        out: Annotated[Path, typer.Option(help="Output directory.")] = Path(
            "out/motor-damping"
        ),
        macro_model: Annotated[str, typer.Option(
            help="Macro law of the main scenarios: linear (seed eq. 4, [c, a]) or quadratic "
                 "([c, a, j], constant acceleration). The macro_models table has both.")
        ] = "linear",
        machine: Annotated[Path | None, typer.Option(
            "--machine", help="Motor machine file (TOML): its [motor] constants replace the "
                              "synthetic motor (the damping trend scaled to its failure "
                              "damping).")] = None,
    ) -> None:
        """Seed 002: multi-scale EKF (micro per cycle, macro across cycles), RUL and metrics."""
        from rulkit.cli.errors import fail
        from rulkit.machine_file import MachineFileError
        from rulkit.systems.motor_damping.machine import read_motor_machine
        from rulkit.systems.motor_damping.motor import failure_damping

        try:
            motor = read_motor_machine(machine) if machine is not None else None
            if motor is not None:
                failure_damping(motor.constants)  # the design point must lie under its curve
        except (MachineFileError, ValueError) as err:
            fail(f"{machine}: {err}" if not str(err).startswith(str(machine)) else str(err))
        parts = ["rulkit", "reproduce", "motor-damping"]
        if quick:
            parts.append("--quick")
        if runs is not None:
            parts += ["--runs", str(runs)]
        parts += ["--seed", str(seed), "--out", str(out)]
        if macro_model != "linear":
            parts += ["--macro-model", macro_model]
        if machine is not None:
            parts += ["--machine", str(machine)]
        reproduce_motor_damping(out, runs, seed, quick, command=shlex.join(parts),
                                macro_model=macro_model, machine=motor)


def _register_damping(motor: typer.Typer) -> None:
    """``rulkit motor damping FILE``."""

    @motor.command("damping")
    def _damping(
        file: Annotated[Path | None, typer.Argument(
            help="CSV or Parquet: cycle, time (s), current (A), speed (rad/s)[, acceleration "
                 "(rad/s^2)].", show_default=False)] = None,
        out: Annotated[Path | None, typer.Option(
            help="Directory for damping_per_cycle.csv and rul_last_cycle.json.")] = None,
        machine: Annotated[Path | None, typer.Option(
            "--machine", help="Motor machine file (TOML): constants, failure point, noise, "
                              "plausible ranges, filter settings; default: the synthetic "
                              "motor.")] = None,
        print_machine: Annotated[bool, typer.Option(
            "--print-machine", help="Print the machine file in effect (the defaults, "
                                    "--machine and the options below) as TOML and exit.")
        ] = False,
        k: Annotated[float | None, typer.Option("--k", help="Torque constant K (N m/A).")] = None,
        j: Annotated[float | None, typer.Option("--j", help="Inertia J (kg m^2).")] = None,
        tl: Annotated[float | None, typer.Option("--tl", help="Load torque T_L (N m).")] = None,
        design_speed: Annotated[float | None, typer.Option(
            help="Design point speed (rad/s).")] = None,
        design_torque: Annotated[float | None, typer.Option(
            help="Design point torque (N m).")] = None,
        c_fail: Annotated[float | None, typer.Option(help="Failure damping (N m s; overrides "
                                                         "the design point).")] = None,
        sigma_w: Annotated[float | None, typer.Option(
            help="Speed noise sd (rad/s; 0: estimated).")] = None,
        sigma_dw: Annotated[float | None, typer.Option(
            help="Acceleration noise sd (rad/s^2; 0: estimated).")] = None,
        q_a: Annotated[float | None, typer.Option(
            help="Random-walk density of the highest state (slope for linear, curvature for "
                 "quadratic; 0: deterministic law).")] = None,
        macro_model: Annotated[str | None, typer.Option(
            help="Macro law: linear (seed eq. 4, [c, a]) or quadratic ([c, a, j], constant "
                 "acceleration of the damping).")] = None,
        mc_samples: Annotated[int | None, typer.Option(help="Monte Carlo RUL samples.")] = None,
        seed: Annotated[int, typer.Option(min=0, help="Seed of the Monte Carlo RUL.")] = 0,
        min_samples: Annotated[int | None, typer.Option(
            help="Fewest samples per cycle.")] = None,
    ) -> None:
        """Per-cycle damping (micro EKF), trend (macro EKF) and RUL of a pull-up test file."""
        from rulkit.cli.errors import EXIT_INPUT, EXIT_USAGE, fail
        from rulkit.machine_file import MachineFileError, machine_file_template
        from rulkit.systems.motor_damping.machine import MOTOR_SCHEMA, read_motor_machine
        from rulkit.systems.motor_damping.pullup import PullupDataError

        flags = {
            "--k": ("motor", "K", k), "--j": ("motor", "J", j), "--tl": ("motor", "T_L", tl),
            "--design-speed": ("failure", "design_speed", design_speed),
            "--design-torque": ("failure", "design_torque", design_torque),
            "--c-fail": ("failure", "c_fail", c_fail),
            "--sigma-w": ("noise", "sigma_w", sigma_w),
            "--sigma-dw": ("noise", "sigma_dw", sigma_dw), "--q-a": ("macro", "q_a", q_a),
            "--macro-model": ("macro", "model", macro_model),
            "--mc-samples": ("rul", "mc_samples", mc_samples),
            "--min-samples": ("limits", "min_samples", min_samples),
        }
        try:
            m = read_motor_machine(machine)
        except MachineFileError as err:
            fail(str(err), EXIT_INPUT)
        try:
            m = m.with_overrides(flags)
        except MachineFileError as err:
            fail(str(err), EXIT_USAGE)
        if out is not None and out.exists() and not out.is_dir():
            fail(f"--out: {out} is an existing file; expected a directory", EXIT_USAGE)
        if print_machine:
            typer.echo(machine_file_template(MOTOR_SCHEMA, f"motor machine file ({m.source})",
                                             values=m.values))
            return
        if file is None:
            fail("missing argument FILE (the pull-up record); see rulkit motor damping --help",
                 EXIT_USAGE)
        try:
            analyse_file(file, out, m, seed=seed)
        except (PullupDataError, ValueError, OverflowError, FloatingPointError) as err:
            msg = str(err)
            if not isinstance(err, PullupDataError) and not msg.startswith(str(file)):
                msg = f"{file}: {msg}"
            fail(msg, EXIT_INPUT)
        except OSError as err:
            fail(f"cannot write into {out}: {err.strerror or err}", EXIT_INPUT)
