"""Commands of the reaction-wheel lubrication system (docs/systems/reaction-wheel.md).

- ``rulkit reproduce rw-lubrication [--quick] [--runs N] [--seed S] [--out DIR] [--workers N]
  [--scheduler ADDRESS]``: steps 1-3, Tables 5-7 beside the paper's, figures, report.md.
- ``rulkit rw estimate-temperature FILE [--out F] [--method M] [--particles N] [--seed S]``:
  lubricant temperature with an interval per sample from a wheel telemetry file.
- :func:`run_quick` is what ``rulkit demo`` (``make demo``) runs: the ``--quick`` reproduction.

Heavy imports stay inside the command functions (``rulkit --help`` stays fast).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Any

import typer

#: The step-1 estimators (the default first); the same as
#: ``rulkit.systems.reaction_wheel.temperature.estimator.METHODS`` (kept here so that
#: ``rulkit --help`` does not import numba).
METHODS = ("imm", "ekf", "rbpf", "pf", "adaptive", "apf", "apf_eq28", "apf_tempered")


def _print_tables(rep: Any, console: Any) -> None:
    """Tables 5-7 as compact rich tables, "ours / paper" per cell."""
    import numpy as np
    from rich.table import Table

    def pair(row: Any, a: str, b: str) -> str:
        x, y = row.get(a, np.nan), row.get(b, np.nan)
        fx = "-" if x is None or (isinstance(x, float) and np.isnan(x)) else f"{x:.2f}"
        fy = "-" if y is None or (isinstance(y, float) and np.isnan(y)) else f"{y:.2f}"
        return f"{fx} / {fy}"

    if rep.table5 is not None and "rmspe_mean" in rep.table5:
        t5 = rep.table5
        tab = Table(title="Table 5: RMSPE of T (%), ours / paper")
        for c in ("method", "design", "noise", "N", "ours / paper"):
            tab.add_column(c)
        for _, r in t5.iterrows():
            tab.add_row(str(r.get("method")), str(r.get("design")), str(r.get("noise")),
                        str(r.get("N")), pair(r, "rmspe_mean", "paper"))
        console.print(tab)
    t6 = rep.table6.table
    tab = Table(title=f"Table 6: RMSPE (%) ours / paper ({rep.table6.n_runs} runs, seed "
                      f"{rep.table6.seed})")
    for c in ("method", "S1 b", "S1 beta0", "S2 b", "S2 beta0"):
        tab.add_column(c)
    for _, r in t6.iterrows():
        tab.add_row(str(r["method"]), pair(r, "S1 b ours", "S1 b paper"),
                    pair(r, "S1 beta ours", "S1 beta paper"), pair(r, "S2 b ours", "S2 b paper"),
                    pair(r, "S2 beta ours", "S2 beta paper"))
    console.print(tab)
    t7 = rep.table7
    tab = Table(title="Table 7: RUL error (%) ours / paper, min / max / mean over runs")
    for c in ("method", "S1 LB", "S1 UB", "S1 mean", "S2 LB", "S2 UB", "S2 mean"):
        tab.add_column(c)
    for _, r in t7.iterrows():
        tab.add_row(str(r["method"]), *(pair(r, f"S{s} {k} ours", f"S{s} {k} paper")
                                        for s in (1, 2) for k in ("LB", "UB", "mean")))
    console.print(tab)


def run_reproduction(out: Path, *, quick: bool, runs: int | None, seed: int, workers: int,
                     scheduler: str | None, show_progress: bool = True,
                     real_step1_runs: int | None = None) -> Any:
    """Run the reproduction with a rich progress bar over its stages; returns the result."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from rulkit.systems.reaction_wheel.degradation.study import SOURCES
    from rulkit.systems.reaction_wheel.report import write_report
    from rulkit.systems.reaction_wheel.reproduce import ReproductionConfig, run, with_overrides

    if runs is not None and runs < 1:
        raise typer.BadParameter(f"--runs: expected >= 1, got {runs}")
    if workers < 1:
        raise typer.BadParameter(f"--workers: expected >= 1, got {workers}")
    if scheduler is not None and workers != 1:
        raise typer.BadParameter("give either --workers or --scheduler, not both")
    cfg = (ReproductionConfig.quick_config(seed=seed, n_runs=runs) if quick
           else with_overrides(ReproductionConfig(seed=seed), n_runs=runs))
    cfg = with_overrides(cfg, workers=workers, scheduler=scheduler,
                         real_step1_runs=real_step1_runs)
    console = Console()
    t0 = time.perf_counter()
    # one log line per stage: step 1, one per T^ source (APF, PF, RBPF), steps 2 and 3, ...,
    # and the files (tables, figures, report.md) at the end
    n_src = len(SOURCES)
    stages = (4 + n_src + n_src * (cfg.validation_hours > 0) + (cfg.sensitivity_runs > 0)
              + cfg.table6_alt + cfg.seed_filters + (cfg.eq28_seconds > 0)
              + (cfg.real_step1_runs > 0))
    if not show_progress:
        rep = run(cfg, log=lambda m: None)
        write_report(rep, out)
        return rep
    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/"
                  "{task.total}"), TimeElapsedColumn(), console=console) as bar:
        task = bar.add_task("rw-lubrication", total=stages)

        def log(msg: str) -> None:
            bar.update(task, advance=1, description=msg[:70])
            console.log(f"{time.perf_counter() - t0:6.1f} s  {msg}")

        rep = run(cfg, log=log)
        log(f"writing tables, figures and report.md into {out}")
        write_report(rep, out)
        bar.update(task, completed=stages, description="done")
    return rep


