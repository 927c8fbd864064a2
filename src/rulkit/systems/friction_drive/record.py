"""Reading and checking a user's friction-drive record for ``rulkit drive``
(docs/systems/friction-drive.md §9; the file format is in docs/file-formats.md).

Columns (CSV or Parquet, one row per sample; names compared with case and blanks ignored, two
columns that differ only in case refused; other columns ignored):

============= ====== ===========================================================
column        unit   meaning
============= ====== ===========================================================
``time_s``    s      sample time: numbers or date-times, strictly increasing
``current_A`` A      motor current, the input (held until the next sample)
``w1_rad_s``  rad/s  motor (roller) speed, measured; an empty cell is missing
``w2_rad_s``  rad/s  wheel speed, measured; an empty cell is missing
============= ====== ===========================================================

Sampling is regular: every step is a whole number of sampling steps (within 1 %); a step of
several is a gap the filter bridges by prediction, holding the last current. Only differences
of times are used, so the time origin does not matter (date-times are converted in integer
nanoseconds since the first row). The plausible ranges come from the machine file
(:mod:`rulkit.systems.friction_drive.machine`): the sampling step, the current and the speeds
(no speed beyond 1.5 times the free-running speed at ``max_current``).

Errors are :class:`DriveRecordError` (a ``ValueError``) naming the file, column and row (data
rows counted from 1); :class:`ImplausibleDriveRecordError` for values outside their plausible
range, with the likely unit mix-up.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rulkit.model import FloatArray
from rulkit.systems.friction_drive.machine import DriveMachine
from rulkit.tables import did_you_mean, match_columns, numeric_columns, read_table, time_seconds

__all__ = ["COLUMNS", "DriveRecord", "DriveRecordError", "ImplausibleDriveRecordError",
           "drive_record", "read_drive_record"]

TIME, CURRENT, W1, W2 = "time_s", "current_A", "w1_rad_s", "w2_rad_s"
COLUMNS = (TIME, CURRENT, W1, W2)
_ALIASES = {TIME: ("t", "time", "timestamp", "t_s"), CURRENT: ("i", "current", "i_a", "amps"),
            W1: ("w1", "omega1", "motor_speed", "speed1"),
            W2: ("w2", "omega2", "wheel_speed", "speed2")}
#: Relative tolerance of a sampling step around a whole number of steps.
STEP_TOLERANCE = 0.01
#: A speed beyond this factor times the free-running speed at max_current is not physical.
SPEED_MARGIN = 1.5


class DriveRecordError(ValueError):
    """A drive record that cannot be used; the message names the file, column and row."""


class ImplausibleDriveRecordError(DriveRecordError):
    """A well-formed record with a value outside its plausible range (a unit or sensor
    error: time in ms, current in mA, speeds in rpm)."""


@dataclass(frozen=True)
class DriveRecord:
    """A checked record on its regular grid of ``n`` steps of ``dt`` seconds: ``row`` (n,) the
    file's data row of each grid step (0-based; -1 inside a gap), ``current`` (n,) the current
    held from each step to the next, ``speeds`` (n, 2) measured ``[w1, w2]`` (NaN: missing or
    inside a gap); ``n_rows`` rows read from ``source``."""

    dt: float
    row: NDArray[np.int64]
    current: FloatArray
    speeds: FloatArray
    source: str
    n_rows: int

    @property
    def t(self) -> FloatArray:
        """Seconds since the first sample on the grid, (n,)."""
        return np.arange(self.row.shape[0], dtype=np.float64) * self.dt

    @property
    def n_gap_steps(self) -> int:
        """Grid steps inside time gaps (no sample)."""
        return int(np.count_nonzero(self.row < 0))

    @property
    def n_missing(self) -> int:
        """Speed values missing in the file's rows (empty cells)."""
        return int(np.count_nonzero(np.isnan(self.speeds[self.row >= 0])))


def read_drive_record(path: str | Path, machine: DriveMachine) -> DriveRecord:
    """Read and check a drive record (``.csv``, ``.parquet``, ``.pq``) against ``machine``."""
    df = read_table(path, error=DriveRecordError, expected_columns=COLUMNS)
    return drive_record(df, machine, source=str(path))


