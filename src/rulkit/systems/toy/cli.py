"""The engine's end-to-end example on the command line: ``rulkit example``.

Simulates the 2-state toy degradation model (rulkit.systems.toy.model), runs the particle
filter (with the exact Kalman filter beside it), propagates the posterior to the failure
threshold at several prediction times, prints a table and writes into ``--out``:

- ``rul.json``: the RUL distribution at the last prediction time
  (``RULDistribution.from_json`` reads it back);
- ``summary.json``: configuration, one row per prediction time, and the metrics;
- ``toy_degradation.png``: state estimates and RUL densities;
- ``report.md``: the table above as markdown.

``rulkit demo`` calls :func:`run_example` when the reaction-wheel pipeline is not available.
Heavy imports stay inside the functions (``rulkit --help`` stays fast).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer


def run_example(out: Path, seed: int, n_particles: int = 2000) -> dict[str, Any]:
    """Run the toy-degradation example with ``seed``; write its files into ``out``.

    Returns the summary dict that is also written to ``out/summary.json``.
    """
    from rich.console import Console
    from rich.table import Table

    from rulkit.systems.toy.example import ToyConfig, run, write_report

    if n_particles < 2:
        raise typer.BadParameter(f"n_particles: need at least 2, got {n_particles}")
    if seed < 0:  # numpy's SeedSequence would fail deep inside with "expected non-negative"
        raise typer.BadParameter(f"seed: expected a non-negative integer, got {seed}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = ToyConfig(seed=seed, n_particles=n_particles)
    result = run(cfg)
    rows = result.table()

    console = Console()
    table = Table(
        title=f"Toy degradation (seed {seed}, {cfg.n_particles} particles): RUL vs truth, "
        f"true end of life {result.t_eol:.2f}"
    )
    lvl = f"{cfg.interval_level:.0%}"
    for col in ("t_pred", "true RUL", "mean", "median", f"{lvl} interval", "censored", "RA",
                "CRPS"):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(
            f"{r['t_pred']:g}", f"{r['rul_true']:.2f}", f"{r['rul_mean']:.2f}",
            f"{r['rul_median']:.2f}", f"[{r['lower']:.1f}, {r['upper']:.1f}]",
            f"{r['fraction_censored']:.1%}", f"{r['relative_accuracy']:.3f}", f"{r['crps']:.3f}",
        )
    console.print(table)
    m = result.metrics
    if "alpha_lambda" in m:
        al = m["alpha_lambda"]
        ph = m["prognostic_horizon"]
        console.print(
            f"alpha-lambda (alpha={al['alpha']}, lambda={al['lambda']}): "
            f"{'pass' if al['passed'] else 'fail'} (mass in bounds {al['prob_mass']:.3f}); "
            f"prognostic horizon (alpha={ph['alpha']}): {ph['horizon']:.2f}; "
            f"CRA {m['cumulative_relative_accuracy']:.3f}"
        )
    pk = m["pf_vs_kf_last"]
    console.print(
        "posterior at the last step, particle filter vs exact Kalman filter: "
        f"damage {pk['pf_mean'][0]:.4f} +- {pk['pf_std'][0]:.4f} vs "
        f"{pk['kf_mean'][0]:.4f} +- {pk['kf_std'][0]:.4f}; "
        f"rate {pk['pf_mean'][1]:.5f} +- {pk['pf_std'][1]:.5f} vs "
        f"{pk['kf_mean'][1]:.5f} +- {pk['kf_std'][1]:.5f}"
    )

    write_report(result, out)
    summary: dict[str, Any] = json.loads((out / "summary.json").read_text())
    console.print(f"wrote {', '.join(summary['files'].values())}")
    return summary


def register(app: typer.Typer, reproduce: typer.Typer) -> None:
    """Add ``rulkit example`` to the top-level app."""

    @app.command()
    def example(
        out: Annotated[Path, typer.Option(help="Directory for the JSON and PNG.")] = Path(
            "example-out"
        ),
        seed: Annotated[int, typer.Option(min=0, help="Seed of the run.")] = 0,
        particles: Annotated[int, typer.Option(min=2, help="Number of particles.")] = 2000,
    ) -> None:
        """Engine end-to-end example: 2-state degradation, particle filter, Monte Carlo RUL."""
        run_example(out=out, seed=seed, n_particles=particles)
