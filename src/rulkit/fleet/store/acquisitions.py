"""Acquisition batches for the component store: reading, validation and component ids.

An acquisition file has one row per (component, time) with the health index ``hi`` or the
condition-indicator columns of the database's HI model (docs/file-formats.md). Everything here
runs before the database is touched: :func:`validate_acquisitions` names the file, column and
row of the first problem, and :func:`check_component_ids` enforces the id alphabet (1 to
:data:`COMPONENT_ID_MAX_LEN` printable characters), so a crafted id can neither forge terminal
output nor bloat the database. :mod:`rulkit.fleet.store.sqlite` applies a validated batch.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from rulkit.fleet.tracking.health_index import HealthIndexModel
from rulkit.fleet.tracking.tracker_chain import (
    LEVEL_NAMES,
    TrackerConfig,
)
from rulkit.tables import cell_repr as _fmt
from rulkit.tables import numeric_columns, read_table, safe_text, time_seconds

COMPONENT_ID_MAX_LEN = 128
"""Longest accepted component id, in characters (ids are names, not payloads)."""


class IngestError(ValueError):
    """A batch of acquisitions was rejected; the database is unchanged."""


class ComponentIdError(IngestError):
    """A component id outside the accepted alphabet or length (:func:`check_component_ids`)."""


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


# --------------------------------------------------------------------------- validation
def read_acquisitions(path: str | Path) -> pd.DataFrame:
    """Read a CSV (``.csv``, ``.csv.gz``, ``.txt``) or Parquet (``.parquet``, ``.pq``)
    acquisition file (``component`` kept as text); file-level problems raise
    :class:`IngestError` (see :func:`rulkit.tables.read_table`)."""
    return read_table(path, error=IngestError, csv_suffixes=(".csv", ".csv.gz", ".txt"),
                      expected_columns=("component", "time", "hi"),
                      csv_dtype={"component": "category"}, text_columns=("component",))


def check_component_ids(comp: pd.Series) -> pd.Series:
    """Component ids as a categorical of stripped ``str``, or :class:`ComponentIdError` at the
    first bad row.

    Accepted: 1 to :data:`COMPONENT_ID_MAX_LEN` characters after stripping surrounding blanks,
    every one printable (:meth:`str.isprintable`). Refused, naming the 1-based row: a missing
    or empty id, a non-text id (e.g. a number in a Parquet column is taken as its text, but
    bytes are refused), a control or format character (ESC, newline, tab, bidi override), and
    an id longer than the limit. The check runs once per distinct id.
    """
    missing = comp.isna().to_numpy()
    if missing.any():
        i = int(np.flatnonzero(missing)[0])
        raise ComponentIdError(f"row {i + 1}: empty component name")
    codes, uniques = pd.factorize(comp, sort=False)
    bad_code = None
    reason = ""
    clean: list[str] = []
    for k, v in enumerate(uniques):
        if isinstance(v, bytes | bytearray):
            bad_code, reason = k, "is binary data, not text"
            break
        text = str(v).strip()
        if not text:
            bad_code, reason = k, "empty component name"
            break
        if len(text) > COMPONENT_ID_MAX_LEN:
            bad_code, reason = k, (f"component id of {len(text)} characters, longer than the "
                                   f"limit of {COMPONENT_ID_MAX_LEN}")
            break
        if not text.isprintable():
            c = next(c for c in text if not c.isprintable())
            bad_code, reason = k, (f"component id '{safe_text(text, 60)}' holds the "
                                   f"non-printable character {safe_text(c)} (control and "
                                   "format characters are not allowed)")
            break
        clean.append(text)
    if bad_code is not None:
        i = int(np.flatnonzero(codes == bad_code)[0])
        raise ComponentIdError(f"row {i + 1}: {reason}")
    # ids equal after stripping share one category; the frame keeps int codes, not 2M strings
    ucodes, ucats = pd.factorize(pd.Index(clean, dtype=object))
    return pd.Series(pd.Categorical.from_codes(np.asarray(ucodes)[codes], categories=ucats),
                     index=comp.index)


def _numeric_column(df: pd.DataFrame, col: str) -> np.ndarray:
    """``df[col]`` as finite float64; the error names row (1-based), component and column.

    A float64 column that is all finite (what a CSV of numbers gives) is returned without a
    copy (read-only use: 16 MB less per column of 2M rows)."""
    if df[col].dtype == np.float64:
        a = df[col].to_numpy()
        if np.isfinite(a).all():
            return a
    return numeric_columns(
        df, [col], error=IngestError,
        row_label=lambda i: f"row {i + 1} (component {df['component'].iloc[i]!r})")[col]


def validate_acquisitions(
    df: pd.DataFrame, config: TrackerConfig, hi_model: HealthIndexModel | None
) -> pd.DataFrame:
    """Check a batch and return it as columns ``component`` (str), ``t``, ``hi``, ``row``.

    ``row`` is the 1-based data row (header excluded) used in error messages; the frame's
    ``attrs["calendar"]`` says whether the time column held date-times (then ``t`` is
    seconds since 1970). Expected columns:
    ``component``, ``time`` and either ``hi`` or exactly the CI columns of the stored
    HI model. Rejected with :class:`IngestError`: an empty batch, missing / unknown / ambiguous
    columns, an empty component name, non-numeric / NaN / infinite values, HI outside
    [0, hi_max], and time not strictly increasing for a component (unsorted or duplicated).
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
    value_cols = [c for c in cols if c not in ("component", "time")]
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

    df["component"] = check_component_ids(df["component"])
    t = time_seconds(df["time"], "time", error=IngestError,
                     row_label=lambda i: f"row {i + 1} (component {df['component'].iloc[i]!r})")
    calendar = t is not None
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
    # time strictly increasing per component, in file order
    codes = np.asarray(comp.cat.codes)
    prev_t = pd.Series(t).groupby(codes, sort=False).shift(1).to_numpy()
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
    out.attrs["calendar"] = calendar  # date-times: t is seconds since 1970, a calendar time
    return out
