"""Fleet histories: rows (component, time, hi[, failed]) read, validated and grouped per unit.

docs/fleet-models.md section 1. A history is one scalar health index per acquisition, failure
at hi = 1 by convention. A unit has failed when its last hi >= 1 or, when the file has a
``failed`` column, when that column says so (it must then be constant within the unit). The
time column holds numbers or date-times; a :class:`~rulkit.fleet.time_axis.TimeAxis` turns it
into each unit's age (the column itself, or the age since the unit's first acquisition or its
``installed`` column), in the unit the axis names.

Bad histories raise :class:`HistoryError` naming the file, the row and the unit: fewer than two
units, no failed unit, time not strictly increasing within a unit, NaN / infinite values,
HI < 0, a column named twice. Implausible but usable histories are reported as warnings by
:mod:`rulkit.fleet.learned.checks`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from rulkit.fleet.rows import (
    check_component_ids,
    numeric_values,
    previous_per_component,
    read_csv_rows,
)
from rulkit.fleet.time_axis import (
    INSTALLED_COLUMN,
    TimeAxis,
    TimeAxisError,
    infer_axis,
    unit_origins,
)

if TYPE_CHECKING:  # pandas is imported where a frame is made or read: a stored model's
    import pandas as pd  # classes (rulkit status of a fitted database) load without it

FloatArray = NDArray[np.float64]
DEFAULT_AXIS = TimeAxis()


class HistoryError(ValueError):
    """A set of histories cannot be used (which file, row, unit and why)."""


@dataclass(frozen=True)
class Histories:
    """Acquisitions of U units, sorted by unit then time (struct of arrays).

    ``unit (N,)`` index 0..U-1 of each row, ``t (N,)`` time, ``hi (N,)``; ``names (U,)`` the
    component names; ``start (U + 1,)`` row offsets (unit u is rows start[u]:start[u+1]);
    ``failed (U,)``; ``source`` the file or "<dataframe>" for messages; ``axis`` how the
    file's time column became the age ``t``; ``row (N,)`` each row's 1-based row in the file
    (for messages; 0 when unknown); ``extra_columns`` the file's columns this reader ignored.
    """

    unit: NDArray[np.int64]
    t: FloatArray
    hi: FloatArray
    names: NDArray[np.object_]
    start: NDArray[np.int64]
    failed: NDArray[np.bool_]
    source: str = "<dataframe>"
    axis: TimeAxis = DEFAULT_AXIS
    row: NDArray[np.int64] | None = None
    extra_columns: tuple[str, ...] = ()
    raw_time: FloatArray | None = None

    @property
    def n_units(self) -> int:
        return int(self.names.size)

    def rows(self, u: int) -> slice:
        return slice(int(self.start[u]), int(self.start[u + 1]))

    def failure_time(self, threshold: float = 1.0) -> FloatArray:
        """True time of hi = threshold per unit: linear interpolation between the last
        acquisition below and the first at or above it; NaN for censored units (a unit flagged
        failed whose hi never reaches the threshold fails at its last acquisition)."""
        out = np.full(self.n_units, np.nan)
        for u in np.flatnonzero(self.failed):
            s = self.rows(int(u))
            t, h = self.t[s], self.hi[s]
            above = np.flatnonzero(h >= threshold)
            if above.size == 0:
                out[u] = t[-1]
            elif above[0] == 0:
                out[u] = t[0]
            else:
                k = int(above[0])
                out[u] = t[k - 1] + (threshold - h[k - 1]) * (t[k] - t[k - 1]) / (h[k] - h[k - 1])
        return out

    def select(self, units: NDArray[np.int64] | list[int]) -> Histories:
        """The histories of the given unit indices (in that order)."""
        units = np.asarray(units, dtype=np.int64)
        idx = np.concatenate([np.arange(self.start[u], self.start[u + 1]) for u in units]) \
            if units.size else np.zeros(0, dtype=np.int64)
        counts = self.start[units + 1] - self.start[units]
        new_unit = np.repeat(np.arange(units.size), counts)
        start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        return Histories(unit=new_unit, t=self.t[idx], hi=self.hi[idx], names=self.names[units],
                         start=start, failed=self.failed[units], source=self.source,
                         axis=self.axis, row=None if self.row is None else self.row[idx],
                         extra_columns=self.extra_columns,
                         raw_time=None if self.raw_time is None else self.raw_time[idx])

    def to_frame(self) -> pd.DataFrame:
        """Back to rows (component, time, hi, failed)."""
        import pandas as pd

        return pd.DataFrame({"component": self.names[self.unit], "time": self.t, "hi": self.hi,
                             "failed": self.failed[self.unit]})


def _number_column(df: pd.DataFrame, col: str, where: str) -> FloatArray:
    try:  # the number rules of every fleet table (rulkit.fleet.rows)
        return numeric_values(df[col], col, error=HistoryError, row_label=lambda i: (
            f"row {i + 1} (component {df['component'].iloc[i]!r})"))
    except HistoryError as err:
        raise HistoryError(f"{where}: {err}") from None


KNOWN_COLUMNS = ("component", "time", "hi", "failed", INSTALLED_COLUMN)


def _check_columns(df: pd.DataFrame, where: str) -> tuple[str, ...]:
    """Required columns present, none named twice (a CSV reader's ``hi.1`` copy included);
    returns the columns the reader ignores."""
    cols = [str(c) for c in df.columns]
    missing = [c for c in ("component", "time", "hi") if c not in cols]
    if missing:
        raise HistoryError(f"{where}: missing column(s) {missing}; expected component, time, hi "
                           f"(optional failed, {INSTALLED_COLUMN}), got {cols}")
    seen: set[str] = set()
    for c in cols:
        if c in seen:
            raise HistoryError(f"{where}: column {c!r} appears twice; rename or drop one")
        seen.add(c)
    for c in KNOWN_COLUMNS:
        copies = [d for d in cols if d.startswith(c + ".") and d[len(c) + 1:].isdigit()]
        if copies and c in cols:
            raise HistoryError(
                f"{where}: columns {c!r} and {copies[0]!r}: the file names {c!r} twice (a CSV "
                f"reader renames the copy {copies[0]!r}); keep one, so which one is meant is "
                "not a guess")
    return tuple(c for c in cols if c not in KNOWN_COLUMNS)


def _ages(df: pd.DataFrame, codes: NDArray[np.int64], n_units: int, where: str,
          unit: str, origin: str | None, axis: TimeAxis | None
          ) -> tuple[FloatArray, FloatArray, TimeAxis]:
    """(age, the time column in the axis' unit, axis) per row; see :mod:`rulkit.fleet.time_axis`."""
    has_inst = INSTALLED_COLUMN in df.columns
    label = lambda i: f"row {i + 1} (component {df['component'].iloc[i]!r})"  # noqa: E731
    try:
        if axis is None:
            axis = infer_axis(df["time"], unit=unit, origin=origin, has_installed=has_inst)
        raw = axis.values(df["time"], "time", where, row_label=label)
        inst = (axis.values(df[INSTALLED_COLUMN], INSTALLED_COLUMN, where, row_label=label)
                if axis.origin == "installed" and has_inst else None)
        origins = unit_origins(axis, raw, codes, n_units, inst)
    except TimeAxisError as err:
        msg = str(err)
        raise HistoryError(msg if msg.startswith(where) else f"{where}: {msg}") from err
    if inst is not None:
        differs = inst != origins[codes]
        if differs.any():
            i = int(np.flatnonzero(differs)[0])
            raise HistoryError(f"{where}: {label(i)}: the {INSTALLED_COLUMN!r} column is not "
                               "constant within the unit")
    return raw - origins[codes], raw, axis


def histories_from_frame(
    df: pd.DataFrame, source: str = "<dataframe>", *, min_units: int = 2,
    require_failure: bool = True, unit: str = "", origin: str | None = None,
    axis: TimeAxis | None = None,
) -> Histories:
    """Validate a frame with columns component, time, hi (optional failed, installed); see the
    module docstring. ``axis`` reads the time column as a fitted model did; without it the axis
    is inferred from the column (:func:`rulkit.fleet.time_axis.infer_axis` with ``unit`` and
    ``origin``)."""
    import pandas as pd

    where = source
    extra = _check_columns(df, where)
    if len(df) == 0:
        raise HistoryError(f"{where}: no rows")
    df = df.reset_index(drop=True)
    try:  # the id rules of every fleet table (rulkit.fleet.rows)
        comp = check_component_ids(df["component"], error=HistoryError)
    except HistoryError as err:
        raise HistoryError(f"{where}: {err}") from None
    names_col = comp.astype(str).to_numpy(dtype=object)
    df = df.assign(component=names_col)
    codes, names = pd.factorize(pd.Series(names_col), sort=False)
    codes = codes.astype(np.int64)
    n_units = len(names)
    t, raw, axis = _ages(df, codes, n_units, where, unit, origin, axis)
    hi = _number_column(df, "hi", where)
    neg = hi < 0
    if neg.any():
        i = int(np.flatnonzero(neg)[0])
        raise HistoryError(f"{where}: row {i + 1} (component {names_col[i]!r}): hi = {hi[i]:g} "
                           "< 0 (the health index is >= 0, failure at 1)")
    # time strictly increasing per unit, in file order
    prev = previous_per_component(codes, t)
    back = np.isfinite(prev) & ~(t > prev)
    if back.any():
        i = int(np.flatnonzero(back)[0])
        raise HistoryError(
            f"{where}: row {i + 1} (component {names_col[i]!r}): time {raw[i]:g} is not after "
            f"the previous acquisition of that component at {raw[i] - t[i] + prev[i]:g} (sort "
            "each unit's rows by time; times must be strictly increasing)"
        )
    if n_units < min_units:
        raise HistoryError(f"{where}: {n_units} unit(s); learning a fleet prior needs at least "
                           f"{min_units} units")
    order = np.argsort(codes, kind="stable")
    codes_s = codes[order]
    counts = np.bincount(codes_s, minlength=n_units)
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    failed = _failed(df, codes, counts, names, hi[order][start[1:] - 1], where)
    if require_failure and not failed.any():
        raise HistoryError(
            f"{where}: no unit has failed (last hi >= 1 or failed = true): a prior learned from "
            "censored units alone cannot place the threshold crossing"
        )
    return Histories(unit=codes_s, t=t[order], hi=hi[order],
                     names=np.asarray(names, dtype=object), start=start, failed=failed,
                     source=source, axis=axis, row=(order + 1).astype(np.int64),
                     extra_columns=extra, raw_time=raw[order])


def _failed(df: pd.DataFrame, codes: NDArray[np.int64], counts: NDArray[np.int64],
            names: pd.Index, last_hi: FloatArray, where: str) -> NDArray[np.bool_]:
    """Per unit: the ``failed`` column (constant within a unit) or last hi >= 1."""
    if "failed" not in df.columns:
        return last_hi >= 1.0
    f = df["failed"]
    fv = f.map(lambda v: str(v).strip().lower()).map(
        {"1": True, "true": True, "yes": True, "0": False, "false": False, "no": False,
         "1.0": True, "0.0": False})
    if fv.isna().any():
        i = int(np.flatnonzero(fv.isna().to_numpy())[0])
        raise HistoryError(f"{where}: row {i + 1}: failed = {f.iloc[i]!r}; expected "
                           "true/false or 1/0")
    fb = fv.to_numpy(dtype=bool)
    n_units = counts.size
    per_unit_any = np.bincount(codes, weights=fb, minlength=n_units) > 0
    per_unit_all = np.bincount(codes, weights=fb, minlength=n_units) == counts
    mixed = per_unit_any & ~per_unit_all
    if mixed.any():
        u = int(np.flatnonzero(mixed)[0])
        raise HistoryError(f"{where}: component {names[u]!r}: the failed column is not "
                           "constant within the unit")
    return np.asarray(per_unit_any, dtype=bool)


def read_histories(path: str | Path, **kwargs: object) -> Histories:
    """Read a CSV or Parquet file (or a directory of Parquet partitions) of histories;
    ``kwargs`` go to :func:`histories_from_frame`."""
    import pandas as pd

    p = Path(path)
    if not p.exists():
        raise HistoryError(f"{p}: no such file or directory")
    try:
        if p.is_dir() or p.suffix.lower() in (".parquet", ".pq"):
            df = pd.read_parquet(p)
        elif p.name.lower().endswith((".csv", ".csv.gz", ".txt")):
            # the one CSV reader of every fleet table: field counts checked, ids kept as text
            df = read_csv_rows(p, error=HistoryError)
        else:
            raise HistoryError(f"{p}: expected a .csv, .csv.gz or .parquet file (or a "
                               "directory of Parquet partitions)")
    except HistoryError:
        raise
    except Exception as err:  # a parser error names the file
        raise HistoryError(f"{p}: cannot read: {err}") from err
    return histories_from_frame(df, str(p), **kwargs)  # type: ignore[arg-type]


__all__ = ["KNOWN_COLUMNS", "Histories", "HistoryError", "histories_from_frame",
           "read_histories"]
