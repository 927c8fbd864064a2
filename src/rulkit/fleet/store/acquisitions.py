"""Acquisition batches for the component store: reading, validation and component ids.

An acquisition file has one row per (component, time) with the health index ``hi`` or the
condition-indicator columns of the database's HI model (docs/file-formats.md). Everything here
runs before the database is touched: :func:`validate_acquisitions` names the file, column and
row of the first problem, and :func:`rulkit.fleet.rows.check_component_ids` enforces the id
alphabet (1 to :data:`rulkit.fleet.rows.COMPONENT_ID_MAX_LEN` printable characters), so a
crafted id can neither forge terminal output nor bloat the database.
:mod:`rulkit.fleet.store.sqlite` applies a validated batch.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from rulkit.fleet.rows import (
    check_component_ids,
    numeric_values,
    previous_per_component,
    read_csv_rows,
)
from rulkit.fleet.time_axis import INSTALLED_COLUMN, TimeAxis, TimeAxisError
from rulkit.fleet.tracking.health_index import HealthIndexModel
from rulkit.fleet.tracking.tracker_chain import (
    LEVEL_NAMES,
    TrackerConfig,
)
from rulkit.tables import cell_repr as _fmt
from rulkit.tables import safe_text, table_format, time_seconds

PARQUET_BYTES_PER_ROW = 512
"""Decoded bytes per allowed row a Parquet input may declare in its metadata (a row is a
component id of at most 128 characters and a few numbers)."""


class IngestError(ValueError):
    """A batch of acquisitions was rejected; the database is unchanged."""


class ConflictError(IngestError):
    """The batch contradicts stored acquisitions (a stored time with another HI, or a time
    before the component's last acquisition that is not stored); nothing was written."""


class ComponentIdError(IngestError):
    """A component id outside the accepted alphabet or length
    (:func:`rulkit.fleet.rows.check_component_ids`)."""


@dataclass(frozen=True)
class Alert:
    """A new alert: a component reached a level above any it had before (latched; the
    rules of :mod:`rulkit.fleet.monitoring.rules`).

    A warning that comes and goes is reported once; the alarm after it once. ``previous`` is
    the highest level the component had reached before; ``rul``, ``rul_low``, ``rul_high``
    the RUL median and interval at that acquisition (NaN median: not estimated yet; 0 once
    failed); ``reason`` the rule that raised it; ``fhi`` the tracker chain's filtered HI.
    """

    component: str
    t: float
    level: int
    previous: int
    hi: float
    rul: float
    rul_low: float
    rul_high: float
    reason: str = ""
    fhi: float = float("nan")
    id: int | None = None
    """Its row in table ``alerts`` once recorded."""
    raised: float | None = None
    """When it was recorded (seconds since the epoch)."""

    @property
    def name(self) -> str:
        """The alert level's name ("warning" or "alarm")."""
        return LEVEL_NAMES[self.level]


@dataclass(frozen=True)
class IngestResult:
    """Outcome of a committed ingestion."""

    n_rows: int
    n_components: int
    n_new_components: int
    alerts: list[Alert] = field(default_factory=list)
    n_duplicates: int = 0
    """Rows already stored (same component, time and HI), skipped."""


# --------------------------------------------------------------------------- validation
def read_acquisitions(source: str | Path | bytes | memoryview, fmt: str | None = None, *,
                      max_rows: int | None = None, name: str | None = None) -> pd.DataFrame:
    """Read a CSV (``.csv``, ``.csv.gz``, ``.txt``) or Parquet (``.parquet``, ``.pq``)
    acquisition file, or the bytes of one (``fmt`` ``"csv"`` / ``"parquet"``; what the
    service receives), ``component`` kept as text. The one reader of ``rulkit track`` and of
    the service's uploads. CSV rows must have as many fields as the header
    (:func:`rulkit.fleet.rows.read_csv_rows`); a Parquet input's row count is read from its
    metadata and refused above ``max_rows`` before any column is decoded. File-level
    problems raise :class:`IngestError` naming ``name`` (default: the path)."""
    if isinstance(source, bytes | memoryview):
        where = name or f"{fmt} body"
    else:
        where = name or str(source)
        fmt = fmt or table_format(source, error=IngestError,
                                  csv_suffixes=(".csv", ".csv.gz", ".txt"))
        _check_file(Path(source))
    if fmt == "csv":
        return read_csv_rows(source, error=IngestError, name=where, max_rows=max_rows)
    if fmt != "parquet":
        raise IngestError(f"{where}: unknown format {fmt!r}; expected csv or parquet")
    return _read_parquet(source, where, max_rows)


def _check_file(p: Path) -> None:
    if not p.exists():
        raise IngestError(f"{p}: file not found (no such file or directory)")
    if p.is_dir():
        raise IngestError(f"{p}: is a directory, expected a CSV or Parquet file")
    if p.stat().st_size == 0:
        raise IngestError(f"{p}: empty file (no header, no rows; expected a header with "
                          "columns ['component', 'time', 'hi'])")


def _read_parquet(source: str | Path | bytes | memoryview, where: str, max_rows: int | None
                  ) -> pd.DataFrame:
    """A Parquet input as a frame; the row count from the metadata is checked first, so a
    small file that decodes to millions of rows is refused before it is decoded."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        pf = pq.ParquetFile(pa.BufferReader(pa.py_buffer(source))
                            if isinstance(source, bytes | memoryview) else str(source))
        n = pf.metadata.num_rows
        if max_rows is not None and n > max_rows:
            raise IngestError(f"{where}: {n} rows, at most {max_rows} per batch")
        size = sum(pf.metadata.row_group(i).total_byte_size
                   for i in range(pf.metadata.num_row_groups))
        if max_rows is not None and size > PARQUET_BYTES_PER_ROW * max_rows:
            raise IngestError(f"{where}: decodes to {size} bytes, at most "
                              f"{PARQUET_BYTES_PER_ROW * max_rows} per batch")
        table = pf.read()
    except IngestError:
        raise
    except Exception as err:  # pyarrow raises many kinds on bad bytes
        raise IngestError(f"{where}: cannot be read as Parquet ({type(err).__name__}: "
                          f"{str(err).strip()[:200]})") from None
    if table.num_rows == 0:
        raise IngestError(f"{where}: no data rows (header only)")
    names = [str(c) for c in table.column_names]
    dup = pd.Index(names).duplicated()
    if dup.any():
        raise IngestError(f"{where}: column {names[int(np.flatnonzero(dup)[0])]!r} appears "
                          "twice; rename or drop one")
    return table.to_pandas()


def _numeric_column(df: pd.DataFrame, col: str) -> np.ndarray:
    """``df[col]`` as finite float64 (:func:`rulkit.fleet.rows.numeric_values`: numbers of a
    numeric type only); the error names row (1-based), component and column."""
    return numeric_values(
        df[col], col, error=IngestError,
        row_label=lambda i: f"row {i + 1} (component {df['component'].iloc[i]!r})")


def validate_acquisitions(
    df: pd.DataFrame, config: TrackerConfig, hi_model: HealthIndexModel | None,
    time_axis: TimeAxis | None = None,
) -> pd.DataFrame:
    """Check a batch and return it as columns ``component`` (str), ``t``, ``hi``, ``row``
    (and ``installed`` when the time axis counts ages from it).

    ``row`` is the 1-based data row (header excluded) used in error messages; the frame's
    ``attrs["calendar"]`` says whether the time column held date-times (then ``t`` is the
    time since 1970 in units of ``attrs["seconds_per_unit"]`` seconds). Expected columns:
    ``component``, ``time`` and either ``hi`` or exactly the CI columns of the stored
    HI model. Rejected with :class:`IngestError`: an empty batch, missing / unknown / ambiguous
    columns, an empty component name, non-numeric / NaN / infinite values, HI outside
    [0, hi_max], and time not strictly increasing for a component (unsorted or duplicated).
    ``time_axis`` (stored by ``rulkit fit``): the time column is read on it
    (:meth:`~rulkit.fleet.time_axis.TimeAxis.values`: date-times converted into its unit, and
    refused where numbers were fitted, or the reverse); without one, date-times are seconds
    since 1970 and numbers are taken as they are.
    """
    if len(df) == 0:
        raise IngestError("the batch holds no acquisitions (0 rows)")
    cols = [str(c) for c in df.columns]
    dup = pd.Index(cols).duplicated()
    if dup.any():
        raise IngestError(f"column {safe_text(cols[int(np.flatnonzero(dup)[0])])!r} appears "
                          "twice; rename or drop one")
    df = df.set_axis(cols, axis=1)  # a new frame; the caller's keeps its columns
    missing = [c for c in ("component", "time") if c not in cols]
    if missing:
        raise IngestError(f"missing required column(s) {missing}; got {cols}")
    ci_names = list(hi_model.names) if hi_model is not None else []
    installed = time_axis is not None and time_axis.origin == "installed"
    if installed and INSTALLED_COLUMN not in cols:
        raise IngestError(f"missing column {INSTALLED_COLUMN!r}: the database's model counts "
                          "each component's age from its install time")
    value_cols = [c for c in cols if c not in ("component", "time")
                  and not (installed and c == INSTALLED_COLUMN)]
    if "hi" in value_cols:
        extra = [c for c in value_cols if c != "hi"]
        if extra:
            raise IngestError(
                f"unknown column(s) {extra}: give either 'hi' or the CI columns, not both"
                if set(extra) & set(ci_names)
                else f"unknown column(s) {extra}; expected component, time and hi"
                + (f" or the CI columns {ci_names}" if ci_names else "")
            )
        mode = "hi"
    elif value_cols:
        if hi_model is None:
            raise IngestError(
                f"unknown column(s) {value_cols}: the database has no HI model, so the batch "
                "must give 'hi' (or store an HI model fitted on healthy CIs first)"
            )
        unknown = [c for c in value_cols if c not in ci_names]
        if unknown:
            raise IngestError(
                f"unknown column(s) {unknown}; expected component, time and hi or the CI "
                f"columns {ci_names}"
            )
        absent = [c for c in ci_names if c not in value_cols]
        if absent:
            raise IngestError(f"missing CI column(s) {absent} of the HI model {ci_names}")
        mode = "ci"
    else:
        raise IngestError("no value column: expected 'hi'" + (
            f" or the CI columns {ci_names}" if ci_names else ""))

    df["component"] = check_component_ids(df["component"], error=ComponentIdError)
    label = lambda i: f"row {i + 1} (component {df['component'].iloc[i]!r})"  # noqa: E731
    inst = None
    t: np.ndarray | None
    if time_axis is not None:
        try:
            t = time_axis.values(df["time"], "time", "batch", row_label=label)
            if installed:
                inst = time_axis.values(df[INSTALLED_COLUMN], INSTALLED_COLUMN, "batch",
                                        row_label=label)
        except TimeAxisError as err:
            raise IngestError(str(err).removeprefix("batch: ")) from err
    else:
        t = time_seconds(df["time"], "time", error=IngestError, row_label=label)
    calendar = time_axis.timestamps if time_axis is not None else t is not None
    if t is None:
        t = _numeric_column(df, "time")
    if mode == "hi":
        hi = _numeric_column(df, "hi")
        source = "hi"
    else:
        assert hi_model is not None
        ci = np.column_stack([_numeric_column(df, c) for c in ci_names])
        hi = hi_model.health_index(ci)
        source = "HI computed from the CIs"
    out_of_range = (hi < 0) | (hi > config.hi_max)
    if out_of_range.any():
        i = int(np.flatnonzero(out_of_range)[0])
        raise IngestError(
            f"row {i + 1} (component {df['component'].iloc[i]!r}): {source} = {_fmt(hi[i])} is "
            f"outside [0, {config.hi_max}]"
        )
    comp = df["component"]
    out = pd.DataFrame({"component": comp.array, "t": t, "hi": hi,
                        "row": np.arange(1, len(df) + 1,
                                         dtype=np.int32 if len(df) < 2**31 - 1 else np.int64)},
                       copy=False)  # no 2M-row copies
    if inst is not None:
        out["installed"] = inst
    # time strictly increasing per component, in file order
    prev_t = previous_per_component(np.asarray(comp.cat.codes), t)
    back = np.isfinite(prev_t) & ~(t > prev_t)
    if back.any():
        i = int(np.flatnonzero(back)[0])
        what = "repeats" if t[i] == prev_t[i] else "goes backwards from"
        raise IngestError(
            f"row {i + 1} (component {out['component'].iloc[i]!r}): time {_fmt(t[i])} {what} the "
            f"previous acquisition of that component at {_fmt(prev_t[i])} (times must be strictly "
            "increasing per component)"
        )
    with np.errstate(over="ignore", invalid="ignore"):
        gap = t - prev_t
    huge = np.isfinite(prev_t) & ~np.isfinite(gap)
    if huge.any():
        i = int(np.flatnonzero(huge)[0])
        raise IngestError(
            f"row {i + 1} (component {out['component'].iloc[i]!r}), column 'time': the "
            f"interval from {_fmt(prev_t[i])} to {_fmt(t[i])} overflows float64; use a "
            "smaller time unit or offset")
    out.attrs["calendar"] = calendar  # date-times: t is a calendar time (units since 1970)
    out.attrs["seconds_per_unit"] = time_axis.seconds_per_unit if time_axis else 1.0
    return out
