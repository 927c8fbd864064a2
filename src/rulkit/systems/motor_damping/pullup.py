"""Reader and validator for a user's motor pull-up test data (seed 002 section 2).

File format (CSV or Parquet), one row per sample, columns (names case-insensitive, extra
columns ignored; two columns whose names differ only in case, such as ``speed`` and ``SPEED``,
are refused, and so are true/false values):

- ``cycle``: the life-test cycle the sample belongs to (integer-valued); the rows of a cycle are
  contiguous and cycles appear in increasing order;
- ``time`` [s]: strictly increasing within a cycle (it may restart at every cycle), or
  date-times (a Parquet timestamp column, ISO 8601 text); only the time since each cycle's
  first sample is used, so the time origin does not matter;
- ``current`` [A], ``speed`` [rad/s];
- ``acceleration`` [rad/s^2], optional. When it is missing it is derived from the speed by
  second-order central differences on the (possibly non-uniform) time grid
  (:func:`numpy.gradient`, one-sided at the ends of each cycle). The derived acceleration is a
  linear function of the speed samples, so it carries no information of its own and its noise is
  correlated with the speed noise; the micro EKF then uses the speed channel only.

Errors are :class:`PullupDataError` (a ``ValueError``) naming the column, the row (1-based data
row, header excluded) or the cycle, and what was expected. :func:`check_plausible` then refuses
values outside the machine file's plausible ranges (:class:`ImplausiblePullupError`: speed in
rpm, current in mA, time in ms).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from rulkit.tables import (
    did_you_mean,
    match_columns,
    numeric_columns,
    read_table,
    time_seconds,
)

FloatArray = NDArray[np.float64]

__all__ = [
    "ACCELERATION_DERIVED",
    "ACCELERATION_MEASURED",
    "MAX_MAGNITUDE",
    "REQUIRED_COLUMNS",
    "ImplausiblePullupError",
    "PullupData",
    "PullupDataError",
    "PullupLimits",
    "check_plausible",
    "estimate_noise_sd",
    "from_frame",
    "read_pullup",
]

REQUIRED_COLUMNS = ("cycle", "time", "current", "speed")
OPTIONAL_COLUMNS = ("acceleration",)
ACCELERATION_MEASURED = "measured (column 'acceleration')"
ACCELERATION_DERIVED = (
    "derived from speed by second-order central differences (numpy.gradient on each cycle's "
    "time grid, one-sided at the cycle ends); the micro EKF uses the speed channel only"
)


class PullupDataError(ValueError):
    """A pull-up data file that cannot be used, with the reason (column, row, cycle)."""


class ImplausiblePullupError(PullupDataError):
    """A well-formed pull-up record with a value outside its plausible range (a unit or sensor
    error: speed in rpm, current in mA, time in ms)."""


@dataclass(frozen=True)
class PullupData:
    """Validated pull-up data, cycles as rows of NaN-padded (n_cycles, T_max) arrays.

    ``cycle`` (n,) cycle numbers; ``n_samples`` (n,); ``time`` (relative to each cycle's first
    sample), ``current``, ``speed``, ``acceleration`` (n, T_max) with NaN after a cycle's last
    sample; ``acceleration_measured`` and ``acceleration_source`` (how it was obtained).
    """

    cycle: FloatArray
    n_samples: NDArray[np.int64]
    time: FloatArray
    current: FloatArray
    speed: FloatArray
    acceleration: FloatArray
    acceleration_measured: bool
    acceleration_source: str
    source: str = ""

    @property
    def n_cycles(self) -> int:
        """Number of pull-up cycles in the data."""
        return int(self.cycle.shape[0])


def read_pullup(path: str | Path, *, min_samples: int = 20) -> PullupData:
    """Read and validate a CSV (``.csv``, ``.txt``) or Parquet (``.parquet``, ``.pq``) file."""
    df = read_table(path, error=PullupDataError, csv_suffixes=(".csv", ".txt"),
                    expected_columns=REQUIRED_COLUMNS)
    return from_frame(df, source=str(path), min_samples=min_samples)


def from_frame(df, *, source: str = "", min_samples: int = 20) -> PullupData:
    """Validate a pandas DataFrame with the file's columns and build :class:`PullupData`."""
    where = f"{source}: " if source else ""
    if isinstance(min_samples, bool) or int(min_samples) != min_samples or min_samples < 3:
        raise ValueError(
            f"min_samples: expected an integer >= 3 (the derived acceleration needs 3 samples "
            f"per cycle), got {min_samples!r}"
        )
    cols = match_columns(df.columns, (*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS),
                         error=PullupDataError, source=source)
    missing = [c for c in REQUIRED_COLUMNS if c not in cols]
    if missing:
        raise PullupDataError(
            f"{where}missing column(s) {', '.join(missing)}"
            + "".join(did_you_mean(m, df.columns) for m in missing)
            + f"; expected columns {', '.join(REQUIRED_COLUMNS)} and optionally acceleration; "
            f"found {', '.join(map(str, df.columns)) or 'none'}"
        )
    if len(df) == 0:
        raise PullupDataError(f"{where}no data rows (header only)")
    has_acc = "acceleration" in cols
    names = list(REQUIRED_COLUMNS) + (["acceleration"] if has_acc else [])
    stamps = time_seconds(df[cols["time"]], "time", error=PullupDataError, source=source,
                          since_first=True)
    if stamps is not None:  # date-times: only differences are used
        df = df.assign(**{str(cols["time"]): stamps})
        cols["time"] = str(cols["time"])
    arrays = numeric_columns(df, {name: cols[name] for name in names}, error=PullupDataError,
                             source=source)
    cyc = arrays["cycle"]
    if np.any(cyc != np.round(cyc)):
        i = int(np.flatnonzero(cyc != np.round(cyc))[0])
        raise PullupDataError(f"{where}column 'cycle', row {i + 1}: {cyc[i]} is not an integer")
    back = np.flatnonzero(np.diff(cyc) < 0)
    if back.size:
        i = int(back[0]) + 1
        raise PullupDataError(
            f"{where}cycles out of order at row {i + 1}: cycle {cyc[i]:g} after cycle "
            f"{cyc[i - 1]:g}; rows must be grouped by cycle in increasing cycle order"
        )
    starts = np.flatnonzero(np.r_[True, np.diff(cyc) != 0])
    ends = np.r_[starts[1:], cyc.size]
    lengths = ends - starts
    t = arrays["time"]
    same = np.diff(cyc) == 0
    not_inc = np.flatnonzero(same & (np.diff(t) <= 0))
    if not_inc.size:
        i = int(not_inc[0]) + 1
        kind = "repeated" if t[i] == t[i - 1] else "decreasing"
        raise PullupDataError(
            f"{where}column 'time', row {i + 1} (cycle {cyc[i]:g}): time {t[i]:g} after "
            f"{t[i - 1]:g} ({kind}); time must increase strictly within a cycle"
        )
    short = np.flatnonzero(lengths < min_samples)
    if short.size:
        k = int(short[0])
        raise PullupDataError(
            f"{where}cycle {cyc[starts[k]]:g} (rows {starts[k] + 1}-{ends[k]}) has "
            f"{lengths[k]} sample(s); at least {min_samples} are needed to estimate its damping"
        )
    n = starts.size
    t_max = int(lengths.max())
    col_idx = np.arange(cyc.size) - np.repeat(starts, lengths)
    row_idx = np.repeat(np.arange(n), lengths)

    def pad(a: FloatArray) -> FloatArray:
        out = np.full((n, t_max), np.nan)
        out[row_idx, col_idx] = a
        return out

    time = pad(t - np.repeat(t[starts], lengths))
    speed = pad(arrays["speed"])
    current = pad(arrays["current"])
    if has_acc:
        acc = pad(arrays["acceleration"])
        src = ACCELERATION_MEASURED
    else:
        acc = np.full((n, t_max), np.nan)
        for k in range(n):  # one call per cycle (I/O path, not a filter loop)
            m = int(lengths[k])
            acc[k, :m] = np.gradient(speed[k, :m], time[k, :m], edge_order=2)
        src = ACCELERATION_DERIVED
    return PullupData(
        cycle=cyc[starts].copy(),
        n_samples=lengths.astype(np.int64),
        time=time,
        current=current,
        speed=speed,
        acceleration=acc,
        acceleration_measured=has_acc,
        acceleration_source=src,
        source=source,
    )


