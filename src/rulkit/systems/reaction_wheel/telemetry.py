"""Reading and validating a user's reaction-wheel telemetry (CSV or Parquet) for step 1 of the
lubrication prognostics: T_lub from wheel speed and motor current with the commanded voltage as
input (docs/systems/reaction-wheel.md §3), a real record's defects (docs/systems/reaction-wheel.md
§3.4).

Required columns (SI units; extra columns are ignored; names are exact, and two columns whose
names differ only by case are refused as ambiguous):

=============== ====== ==========================================================
column          unit   meaning
=============== ====== ==========================================================
``time_s``      s      sample time, strictly increasing (seconds, or date-times)
``v_comm_V``    V      commanded (torque-command) voltage, ``|V| <= 5`` (Table 2)
``speed_rad_s`` rad/s  wheel speed, ``|w| <= 1000`` (larger looks like rpm)
``current_A``   A      motor current, ``|I| <= 5`` (larger looks like mA)
=============== ====== ==========================================================

Two modes. **Strict** (the particle filters, which step on a fixed grid): every cell a finite
number, regular sampling, no speed jump no wheel can make. **Lenient** (the robust EKF of
:mod:`rulkit.systems.reaction_wheel.temperature.ekf`, the default estimator): empty cells
(dropouts) are kept as NaN, gaps in time are allowed (any strictly increasing time), speed
jumps are left to the filter's outlier gate, and a rare value beyond the plausibility limits
(at most :data:`MAX_OUT_OF_RANGE_FRACTION` of a chunk) is kept as a missing cell; more, and the
column is refused with the likely unit mistake. Both modes refuse text, booleans, inf, an
unordered time, and a record without any speed.

Every problem raises :class:`TelemetryError` (a ``ValueError``) saying which column, which row
and what was expected. Rows are numbered from 0 over the data (for a CSV the file line is the
row + 2, the header being line 1); both are given in CSV messages.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rulkit.systems.reaction_wheel.wheel import simulate_table3
from rulkit.tables import did_you_mean, numeric_columns, read_table, read_table_chunks

TIME, VOLT, SPEED, CURRENT = "time_s", "v_comm_V", "speed_rad_s", "current_A"
COLUMNS: tuple[str, ...] = (TIME, VOLT, SPEED, CURRENT)

#: Plausibility limits (absolute values) of the seed wheel, used to catch wrong units; another
#: wheel's come from its wheel file (:class:`TelemetryLimits`).
MAX_SPEED_RAD_S = 1000.0  # the overspeed threshold is 690 rad/s (Table 2)
MAX_CURRENT_A = 5.0  # G_d * 5 V = 0.95 A at full command
MAX_VOLTAGE_V = 5.0  # Table 2: input voltage 0-5 V
#: Lenient mode: the largest fraction of a chunk's values of one column that may lie beyond
#: the plausibility limits (kept as missing); more means wrong units.
MAX_OUT_OF_RANGE_FRACTION = 0.01

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
#: The sampling step comes from the first DT_WINDOW steps (all of them in a shorter record):
#: the same step whether a record is read whole or in chunks (:func:`sampling_step`).
DT_WINDOW = 1000


class TelemetryError(ValueError):
    """A telemetry file or frame that cannot be used; the message names field and row."""


class ImplausibleTelemetryError(TelemetryError):
    """Well-formed telemetry that is not a physically possible wheel record (sampling step
    out of range, speed jumps no wheel can make, or no temperature information at all)."""


@dataclass(frozen=True)
class TelemetryLimits:
    """Largest plausible |speed| (rad/s), |current| (A) and |command| (V) of a wheel: a larger
    value means wrong units (rpm, mA) or a corrupted cell."""

    speed_rad_s: float = MAX_SPEED_RAD_S
    current_A: float = MAX_CURRENT_A
    voltage_V: float = MAX_VOLTAGE_V


def _where(row: int, csv: bool) -> str:
    return f"row {row} (file line {row + 2})" if csv else f"row {row}"


def read_wheel_telemetry(path: str | Path, *, dt_tolerance: float = 0.01, lenient: bool = False,
                         limits: TelemetryLimits | None = None) -> Any:
    """Read and validate a wheel telemetry file (``.csv``, ``.parquet`` or ``.pq``).

    Returns a ``pandas.DataFrame`` with exactly the columns :data:`COLUMNS` (float64) and
    ``df.attrs["dt"]`` the sampling step. See :func:`validate_wheel_telemetry`; for a record
    too large to hold at once, :func:`iter_wheel_telemetry`.
    """
    df = read_table(path, error=TelemetryError, expected_columns=COLUMNS)
    return validate_wheel_telemetry(df, source=str(path), dt_tolerance=dt_tolerance,
                                    csv=df.attrs["format"] == "csv", lenient=lenient,
                                    limits=limits)


def iter_wheel_telemetry(
    path: str | Path, *, chunk_rows: int = 200_000, dt_tolerance: float = 0.01,
    lenient: bool = False, limits: TelemetryLimits | None = None,
) -> Iterator[Any]:
    """Read and validate a wheel telemetry file ``chunk_rows`` rows at a time (memory bounded
    by the chunk): yields clean float64 frames (columns :data:`COLUMNS`, ``attrs`` ``"dt"``,
    ``"row0"`` the file row of the chunk's first row, ``"source"``, ``"n_out_of_range"``).

    The checks are those of :func:`validate_wheel_telemetry`, carried across chunks (a
    repeated, decreasing or irregular time, or a speed jump, at a chunk boundary is found as
    anywhere else); the first chunk is extended to hold the :data:`DT_WINDOW` steps that set
    the sampling step, so the step (and every estimate) does not depend on ``chunk_rows``. The
    no-information check (peak speed) needs the whole record and is made after the last chunk
    has been yielded, so a caller writing results as it goes must write them to a temporary
    file and keep it only when the iteration ends without an error.
    """
    import pandas as pd

    if chunk_rows < 2:
        raise ValueError(f"chunk_rows: expected >= 2, got {chunk_rows}")
    check: TelemetryCheck | None = None
    head: list[Any] = []  # the first chunks, until they hold the sampling-step window

    def start(first: Any) -> TelemetryCheck:
        return TelemetryCheck(str(path), first.attrs["format"] == "csv", dt_tolerance,
                              first.attrs["header"], lenient=lenient, limits=limits)

    for raw in read_table_chunks(path, COLUMNS, chunk_rows=chunk_rows, error=TelemetryError):
        if check is None:
            head.append(raw)
            if sum(len(h) for h in head) <= DT_WINDOW:
                continue
            check = start(head[0])
            yield check.chunk(pd.concat(head) if len(head) > 1 else head[0], 0)
            head = []
            continue
        yield check.chunk(raw, raw.attrs["row0"])
    if check is None and head:  # a record shorter than the window
        check = start(head[0])
        yield check.chunk(pd.concat(head) if len(head) > 1 else head[0], 0)
    if check is not None:
        check.finish()


def validate_wheel_telemetry(
    df: Any, *, source: str = "telemetry", dt_tolerance: float = 0.01, csv: bool = False,
    lenient: bool = False, limits: TelemetryLimits | None = None,
) -> Any:
    """Validate a telemetry frame and return a clean float64 copy (columns :data:`COLUMNS`).

    Checks, in order: not empty; the four columns present (close names suggested), no two
    names equal but for case; values numeric, not booleans; no NaN/inf (lenient: NaN kept
    outside ``time_s``); ``time_s`` strictly increasing (first repeated or decreasing row);
    regular sampling (strict: every step within ``dt_tolerance`` (relative) of the median of
    the first :data:`DT_WINDOW` steps; first offending row); plausible units (``limits``,
    default the seed wheel's: speed ``<= 1000`` rad/s, current ``<= 5`` A, ``|voltage| <= 5``
    V; first offending row; lenient: rare values beyond are kept as missing); physics
    (sampling step; strict: speed jumps; some speed at all: :class:`ImplausibleTelemetryError`).
    At least 2 rows.
    """
    import pandas as pd

    if not isinstance(df, pd.DataFrame):
        raise TelemetryError(f"{source}: expected a pandas DataFrame, got {type(df).__name__}")
    check = TelemetryCheck(source, csv, dt_tolerance, [str(c) for c in df.columns],
                           lenient=lenient, limits=limits)
    out = check.chunk(df, 0)
    check.finish()
    return out


class TelemetryCheck:
    """The checks of :func:`validate_wheel_telemetry` over a record given in one or more
    consecutive chunks (state: the last time and speed seen, the sampling step, the peak
    speed, the row count, the values kept as missing)."""

    def __init__(self, source: str, csv: bool, dt_tolerance: float, header: list[str], *,
                 lenient: bool = False, limits: TelemetryLimits | None = None) -> None:
        if not dt_tolerance >= 0:
            raise ValueError(f"dt_tolerance: must be >= 0, got {dt_tolerance}")
        self.source, self.csv, self.tol, self.lenient = source, csv, dt_tolerance, lenient
        self.limits = limits or TelemetryLimits()
        missing = [c for c in COLUMNS if c not in header]
        if missing:
            msgs = [f"missing column {m!r}{did_you_mean(m, header, _ALIASES[m])}"
                    for m in missing]
            raise TelemetryError(f"{source}: " + "; ".join(msgs) + f" (columns found: {header})")
        _refuse_case_collisions(header, source)
        self.dt: float | None = None
        self.last_t = self.last_w = np.nan
        self.peak = 0.0
        self.rows = 0
        self.n_out_of_range = 0

    def where(self, r: int) -> str:
        """How row ``r`` of the record is named in messages."""
        return _where(r, self.csv)

    def chunk(self, df: Any, row0: int) -> Any:
        """The clean float64 frame of rows ``row0 ..`` of the current file (the record may
        continue over several files, :attr:`source` naming the current one): ``attrs`` dt,
        ``row0`` (the record's row of the chunk's first row: rows count over every file),
        ``file_row0`` (``row0`` as given), ``source``, ``n_out_of_range``."""
        import pandas as pd

        src = self.source
        rec0 = self.rows
        if TIME in df.columns:
            df = _time_in_seconds(df, src)
        if len(df) == 0:
            raise TelemetryError(f"{src}: no data rows (header only)")
        if rec0 == 0 and len(df) < 2:
            raise TelemetryError(f"{src}: need at least 2 rows, got {len(df)}")
        _refuse_booleans(df, src, lambda r: self.where(row0 + r))
        if self.lenient:
            cols = _numbers_with_gaps(df, src, lambda r: self.where(row0 + r))
        else:
            try:
                cols = numeric_columns(df, COLUMNS, error=TelemetryError, source=src,
                                       row_label=lambda r: self.where(row0 + r))
            except TelemetryError as err:
                if "NaN (an empty" not in str(err):
                    raise
                raise TelemetryError(f"{err}; this method needs every cell, use the default "
                                     "method 'imm', which skips an empty cell's update") from None
        out = pd.DataFrame(cols, index=pd.RangeIndex(rec0, rec0 + len(df)))
        t = out[TIME].to_numpy()
        first = rec0 == 0  # the record's first chunk: nothing before it to compare with
        self._check_times(t, row0, first)
        self._check_units(out, row0)
        w = out[SPEED].to_numpy()
        if not self.lenient:
            at = row0 + (1 if first else 0)
            _check_jumps(w if first else np.concatenate([[self.last_w], w]),
                         float(self.dt or 0.0), src, lambda j: self.where(at + j - 1))
        finite = w[np.isfinite(w)]
        if finite.size:
            self.peak = max(self.peak, float(np.max(np.abs(finite))))
        self.last_t, self.last_w = float(t[-1]), float(w[-1])
        self.rows += len(out)
        out.attrs.update(dt=self.dt, source=src, row0=rec0, file_row0=row0,
                         n_out_of_range=self.n_out_of_range)
        return out

    def _check_times(self, t: Any, row0: int, first: bool) -> None:
        """Strictly increasing times (across chunks and files); the sampling step; (strict)
        regular steps."""
        src = self.source
        # steps from the previous chunk's last row on (d[j] ends at row row0 + j + first)
        d = np.diff(t) if first else np.diff(t, prepend=self.last_t)
        at = row0 + (1 if first else 0)  # the file row d[0] ends at
        tprev = t[:-1] if first else np.concatenate([[self.last_t], t[:-1]])
        if (d == 0).any():
            j = int(np.flatnonzero(d == 0)[0])
            raise TelemetryError(
                f"{src}: column {TIME!r}, {self.where(at + j)}: repeated time {tprev[j]} (same "
                "as the previous row)")
        if (d < 0).any():
            j = int(np.flatnonzero(d < 0)[0])
            raise TelemetryError(
                f"{src}: column {TIME!r}, {self.where(at + j)}: time {tprev[j] + d[j]} is "
                f"before the previous row's {tprev[j]} (times must be sorted, strictly "
                "increasing)")
        if self.dt is None:
            self.dt = sampling_step(d[:DT_WINDOW])
            _check_step(self.dt, src)
        dt = self.dt
        irregular = np.abs(d - dt) > self.tol * dt
        if irregular.any() and not self.lenient:
            j = int(np.flatnonzero(irregular)[0])
            raise TelemetryError(
                f"{src}: column {TIME!r}, {self.where(at + j)}: step {d[j]:.6g} s differs from "
                f"the median step {dt:.6g} s by more than {100 * self.tol:g} % (irregular "
                "sampling; resample to a fixed step first, or use the default method 'imm', "
                "which predicts over gaps)")

    def _check_units(self, out: Any, row0: int) -> None:
        """Values beyond the plausibility limits: refused (strict, or too many: wrong units)
        or kept as missing cells (lenient, rare)."""
        lim = self.limits
        checks = (
            (SPEED, lim.speed_rad_s, "rad/s", "looks like rpm? rad/s = rpm * 2 pi / 60"),
            (CURRENT, lim.current_A, "A", "looks like mA? A = mA / 1000"),
            (VOLT, lim.voltage_V, "V", f"the wheel's command range is 0-{lim.voltage_V:g} V "
                                       "(seed Table 2; wheel file [telemetry] max_voltage_V)"),
        )
        for c, limit, unit, hint in checks:
            v = np.abs(out[c].to_numpy())
            bad = v > limit  # NaN compares False
            if not bad.any():
                continue
            n_bad = int(bad.sum())
            if self.lenient and n_bad <= MAX_OUT_OF_RANGE_FRACTION * len(v):
                out.loc[out.index[bad], c] = np.nan
                self.n_out_of_range += n_bad
                continue
            r = int(np.flatnonzero(bad)[0])
            many = (f"; {n_bad} of {len(v)} values of this chunk are" if self.lenient else "")
            raise TelemetryError(
                f"{self.source}: column {c!r}, {self.where(row0 + r)}: |value| {v[r]:.6g} "
                f"{unit} exceeds {limit:g} {unit}{many} ({hint})")

    def state(self) -> dict[str, Any]:
        """What the checks carry between chunks (a checkpoint; :meth:`restore`)."""
        return {"dt": self.dt, "last_t": self.last_t, "last_w": self.last_w, "peak": self.peak,
                "rows": self.rows, "n_out_of_range": self.n_out_of_range}

    def restore(self, st: dict[str, Any]) -> None:
        """Continue the checks of a record from :meth:`state`."""
        self.dt = None if st["dt"] is None else float(st["dt"])
        self.last_t, self.last_w = float(st["last_t"]), float(st["last_w"])
        self.peak, self.rows = float(st["peak"]), int(st["rows"])
        self.n_out_of_range = int(st["n_out_of_range"])

    def finish(self) -> None:
        """The checks that need the whole record (raises :class:`TelemetryError`)."""
        if self.rows == 0:
            raise TelemetryError(f"{self.source}: no data rows (header only)")
        if self.peak < MIN_PEAK_SPEED_RAD_S:
            raise ImplausibleTelemetryError(
                f"{self.source}: column {SPEED!r}: the wheel never exceeds "
                f"{MIN_PEAK_SPEED_RAD_S:g} rad/s (all-zero or standing-still record); the "
                "lubricant temperature acts only through the viscous torque b_v(T) w, so this "
                "record carries no temperature information")


def _refuse_case_collisions(header: list[str], source: str) -> None:
    """Two columns whose names differ only by case (``speed_rad_s`` and ``SPEED_RAD_S``): which
    one is meant is a guess, so neither is used."""
    seen: dict[str, str] = {}
    for name in header:
        key = name.strip().lower()
        if key in seen:
            raise TelemetryError(
                f"{source}: columns {seen[key]!r} and {name!r} differ only by case; which one "
                "holds the data is ambiguous: rename or drop one")
        seen[key] = name


def _refuse_booleans(df: Any, source: str, where: Any) -> None:
    """A column of true/false values (a Parquet boolean, or a CSV of True/False) is not a
    number, even though it would convert to 0/1."""
    import pandas as pd

    for c in COLUMNS:
        col = df[c]
        if pd.api.types.is_bool_dtype(col.dtype):
            raise TelemetryError(f"{source}: column {c!r}, {where(0)}: {col.iloc[0]!r} is a "
                                 "boolean (true/false), not a number")
        if col.dtype == object:
            isbool = col.map(lambda v: isinstance(v, bool | np.bool_)).to_numpy()
            if isbool.any():
                r = int(np.flatnonzero(isbool)[0])
                raise TelemetryError(f"{source}: column {c!r}, {where(r)}: {col.iloc[r]!r} is "
                                     "a boolean (true/false), not a number")


def _numbers_with_gaps(df: Any, source: str, where: Any) -> dict[str, Any]:
    """Lenient coercion: every cell a number or empty (NaN, a dropout; not in ``time_s``);
    text and +-inf refused naming the column and row."""
    import pandas as pd

    out = {}
    for c in COLUMNS:
        col = df[c]
        num = pd.to_numeric(col, errors="coerce")
        text = (num.isna() & col.notna()).to_numpy()
        if text.any():
            r = int(np.flatnonzero(text)[0])
            raise TelemetryError(f"{source}: column {c!r}, {where(r)}: {col.iloc[r]!r} is not a "
                                 f"number ({int(text.sum())} non-numeric value(s) in this column)")
        a = np.array(num.to_numpy(dtype=np.float64), dtype=np.float64, copy=True)
        bad = np.isinf(a) | (np.isnan(a) if c == TIME else np.zeros(a.size, dtype=bool))
        if bad.any():
            r = int(np.flatnonzero(bad)[0])
            what = "an empty time" if np.isnan(a[r]) else f"{a[r]}"
            raise TelemetryError(f"{source}: column {c!r}, {where(r)}: {what} is not allowed "
                                 "(every row needs a finite time; other cells may be empty, "
                                 "never +-inf)")
        out[c] = a
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


def sampling_step(d: Any) -> float:
    """The sampling step from the first steps ``d`` of a record: the mean of the steps within
    1 % of their median. Epoch seconds (~1.7e9) hold a time only to 2.4e-7 s, so single steps
    are quantised; their mean is exact to ~1e-10 s, and the result does not depend on the time
    origin (the median alone would move the step by up to 5e-6 relative)."""
    med = float(np.median(d))
    near = d[np.abs(d - med) <= 0.01 * abs(med)]
    return float(near.mean()) if near.size else med


def _check_step(dt: float, source: str) -> None:
    """A sampling step the wheel model can integrate (:class:`ImplausibleTelemetryError`)."""
    if not MIN_DT_S <= dt <= MAX_DT_S:
        shown = f"{dt:.6g}"
        if shown in (f"{MIN_DT_S:g}", f"{MAX_DT_S:g}"):  # just outside: show every digit
            shown = repr(dt)
        raise ImplausibleTelemetryError(
            f"{source}: column {TIME!r}: sampling step {shown} s is outside "
            f"[{MIN_DT_S:g}, {MAX_DT_S:g}] s, the steps the wheel model can be integrated with "
            "(is time in seconds?)"
        )


def _check_jumps(w: Any, dt: float, source: str, where: Any) -> None:
    """No speed change between consecutive samples of ``w`` that no wheel can make;
    ``where(j)`` names the row of ``w[j]``."""
    jump = np.abs(np.diff(w)) > MAX_ACCEL_RAD_S2 * dt + JUMP_SLACK_RAD_S
    if jump.any():
        r = int(np.flatnonzero(jump)[0]) + 1
        raise ImplausibleTelemetryError(
            f"{source}: column {SPEED!r}, {where(r)}: speed jumps from {w[r - 1]:.6g} to "
            f"{w[r]:.6g} rad/s in one {dt:.6g} s step; no wheel accelerates that fast "
            f"(> {MAX_ACCEL_RAD_S2:g} rad/s^2): records spliced or tiled together? Give one "
            "continuous record, or use the default method 'imm', whose outlier gate takes "
            "such samples out"
        )


def table3_telemetry(
    rng: np.random.Generator, noise: str = "low", *, t_end: float = 500.0
) -> Any:
    """A simulated telemetry frame of the Table 3 path in the
    :mod:`rulkit.systems.reaction_wheel.telemetry`
    format (columns time_s, v_comm_V, speed_rad_s, current_A) plus the true ``T_lub_C``."""
    import pandas as pd

    d = simulate_table3(rng, noise, t_end=t_end)
    return pd.DataFrame(dict(zip(COLUMNS, (d.t, d.V, d.y[:, 0], d.y[:, 1]), strict=True))
                        | {"T_lub_C": d.T})
