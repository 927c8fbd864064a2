"""Acquisition batches for the component store: reading, validation and component ids.

An acquisition file has one row per (component, time) with the health index ``hi`` or the
condition-indicator columns of the database's HI model (docs/file-formats.md). Everything here
runs before the database is touched: :func:`validate_acquisitions` names the file, column and
row of the first problem, and :func:`rulkit.fleet.rows.component_codes` enforces the id
alphabet (1 to :data:`rulkit.fleet.rows.COMPONENT_ID_MAX_LEN` printable characters), so a
crafted id can neither forge terminal output nor bloat the database.
:mod:`rulkit.fleet.store.sqlite` applies a validated batch.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from rulkit.fleet.rows import (
    arrow_frame,
    component_codes,
    numeric_values,
    previous_per_component,
    read_csv_columns,
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

if TYPE_CHECKING:
    import pandas as pd

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
    (:func:`rulkit.fleet.rows.component_codes`)."""


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


Columns = Mapping[str, Any]
"""A batch as columns: name -> array (what the service's JSON body decodes to)."""


@dataclass(frozen=True)
class Batch:
    """A validated batch (:func:`validate_acquisitions`) as arrays: per row, ``codes`` the index
    of its component in ``names`` (the distinct ids in order of first appearance), ``t``, ``hi``
    and ``row`` (the 1-based data row, for messages), ``installed`` when the time axis counts
    ages from it; ``calendar``: the time column held date-times (then ``t`` is the time since
    1970 in units of ``seconds_per_unit`` seconds)."""

    codes: NDArray[np.integer]
    names: list[str]
    t: NDArray[np.float64]
    hi: NDArray[np.float64]
    row: NDArray[np.integer]
    installed: NDArray[np.float64] | None = None
    calendar: bool = False
    seconds_per_unit: float = 1.0

    def __len__(self) -> int:
        return int(self.t.size)

    def take(self, keep: NDArray[np.bool_]) -> Batch:
        """The rows where ``keep``, their components renumbered in order of first
        appearance."""
        codes = self.codes[keep]
        uniq, first, inverse = np.unique(codes, return_index=True, return_inverse=True)
        order = np.argsort(first, kind="stable")  # uniq by first appearance
        rank = np.empty(order.size, dtype=np.intp)
        rank[order] = np.arange(order.size)
        return replace(
            self, codes=rank[inverse.reshape(-1)], names=[self.names[k] for k in uniq[order]],
            t=self.t[keep], hi=self.hi[keep], row=self.row[keep],
            installed=None if self.installed is None else self.installed[keep])

    def first_rows(self) -> NDArray[np.intp]:
        """Each component's first row (indexed like ``names``)."""
        return np.unique(self.codes, return_index=True)[1]


# --------------------------------------------------------------------------- validation
def read_acquisitions(source: str | Path | bytes | memoryview, fmt: str | None = None, *,
                      max_rows: int | None = None, name: str | None = None,
                      columns: bool = False) -> pd.DataFrame | Columns:
    """Read a CSV (``.csv``, ``.csv.gz``, ``.txt``) or Parquet (``.parquet``, ``.pq``)
    acquisition file, or the bytes of one (``fmt`` ``"csv"`` / ``"parquet"``; what the
    service receives), ``component`` kept as text. The one reader of ``rulkit track`` and of
    the service's uploads. CSV rows must have as many fields as the header
    (:func:`rulkit.fleet.rows.read_csv_rows`); a Parquet input's row count is read from its
    metadata and refused above ``max_rows`` before any column is decoded. File-level
    problems raise :class:`IngestError` naming ``name`` (default: the path). ``columns``: a
    CSV whose columns are all plain is returned as :data:`Columns` without pandas
    (:func:`rulkit.fleet.rows.read_csv_columns`; what ``rulkit track`` reads)."""
    if isinstance(source, bytes | memoryview):
        where = name or f"{fmt} body"
    else:
        where = name or str(source)
        fmt = fmt or table_format(source, error=IngestError,
                                  csv_suffixes=(".csv", ".csv.gz", ".txt"))
        _check_file(Path(source))
    if fmt == "csv":
        read = read_csv_columns if columns else read_csv_rows
        return read(source, error=IngestError, name=where, max_rows=max_rows)
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
    dup = [c for j, c in enumerate(names) if c in names[:j]]
    if dup:
        raise IngestError(f"{where}: column {dup[0]!r} appears twice; rename or drop one")
    return arrow_frame(table)