def estimate_noise_sd(signal: np.ndarray) -> float:
    """Robust white-noise sd of smooth signals (rows, NaN-padded) from second differences:
    ``d2 = x[k+1] - 2 x[k] + x[k-1]`` has variance ``6 sigma^2`` for white noise on a signal
    whose own second difference is negligible; ``sigma = 1.4826 MAD(d2) / sqrt(6)``."""
    x = np.atleast_2d(np.asarray(signal, dtype=np.float64))
    d2 = x[:, 2:] - 2.0 * x[:, 1:-1] + x[:, :-2]
    d2 = d2[np.isfinite(d2)]
    if d2.size == 0:
        raise ValueError("estimate_noise_sd: fewer than 3 finite samples")
    mad = np.median(np.abs(d2 - np.median(d2)))
    return float(1.4826 * mad / np.sqrt(6.0))



@dataclass(frozen=True)
class PullupLimits:
    """Plausible ranges of a pull-up record (the machine file's ``[limits]``,
    :mod:`rulkit.systems.motor_damping.machine`): a value outside them is refused as a unit or
    sensor error before any estimate is made."""

    max_speed: float = 1000.0
    max_current: float = 20.0
    max_step: float = 1.0
    min_step: float = 1e-5
    min_samples: int = 20


MAX_MAGNITUDE = 1e150
"""Largest accepted |acceleration|: the filters square the data, and float64 overflows above
~1.3e154 (speed and current have tighter, physical limits)."""