def check_scheduler(address: str, timeout: float = 5.0) -> None:
    """Fail fast, before any work, when the Dask scheduler at ``address`` (``tcp://host:port``)
    is not listening (before: a traceback after distributed's 30 s connect timeout)."""
    import socket
    from urllib.parse import urlsplit

    from rulkit.cli.errors import bad_option, fail

    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    try:
        host, port = parts.hostname, parts.port
    except ValueError:
        host, port = None, None
    if parts.scheme not in ("tcp", "tls") or not host or port is None:
        bad_option("--scheduler", f"expected tcp://host:port, got {address!r}")
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as err:
        fail(f"--scheduler {address}: cannot reach the Dask scheduler "
             f"({err.strerror or err}); start it or check the address; nothing was run")


def run_quick(out: Path, seed: int) -> None:
    """``rulkit demo``: the ``--quick`` reproduction; prints the tables, writes the figures."""
    from rich.console import Console
    from rich.markup import escape

    t0 = time.perf_counter()
    rep = run_reproduction(Path(out), quick=True, runs=None, seed=seed, workers=1,
                           scheduler=None)
    console = Console()
    _print_tables(rep, console)
    console.print(f"wrote {len(rep.files)} files to {escape(str(out))} (report: "
                  f"{escape(str(Path(out) / 'report.md'))}) in {time.perf_counter() - t0:.1f} s",
                  highlight=False)


def register(app: typer.Typer, reproduce: typer.Typer) -> None:
    """Add ``reproduce rw-lubrication`` and the ``rw`` group to the CLI."""
    _register_reproduce(reproduce)
    rw = typer.Typer(help="Reaction-wheel lubrication tools.", no_args_is_help=True)
    app.add_typer(rw, name="rw")
    _register_step1(rw)
    _register_pipeline(rw)
    _register_steps_2_3(rw)


def _register_reproduce(reproduce: typer.Typer) -> None:
    """``rulkit reproduce rw-lubrication``."""

    @reproduce.command("rw-lubrication")
    def reproduce_rw(
        quick: Annotated[bool, typer.Option("--quick", help="Reduced run (< 3 min).")] = False,
        runs: Annotated[int | None, typer.Option(help="Runs per table (default 20; "
                                                      "quick 5).")] = None,
        seed: Annotated[int, typer.Option(min=0, help="Seed of the runs.")] = 0,
        out: Annotated[Path, typer.Option(help="Output directory.")] = Path(
            "out/rw-lubrication"),
        workers: Annotated[int, typer.Option(help="Local worker processes.")] = 1,
        scheduler: Annotated[str | None, typer.Option(
            help="Address of an existing Dask scheduler (tcp://host:port).")] = None,
        real_step1_runs: Annotated[int | None, typer.Option(
            min=0, help="Runs of the real step 1 (IMM) over the whole horizon against the T^ "
                        "shortcut (default 2; quick 0).")] = None,
    ) -> None:
        """Reproduce seed 001 Tables 5-7 (reaction-wheel lubrication prognostics)."""
        from rich.console import Console
        from rich.markup import escape

        from rulkit.cli.errors import fail

        t0 = time.perf_counter()
        if scheduler is not None and workers == 1:
            check_scheduler(scheduler)
        try:
            rep = run_reproduction(out, quick=quick, runs=runs, seed=seed, workers=workers,
                                   scheduler=scheduler, real_step1_runs=real_step1_runs)
        except (OSError, TimeoutError) as err:
            if scheduler is None:
                raise
            fail(f"--scheduler {scheduler}: cannot reach the Dask scheduler ({err}); start it "
                 "or check the address (tcp://host:port)")
        console = Console()
        _print_tables(rep, console)
        console.print(f"wrote {len(rep.files)} files to {escape(str(out))} in "
                      f"{time.perf_counter() - t0:.1f} s; see "
                      f"{escape(str(out / 'report.md'))}", highlight=False)


