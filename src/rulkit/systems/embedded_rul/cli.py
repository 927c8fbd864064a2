"""``rulkit reproduce embedded-rul``: seed 004 on the Lu & Meeker crack-growth data
(docs/systems/embedded-rul.md §5). Heavy imports stay inside the command."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def register(app: typer.Typer, reproduce: typer.Typer) -> None:
    """Add ``reproduce embedded-rul``."""

    @reproduce.command("embedded-rul")
    def reproduce_embedded_rul(
        out: Annotated[Path, typer.Option(
            "--out", help="Directory for report.md, tables and figures.")
        ] = Path("out/embedded-rul"),
        figures: bool = typer.Option(True, "--figures/--no-figures",
                                     help="Write one figure per unit."),
        seed: int = typer.Option(0, "--seed", min=0, help="Seed of the false-alarm study."),
        false_alarms: bool = typer.Option(True, "--false-alarms/--no-false-alarms",
                                          help="Run the HI false-alarm study (~5 s)."),
    ) -> None:
        """Trackers on the 21 Lu & Meeker crack-growth units: RUL accuracy, validity, report."""
        from rulkit.systems.embedded_rul.reproduce import EmbeddedRULConfig, run, write_report

        cmd = ("rulkit reproduce embedded-rul" + ("" if figures else " --no-figures")
               + (f" --seed {seed}" if false_alarms else " --no-false-alarms"))
        res = run(EmbeddedRULConfig(false_alarms=false_alarms, seed=seed))
        far = res.false_alarms
        rep = write_report(res, out, figures=figures, command=cmd)
        typer.echo(f"Paris exponent from the data: m = {res.m_all:.3f}")
        typer.echo(res.summary.to_string())
        if far is not None:
            typer.echo(far.to_string(index=False))
        typer.echo(f"report: {rep}")
