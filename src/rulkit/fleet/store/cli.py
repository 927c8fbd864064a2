"""``rulkit track`` and ``rulkit status`` (seed 004).

docs/systems/embedded-rul.md: the per-component tracker chain with its state in an SQLite database
(:mod:`rulkit.fleet.store.sqlite`). Heavy imports stay inside the commands.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Any

import typer


def _fmt(v: float, spec: str = ".3g") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return format(v + 0.0, spec)  # + 0.0 turns -0.0 into 0.0


def _format_all(pattern: str, values: list) -> list[str]:
    """``[pattern % v for v in values]`` in one %-operation (``"%.3f"``, ``"%.3g"``,
    ``"%g"``, ``"%d"``: the same text as :func:`format` with ``.3f`` ...), no Python call per
    value."""
    if not values:
        return []
    return ((pattern + "\n") * len(values) % tuple(values)).split("\n")[:-1]


def _aligned_table(columns: dict[str, list[str]], left: tuple[str, ...]) -> Iterator[str]:
    """:func:`rulkit.tables.text_table` (same text), in chunks of rows: each column justified
    to its width, two blanks between columns, trailing blanks stripped. Printable ASCII
    cells are laid out by :func:`_ascii_rows` in a few array operations; others by one
    %-format per row. Cells must already be terminal-safe."""
    names = list(columns)
    cells = list(columns.values())
    texts = _ascii_texts(names, cells)
    if texts is not None:
        yield from _ascii_rows(*texts, [n in left for n in names])
        return
    widths = [max(len(n), max(map(len, c), default=0)) for n, c in zip(names, cells, strict=True)]
    row_fmt = "  ".join(f"%-{w}s" if n in left else f"%{w}s"
                        for n, w in zip(names, widths, strict=True))
    lines = [(row_fmt % tuple(names)).rstrip(), "  ".join("-" * w for w in widths)]
    lines += [(row_fmt % row).rstrip() for row in zip(*cells, strict=True)]
    yield "\n".join(lines) + "\n"


def _ascii_texts(names: list[str], cells: list[list[str]]) -> tuple[list, list] | None:
    """Each column's name and cells as ``(bytes, lengths)``
    (:func:`~rulkit.fleet.store.status_view.split_texts`) with no characters on the dashes'
    row, when every one is printable ASCII (else None)."""
    import numpy as np

    from rulkit.fleet.store.status_view import split_texts

    if not cells or not cells[0]:
        return None
    raws, lens = [], []
    for name, texts in zip(names, cells, strict=True):
        try:  # the name, then the cells joined by newlines, which no terminal-safe cell holds
            joined = "\n".join([name, *texts]).encode("ascii")
        except UnicodeEncodeError:
            return None
        raw, ln = split_texts(joined, ord("\n"))
        if not np.all((raw >= ord(" ")) & (raw <= ord("~"))):
            return None
        raws.append(raw)
        lens.append(np.concatenate([ln[:1], [0], ln[1:]]))
    return raws, lens


def _ascii_rows(raws: list, lens: list, left: list[bool]) -> Iterator[str]:
    """The lines of :func:`_aligned_table` from :func:`_ascii_texts`, by chunk of rows: every
    character copied to its place in a byte matrix of blanks (a row per line,
    :func:`~rulkit.fleet.store.status_view.place_texts`), each line then cut after its last
    non-blank character (the dashes' line kept whole: a last column may have width 0)."""
    import numpy as np

    from rulkit.fleet.store.status_view import CHUNK_ROWS, place_texts

    widths = [int(ln.max()) for ln in lens]
    size = sum(widths) + 2 * len(widths) - 1  # the columns, the blanks between, a newline
    starts = np.cumsum([0] + [w + 2 for w in widths[:-1]])
    ends = [np.concatenate([[0], np.cumsum(ln)]) for ln in lens]
    rows = len(lens[0])  # the names, the dashes, the cells
    for r0 in range(0, rows, CHUNK_ROWS):
        r1 = min(r0 + CHUNK_ROWS, rows)
        out = np.full((r1 - r0, size), ord(" "), dtype=np.uint8)
        out[:, -1] = ord("\n")
        for raw, ln, end, at, w, is_left in zip(raws, lens, ends, starts, widths, left,
                                                strict=True):
            if r0 <= 1 < r1:
                out[1 - r0, at:at + w] = ord("-")
            piece = ln[r0:r1]
            place_texts(out, raw[end[r0]:end[r1]], piece, at if is_left else at + w - piece)
        filled = out[:, :-1] != ord(" ")
        last = np.where(filled.any(axis=1), size - 2 - np.argmax(filled[:, ::-1], axis=1), -1)
        if r0 <= 1 < r1:
            last[1 - r0] = size - 2
        keep = np.arange(size)[None, :] <= last[:, None]
        keep[:, -1] = True
        yield out[keep].tobytes().decode("ascii")


def rul_texts(med: Any, low: Any, high: Any, failed: Any) -> list[str]:
    """``median [low, high]`` per component (``.3g``; ``-`` while not estimated, ``failed``
    once the alarm rule held), vectorised: one %-format for the rows that show numbers, a
    row with a missing bound (``-`` inside the brackets) written apart."""
    import numpy as np

    m, lo, hi = (np.asarray(v, dtype=np.float64).reshape(-1) + 0.0  # -0.0 printed as 0
                 for v in (med, low, high))
    is_failed = np.asarray(failed, dtype=bool).reshape(-1)
    out = np.where(is_failed, "failed", "-").astype(object)
    shown = np.flatnonzero(~is_failed & ~np.isnan(m))
    if shown.size:
        values = np.column_stack([m[shown], lo[shown], hi[shown]]).ravel().tolist()
        out[shown] = (("%.3g [%.3g, %.3g]\n" * shown.size) % tuple(values)).split("\n")[:-1]
    for i in shown[np.isnan(lo[shown]) | np.isnan(hi[shown])].tolist():
        out[i] = f"{_fmt(m[i])} [{_fmt(lo[i])}, {_fmt(hi[i])}]"
    texts: list[str] = out.tolist()
    return texts


def _format_distinct(pattern: str, values: Any) -> list[str]:
    """:func:`_format_all` of a float64 or int64 array, each distinct value (bit pattern:
    -0.0 apart from 0.0) formatted once: acquisition counts and last times repeat across a
    fleet fed in batches."""
    import numpy as np

    a = np.ascontiguousarray(values)
    distinct, where = np.unique(a.view(np.int64), return_inverse=True)
    texts = np.array(_format_all(pattern, distinct.view(a.dtype).tolist()), dtype=object)
    out: list[str] = texts[where.reshape(-1)].tolist()
    return out


def _duration(seconds: float) -> str:
    for unit, scale in (("d", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if seconds >= scale and seconds % scale == 0:
            return f"{seconds / scale:g} {unit}"
    return f"{seconds:g} s"


def status_footer(info: Any) -> list[str]:
    """The lines under the ``rulkit status`` table: what gave the RUL, the rules, the fitted
    model's warnings."""
    est = info.estimator
    unit = est.time_unit
    rules = est.rules
    stale = (f"stale: no acquisition for {_duration(rules.stale_after)}"
             if rules.stale_after is not None else "stale: not judged (no --stale-after)")
    lines = [f"RUL in {unit or 'the time unit of the data'}: {est.label}",
             f"alarm: {rules.alarm_text()}; warning: {rules.warning_text(unit)}; {stale}"]
    lines += [f"model warning: {w}" for w in est.warnings]
    return lines


def _minutes(times: list[str | None]) -> list[str]:
    """ISO 8601 date-times to the minute (``2024-05-01T12:00Z``), ``-`` where missing; each
    distinct value written once."""
    short = {d: (d[:16] + "Z") if d else "-" for d in set(times)}
    return list(map(short.__getitem__, times))


def _echo_table(db: str, info: Any, cols: dict[str, Any]) -> None:
    """The ``rulkit status`` table of the columns of
    :func:`rulkit.fleet.store.status_view.status_columns` (every id through
    :func:`safe_text`)."""
    import numpy as np

    from rulkit.fleet.tracking.tracker_chain import LEVEL_NAMES
    from rulkit.tables import safe_text

    n = len(cols["component"])
    shown = f", the first {n} shown" if n < info.n_all else ""
    ids = cols["component"]
    text = "".join(ids)
    unit = info.estimator.time_unit
    flags = np.array(["", "stale"], dtype=object)[np.asarray(cols["stale"], dtype=np.int64)]
    table = {
        "component": (ids if text.isprintable() and max(map(len, ids), default=0) <= 40
                      else [safe_text(c, 40) for c in ids]),  # safe_text changes nothing
        "level": [LEVEL_NAMES[v] for v in cols["level"].tolist()],
        f"RUL{f' ({unit})' if unit else ''}": rul_texts(cols["rul"], cols["rul_low"],
                                                        cols["rul_high"], cols["failed"]),
        "due": _minutes(cols["due"]),
        "HI": _format_all("%.3f", cols["hi"].tolist()),
        "n": _format_distinct("%d", np.asarray(cols["n"], dtype=np.int64)),
        "last t": _format_distinct("%g", np.asarray(cols["t"], dtype=np.float64)),
        "last seen": _minutes(cols["last_seen"]),
        "": flags.tolist(),
    }
    c = info.counts
    typer.echo(f"{safe_text(db)}: {info.n_all} components ({c['alarm']} alarm, "
               f"{c['warning']} warning, {c['ok']} ok; {c['stale']} stale){shown}")
    for chunk in _aligned_table(table, left=("component", "level", "")):
        typer.echo(chunk, nl=False)
    for line in status_footer(info):
        typer.echo(safe_text(line))


def _status_from_frame(db: str, limit: int, fmt: str, now: float, sort: str) -> None:
    """``rulkit status`` through :meth:`ComponentStore.status` (pandas), for a components
    table rulkit cannot have written: it names the bad row, or coerces as it always did;
    printed by the same writers as the fast path."""
    from rulkit.cli.errors import fail
    from rulkit.fleet.monitoring.estimators import estimator_in_force
    from rulkit.fleet.store.database_file import StoreError, is_postgres_url
    from rulkit.fleet.store.postgres import open_store
    from rulkit.fleet.store.sqlite import ComponentStore
    from rulkit.fleet.store.status_view import STORED_COLUMNS, status_columns

    try:
        with (open_store(db, create=False) if is_postgres_url(db)
              else ComponentStore(db, readonly=True)) as store:
            df = store.status()
            est = estimator_in_force(store.rules, store.config, store.degradation, store.trend)
    except (FileNotFoundError, ConnectionError) as err:
        fail(str(err))
    except StoreError as err:
        fail(str(err), code=err.exit_code)
    stored = {c: df[c].tolist() if c == "component" else df[c].to_numpy()
              for c in STORED_COLUMNS}
    info, cols = status_columns(stored, est, now, sort)
    _print_status(db, info, cols, limit, fmt)


def _print_status(db: str, info: Any, cols: dict[str, Any], limit: int, fmt: str) -> None:
    from rulkit.fleet.store.status_view import format_csv, format_json, limited

    cols = limited(cols, limit)
    if fmt == "csv":  # UTF-8 bytes, written as they are
        typer.echo(format_csv(cols), nl=False)
    elif fmt == "json":  # ASCII (non-ASCII and control characters escaped)
        for chunk in format_json(cols):
            typer.echo(chunk, nl=False)
        typer.echo(b"\n", nl=False)
    else:
        _echo_table(db, info, cols)


def _tracker_options(given: dict[str, float | str]):
    """The tracker settings from the options, each refused value naming its option (exit 2)."""
    from rulkit.cli.errors import bad_option
    from rulkit.fleet.tracking.tracker_chain import TrackerConfig

    for key, value in given.items():
        try:
            TrackerConfig.from_dict({**TrackerConfig().to_dict(), key: value})
        except ValueError as err:
            msg = str(err).split(": ", 1)[-1]
            bad_option("--" + key.replace("_", "-"), msg)
    return TrackerConfig.from_dict({**TrackerConfig().to_dict(), **given})


def _fit_baseline(baseline: Path, pfa: float, offset: str):
    import numpy as np

    from rulkit.cli.errors import fail
    from rulkit.fleet.store.acquisitions import IngestError, read_acquisitions
    from rulkit.fleet.tracking.health_index import HealthIndexModel
    from rulkit.tables import numeric_columns

    try:
        base: Any = read_acquisitions(baseline)  # a frame (columns=False)
    except IngestError as err:
        fail(f"baseline: {err}")
    if base.shape[1] < 1 or len(base) < 2:
        fail(f"baseline {baseline}: expected rows of healthy CIs, one column per CI")
    try:
        cols = numeric_columns(base, [str(c) for c in base.columns], error=ValueError,
                               source=f"baseline {baseline}")
        return HealthIndexModel.fit(
            np.column_stack(list(cols.values())), pfa=pfa, offset=offset,  # type: ignore[arg-type]
            names=list(cols))
    except ValueError as err:
        fail(str(err) if str(err).startswith("baseline") else f"baseline {baseline}: {err}")


def status(
    db: Annotated[str, typer.Option(
        "--db", help="Component database: a SQLite file or a postgresql:// URL.")],
    limit: int = typer.Option(0, "--limit", min=0, help="Show the first N (0 = all)."),
    fmt: str = typer.Option("table", "--format",
                            help="table (for people), csv or json (for scripts)."),
    sort: str = typer.Option("worst", "--sort",
                             help="worst (level, then RUL), rul or due (date)."),
    now: str | None = typer.Option(
        None, "--now", help="Judge staleness at this ISO 8601 date-time (default: now)."),
) -> None:
    """Components with their alert level, RUL (median [interval] and due date), last HI
    and acquisition, worst first (read-only).

    Exit codes: 0 done; 1 the database was refused; 2 a bad option; 65 the database is
    damaged; 74 I/O error; 75 busy (retry); 77 it cannot be read by this user.
    """
    import time

    from rulkit.cli.errors import bad_option, fail
    from rulkit.fleet.store.database_file import StoreError, is_postgres_url
    from rulkit.fleet.store.status_view import SORTS, read_status

    if fmt not in ("table", "csv", "json"):
        bad_option("--format", f"expected table, csv or json, got {fmt!r}")
    if sort not in SORTS:
        bad_option("--sort", f"expected one of {', '.join(SORTS)}, got {sort!r}")
    at = time.time() if now is None else _iso_seconds(now)
    if is_postgres_url(db):  # through the store (the fast path reads SQLite files)
        _status_from_frame(db, limit, fmt, at, sort)
        return
    try:  # sqlite3 only; None: a row rulkit cannot have written
        got = read_status(db, now=at, sort=sort)
    except FileNotFoundError as err:
        fail(str(err))
    except StoreError as err:
        fail(str(err), code=err.exit_code)
    if got is None:
        _status_from_frame(db, limit, fmt, at, sort)
        return
    _print_status(db, got[0], got[1], limit, fmt)


def track(
    acquisitions: Annotated[Path, typer.Argument(
        help="CSV or Parquet file (or a directory of Parquet partitions) with columns "
             "component, time and hi (or the CI columns of the database's HI model); "
             "see docs/file-formats.md.")],
    db: Annotated[str, typer.Option(
        "--db", help="Component database: a SQLite file or a postgresql:// URL (created "
                     "with the first accepted batch).")],
    baseline: Annotated[Path | None, typer.Option(
        "--baseline", help="CSV of healthy CIs (one column per CI) to fit and store "
                           "the CI -> HI model (new database or one without a model).")
    ] = None,
    pfa: float = typer.Option(1e-6, "--pfa", min=0.0, max=1.0,
                              help="False-alarm probability of HI = 0.5."),
    offset: str = typer.Option("cdf05", "--offset", help="CI offset: cdf05 or none."),
    dt: float | None = typer.Option(None, "--dt", help="Nominal acquisition interval."),
    lambda_hi: float | None = typer.Option(None, "--lambda-hi", help="Tracking index, HI."),
    lambda_rul: float | None = typer.Option(None, "--lambda-rul",
                                            help="Tracking index, RUL."),
    design_life: float | None = typer.Option(None, "--design-life",
                                             help="dHI floor = 1/design life."),
    warn_rul: float | None = typer.Option(
        None, "--warn-rul", help="The seed chain's own warning RUL (its reproduction; the "
                                 "store warns on --lead-time)."),
    hi_sigma: float | None = typer.Option(None, "--hi-sigma",
                                          help="HI std for the confidence limits."),
    valid_d2rul: float | None = typer.Option(None, "--valid-d2rul",
                                             help="Validity limit of |d2RUL/dt2|."),
    paris_exponent: float | None = typer.Option(None, "--paris-exponent",
                                                help="Paris exponent m of the RUL."),
    initiation: str | None = typer.Option(None, "--initiation",
                                          help="Track start: floor or two-point."),
    estimator: str | None = typer.Option(
        None, "--estimator", help="RUL estimator: auto (a fitted model, else the per-unit "
                                  "trend; default), trend, or tracker (the seed-004 chain)."),
    time_unit: str | None = typer.Option(
        None, "--time-unit", help="Unit of the time column (h, d, s, kcycles...), printed "
                                  "with every RUL; a duration gives due dates."),
    lead_time: float | None = typer.Option(
        None, "--lead-time", help="Warning when the RUL's low quantile is below this "
                                  "(time unit of the data; default 100)."),
    alarm_hi: float | None = typer.Option(
        None, "--alarm-hi", help="Alarm level of the measured HI (default 1)."),
    alarm_persistence: str | None = typer.Option(
        None, "--alarm-persistence", help="Alarm when the measured HI reached --alarm-hi "
                                          "in K of the last N acquisitions: K/N "
                                          "(default 1/1)."),
    stale_after: str | None = typer.Option(
        None, "--stale-after", help="Stale after this long without an acquisition: 36h, "
                                    "2d, 90min or seconds (default: not judged)."),
    interval: float | None = typer.Option(
        None, "--interval", help="Probability of the RUL interval (default 0.9)."),
    wait: float = typer.Option(60.0, "--wait", min=0.0,
                               help="Seconds to wait for another writer before giving up "
                                    "(exit code 75, retry)."),
    scheduler: str | None = typer.Option(
        None, "--scheduler", help="Dask scheduler address (tcp://host:port): track a "
                                  "directory of Parquet partitions on its workers."),
    buckets: int = typer.Option(0, "--buckets", min=0,
                                help="Tasks to split the components into with "
                                     "--scheduler (0: 4 per worker)."),
) -> None:
    """Ingest acquisitions (one transaction) and print new warnings and alarms.

    The estimator and alert options are stored with the database; given for an existing
    one they replace the stored ones (every component's RUL and level recomputed).
    Exit codes: 0 done; 1 the file or database was refused (nothing written); 2 a bad
    option; 65 the database is damaged; 74 disk full or I/O error; 75 the database stayed
    busy (retry); 77 the database or its directory cannot be written.
    """
    from rulkit.cli.errors import bad_option

    given = {k: v for k, v in {
        "dt": dt, "lambda_hi": lambda_hi, "lambda_rul": lambda_rul,
        "design_life": design_life, "warn_rul": warn_rul, "hi_sigma": hi_sigma,
        "valid_d2rul": valid_d2rul, "paris_exponent": paris_exponent,
        "initiation": initiation}.items()
        if v is not None}
    if offset not in ("cdf05", "none"):
        bad_option("--offset", f"expected cdf05 or none, got {offset!r}")
    rule_opts = {k: v for k, v in {
        "estimator": estimator, "time_unit": time_unit, "lead_time": lead_time,
        "alarm_hi": alarm_hi, "alarm_persistence": alarm_persistence,
        "stale_after": stale_after, "interval": interval}.items() if v is not None}
    _rules_options(None, rule_opts)  # refuse bad values before reading anything
    hi_model = _fit_baseline(baseline, pfa, offset) if baseline is not None else None
    if scheduler is not None and not acquisitions.is_dir():
        bad_option("--scheduler", "needs a directory of Parquet partitions")
    df, cfg, rules, new = _track_inputs(acquisitions, db, given, rule_opts, scheduler)
    res, created = _track_run(acquisitions, db, df, cfg, hi_model, rules, new, wait, scheduler,
                              buckets)
    _echo_track(res, created, db, rules)


def _track_inputs(acquisitions: Path, db: str, given: dict[str, float | str],
                  rule_opts: dict[str, Any], scheduler: str | None) -> tuple[Any, Any, Any, bool]:
    """``track``'s file (None for a directory of partitions), tracker settings and rules, and
    whether the database is new; a bad file or settings that differ from the stored ones
    end the command."""
    from rulkit.cli.errors import bad_option, fail
    from rulkit.fleet.store.acquisitions import IngestError, read_acquisitions
    from rulkit.fleet.store.database_file import StoreError, is_postgres_url
    from rulkit.fleet.tracking.tracker_chain import TrackerConfig

    new_cfg = _tracker_options(given)
    if scheduler is not None and is_postgres_url(db):
        bad_option("--scheduler", "tracks into a SQLite database (give a file as --db)")
    try:
        df = None if acquisitions.is_dir() else read_acquisitions(acquisitions, columns=True)
        settings, stored_rules = _stored_settings(db)
        rules = _rules_options(stored_rules, rule_opts)
    except IngestError as err:
        fail(f"{err} (nothing was written to {db})")
    except StoreError as err:
        fail(str(err), code=err.exit_code)
    except ConnectionError as err:
        fail(str(err))
    if settings is None:
        return df, new_cfg, rules, True
    stored = settings[0].to_dict()
    cfg = TrackerConfig.from_dict({**stored, **given})
    if cfg != settings[0]:
        diff = {k: (stored[k], v) for k, v in given.items() if stored[k] != v}
        fail(f"{db} was created with other tracker settings (stored, given): {diff}; "
             "the state is only meaningful with its own settings")
    return df, cfg, rules, False


def _track_run(acquisitions: Path, db: str, df: Any, cfg: Any, hi_model: Any, rules: Any,
               new: bool, wait: float, scheduler: str | None, buckets: int) -> tuple[Any, bool]:
    """``track``'s ingestion into ``db`` (PostgreSQL, a directory of partitions, or one
    file): the result and whether the database was created; a refusal ends the command."""
    from rulkit.cli.errors import fail
    from rulkit.fleet.store.acquisitions import IngestError
    from rulkit.fleet.store.database_file import StoreBusyError, StoreError, is_postgres_url
    from rulkit.fleet.store.ingest import ingest_into

    nothing = f"nothing was written to {db}"
    try:
        if is_postgres_url(db):
            return _track_postgres(db, acquisitions, df, cfg, hi_model, rules, wait,
                                   new=new), new
        if df is None:  # a directory of partitions, serially or on Dask workers
            from rulkit.fleet.store.partitions import track_directory

            return track_directory(db, acquisitions, config=cfg, hi_model=hi_model,
                                   scheduler=scheduler, buckets=buckets, timeout=wait,
                                   rules=rules)
        return ingest_into(db, df, config=cfg, hi_model=hi_model, source=str(acquisitions),
                           timeout=wait, rules=rules)
    except IngestError as err:
        msg = str(err)  # file-level errors already start with the path
        where = "" if msg.startswith(str(acquisitions)) else f"{acquisitions}: "
        fail(f"{where}{msg} ({nothing})")
    except StoreBusyError as err:
        fail(f"{err}; retry the same command", code=err.exit_code)
    except StoreError as err:
        fail(f"{err} ({nothing})", code=err.exit_code)
    except ConnectionError as err:
        fail(f"{err} ({nothing})")


def _echo_track(res: Any, created: bool, db: str, rules: Any) -> None:
    """``track``'s summary line and its new warnings and alarms."""
    from rulkit.fleet.tracking.tracker_chain import LEVEL_NAMES
    from rulkit.tables import safe_text

    typer.echo(f"ingested {res.n_rows} acquisitions of {res.n_components} components "
               f"({res.n_new_components} new) into {safe_text(db)}"
               + (" (new database)" if created else "")
               + (f"; {res.n_duplicates} already stored, skipped" if res.n_duplicates
                  else ""))
    if not res.alerts:
        typer.echo("no new warnings or alarms")
        return
    words = {name: typer.style(f"{name.upper():7s}", fg="red" if name == "alarm"
                               else "yellow", bold=name == "alarm")
             for name in LEVEL_NAMES.values()}
    unit = f" {safe_text(rules.time_unit)}" if rules.time_unit else ""
    ruls = rul_texts([a.rul for a in res.alerts], [a.rul_low for a in res.alerts],
                     [a.rul_high for a in res.alerts], [False] * len(res.alerts))
    reasons: dict[str, str] = {}
    typer.echo("\n".join(
        f"{words[a.name]} {safe_text(a.component)}  t={a.t:g}  HI={a.hi:.3f}  "
        + ("failed" if a.name == "alarm" else f"RUL={rul}{unit}") + ": "
        + (reasons.get(a.reason) or reasons.setdefault(a.reason, safe_text(a.reason)))
        for a, rul in zip(res.alerts, ruls, strict=True)))


def register(app: typer.Typer, reproduce: typer.Typer) -> None:
    """Add ``track`` and ``status``."""
    app.command("track")(track)
    app.command("status")(status)


def _stored_settings(db: str) -> tuple[Any, Any]:
    """``((tracker config, HI model), rules)`` stored in the database ``db`` (a SQLite path or
    a ``postgresql://`` URL), ``(None, None)`` when there is none yet."""
    from rulkit.fleet.store.database_file import is_postgres_url
    from rulkit.fleet.store.ingest import read_rules, read_settings

    if not is_postgres_url(db):
        return read_settings(db), read_rules(db)
    from rulkit.fleet.store.postgres import open_store

    try:
        with open_store(db, create=False) as store:
            return (store.config, store.hi_model), store.rules
    except FileNotFoundError:
        return None, None


def _track_postgres(db: str, acquisitions: Path, df: Any, cfg: Any, hi_model: Any,
                    rules: Any, wait: float, new: bool) -> Any:
    """``rulkit track`` into PostgreSQL: the file (or the partitions read serially) through
    the store's one ingestion path; a ``new`` database's schema is created only once its
    first batch has been validated (a refused batch creates nothing)."""
    from rulkit.fleet.store.acquisitions import validate_acquisitions
    from rulkit.fleet.store.partitions import read_directory
    from rulkit.fleet.store.postgres import open_store

    if df is None:
        df = read_directory(acquisitions)
    if new:
        validate_acquisitions(df, cfg, hi_model)
    with open_store(db, config=cfg, hi_model=hi_model, rules=rules, timeout=wait) as store:
        return store.ingest(df, source=str(acquisitions))


def _iso_seconds(text: str) -> float:
    """An ISO 8601 date-time (UTC when it names no zone) as seconds since 1970 (exit 2 when
    it is not one)."""
    from datetime import UTC, datetime

    from rulkit.cli.errors import bad_option

    try:
        d = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        bad_option("--now", f"expected an ISO 8601 date-time such as 2024-05-01T12:00, got "
                            f"{text!r}")
    return (d if d.tzinfo else d.replace(tzinfo=UTC)).timestamp()


def _rules_options(stored: Any, given: dict[str, Any]) -> Any:
    """The monitoring rules: ``stored`` (or the defaults) with the given options, each refused
    value naming its option (exit 2)."""
    from rulkit.cli.errors import bad_option
    from rulkit.fleet.monitoring.rules import MonitoringRules, parse_duration

    base = (stored or MonitoringRules()).to_dict()
    for key, value in given.items():
        opt = "--" + key.replace("_", "-")
        try:
            if key == "alarm_persistence":
                k, _, n = str(value).replace("of", "/").partition("/")
                base["alarm_hits"], base["alarm_window"] = int(k), int(n)
            elif key == "stale_after":
                base[key] = parse_duration(str(value))
            else:
                base[key] = value
            MonitoringRules.from_dict(base)
        except ValueError as err:
            bad_option(opt, str(err).split(": ", 1)[-1])
    return MonitoringRules.from_dict(base)