def _register_step1(rw: typer.Typer) -> None:
    """``rw estimate-temperature`` and ``rw wheel-template``."""

    @rw.command("estimate-temperature")
    def estimate_temperature_cmd(
        file: Annotated[Path, typer.Argument(help="Telemetry CSV or Parquet: time_s, v_comm_V, "
                                                  "speed_rad_s, current_A.")],
        out: Annotated[Path | None, typer.Option(
            help="Output CSV or Parquet (default FILE stem + _temperature.csv).")] = None,
        wheel: Annotated[Path | None, typer.Option(
            help="Wheel file (TOML; default the seed's wheel): `rulkit rw wheel-template`.")
        ] = None,
        method: Annotated[str | None, typer.Option(
            help=f"One of {', '.join(METHODS)} (default the wheel file's, imm).")] = None,
        particles: Annotated[int | None, typer.Option(help="Particles (PF methods).")] = None,
        seed: Annotated[int, typer.Option(min=0, help="Seed of the particle filter.")] = 0,
        noise: Annotated[str | None, typer.Option(
            help="Noise level low or high of seed Table 5 (default the wheel file's).")] = None,
        level: Annotated[float, typer.Option(help="Interval level.")] = 0.95,
        chunk_rows: Annotated[int, typer.Option(
            help="Rows read, filtered and written at a time (bounds the memory).")] = 100_000,
    ) -> None:
        """Estimate the lubricant temperature (with an interval per sample) from telemetry."""
        from rulkit.cli.errors import EXIT_USAGE, fail
        from rulkit.systems.reaction_wheel.pipeline import stream_temperature

        if method is not None and method not in METHODS:
            fail(f"--method: expected one of {', '.join(METHODS)}, got {method!r}",
                 code=EXIT_USAGE)
        if particles is not None and particles < 2:
            fail(f"--particles: need at least 2, got {particles}", code=EXIT_USAGE)
        if noise not in (None, "low", "high"):
            fail(f"--noise: expected 'low' or 'high', got {noise!r}", code=EXIT_USAGE)
        if not 0 < level < 1:
            fail(f"--level: expected a value in (0, 1), got {level}", code=EXIT_USAGE)
        if chunk_rows < 2:
            fail(f"--chunk-rows: need at least 2, got {chunk_rows}", code=EXIT_USAGE)
        dest = out or file.with_name(file.stem + "_temperature.csv")
        _check_output_file(dest, file, (".csv", ".parquet", ".pq"))
        w = _wheel(wheel)
        try:
            summary = stream_temperature(file, dest, wheel=w, method=method, particles=particles,
                                         seed=seed, noise=noise, level=level,
                                         chunk_rows=chunk_rows)
        except ValueError as err:  # the telemetry, or the filter on it: named in the message
            fail(str(err))
        except OSError as err:
            fail(f"cannot write {dest}: {err}")
        for line in summary.notes:
            typer.echo(line, err=True)
        typer.echo(f"{summary.rows} samples, T_lub {summary.last['T_mean']:.2f} C at t = "
                   f"{summary.last['time_s']:.10g} s ({level:.0%} interval "
                   f"{summary.last['T_lo']:.2f} .. {summary.last['T_hi']:.2f} C)")
        typer.echo(f"wrote {dest}")

    @rw.command("wheel-template")
    def wheel_template_cmd(
        out: Annotated[Path | None, typer.Option(
            help="Write the template here (default: print it).")] = None,
    ) -> None:
        """Print (or write) a wheel file with every key at the seed wheel's value, commented
        with its unit, range and meaning."""
        from rulkit.systems.reaction_wheel.wheel_file import wheel_file_template

        text = wheel_file_template()
        if out is None:
            typer.echo(text, nl=False)
            return
        out.write_text(text)
        typer.echo(f"wrote {out}")