def validate_acquisitions(
    df: pd.DataFrame | Columns, config: TrackerConfig, hi_model: HealthIndexModel | None,
    time_axis: TimeAxis | None = None,
) -> Batch:
    """Check a batch and return it as a :class:`Batch` of arrays.

    ``df``: a frame, or :data:`Columns` (arrays of one length). Expected columns:
    ``component``, ``time`` and either ``hi`` or exactly the CI columns of the stored HI
    model. Rejected with :class:`IngestError`: an empty batch, missing / unknown / ambiguous
    columns, an empty component name, non-numeric / NaN / infinite values, HI outside
    [0, hi_max], and time not strictly increasing for a component (unsorted or duplicated).
    ``time_axis`` (stored by ``rulkit fit``): the time column is read on it
    (:meth:`~rulkit.fleet.time_axis.TimeAxis.values`: date-times converted into its unit, and
    refused where numbers were fitted, or the reverse); without one, date-times are seconds
    since 1970 and numbers are taken as they are. Every check is an array operation over the
    batch's columns (docs/service-load.md).
    """
    cols = _batch_columns(df)
    installed = time_axis is not None and time_axis.origin == "installed"
    mode = _value_mode(list(cols), hi_model, installed)
    codes, names = component_codes(cols["component"], error=ComponentIdError)

    def label(i: int) -> str:
        return f"row {i + 1} (component {names[codes[i]]!r})"

    t, inst, calendar = _times(cols, time_axis, installed, label)
    hi = _health_index(cols, mode, hi_model, config, label)
    _check_time_order(codes, t, label)
    n = t.size
    return Batch(codes=codes, names=names, t=t, hi=hi,
                 row=np.arange(1, n + 1, dtype=np.int32 if n < 2**31 - 1 else np.int64),
                 installed=inst, calendar=bool(calendar),
                 seconds_per_unit=time_axis.seconds_per_unit if time_axis else 1.0)


def _batch_columns(df: pd.DataFrame | Columns) -> dict[str, Any]:
    """The batch's columns by name (text), refused when empty, when a name appears twice or
    when the columns differ in length."""
    if not isinstance(df, Mapping):  # a pandas DataFrame
        n = len(df)
    else:
        lengths = {len(v) for v in df.values()}
        if len(lengths) > 1:
            raise IngestError(f"columns of different lengths {sorted(lengths)}")
        n = lengths.pop() if lengths else 0
    if n == 0:
        raise IngestError("the batch holds no acquisitions (0 rows)")
    names = [str(c) for c in (df if isinstance(df, Mapping) else df.columns)]
    seen: set[str] = set()
    for c in names:
        if c in seen:
            raise IngestError(f"column {safe_text(c)!r} appears twice; rename or drop one")
        seen.add(c)
    cols = (dict(zip(names, df.values(), strict=True)) if isinstance(df, Mapping)
            else {c: df.iloc[:, j] for j, c in enumerate(names)})
    missing = [c for c in ("component", "time") if c not in cols]
    if missing:
        raise IngestError(f"missing required column(s) {missing}; got {names}")
    return cols


def _value_mode(cols: list[str], hi_model: HealthIndexModel | None, installed: bool) -> str:
    """``"hi"`` or ``"ci"``: what the batch's value columns give, or :class:`IngestError`."""
    ci_names = list(hi_model.names) if hi_model is not None else []
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
        return "hi"
    if not value_cols:
        raise IngestError("no value column: expected 'hi'" + (
            f" or the CI columns {ci_names}" if ci_names else ""))
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
    return "ci"