def drive_record(df: Any, machine: DriveMachine, source: str = "") -> DriveRecord:
    """Check a frame with the columns of :data:`COLUMNS` (module docstring) and put it on its
    regular grid."""
    where = f"{source}: " if source else ""
    cols = match_columns(df.columns, COLUMNS, error=DriveRecordError, source=source)
    missing = [c for c in COLUMNS if c not in cols]
    if missing:
        raise DriveRecordError(
            f"{where}missing column(s) {', '.join(repr(m) for m in missing)}"
            + "".join(did_you_mean(m, df.columns, _ALIASES[m]) for m in missing)
            + f"; expected {', '.join(COLUMNS)}; found {', '.join(map(str, df.columns))}")
    if len(df) < 2:
        raise DriveRecordError(f"{where}need at least 2 rows, got {len(df)}")
    stamps = time_seconds(df[cols[TIME]], TIME, error=DriveRecordError, source=source,
                          since_first=True)
    if stamps is not None:
        df = df.assign(**{str(cols[TIME]): stamps})
    a = numeric_columns(df, {c: cols[c] for c in COLUMNS}, error=DriveRecordError,
                        source=source, missing_ok=(W1, W2))
    lim = machine.values["limits"]
    steps, dt = _grid_steps(a[TIME] - a[TIME][0], lim["max_gap_steps"], where)
    _check_plausible(a, dt, machine, where)
    k = np.concatenate([[0], np.cumsum(steps)])
    n = int(k[-1]) + 1
    row = np.full(n, -1, dtype=np.int64)
    row[k] = np.arange(k.size)
    held = np.maximum.accumulate(row)  # the last sample at or before each grid step
    speeds = np.full((n, 2), np.nan)
    speeds[k, 0], speeds[k, 1] = a[W1], a[W2]
    return DriveRecord(dt=dt, row=row, current=a[CURRENT][held], speeds=speeds, source=source,
                       n_rows=int(k.size))


def _grid_steps(t: FloatArray, max_gap: int, where: str) -> tuple[NDArray[np.int64], float]:
    """Whole steps between consecutive rows and the sampling step (least squares of
    ``t_i = k_i dt`` over all rows, so one jittered time does not set it)."""
    d = np.diff(t)
    if (d <= 0).any():
        i = int(np.flatnonzero(d <= 0)[0]) + 1
        kind = "repeated" if d[i - 1] == 0 else "decreasing"
        raise DriveRecordError(f"{where}column {TIME!r}, row {i + 1}: {kind} time "
                               "(time must increase strictly)")
    dt0 = float(np.median(d))
    steps = np.rint(d / dt0)
    off = np.abs(d - steps * dt0) > STEP_TOLERANCE * dt0
    if off.any():
        i = int(np.flatnonzero(off)[0]) + 1
        raise DriveRecordError(
            f"{where}column {TIME!r}, row {i + 1}: step {d[i - 1]:.6g} s is not a whole number "
            f"of sampling steps ({dt0:.6g} s, the median step); sampling must be regular")
    if (steps > max_gap).any():
        i = int(np.flatnonzero(steps > max_gap)[0]) + 1
        raise DriveRecordError(
            f"{where}column {TIME!r}, row {i + 1}: a gap of {d[i - 1]:.6g} s "
            f"({int(steps[i - 1])} steps) is longer than max_gap_steps = {max_gap} of the "
            "machine file; split the record there")
    k = np.concatenate([[0.0], np.cumsum(steps)])
    return steps.astype(np.int64), float(np.dot(k, t) / np.dot(k, k))


def _check_plausible(a: dict[str, FloatArray], dt: float, machine: DriveMachine,
                     where: str) -> None:
    """Refuse a sampling step, a current or a speed outside the machine's plausible range."""
    lim, p = machine.values["limits"], machine.params
    if not lim["min_step"] <= dt <= lim["max_step"]:
        raise ImplausibleDriveRecordError(
            f"{where}column {TIME!r}: sampling step {dt:.6g} s is outside the plausible "
            f"[{lim['min_step']:g}, {lim['max_step']:g}] s of the machine file; "
            + ("time in ms? (s = ms / 1000)" if dt > lim["max_step"] else
               "time in another unit than seconds?"))
    w1_max = SPEED_MARGIN * p.Km * lim["max_current"] / p.B1
    sig = machine.values["sensors"]
    checks = ((CURRENT, lim["max_current"], "A", "the plausible max_current",
               "current in mA? (A = mA / 1000)"),
              (W1, w1_max + 6.0 * sig["sigma_w1"], "rad/s",
               f"{SPEED_MARGIN:g} x the free-running speed Km max_current / B1",
               "speed in rpm? (rad/s = rpm / 9.549)"),
              (W2, w1_max * p.r1 / p.r2 + 6.0 * sig["sigma_w2"], "rad/s",
               "the wheel speed that limit allows (x r1 / r2)",
               "speed in rpm? (rad/s = rpm / 9.549)"))
    for col, limit, unit, what, hint in checks:
        bad = np.abs(np.nan_to_num(a[col], nan=0.0)) > limit
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ImplausibleDriveRecordError(
                f"{where}column {col!r}, row {i + 1}: {a[col][i]:.6g} {unit} is beyond "
                f"{what} ({limit:.4g} {unit}; {int(bad.sum())} such value(s)); {hint} Or "
                "check [drive] and [limits] in the machine file.")