def _register_pipeline(rw: typer.Typer) -> None:
    """``rw pipeline``: steps 1-3 over long records."""

    @rw.command("pipeline")
    def pipeline_cmd(
        records: Annotated[list[Path], typer.Argument(
            help="Telemetry file, directory of telemetry files, or wheel directory "
                 "(telemetry/, losses.csv, wheel.toml, future.csv); several: one per wheel.")],
        out: Annotated[Path, typer.Option(help="Output directory.")] = Path("out/rw-pipeline"),
        losses: Annotated[Path | None, typer.Option(
            help="Loss measurements or injection log (CSV/Parquet; one record only).")] = None,
        wheel: Annotated[Path | None, typer.Option(help="Wheel file (one record only).")] = None,
        future: Annotated[Path | None, typer.Option(
            help="Future temperature profile: time_s (s from now), T_C.")] = None,
        threshold: Annotated[float | None, typer.Option(
            help="Loss threshold of the RUL (mL, cumulative since the record's start).")
        ] = None,
        repeat_days: Annotated[float, typer.Option(
            help="Without --future: repeat the last days of the estimate.")] = 7.0,
        method: Annotated[str | None, typer.Option(help="Step-1 method: imm or ekf.")] = None,
        seed: Annotated[int, typer.Option(min=0, help="Seed of the step-2 trackers.")] = 0,
        level: Annotated[float, typer.Option(help="Level of the step-2/3 intervals.")] = 0.9,
        chunk_rows: Annotated[int, typer.Option(help="Rows read at a time.")] = 1_000_000,
        samples: Annotated[bool, typer.Option(
            "--samples", help="Also write the estimate of every sample (Parquet).")] = False,
        restart: Annotated[bool, typer.Option(
            "--restart", help="Ignore a checkpoint in --out and start over.")] = False,
        workers: Annotated[int, typer.Option(help="Wheels run in parallel processes.")] = 1,
        scheduler: Annotated[str | None, typer.Option(
            help="Address of a Dask scheduler (tcp://host:port) to run the wheels on.")] = None,
    ) -> None:
        """Steps 1-3 over long records (streaming, resumable): temperature, lubricant-loss
        parameters, RUL; a report per wheel."""
        from rulkit.cli.errors import EXIT_USAGE, fail
        from rulkit.systems.reaction_wheel.pipeline import (
            PipelineOptions,
            find_record,
        )

        _check_record_options(records, losses, wheel, future, threshold, method, level,
                              chunk_rows, workers, scheduler)
        opts = PipelineOptions(threshold_mL=threshold, repeat_days=repeat_days, seed=seed,
                               level=level, chunk_rows=chunk_rows, samples=samples,
                               restart=restart, method=method)
        try:
            recs = [find_record(r, losses=losses, wheel=wheel, future=future) for r in records]
        except ValueError as err:
            fail(str(err), code=EXIT_USAGE if "no telemetry files" not in str(err) else 1)
        if len(recs) == 1:
            _run_one(recs[0], out, opts)
        else:
            _run_many(recs, out, opts, workers, scheduler)



