"""Fleet histories: rows (component, time, hi[, failed]) read, validated and grouped per unit.

docs/fleet-models.md section 1. A history is one scalar health index per acquisition, failure
at hi = 1 by convention. A unit has failed when its last hi >= 1 or, when the file has a
``failed`` column, when that column says so (it must then be constant within the unit). Time is
the unit's age in the file's time unit (a number; a datetime column is refused: convert it
first, e.g. to hours since the unit's first acquisition).

Bad histories raise :class:`HistoryError` naming the file, the row and the unit: fewer than two
units, no failed unit, time not strictly increasing within a unit, NaN / infinite values,
HI < 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from rulkit.fleet.rows import check_component_ids, numeric_values, read_csv_rows

FloatArray = NDArray[np.float64]


class HistoryError(ValueError):
    """A set of histories cannot be used (which file, row, unit and why)."""


@dataclass(frozen=True)
class Histories:
    """Acquisitions of U units, sorted by unit then time (struct of arrays).

    ``unit (N,)`` index 0..U-1 of each row, ``t (N,)`` time, ``hi (N,)``; ``names (U,)`` the
    component names; ``start (U + 1,)`` row offsets (unit u is rows start[u]:start[u+1]);
    ``failed (U,)``; ``source`` the file or "<dataframe>" for messages.
    """

    unit: NDArray[np.int64]
    t: FloatArray
    hi: FloatArray
    names: NDArray[np.object_]
    start: NDArray[np.int64]
    failed: NDArray[np.bool_]
    source: str = "<dataframe>"

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
                         start=start, failed=self.failed[units], source=self.source)

    def to_frame(self) -> pd.DataFrame:
        """Back to rows (component, time, hi, failed)."""
        return pd.DataFrame({"component": self.names[self.unit], "time": self.t, "hi": self.hi,
                             "failed": self.failed[self.unit]})


def _number_column(df: pd.DataFrame, col: str, where: str) -> FloatArray:
    s = df[col]
    if pd.api.types.is_datetime64_any_dtype(s) or pd.api.types.is_timedelta64_dtype(s):
        raise HistoryError(
            f"{where}: column {col!r} holds dates/durations; convert it to a number in one time "
            "unit first (e.g. hours since the unit's first acquisition)"
        )
    # the rules of every fleet table (rulkit.fleet.rows): numbers of a numeric type only
    try:
        return np.array(numeric_values(s, col, error=HistoryError, row_label=lambda i: (
            f"row {i + 1} (component {df['component'].iloc[i]!r})")), dtype=np.float64)
    except HistoryError as err:
        raise HistoryError(f"{where}: {err}") from None


def histories_from_frame(
    df: pd.DataFrame, source: str = "<dataframe>", *, min_units: int = 2,
    require_failure: bool = True,
) -> Histories:
    """Validate a frame with columns component, time, hi (optional failed); see module doc."""
    where = source
    missing = [c for c in ("component", "time", "hi") if c not in df.columns]
    if missing:
        raise HistoryError(f"{where}: missing column(s) {missing}; expected component, time, hi "
                           f"(optional failed), got {[str(c) for c in df.columns]}")
    if len(df) == 0:
        raise HistoryError(f"{where}: no rows")
    df = df.reset_index(drop=True)
    try:  # the id rules of every fleet table (rulkit.fleet.rows)
        comp = check_component_ids(df["component"], error=HistoryError)
    except HistoryError as err:
        raise HistoryError(f"{where}: {err}") from None
    names_col = comp.astype(str).to_numpy(dtype=object)
    df = df.assign(component=names_col)
    t = _number_column(df, "time", where)
    hi = _number_column(df, "hi", where)
    neg = hi < 0
    if neg.any():
        i = int(np.flatnonzero(neg)[0])
        raise HistoryError(f"{where}: row {i + 1} (component {names_col[i]!r}): hi = {hi[i]:g} "
                           "< 0 (the health index is >= 0, failure at 1)")
    codes, names = pd.factorize(pd.Series(names_col), sort=False)
    codes = codes.astype(np.int64)
    # time strictly increasing per unit, in file order
    prev = pd.Series(t).groupby(codes).shift(1).to_numpy()
    back = np.isfinite(prev) & ~(t > prev)
    if back.any():
        i = int(np.flatnonzero(back)[0])
        raise HistoryError(
            f"{where}: row {i + 1} (component {names_col[i]!r}): time {t[i]:g} is not after the "
            f"previous acquisition of that component at {prev[i]:g} (sort each unit's rows by "
            "time; times must be strictly increasing)"
        )
    n_units = len(names)
    if n_units < min_units:
        raise HistoryError(f"{where}: {n_units} unit(s); learning a fleet prior needs at least "
                           f"{min_units} units")
    order = np.argsort(codes, kind="stable")
    codes_s, t_s, hi_s = codes[order], t[order], hi[order]
    counts = np.bincount(codes_s, minlength=n_units)
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    last_hi = hi_s[start[1:] - 1]
    if "failed" in df.columns:
        f = df["failed"]
        fv = f.map(lambda v: str(v).strip().lower()).map(
            {"1": True, "true": True, "yes": True, "0": False, "false": False, "no": False,
             "1.0": True, "0.0": False})
        if fv.isna().any():
            i = int(np.flatnonzero(fv.isna().to_numpy())[0])
            raise HistoryError(f"{where}: row {i + 1}: failed = {f.iloc[i]!r}; expected "
                               "true/false or 1/0")
        fb = fv.to_numpy(dtype=bool)
        per_unit_any = np.bincount(codes, weights=fb, minlength=n_units) > 0
        per_unit_all = np.bincount(codes, weights=fb, minlength=n_units) == counts
        mixed = per_unit_any & ~per_unit_all
        if mixed.any():
            u = int(np.flatnonzero(mixed)[0])
            raise HistoryError(f"{where}: component {names[u]!r}: the failed column is not "
                               "constant within the unit")
        failed = per_unit_any
    else:
        failed = last_hi >= 1.0
    if require_failure and not failed.any():
        raise HistoryError(
            f"{where}: no unit has failed (last hi >= 1 or failed = true): a prior learned from "
            "censored units alone cannot place the threshold crossing"
        )
    return Histories(unit=codes_s, t=t_s, hi=hi_s, names=np.asarray(names, dtype=object),
                     start=start, failed=failed, source=source)


def read_histories(path: str | Path, **kwargs: object) -> Histories:
    """Read a CSV or Parquet file (or a directory of Parquet partitions) of histories."""
    p = Path(path)
    if not p.exists():
        raise HistoryError(f"{p}: no such file or directory")
    try:
        if p.is_dir() or p.suffix.lower() in (".parquet", ".pq"):
            df = pd.read_parquet(p)
        elif p.suffix.lower() in (".csv", ".txt"):  # field counts checked, ids kept as text
            df = read_csv_rows(p, error=HistoryError)
        else:
            raise HistoryError(f"{p}: expected a .csv or .parquet file (or a Parquet directory)")
    except HistoryError:
        raise
    except Exception as err:  # a parser error names the file
        raise HistoryError(f"{p}: cannot read: {err}") from err
    return histories_from_frame(df, str(p), **kwargs)  # type: ignore[arg-type]


__all__ = ["Histories", "HistoryError", "histories_from_frame", "read_histories"]
