"""``rulkit track``, ``rulkit status`` and ``rulkit reproduce embedded-rul`` (seed 004).

embedded-rul.md: the per-component tracker chain with its state in an SQLite database
(:mod:`rulkit.fleet.store`). Heavy imports stay inside the commands.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer


def _fail(msg: str) -> None:
    typer.echo(f"error: {msg}", err=True)
    raise typer.Exit(code=1)


def _open_store(db: Path, given: dict[str, float | str], baseline: Path | None, pfa: float,
                offset: str):
    """Open or create the database; options only set a new database's configuration."""
    import numpy as np

    from rulkit.fleet.health_index import HealthIndexModel
    from rulkit.fleet.store import ComponentStore, IngestError, read_acquisitions
    from rulkit.fleet.tracker_chain import TrackerConfig
    from rulkit.tables import numeric_columns

    hi_model = None
    if baseline is not None:
        try:
            base = read_acquisitions(baseline)
        except IngestError as err:
            _fail(f"baseline: {err}")
        if base.shape[1] < 1 or len(base) < 2:
            _fail(f"baseline {baseline}: expected rows of healthy CIs, one column per CI")
        try:
            cols = numeric_columns(base, [str(c) for c in base.columns], error=ValueError,
                                   source=f"baseline {baseline}")
        except ValueError as err:
            _fail(str(err))
        try:
            hi_model = HealthIndexModel.fit(
                np.column_stack(list(cols.values())), pfa=pfa, offset=offset,  # type: ignore[arg-type]
                names=list(cols))
        except ValueError as err:
            _fail(f"baseline {baseline}: {err}")
    try:
        if db.exists():
            store = ComponentStore(db, create=False)
            if given:
                merged = {**store.config.to_dict(), **given}
                if TrackerConfig.from_dict(merged) != store.config:
                    store.close()
                    diff = {k: (store.config.to_dict()[k], v) for k, v in given.items()
                            if store.config.to_dict()[k] != v}
                    _fail(f"{db} was created with other tracker settings (stored, given): "
                          f"{diff}; the state is only meaningful with its own settings")
            if hi_model is not None:
                store.close()
                store = ComponentStore(db, hi_model=hi_model)
            return store
        cfg = TrackerConfig.from_dict({**TrackerConfig().to_dict(), **given})
        return ComponentStore(db, config=cfg, hi_model=hi_model)
    except (ValueError, FileNotFoundError) as err:
        _fail(str(err))
    raise AssertionError  # unreachable


def _fmt(v: float, spec: str = ".3g") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return format(v + 0.0, spec)  # + 0.0 turns -0.0 into 0.0


