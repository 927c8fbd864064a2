"""``rulkit reproduce friction-drive``: seed 003 (friction-drive deterioration, EKF, RUL), and
``rulkit drive FILE``: the same filter and RUL on a user's record.

Heavy imports stay inside the command (cli/__init__.py).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

DEFAULT_OUT = Path("out/friction-drive")


def register(app: typer.Typer, reproduce: typer.Typer) -> None:
    """Add ``rulkit reproduce friction-drive`` to the ``reproduce`` group and ``rulkit drive``
    to the commands."""
    register_drive(app)

    @reproduce.command("friction-drive")
    def friction_drive(
        quick: bool = typer.Option(False, "--quick", help="One run per filter, 3 LSODA checks."),
        runs: int | None = typer.Option(
            None, "--runs", min=1, help="Runs per (filter, scenario); default 1 quick, 5 full."
        ),
        seed: int = typer.Option(0, "--seed", min=0, help="Seed of the run (all draws)."),
        out: Annotated[
            Path, typer.Option("--out", help="Directory for tables, figures, report.")
        ] = DEFAULT_OUT,
        n_rul: int = typer.Option(100, "--n-rul", min=2, help="Monte Carlo RUL trajectories."),
        duration: float = typer.Option(
            20.0, "--duration", min=3.0, help="Filtered seconds; the RUL is predicted at its end."
        ),
        machine: Annotated[Path | None, typer.Option(
            "--machine", help="Drive machine file (TOML): its [drive] constants and [failure] "
                              "level replace the seed's drive in the study.")] = None,
    ) -> None:
        """Augmented EKF on the roller-on-tire drive, consistency, observability, MC RUL."""
        from rulkit.cli.errors import fail
        from rulkit.machine_file import MachineFileError
        from rulkit.systems.friction_drive.machine import read_drive_machine
        from rulkit.systems.friction_drive.report import tables, write_report
        from rulkit.systems.friction_drive.reproduce import FrictionDriveConfig, run

        try:
            params = read_drive_machine(machine).params
        except MachineFileError as err:
            fail(str(err))

        n_runs = runs if runs is not None else (1 if quick else 5)
        cmd = (
            "rulkit reproduce friction-drive"
            + (" --quick" if quick else "")
            + f" --runs {n_runs} --seed {seed} --n-rul {n_rul} --duration {duration:g}"
            + (f" --machine {machine}" if machine is not None else "")
        )
        typer.echo(f"friction-drive: {n_runs} run(s) per filter/scenario, seed {seed} ...")
        res = run(FrictionDriveConfig(
            n_runs=n_runs, seed=seed, n_rul=n_rul, duration=duration,
            n_validate=3 if quick else 10, tuning_runs=2 if quick else 8, params=params,
        ))
        rep = write_report(res, out, command=cmd)
        tabs = tables(res)
        cols = ["config", "N", "fit_mean_h", "fit_std_h", "median_h", "frac_censored",
                "lsoda_check_max_abs_h"]
        typer.echo(f"true RUL from the truth state at {duration:g} s: {res.rul_truth_h:.2f} h "
                   "(seed: 106.09 h, sd 3.36 h)")
        typer.echo(tabs["rul"][cols].to_string(index=False, float_format=lambda v: f"{v:.3f}"))
        v = tabs["verdicts"]
        typer.echo(
            v[["config", "scenario", "runs", "mean_NIS", "frac_NIS_ok", "frac_white",
               "frac_consistent", "median_sigma_m"]].to_string(
                index=False, float_format=lambda x: f"{x:.3g}"
            )
        )
        typer.echo(f"report: {rep}")


def register_drive(app: typer.Typer) -> None:
    """Add ``rulkit drive FILE``: the augmented EKF, its consistency checks and the RUL on a
    user's record (docs/commands/drive.md)."""

    @app.command("drive")
    def drive(
        file: Annotated[Path | None, typer.Argument(
            help="CSV or Parquet: time_s (s), current_A (A), w1_rad_s, w2_rad_s (rad/s).",
            show_default=False)] = None,
        machine: Annotated[Path | None, typer.Option(
            "--machine", help="Drive machine file (TOML): constants, failure level, sensor "
                              "noise, plausible ranges, filter tuning, RUL settings; default: "
                              "the seed's drive.")] = None,
        out: Annotated[Path | None, typer.Option(
            "--out", help="Directory for estimates.csv, rul.json, summary.json, "
                          "machine.toml.")] = None,
        seed: Annotated[int, typer.Option("--seed", min=0,
                                          help="Seed of the Monte Carlo RUL.")] = 0,
        current: Annotated[float | None, typer.Option(
            "--current", help="Future current of the RUL (A), held constant.")] = None,
        samples: Annotated[int | None, typer.Option(
            "--samples", help="Monte Carlo RUL trajectories.")] = None,
        print_machine: Annotated[bool, typer.Option(
            "--print-machine", help="Print the machine file in effect as TOML and exit.")
        ] = False,
    ) -> None:
        """Contact deterioration and RUL of a friction drive from its measured speeds."""
        import numpy as np

        from rulkit.cli.errors import EXIT_INPUT, EXIT_USAGE, fail
        from rulkit.machine_file import MachineFileError, machine_file_template
        from rulkit.systems.friction_drive.estimate import estimate, summary_lines, write_outputs
        from rulkit.systems.friction_drive.machine import DRIVE_SCHEMA, read_drive_machine
        from rulkit.systems.friction_drive.record import DriveRecordError, read_drive_record

        try:
            m = read_drive_machine(machine)
        except MachineFileError as err:
            fail(str(err), EXIT_INPUT)
        try:
            m = m.with_overrides({"--current": ("rul", "current", current),
                                  "--samples": ("rul", "samples", samples)})
        except MachineFileError as err:
            fail(str(err), EXIT_USAGE)
        if print_machine:
            typer.echo(machine_file_template(DRIVE_SCHEMA, f"drive machine file ({m.source})",
                                             values=m.values))
            return
        if file is None:
            fail("missing argument FILE (the drive's record); see rulkit drive --help",
                 EXIT_USAGE)
        if out is not None and out.exists() and not out.is_dir():
            fail(f"--out: {out} is an existing file; expected a directory", EXIT_USAGE)
        try:
            est = estimate(read_drive_record(file, m), m, np.random.default_rng(seed))
        except (DriveRecordError, ValueError) as err:
            msg = str(err)
            fail(msg if msg.startswith(str(file)) else f"{file}: {msg}", EXIT_INPUT)
        typer.echo(f"{file}:\n" + "\n".join(summary_lines(est)))
        if out is not None:
            try:
                paths = write_outputs(est, out)
            except OSError as err:
                fail(f"cannot write into {out}: {err.strerror or err}", EXIT_INPUT)
            typer.echo("wrote " + ", ".join(p.name for p in paths) + f" into {out}")
