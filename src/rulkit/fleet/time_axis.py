"""One notion of time for ``rulkit fit``, ``track`` and ``evaluate``: a time column becomes an age.

docs/fleet-models.md section 1. A time column holds numbers or date-times (ISO 8601 text,
Parquet timestamps). The models need each unit's **age** in one time unit; the
:class:`TimeAxis` says how to get it, and is stored with the fitted model and the database so
every later batch is read the same way and every RUL is printed with its unit:

* ``unit``: the label of the time unit. Date-times are converted into it, so it must then be a
  duration (s, min, h, d, week; hours by default); numbers are taken as they are, in whatever
  unit the label names (kcycles, h, ...);
* ``origin``: ``time`` (the column already is the age: the default for numbers), ``first`` (age
  since the unit's first acquisition: the default for date-times) or ``installed`` (age since
  the unit's ``installed`` column, a date-time or number constant within the unit).

:meth:`TimeAxis.values` converts a column (refusing date-times where numbers were fitted and the
reverse, naming the column and what to do); the age is ``values - origin`` per unit.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
DURATIONS = {"s": 1.0, "sec": 1.0, "seconds": 1.0, "min": 60.0, "minutes": 60.0, "h": 3600.0,
             "hours": 3600.0, "hour": 3600.0, "d": 86400.0, "days": 86400.0, "day": 86400.0,
             "week": 604800.0, "weeks": 604800.0}
"""Time units a date-time column can be converted into (seconds per unit)."""
ORIGINS = ("time", "first", "installed")
INSTALLED_COLUMN = "installed"


class TimeAxisError(ValueError):
    """A time column that cannot be read on the axis (which column, what was expected)."""


@dataclass(frozen=True)
class TimeAxis:
    """How a time column becomes an age (module docstring)."""

    unit: str = ""
    timestamps: bool = False
    origin: str = "time"

    def __post_init__(self) -> None:
        if self.origin not in ORIGINS:
            raise TimeAxisError(f"age origin: expected one of {', '.join(ORIGINS)}, got "
                                f"{self.origin!r}")
        if self.timestamps and self.unit not in DURATIONS:
            raise TimeAxisError(
                f"time unit {self.unit!r}: date-times are converted into a duration; give "
                f"--time-unit as one of {', '.join(sorted(set(DURATIONS)))}")

    @property
    def seconds_per_unit(self) -> float:
        """Seconds in one unit (date-times only; 1 for numbers)."""
        return DURATIONS[self.unit] if self.timestamps else 1.0

    def label(self) -> str:
        """The unit as printed beside every RUL (``"time units"`` when unnamed)."""
        return self.unit or "time units"

    def describe(self) -> str:
        """One line: what the time column holds and what the age is."""
        what = "date-times, converted to" if self.timestamps else "numbers in"
        since = {"time": "the column is the age",
                 "first": "age since each unit's first acquisition",
                 "installed": f"age since each unit's '{INSTALLED_COLUMN}' column"}[self.origin]
        return f"time: {what} {self.label()}; {since}"

    def values(self, col: Any, name: str = "time", where: str = "",
               row_label: Any = None) -> FloatArray:
        """The column in this axis' unit (date-times: units since 1970-01-01 UTC)."""
        import pandas as pd

        from rulkit.fleet.rows import numeric_values
        from rulkit.tables import time_seconds

        prefix = f"{where}: " if where else ""
        kw = {"row_label": row_label} if row_label is not None else {}
        secs = time_seconds(col, name, error=TimeAxisError, source=where, **kw)
        if secs is not None and not self.timestamps:
            raise TimeAxisError(
                f"{prefix}column {name!r} holds date-times, but this "
                + ("database's" if where.startswith("batch") else "model's")
                + f" time is numbers in {self.label()} ({self.describe()}); give the same "
                "kind of time column as the model was fitted on")
        if secs is None and self.timestamps:
            raise TimeAxisError(
                f"{prefix}column {name!r} holds numbers, but the time axis is date-times "
                f"converted to {self.label()}; give date-times (ISO 8601) as when fitted")
        if secs is not None:
            return secs / self.seconds_per_unit
        _mostly_dates(col, name, prefix, row_label)
        try:  # the number rules of every fleet table
            return numeric_values(pd.Series(col).reset_index(drop=True), name,
                                  error=TimeAxisError, **kw)
        except TimeAxisError as err:
            raise TimeAxisError(f"{prefix}{err}") from None

    def to_dict(self) -> dict[str, Any]:
        """The axis as JSON-ready values."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> TimeAxis:
        """Inverse of :meth:`to_dict` (None or empty: the default axis)."""
        return cls() if not d else cls(**d)


_DATE = r"^\s*\d{4}-\d{2}-\d{2}"


def _mostly_dates(col: Any, name: str, prefix: str, row_label: Any) -> None:
    """A text column whose cells are mostly date-times but not all: name the first other
    cell (instead of calling every date 'not a number')."""
    import pandas as pd

    s = pd.Series(col).reset_index(drop=True)
    if not (s.dtype == object or pd.api.types.is_string_dtype(s.dtype)):
        return
    is_date = s.astype(str).str.match(_DATE).to_numpy()
    if is_date.mean() > 0.5 and not is_date.all():
        i = int(np.flatnonzero(~is_date)[0])
        where = row_label(i) if row_label is not None else f"row {i + 1}"
        raise TimeAxisError(f"{prefix}column {name!r}, {where}: {s.iloc[i]!r} is not a "
                            "date-time (ISO 8601), as the column's other cells are")


def infer_axis(col: Any, *, unit: str = "", origin: str | None = None,
               has_installed: bool = False) -> TimeAxis:
    """The axis of a history's time column: date-times or numbers as found; the unit
    (date-times: hours unless given); the origin (given, else ``installed`` when the file has
    that column, else ``first`` for date-times and ``time`` for numbers)."""
    from rulkit.tables import time_seconds

    stamps = time_seconds(col, "time", error=TimeAxisError) is not None
    if origin is None:
        origin = "installed" if has_installed else ("first" if stamps else "time")
    return TimeAxis(unit=unit or ("h" if stamps else ""), timestamps=stamps, origin=origin)


def unit_origins(axis: TimeAxis, t: FloatArray, codes: NDArray[np.int64], n_units: int,
                 installed: FloatArray | None = None) -> FloatArray:
    """Each unit's age origin on the axis: 0, its first (smallest) time, or its installed
    value (``installed`` per row, already converted; constant within a unit)."""
    if axis.origin == "time":
        return np.zeros(n_units)
    if axis.origin == "first":
        out = np.full(n_units, np.inf)
        np.minimum.at(out, codes, t)
        return out
    if installed is None:
        raise TimeAxisError(f"the time axis counts age from the '{INSTALLED_COLUMN}' column, "
                            "which is missing")
    out = np.full(n_units, np.nan)
    out[codes] = installed
    return out


__all__ = ["DURATIONS", "INSTALLED_COLUMN", "ORIGINS", "TimeAxis", "TimeAxisError",
           "infer_axis", "unit_origins"]