def check_plausible(data: PullupData, limits: PullupLimits) -> None:
    """Refuse a record with a value outside ``limits``: a speed beyond ``max_speed`` (rpm?), a
    current beyond ``max_current`` (mA?), a sampling step within a cycle outside
    ``[min_step, max_step]`` (ms?), an acceleration beyond :data:`MAX_MAGNITUDE`.
    :class:`ImplausiblePullupError` names the column, cycle and sample, the value, the limit
    and the likely unit mix-up."""
    step = np.diff(data.time, axis=1)
    checks = (
        ("speed", np.abs(data.speed), limits.max_speed, "rad/s",
         "speed in rpm? (rad/s = rpm / 9.549)"),
        ("current", np.abs(data.current), limits.max_current, "A",
         "current in mA? (A = mA / 1000)"),
        ("acceleration", np.abs(data.acceleration), MAX_MAGNITUDE, "rad/s^2",
         "beyond it float64 arithmetic overflows; check the unit"),
        ("time", step, limits.max_step, "s between samples", "time in ms? (s = ms / 1000)"),
    )
    for col, a, limit, unit, hint in checks:
        bad = np.nan_to_num(a, nan=-np.inf) > limit
        if bad.any():
            _implausible(data, col, a, bad, f"beyond the plausible {limit:g} {unit}", hint)
    small = np.nan_to_num(step, nan=np.inf) < limits.min_step
    if small.any():
        _implausible(data, "time", step, small, f"below the plausible {limits.min_step:g} s "
                     "between samples", "time in another unit than seconds?")


def _implausible(data: PullupData, col: str, a: FloatArray, bad: NDArray[np.bool_], what: str,
                 hint: str) -> None:
    k, j = (int(v[0]) for v in np.nonzero(bad))
    sample = j + 2 if col == "time" else j + 1  # a step ends at the next sample
    where = f"{data.source}: " if data.source else ""
    raise ImplausiblePullupError(
        f"{where}column {col!r}, cycle {data.cycle[k]:g}, sample {sample}: {a[k, j]:.6g} is "
        f"{what} ({int(bad.sum())} such value(s)); {hint} Or change [limits] in the machine "
        "file.")