def _is_numbers(col: Any) -> bool:
    """Whether a column is of an integer or floating type (so it holds no date-times; a
    boolean dtype, numpy's or pandas', is of kind ``"b"``)."""
    return getattr(getattr(col, "dtype", None), "kind", "") in "iuf"


def _times(cols: dict[str, Any], time_axis: TimeAxis | None, installed: bool,
           label: Callable[[int], str]) -> tuple[np.ndarray, np.ndarray | None, bool]:
    """The time column as float64 (and the install times), and whether it held date-times.
    A column of numbers is read as numbers directly (it cannot hold date-times)."""
    col = cols["time"]
    if _is_numbers(col) and not installed and not (time_axis and time_axis.timestamps):
        return _numbers(col, "time", label), None, False
    inst = None
    t: np.ndarray | None
    if time_axis is not None:
        try:
            t = time_axis.values(col, "time", "batch", row_label=label)
            if installed:
                inst = time_axis.values(cols[INSTALLED_COLUMN], INSTALLED_COLUMN, "batch",
                                        row_label=label)
        except TimeAxisError as err:
            raise IngestError(str(err).removeprefix("batch: ")) from err
    else:
        t = time_seconds(col, "time", error=IngestError, row_label=label)
    calendar = time_axis.timestamps if time_axis is not None else t is not None
    if t is None:
        t = _numbers(col, "time", label)
    return t, inst, calendar


def _numbers(col: Any, name: str, label: Callable[[int], str]) -> np.ndarray:
    """A column as finite float64 (:func:`rulkit.fleet.rows.numeric_values`: numbers of a
    numeric type only); the error names row (1-based), component and column."""
    return numeric_values(col, name, error=IngestError, row_label=label)


def _health_index(cols: dict[str, Any], mode: str, hi_model: HealthIndexModel | None,
                  config: TrackerConfig, label: Callable[[int], str]) -> np.ndarray:
    """The batch's HI (given, or computed from the CIs), refused outside [0, hi_max]."""
    if mode == "hi":
        hi = _numbers(cols["hi"], "hi", label)
        source = "hi"
    else:
        assert hi_model is not None
        ci = np.column_stack([_numbers(cols[c], c, label) for c in hi_model.names])
        hi = hi_model.health_index(ci)
        source = "HI computed from the CIs"
    out_of_range = (hi < 0) | (hi > config.hi_max)
    if out_of_range.any():
        i = int(np.flatnonzero(out_of_range)[0])
        raise IngestError(f"{label(i)}: {source} = {_fmt(hi[i])} is outside "
                          f"[0, {config.hi_max}]")
    return hi


def _check_time_order(codes: np.ndarray, t: np.ndarray, label: Callable[[int], str]) -> None:
    """Time strictly increasing per component in file order, and every interval finite."""
    prev_t = previous_per_component(codes, t)
    back = np.isfinite(prev_t) & ~(t > prev_t)
    if back.any():
        i = int(np.flatnonzero(back)[0])
        what = "repeats" if t[i] == prev_t[i] else "goes backwards from"
        raise IngestError(
            f"{label(i)}: time {_fmt(t[i])} {what} the previous acquisition of that component "
            f"at {_fmt(prev_t[i])} (times must be strictly increasing per component)")
    with np.errstate(over="ignore", invalid="ignore"):
        gap = t - prev_t
    huge = np.isfinite(prev_t) & ~np.isfinite(gap)
    if huge.any():
        i = int(np.flatnonzero(huge)[0])
        raise IngestError(
            f"{label(i)}, column 'time': the interval from {_fmt(prev_t[i])} to {_fmt(t[i])} "
            "overflows float64; use a smaller time unit or offset")
