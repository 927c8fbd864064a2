"""``rulkit reproduce friction-drive``: seed 003 (friction-drive deterioration, EKF, RUL).

Heavy imports stay inside the command (cli/__init__.py).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

DEFAULT_OUT = Path("out/friction-drive")


def register(app: typer.Typer, reproduce: typer.Typer) -> None:
    """Add ``rulkit reproduce friction-drive`` to the ``reproduce`` group."""

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
    ) -> None:
        """Augmented EKF on the roller-on-tire drive, consistency, observability, MC RUL."""
        from rulkit.systems.friction_drive.report import tables, write_report
        from rulkit.systems.friction_drive.reproduce import FrictionDriveConfig, run

        n_runs = runs if runs is not None else (1 if quick else 5)
        cmd = (
            "rulkit reproduce friction-drive"
            + (" --quick" if quick else "")
            + f" --runs {n_runs} --seed {seed} --n-rul {n_rul} --duration {duration:g}"
        )
        typer.echo(f"friction-drive: {n_runs} run(s) per filter/scenario, seed {seed} ...")
        res = run(FrictionDriveConfig(
            n_runs=n_runs, seed=seed, n_rul=n_rul, duration=duration,
            n_validate=3 if quick else 10,
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