def _register_steps_2_3(rw: typer.Typer) -> None:
    """``rw degradation`` and ``rw rul``: steps 2 and 3 on a user's files."""

    @rw.command("degradation")
    def degradation_cmd(
        losses: Annotated[Path, typer.Option(
            help="Loss measurements (loss_mL or cumulative_mL) or injection log "
                 "(injected_mL), with time_s.")],
        telemetry: Annotated[Path | None, typer.Option(
            help="Telemetry file or directory (step 1 runs on it).")] = None,
        temperature: Annotated[Path | None, typer.Option(
            help="Or a step-1 estimate file (rw estimate-temperature's output).")] = None,
        out: Annotated[Path, typer.Option(help="Output directory.")] = Path("out/rw-degradation"),
        wheel: Annotated[Path | None, typer.Option(help="Wheel file.")] = None,
        seed: Annotated[int, typer.Option(min=0, help="Seed of the trackers.")] = 0,
        level: Annotated[float, typer.Option(help="Interval level.")] = 0.9,
    ) -> None:
        """Step 2: track the lubricant-loss parameters b and beta0 (one-step, two-step and
        Rao-Blackwellised PFs, with intervals) from loss measurements and the temperature."""
        from rulkit.cli.errors import EXIT_USAGE, fail
        from rulkit.systems.reaction_wheel.pipeline import (
            PipelineOptions,
            WheelRecord,
            find_record,
        )

        if (telemetry is None) == (temperature is None):
            fail("give exactly one of --telemetry (run step 1) and --temperature (its output)",
                 code=EXIT_USAGE)
        _check_record_options([], losses, wheel, None, None, None, level, 10**6, 1, None)
        try:
            rec = (find_record(telemetry, losses=losses, wheel=wheel) if telemetry is not None
                   else WheelRecord(Path(str(temperature)).stem, (), losses, wheel, None,
                                    temperature))
        except ValueError as err:
            fail(str(err))
        _run_one(rec, out, PipelineOptions(seed=seed, level=level))

    @rw.command("rul")
    def rul_cmd(
        step2: Annotated[Path, typer.Argument(
            help="Output directory of rw degradation or rw pipeline.")],
        threshold: Annotated[float, typer.Option(
            help="Loss threshold (mL, cumulative since the record's start).")],
        future: Annotated[Path | None, typer.Option(
            help="Future temperature profile: time_s (s from now), T_C.")] = None,
        repeat_days: Annotated[float, typer.Option(
            help="Without --future: repeat the last days of the estimate.")] = 7.0,
        wheel: Annotated[Path | None, typer.Option(help="Wheel file ([rul] settings).")] = None,
        out: Annotated[Path | None, typer.Option(help="Output directory (default STEP2).")] = None,
    ) -> None:
        """Step 3: the RUL distribution from the step-2 posterior along a future temperature
        profile, to a loss threshold."""
        _run_rul(step2, threshold, future, repeat_days, wheel, out or step2)


def _check_record_options(records: list[Path], losses: Path | None, wheel: Path | None,
                          future: Path | None, threshold: float | None, method: str | None,
                          level: float, chunk_rows: int, workers: int,
                          scheduler: str | None) -> None:
    """Refuse (exit 2) option values and combinations no run can use."""
    from rulkit.cli.errors import EXIT_USAGE, fail

    if len(records) > 1 and any(x is not None for x in (losses, wheel, future)):
        fail("--losses, --wheel and --future go with one record; for several wheels put them in "
             "each wheel directory (losses.csv, wheel.toml, future.csv)", code=EXIT_USAGE)
    if threshold is not None and not threshold > 0:
        fail(f"--threshold: expected a positive loss (mL), got {threshold}", code=EXIT_USAGE)
    if method is not None and method not in ("imm", "ekf"):
        fail(f"--method: the pipeline runs 'imm' or 'ekf', got {method!r}", code=EXIT_USAGE)
    if not 0 < level < 1:
        fail(f"--level: expected a value in (0, 1), got {level}", code=EXIT_USAGE)
    if chunk_rows <= 1000:
        fail(f"--chunk-rows: expected more than 1000, got {chunk_rows}", code=EXIT_USAGE)
    if workers < 1 or (scheduler is not None and workers != 1):
        fail("--workers: expected >= 1, and not together with --scheduler", code=EXIT_USAGE)
    if scheduler is not None:
        check_scheduler(scheduler)


def _run_one(rec: Any, out: Path, opts: Any) -> None:
    """One record with a progress bar; exit 1 naming the input on refusal."""
    from rich.console import Console
    from rich.markup import escape
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from rulkit.cli.errors import fail
    from rulkit.machine_file import MachineFileError
    from rulkit.systems.reaction_wheel.pipeline import run_pipeline

    total = _total_rows(rec.telemetry)
    console = Console(stderr=True)
    try:
        with Progress(TextColumn("{task.description}"), BarColumn(),
                      TextColumn("{task.percentage:>3.0f}%"), TimeElapsedColumn(),
                      console=console, transient=True) as bar:
            task = bar.add_task(rec.name, total=total or None)
            res = run_pipeline(rec, out, opts, progress=lambda n, msg: bar.update(
                task, advance=n, description=escape(msg[:60])))
    except (ValueError, MachineFileError) as err:
        fail(str(err))
    except OSError as err:
        fail(f"cannot read or write: {err}")
    for n in res.notes:
        typer.echo(f"note: {n}", err=True)
    typer.echo(_result_line(res))
    typer.echo(f"wrote {out / 'report.md'}")


