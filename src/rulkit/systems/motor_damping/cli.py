"""Commands of the reaction-wheel motor damping system (seed 002, issue #4).

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
from typing import Annotated

import typer


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
    macro_model: str = "linear",
) -> Path:
    """Run the reproduction and write its outputs; returns the report path."""
    from rich.console import Console
    from rich.markup import escape

    from rulkit.systems.motor_damping.macro import MacroSettings
    from rulkit.systems.motor_damping.report import write_report
    from rulkit.systems.motor_damping.reproduce import MotorDampingConfig, run

    console = Console()
    kw: dict = {"seed": seed, "macro": MacroSettings(model=_check_macro_model(macro_model))}
    if runs is not None:
        if runs < 1:
            raise typer.BadParameter(f"--runs: expected >= 1, got {runs}")
        kw["runs"] = runs
    cfg = MotorDampingConfig.quick(**kw) if quick else MotorDampingConfig(**kw)
    t0 = time.perf_counter()

    def progress(msg: str) -> None:
        console.print(f"[dim]{time.perf_counter() - t0:6.1f} s[/dim] {msg}")

    res = run(cfg, progress=progress)
    report = write_report(res, out, command=command)
    lin = res.scenarios["linear"]
    n_ref = min(58, cfg.life.n_cycles)
    k58 = int((lin.cycles == n_ref).nonzero()[0][0])
    a58 = lin.track.x[k58, :, 1]
    console.print(f"[bold]Seed 002 vs ours[/bold] ({cfg.runs} runs, seed {cfg.seed}):")
    console.print(
        f"  slope per cycle after cycle {n_ref}: seed 2.67e-6, ours {a58.mean():.4g} "
        f"(true {cfg.life.slope:.3g}, synthetic motor)"
    )
    console.print(
        f"  failure damping c_fail: seed 0.000147, ours {res.c_fail:.4g} (design-point algebra), "
        f"{res.c_fail_from_curves:.4g} (from characteristic curves)"
    )
    met = res.tables["rul_metrics"]
    for _, row in met.iterrows():
        console.print(
            f"  {row['scenario']:<22} {row['method']:<11} cover90 {row['coverage_90']:.3f} "
            f"a-l(0.5) {row['alpha_lambda_pass_0.5']:.2f}"
        )
    console.print("[bold]Macro law comparison[/bold] (coverage of 90 % intervals, alpha-lambda "
                  "pass at lambda 0.5, RA, median interval width in cycles):")
    for _, row in res.tables["macro_models"].iterrows():
        console.print(
            f"  truth {row['truth']:<12} model {row['macro_model']:<9} {row['method']:<11} "
            f"cover90 {row['coverage_90']:.3f} (1st half {row['coverage_90_first_half']:.3f}, "
            f"2nd {row['coverage_90_second_half']:.3f}) a-l(0.5) "
            f"{row['alpha_lambda_pass_0.5']:.2f} RA {row['ra_0.5_median']:.3f} width "
            f"{_fmt(float(row['median_width']), '.3g')}", highlight=False,
        )
    console.print(f"wrote tables, figures and {escape(str(report))} "
                  f"({time.perf_counter() - t0:.1f} s)", highlight=False)
    return report


MAX_MAGNITUDE = 1e150
"""Largest accepted |value| of a pull-up column: the filters square the data (noise variances,
covariances), and float64 overflows above ~1.3e154."""


def check_magnitudes(data: object) -> None:
    """Refuse values whose squares overflow float64, naming the file, column, cycle and sample
    (before: ``OverflowError`` from inside the micro EKF)."""
    import numpy as np

    from rulkit.systems.motor_damping.pullup import PullupDataError

    for name in ("time", "current", "speed", "acceleration"):
        a = np.asarray(getattr(data, name))
        big = np.abs(np.nan_to_num(a, nan=0.0)) > MAX_MAGNITUDE
        if big.any():
            k, j = (int(v[0]) for v in np.nonzero(big))
            cyc = np.asarray(data.cycle)[k]  # type: ignore[attr-defined]
            raise PullupDataError(
                f"{data.source}: column {name!r}, cycle {cyc:g}, sample {j + 1}: {a[k, j]:.3g} "  # type: ignore[attr-defined]
                f"is beyond +-{MAX_MAGNITUDE:g}, where the filter's float64 arithmetic "
                f"overflows; check the unit ({int(big.sum())} such value(s))")


def analyse_file(
    file: Path,
    out: Path | None = None,
    *,
    K: float | None = None,
    J: float | None = None,
    T_L: float | None = None,
    design_speed: float = 300.0,
    design_torque: float = 16e-3,
    c_fail: float | None = None,
    sigma_w: float | None = None,
    sigma_dw: float | None = None,
    q_a: float = 0.0,
    mc_samples: int = 2000,
    seed: int = 0,
    min_samples: int = 20,
    macro_model: str = "linear",
) -> object:
    """Read, validate and analyse a pull-up file; print the per-cycle table; write CSV/JSON."""
    import numpy as np
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from rulkit.prognosis.rul import RULDistribution
    from rulkit.systems.motor_damping.analysis import analyse_pullup
    from rulkit.systems.motor_damping.motor import MotorConstants
    from rulkit.systems.motor_damping.pullup import read_pullup

    console = Console(width=150)
    data = read_pullup(file, min_samples=min_samples)
    check_magnitudes(data)
    base = MotorConstants()
    consts = MotorConstants(
        K=base.K if K is None else K, J=base.J if J is None else J,
        T_L=base.T_L if T_L is None else T_L,
    )
    res = analyse_pullup(
        data, consts, design_speed=design_speed, design_torque=design_torque, c_fail=c_fail,
        sigma_w=sigma_w, sigma_dw=sigma_dw, q_a=q_a, mc_samples=mc_samples,
        rng=np.random.default_rng(seed), macro_model=macro_model,
    )
    n_s = int(data.n_samples.sum())
    console.print(f"[bold]{escape(str(file))}[/bold]: {data.n_cycles} cycles, {n_s} samples",
                  highlight=False)
    console.print(f"acceleration: {res.acceleration_source}")
    console.print(
        f"motor constants K={consts.K:g} N m/A, J={consts.J:g} kg m^2, T_L={consts.T_L:g} N m"
        f"{' (defaults: the synthetic motor; pass --k/--j/--tl for yours)' if K is None else ''}"
    )
    acc_sd = (f"acceleration {res.sigma_dw:.4g} rad/s^2" if data.acceleration_measured
              else "acceleration channel not used")
    console.print(
        f"noise sd: speed {res.sigma_w:.4g} rad/s, {acc_sd} "
        f"({'given' if sigma_w is not None else 'estimated from second differences'}); "
        f"steady current {res.steady_current:.4g} A"
    )
    console.print(
        f"failure damping c_fail = {res.c_fail:.4g} N m s "
        f"({'given' if c_fail is not None else f'design point {design_speed:g} rad/s, '}"
        f"{'' if c_fail is not None else f'{design_torque * 1e3:g} mN m'})"
    )
    quad = macro_model == "quadratic"
    console.print(
        "macro law: " + ("quadratic c + a n + j n^2/2 (state [c, a, j])" if quad
                         else "linear c + a n (seed eq. 4, state [c, a])")
    )
    tab = Table(title="Per-cycle damping [N m s], trend and RUL in cycles (90 % interval)")
    cols = ["cycle", "damping", "+-sd", "trend", "slope/cycle"]
    cols += ["curv./cycle^2"] if quad else []
    for c in (*cols, "RUL median", "RUL 90 %", "MC median", "MC 90 %"):
        tab.add_column(c, justify="right")
    for _, r in res.table.iterrows():
        curv = [_fmt(r["curvature_per_cycle2"], ".3g")] if quad else []
        tab.add_row(
            str(int(r["cycle"])), _fmt(r["damping"]), _fmt(r["damping_sd"], ".2g"),
            _fmt(r["trend_damping"]), _fmt(r["slope_per_cycle"], ".3g"), *curv,
            _fmt(r["rul_median"], ".1f"),
            f"[{_fmt(r['rul_p05'], '.1f')}, {_fmt(r['rul_p95'], '.1f')}]",
            _fmt(r["rul_mc_median"], ".1f"),
            f"[{_fmt(r['rul_mc_p05'], '.1f')}, {_fmt(r['rul_mc_p95'], '.1f')}]",
        )
    console.print(tab)
    n_rul = int(np.isfinite(res.table["rul_median"]).sum())
    if n_rul == 0:
        console.print(
            f"no RUL: the first prediction needs 3 cycles (the damping's scatter about its "
            f"trend is estimated from the residuals of a line); this file has "
            f"{data.n_cycles} cycle(s)"
        )
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        res.table.to_csv(out / "damping_per_cycle.csv", index=False)
        if res.last_rul_samples.size:
            RULDistribution(
                res.last_rul_samples, censored=res.last_rul_censored, horizon=res.horizon
            ).to_json(out / "rul_last_cycle.json")
        console.print(f"wrote {escape(str(out / 'damping_per_cycle.csv'))}", highlight=False)
    return res


def register(app: typer.Typer, reproduce: typer.Typer) -> None:
    """Add ``rulkit motor damping`` and ``rulkit reproduce motor-damping``."""
    motor = typer.Typer(help="Reaction-wheel motor (seed 002): damping and life from pull-ups.",
                        no_args_is_help=True)
    app.add_typer(motor, name="motor")

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
    ) -> None:
        """Seed 002: multi-scale EKF (micro per cycle, macro across cycles), RUL and metrics."""
        parts = ["rulkit", "reproduce", "motor-damping"]
        if quick:
            parts.append("--quick")
        if runs is not None:
            parts += ["--runs", str(runs)]
        parts += ["--seed", str(seed), "--out", str(out)]
        if macro_model != "linear":
            parts += ["--macro-model", macro_model]
        reproduce_motor_damping(out, runs, seed, quick, command=shlex.join(parts),
                                macro_model=macro_model)

    @motor.command("damping")
    def _damping(
        file: Annotated[Path, typer.Argument(help="CSV or Parquet: cycle, time, current, "
                                             "speed[, acceleration].")],
        out: Annotated[Path | None, typer.Option(
            help="Directory for damping_per_cycle.csv and rul_last_cycle.json.")] = None,
        k: Annotated[float | None, typer.Option("--k", help="Torque constant K (N m/A).")] = None,
        j: Annotated[float | None, typer.Option("--j", help="Inertia J (kg m^2).")] = None,
        tl: Annotated[float | None, typer.Option("--tl", help="Load torque T_L (N m).")] = None,
        design_speed: Annotated[float, typer.Option(help="Design point speed (rad/s).")] = 300.0,
        design_torque: Annotated[float, typer.Option(help="Design point torque (N m).")] = 16e-3,
        c_fail: Annotated[float | None, typer.Option(help="Failure damping (N m s; overrides "
                                                         "the design point).")] = None,
        sigma_w: Annotated[float | None, typer.Option(
            help="Speed noise sd (rad/s; default: estimated).")] = None,
        sigma_dw: Annotated[float | None, typer.Option(
            help="Acceleration noise sd (rad/s^2; default: estimated).")] = None,
        q_a: Annotated[float, typer.Option(
            help="Random-walk density of the highest state (slope for linear, curvature for "
                 "quadratic; 0: deterministic law).")] = 0.0,
        macro_model: Annotated[str, typer.Option(
            help="Macro law: linear (seed eq. 4, [c, a]) or quadratic ([c, a, j], constant "
                 "acceleration of the damping).")] = "linear",
        mc_samples: Annotated[int, typer.Option(help="Monte Carlo RUL samples.")] = 2000,
        seed: Annotated[int, typer.Option(min=0, help="Seed of the Monte Carlo RUL.")] = 0,
        min_samples: Annotated[int, typer.Option(help="Fewest samples per cycle.")] = 20,
    ) -> None:
        """Per-cycle damping (micro EKF), trend (macro EKF) and RUL of a pull-up test file."""
        from rich.console import Console
        from rich.markup import escape

        from rulkit.cli.errors import EXIT_INPUT, EXIT_USAGE
        from rulkit.systems.motor_damping.pullup import PullupDataError
        from rulkit.tables import safe_text

        err_console = Console(stderr=True, soft_wrap=True)
        problems = [
            f"{flag}: expected a positive finite number, got {v!r}"
            for flag, v in (("--k", k), ("--j", j), ("--c-fail", c_fail), ("--sigma-w", sigma_w),
                            ("--sigma-dw", sigma_dw), ("--design-speed", design_speed),
                            ("--design-torque", design_torque))
            if v is not None and not (math.isfinite(v) and v > 0)
        ]
        if tl is not None and not (math.isfinite(tl) and tl >= 0):
            problems.append(f"--tl: expected a finite load torque >= 0, got {tl!r}")
        if out is not None and out.exists() and not out.is_dir():
            problems.append(f"--out: {out} is an existing file; expected a directory")
        if not (math.isfinite(q_a) and q_a >= 0):
            problems.append(f"--q-a: expected a finite number >= 0, got {q_a!r}")
        if macro_model not in ("linear", "quadratic"):
            problems.append(
                f"--macro-model: expected linear or quadratic, got {macro_model!r}"
            )
        if mc_samples < 1:
            problems.append(f"--mc-samples: expected >= 1, got {mc_samples}")
        if min_samples < 3:
            problems.append(f"--min-samples: expected >= 3, got {min_samples}")
        if problems:
            err_console.print(f"[red]error:[/red] {escape('; '.join(problems))}", highlight=False)
            raise typer.Exit(code=EXIT_USAGE)
        try:
            analyse_file(
                file, out, K=k, J=j, T_L=tl, design_speed=design_speed,
                design_torque=design_torque, c_fail=c_fail, sigma_w=sigma_w,
                sigma_dw=sigma_dw, q_a=q_a, mc_samples=mc_samples, seed=seed,
                min_samples=min_samples, macro_model=macro_model,
            )
        except (PullupDataError, ValueError, OverflowError, FloatingPointError) as err:
            msg = str(err)
            if not isinstance(err, PullupDataError) and not msg.startswith(str(file)):
                msg = f"{file}: {msg}"
            err_console.print(f"[red]error:[/red] {escape(safe_text(msg, 2000))}",
                              highlight=False)
            raise typer.Exit(code=EXIT_INPUT) from None
        except OSError as err:
            err_console.print(f"[red]error:[/red] cannot write into {escape(str(out))}: "
                              f"{escape(str(err.strerror or err))}", highlight=False)
            raise typer.Exit(code=EXIT_INPUT) from None