def register(app: typer.Typer, reproduce: typer.Typer) -> None:
    """Add ``track``, ``status`` and ``reproduce embedded-rul``."""

    @app.command("track")
    def track(
        acquisitions: Annotated[Path, typer.Argument(
            help="CSV or Parquet with columns component, time and hi (or the CI columns "
                 "of the database's HI model).")],
        db: Annotated[Path, typer.Option(
            "--db", help="SQLite component database (created if new).")],
        baseline: Annotated[Path | None, typer.Option(
            "--baseline", help="CSV of healthy CIs (one column per CI) to fit and store "
                               "the CI -> HI model (new database or one without a model).")
        ] = None,
        pfa: float = typer.Option(1e-6, "--pfa", help="False-alarm probability of HI = 0.5."),
        offset: str = typer.Option("cdf05", "--offset", help="CI offset: cdf05 or none."),
        dt: float | None = typer.Option(None, "--dt", help="Nominal acquisition interval."),
        lambda_hi: float | None = typer.Option(None, "--lambda-hi", help="Tracking index, HI."),
        lambda_rul: float | None = typer.Option(None, "--lambda-rul",
                                                help="Tracking index, RUL."),
        design_life: float | None = typer.Option(None, "--design-life",
                                                 help="dHI floor = 1/design life."),
        warn_rul: float | None = typer.Option(None, "--warn-rul",
                                              help="Warning when a valid RUL is below this."),
        hi_sigma: float | None = typer.Option(None, "--hi-sigma",
                                              help="HI std for the confidence limits."),
        valid_d2rul: float | None = typer.Option(None, "--valid-d2rul",
                                                 help="Validity limit of |d2RUL/dt2|."),
        paris_exponent: float | None = typer.Option(None, "--paris-exponent",
                                                    help="Paris exponent m of the RUL."),
        initiation: str | None = typer.Option(None, "--initiation",
                                              help="Track start: floor or two-point."),
    ) -> None:
        """Ingest acquisitions (one transaction) and print new warnings and alarms."""
        from rich.console import Console

        from rulkit.fleet.store import IngestError

        given = {k: v for k, v in {
            "dt": dt, "lambda_hi": lambda_hi, "lambda_rul": lambda_rul,
            "design_life": design_life, "warn_rul": warn_rul, "hi_sigma": hi_sigma,
            "valid_d2rul": valid_d2rul, "paris_exponent": paris_exponent,
            "initiation": initiation}.items()
            if v is not None}
        if offset not in ("cdf05", "none"):
            _fail(f"--offset: expected cdf05 or none, got {offset!r}")
        store = _open_store(db, given, baseline, pfa, offset)
        try:
            res = store.ingest_file(acquisitions)
        except IngestError as err:
            msg = str(err)  # file-level errors already start with the path
            where = "" if msg.startswith(str(acquisitions)) else f"{acquisitions}: "
            _fail(f"{where}{msg} (nothing was written to {db})")
        finally:
            store.close()
        from rich.markup import escape

        console = Console(highlight=False)
        console.print(f"ingested {res.n_rows} acquisitions of {res.n_components} components "
                      f"({res.n_new_components} new) into {db}")
        if not res.alerts:
            console.print("no new warnings or alarms")
        for a in res.alerts:
            style = "bold red" if a.name == "alarm" else "yellow"
            console.print(
                f"[{style}]{a.name.upper():7s}[/{style}] {escape(str(a.component))}  t={a.t:g}  "
                f"HI={a.hi:.3f}  fHI={a.fhi:.3f}  RUL={_fmt(a.frul)} "
                f"{escape(f'[{_fmt(a.rul_low)}, {_fmt(a.rul_high)}]')}  "
                f"valid={'yes' if a.valid else 'no'}"
            )

    @app.command("status")
    def status(
        db: Annotated[Path, typer.Option("--db", help="SQLite component database.")],
        limit: int = typer.Option(0, "--limit", min=0, help="Show the worst N (0 = all)."),
    ) -> None:
        """Table of components with HI, RUL, validity and alert level, worst first."""
        from rich.console import Console
        from rich.markup import escape
        from rich.table import Table

        from rulkit.fleet.store import ComponentStore
        from rulkit.fleet.tracker_chain import LEVEL_NAMES

        try:
            store = ComponentStore(db, create=False)
        except (FileNotFoundError, ValueError) as err:
            _fail(str(err))
        try:
            df = store.status()
        finally:
            store.close()
        n_all = len(df)
        if limit:
            df = df.head(limit)
        shown = f", the worst {len(df)} shown" if len(df) < n_all else ""
        table = Table(
            title=escape(f"{db}: {n_all} components, worst first{shown}"),
            caption="RUL: the alpha-beta-gamma filtered RUL, trusted only when valid = yes; "
                    "RUL low/high: Paris-law RUL from fHI, dHI under HI +- hi_sigma and "
                    "load +- load_factor",
        )
        for col in ("component", "level", "HI", "fHI", "RUL", "RUL low", "RUL high", "valid",
                    "dRUL/dt", "d2RUL/dt2", "n", "last t"):
            table.add_column(col, justify="left" if col in ("component", "level") else "right")
        styles = {2: "bold red", 1: "yellow", 0: ""}
        for r in df.itertuples(index=False):
            table.add_row(
                escape(str(r.component)), LEVEL_NAMES[int(r.level)], f"{r.hi:.3f}", f"{r.fhi:.3f}",
                _fmt(r.frul), _fmt(r.rul_low), _fmt(r.rul_high), "yes" if r.valid else "no",
                _fmt(r.drul), _fmt(r.d2rul), str(int(r.n)), f"{r.t:g}",
                style=styles[int(r.level)],
            )
        Console(width=160).print(table)

    @reproduce.command("embedded-rul")
    def reproduce_embedded_rul(
        out: Annotated[Path, typer.Option(
            "--out", help="Directory for report.md, tables and figures.")
        ] = Path("out/embedded-rul"),
        figures: bool = typer.Option(True, "--figures/--no-figures",
                                     help="Write one figure per unit."),
        seed: int = typer.Option(0, "--seed", help="Seed of the false-alarm study."),
        false_alarms: bool = typer.Option(True, "--false-alarms/--no-false-alarms",
                                          help="Run the HI false-alarm study (~5 s)."),
    ) -> None:
        """Trackers on the 21 Lu & Meeker crack-growth units: RUL accuracy, validity, report."""
        from rulkit.fleet.reproduce import EmbeddedRULConfig, run, write_report

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