def _result_line(res: Any) -> str:
    line = f"{res.record.name}: {res.rows:,} rows"
    if len(res.hourly):
        line += f", T_lub {res.hourly['T_mean'].iloc[-1]:.2f} C (last hour)"
    if res.tracks is not None:
        r = res.tracks.table.iloc[-1]
        line += f", b {r['b_two_step']:.3g} C, beta0 {r['beta0_two_step']:.4g} mL/s (two-step)"
    d = res.ruls.get("two_step")
    if d is not None:
        lo, hi = d.interval(res.options.level)
        line += (f", RUL {d.median:.3g} d ({res.options.level:.0%} interval "
                 f"{lo:.3g} .. {hi:.3g} d)")
    return line


def _total_rows(files: tuple[Path, ...]) -> int:
    """Rows of the Parquet files (from their metadata; 0 when a CSV is among them)."""
    import pyarrow.parquet as pq

    total = 0
    for f in files:
        if not f.name.lower().endswith((".parquet", ".pq")):
            return 0
        try:
            total += pq.ParquetFile(f).metadata.num_rows
        except Exception:  # an unreadable file is refused with its message by the reader
            return 0
    return total


def _run_many(recs: list[Any], out: Path, opts: Any, workers: int,
              scheduler: str | None) -> None:
    """Several wheels as independent tasks; prints the fleet table."""
    from rulkit.cli.errors import fail
    from rulkit.machine_file import MachineFileError
    from rulkit.systems.reaction_wheel.pipeline import run_fleet

    try:
        table = run_fleet(recs, out, opts, workers=workers, scheduler=scheduler, progress=True)
    except (ValueError, MachineFileError) as err:
        fail(str(err))
    typer.echo(table.to_string(index=False))
    typer.echo(f"wrote {out / 'fleet.csv'} and a report per wheel in {out}/<wheel>/")


def _run_rul(step2: Path, threshold: float, future: Path | None, repeat_days: float,
             wheel: Path | None, out: Path) -> None:
    from rulkit.cli.errors import EXIT_USAGE, fail
    from rulkit.systems.reaction_wheel.degradation.track import load_step2
    from rulkit.systems.reaction_wheel.pipeline import future_cycle, ruls

    if not threshold > 0 or not repeat_days > 0:
        fail("--threshold and --repeat-days: expected positive values", code=EXIT_USAGE)
    w = _wheel(wheel)
    try:
        st = load_step2(step2)
        cycle = future_cycle(w, future, st.losses, st.sums, repeat_days)
        dists = ruls(st.posteriors, st.X_end, cycle, threshold, w.rul["horizon_days"])
    except ValueError as err:
        fail(str(err))
    out.mkdir(parents=True, exist_ok=True)
    lvl = float(st.meta.get("level", 0.9))
    for name, d in dists.items():
        d.to_json(out / f"rul_{name}.json")
        lo, hi = d.interval(lvl)
        typer.echo(f"{name}: RUL median {d.median:.4g} d, {lvl:.0%} interval {lo:.4g} .. "
                   f"{hi:.4g} d (to {threshold:g} mL from {st.X_end:.6g} mL along "
                   f"{cycle.description})")
    typer.echo(f"wrote {', '.join(f'rul_{n}.json' for n in dists)} to {out}")


def _wheel(path: Path | None) -> Any:
    """The wheel file ``path`` read and checked (exit 1 naming the key when it is refused)."""
    from rulkit.cli.errors import fail
    from rulkit.machine_file import MachineFileError
    from rulkit.systems.reaction_wheel.wheel_file import read_wheel_file

    try:
        return read_wheel_file(path)
    except MachineFileError as err:
        fail(str(err))


def _check_output_file(dest: Path, source: Path, suffixes: tuple[str, ...]) -> None:
    """Refuse (exit 2) an output that is the input file or has an unknown ending."""
    import os

    from rulkit.cli.errors import EXIT_USAGE, fail

    if dest.exists() and source.exists() and os.path.samefile(dest, source):
        fail(f"--out {dest} is the input file; refusing to overwrite it (choose another name)",
             code=EXIT_USAGE)
    if not dest.name.lower().endswith(suffixes):
        fail(f"--out: expected a {', '.join(suffixes)} file name, got {dest.name!r}",
             code=EXIT_USAGE)
