"""Reading and validating a user's reaction-wheel telemetry (CSV or Parquet) for step 1 of the
lubrication prognostics (docs/systems/reaction-wheel.md §3: T_lub from wheel speed and motor
current with the commanded voltage as input).

Required columns (SI units; extra columns are ignored):

=============== ====== ==========================================================
column          unit   meaning
=============== ====== ==========================================================
``time_s``      s      sample time, strictly increasing, regular sampling
``v_comm_V``    V      commanded (torque-command) voltage, ``|V| <= 5`` (Table 2)
``speed_rad_s`` rad/s  wheel speed, ``|w| <= 1000`` (larger looks like rpm)
``current_A``   A      motor current, ``|I| <= 5`` (larger looks like mA)
=============== ====== ==========================================================

Every problem raises :class:`TelemetryError` (a ``ValueError``) saying which column, which row
and what was expected. Rows are numbered from 0 over the data (for a CSV the file line is the
row + 2, the header being line 1); both are given in CSV messages.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from rulkit.tables import did_you_mean, numeric_columns, read_table

TIME, VOLT, SPEED, CURRENT = "time_s", "v_comm_V", "speed_rad_s", "current_A"
COLUMNS: tuple[str, ...] = (TIME, VOLT, SPEED, CURRENT)

#: Plausibility limits (absolute values) used to catch wrong units.
MAX_SPEED_RAD_S = 1000.0  # the overspeed threshold is 690 rad/s (Table 2)
MAX_CURRENT_A = 5.0  # G_d * 5 V = 0.95 A at full command
MAX_VOLTAGE_V = 5.0  # Table 2: input voltage 0-5 V

_ALIASES = {
    TIME: ("t", "time", "timestamp", "t_s", "time_sec", "seconds"),
    VOLT: ("v", "v_comm", "voltage", "vcomm", "v_cmd", "command_voltage", "u"),
    SPEED: ("w", "omega", "speed", "wheel_speed", "speed_rpm", "rpm", "omega_rad_s"),
    CURRENT: ("i", "i_m", "current", "motor_current", "current_ma", "im"),
}


#: Sampling steps the wheel model can be integrated with (RK4 on the driver pole w_d = 9
#: rad/s is unstable above ~0.3 s; below 1e-4 s the record is not wheel telemetry in seconds).
MIN_DT_S, MAX_DT_S = 1e-4, 0.25
#: Largest speed change per sample that is physics plus noise: |dw/dt| <= (K_t I_max +
#: tau_c) / J ~ 19 rad/s^2 at 5 A, so a jump above MAX_ACCEL dt + JUMP_SLACK is a splice.
MAX_ACCEL_RAD_S2 = 20.0
JUMP_SLACK_RAD_S = 1.0
#: Temperature is observable only through the viscous torque b_v(T) w: below this peak speed
#: the record carries no temperature information.
MIN_PEAK_SPEED_RAD_S = 0.5


class TelemetryError(ValueError):
    """A telemetry file or frame that cannot be used; the message names field and row."""


class ImplausibleTelemetryError(TelemetryError):
    """Well-formed telemetry that is not a physically possible wheel record (sampling step
    out of range, speed jumps no wheel can make, or no temperature information at all)."""


def _where(row: int, csv: bool) -> str:
    return f"row {row} (file line {row + 2})" if csv else f"row {row}"


def read_wheel_telemetry(path: str | Path, *, dt_tolerance: float = 0.01) -> Any:
    """Read and validate a wheel telemetry file (``.csv``, ``.parquet`` or ``.pq``).

    Returns a ``pandas.DataFrame`` with exactly the columns :data:`COLUMNS` (float64) and
    ``df.attrs["dt"]`` the sampling step. See :func:`validate_wheel_telemetry`.
    """
    df = read_table(path, error=TelemetryError, expected_columns=COLUMNS)
    return validate_wheel_telemetry(df, source=str(path), dt_tolerance=dt_tolerance,
                                    csv=df.attrs["format"] == "csv")


def validate_wheel_telemetry(
    df: Any, *, source: str = "telemetry", dt_tolerance: float = 0.01, csv: bool = False
) -> Any:
    """Validate a telemetry frame and return a clean float64 copy (columns :data:`COLUMNS`).

    Checks, in order: not empty; the four columns present (close names suggested); values
    numeric; no NaN/inf (first bad row); ``time_s`` strictly increasing (first repeated or
    decreasing row); regular sampling (every step within ``dt_tolerance`` (relative) of the
    median step; first offending row); plausible units (speed ``<= 1000`` rad/s, current
    ``<= 5`` A, ``|voltage| <= 5`` V; first offending row). At least 2 rows.
    """
    import pandas as pd

    if not isinstance(df, pd.DataFrame):
        raise TelemetryError(f"{source}: expected a pandas DataFrame, got {type(df).__name__}")
    if TIME in df.columns:
        df = _time_in_seconds(df, source)
    present = [str(c) for c in df.columns]
    missing = [c for c in COLUMNS if c not in present]
    if missing:
        msgs = [f"missing column {m!r}{did_you_mean(m, present, _ALIASES[m])}" for m in missing]
        raise TelemetryError(f"{source}: " + "; ".join(msgs) + f" (columns found: {present})")
    if len(df) == 0:
        raise TelemetryError(f"{source}: no data rows (header only)")
    if len(df) < 2:
        raise TelemetryError(f"{source}: need at least 2 rows, got {len(df)}")
    cols = numeric_columns(df, COLUMNS, error=TelemetryError, source=source,
                           row_label=lambda r: _where(r, csv))
    out = pd.DataFrame(cols, index=pd.RangeIndex(len(df)))
    t = out[TIME].to_numpy()
    d = np.diff(t)
    if (d == 0).any():
        r = int(np.flatnonzero(d == 0)[0]) + 1
        raise TelemetryError(
            f"{source}: column {TIME!r}, {_where(r, csv)}: repeated time {t[r]} (same as the "
            f"previous row)"
        )
    if (d < 0).any():
        r = int(np.flatnonzero(d < 0)[0]) + 1
        raise TelemetryError(
            f"{source}: column {TIME!r}, {_where(r, csv)}: time {t[r]} is before the previous "
            f"row's {t[r - 1]} (times must be sorted, strictly increasing)"
        )
    dt = float(np.median(d))
    if not dt_tolerance >= 0:
        raise ValueError(f"dt_tolerance: must be >= 0, got {dt_tolerance}")
    irregular = np.abs(d - dt) > dt_tolerance * dt
    if irregular.any():
        r = int(np.flatnonzero(irregular)[0]) + 1
        raise TelemetryError(
            f"{source}: column {TIME!r}, {_where(r, csv)}: step {d[r - 1]:.6g} s differs from "
            f"the median step {dt:.6g} s by more than {100 * dt_tolerance:g} % (irregular "
            f"sampling; resample to a fixed step first)"
        )
    checks = (
        (SPEED, MAX_SPEED_RAD_S, "rad/s", "looks like rpm? rad/s = rpm * 2 pi / 60"),
        (CURRENT, MAX_CURRENT_A, "A", "looks like mA? A = mA / 1000"),
        (VOLT, MAX_VOLTAGE_V, "V", "the wheel model's command range is 0-5 V (seed Table 2)"),
    )
    for c, lim, unit, hint in checks:
        v = np.abs(out[c].to_numpy())
        if (v > lim).any():
            r = int(np.flatnonzero(v > lim)[0])
            raise TelemetryError(
                f"{source}: column {c!r}, {_where(r, csv)}: |value| {v[r]:.6g} {unit} exceeds "
                f"{lim:g} {unit} ({hint})"
            )
    _check_physics(out, dt, source, csv)
    out.attrs["dt"] = dt
    out.attrs["source"] = source
    return out


def _time_in_seconds(df: Any, source: str) -> Any:
    """A datetime64 / timedelta64 ``time_s`` (Parquet timestamps) as float seconds (since the
    Unix epoch / of the duration), not nanoseconds taken for seconds."""
    import pandas as pd

    col = df[TIME]
    if isinstance(col, pd.DataFrame):
        raise TelemetryError(f"{source}: column {TIME!r} appears more than once")
    if pd.api.types.is_datetime64_any_dtype(col):
        if col.isna().any():
            r = int(np.flatnonzero(col.isna().to_numpy())[0])
            raise TelemetryError(f"{source}: column {TIME!r}, row {r}: missing timestamp (NaT)")
        ts = col.dt.tz_convert("UTC") if getattr(col.dt, "tz", None) is not None else col
        ns = ts.to_numpy(dtype="datetime64[ns]").astype(np.int64)
        sec = (ns // 1_000_000_000).astype(np.float64) + (ns % 1_000_000_000) * 1e-9
    elif pd.api.types.is_timedelta64_dtype(col):
        ns = col.to_numpy(dtype="timedelta64[ns]").astype(np.int64)
        sec = ns * 1e-9
    else:
        return df
    df = df.copy()
    df[TIME] = sec
    return df


def _check_physics(out: Any, dt: float, source: str, csv: bool) -> None:
    """Physical plausibility of a well-formed record (raises :class:`ImplausibleTelemetryError`)."""
    if not MIN_DT_S <= dt <= MAX_DT_S:
        raise ImplausibleTelemetryError(
            f"{source}: column {TIME!r}: sampling step {dt:.6g} s is outside "
            f"[{MIN_DT_S:g}, {MAX_DT_S:g}] s, the steps the wheel model can be integrated with "
            "(is time in seconds?)"
        )
    w = out[SPEED].to_numpy()
    jump = np.abs(np.diff(w)) > MAX_ACCEL_RAD_S2 * dt + JUMP_SLACK_RAD_S
    if jump.any():
        r = int(np.flatnonzero(jump)[0]) + 1
        raise ImplausibleTelemetryError(
            f"{source}: column {SPEED!r}, {_where(r, csv)}: speed jumps from {w[r - 1]:.6g} to "
            f"{w[r]:.6g} rad/s in one {dt:.6g} s step; no wheel accelerates that fast "
            f"(> {MAX_ACCEL_RAD_S2:g} rad/s^2): records spliced or tiled together? Give one "
            "continuous record"
        )
    if np.max(np.abs(w)) < MIN_PEAK_SPEED_RAD_S:
        raise ImplausibleTelemetryError(
            f"{source}: column {SPEED!r}: the wheel never exceeds {MIN_PEAK_SPEED_RAD_S:g} rad/s "
            "(all-zero or standing-still record); the lubricant temperature acts only through "
            "the viscous torque b_v(T) w, so this record carries no temperature information"
        )
