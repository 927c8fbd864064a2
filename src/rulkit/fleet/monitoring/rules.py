"""Alert rules an operator can act on, and the time units behind due dates
(docs/systems/embedded-rul.md §7, eqs. (EI-20)-(EI-23)).

Per acquisition, for all components at once (:func:`apply_rules`):

* **alarm** (EI-20): the *measured* HI reached ``alarm_hi`` in at least ``alarm_hits`` of the
  component's last ``alarm_window`` acquisitions (1 of 1 by default: every crossing; 2 of 3
  ignores a single spike). A component in alarm has failed: it stays in alarm (latched,
  ``failed_at`` the time the rule first held) and its RUL is 0 [0, 0];
* **warning** (EI-21): the RUL's lower quantile (the interval's low end) is below
  ``lead_time``, in the data's time unit;
* **ok** otherwise, also while the RUL is not estimated yet.

**Stale** (EI-22, :func:`stale`): no acquisition for ``stale_after`` seconds of calendar time,
judged when read. **Due date** (EI-23, :func:`due_time`): the calendar time of the last
acquisition plus the RUL median, when the time unit is a duration (s, min, h, d, w). The
calendar time of an acquisition (``seen``) is its own time when the file gave date-times
(seconds since 1970), else the time it was ingested.

The rules are stored in the database with the estimator choice (:class:`MonitoringRules`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rulkit.fleet.tracking.tracker_chain import LEVEL_ALARM, LEVEL_NONE, LEVEL_WARNING

FloatArray = NDArray[np.float64]
ESTIMATORS = ("auto", "trend", "tracker")
"""``auto``: the fitted model when there is one, else the trend; ``trend``: the per-unit trend
(:mod:`rulkit.fleet.monitoring.unit_trend`) even with a fitted model; ``tracker``: the seed-004
tracker chain (an explicit choice, labelled as such)."""
MAX_WINDOW = 16
"""Longest persistence window (the last 16 acquisitions' crossings are kept per component)."""
UNIT_SECONDS = {
    "s": 1.0, "sec": 1.0, "second": 1.0, "seconds": 1.0,
    "min": 60.0, "minute": 60.0, "minutes": 60.0,
    "h": 3600.0, "hr": 3600.0, "hour": 3600.0, "hours": 3600.0,
    "d": 86400.0, "day": 86400.0, "days": 86400.0,
    "w": 604800.0, "week": 604800.0, "weeks": 604800.0,
}
"""Time units that are durations (a due date needs one); others (cycles, km) have no
calendar."""


def unit_seconds(unit: str) -> float | None:
    """Seconds per time unit, or ``None`` when the unit is not a duration."""
    return UNIT_SECONDS.get(unit.strip().lower())


def parse_duration(text: str) -> float:
    """``"36h"``, ``"2d"``, ``"90min"``, ``"1w"`` or a number of seconds -> seconds
    (``ValueError`` naming what was expected)."""
    s = text.strip().lower()
    for unit in sorted(UNIT_SECONDS, key=len, reverse=True):
        if s.endswith(unit):
            number, scale = s[: -len(unit)].strip(), UNIT_SECONDS[unit]
            break
    else:
        number, scale = s, 1.0
    try:
        v = float(number) * scale
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"expected a positive duration such as 36h, 2d, 90min or 3600, got "
                         f"{text!r}")
    return v


@dataclass(frozen=True)
class MonitoringRules:
    """The estimator choice and the alert rules of a component database (module docstring).

    ``estimator``: one of :data:`ESTIMATORS`. ``time_unit``: the label of the time column's
    unit (printed with every RUL; a fitted model's own unit takes precedence). ``interval``:
    the central probability of the RUL interval (0.9: the 5 % and 95 % quantiles).
    ``alarm_hi``, ``alarm_hits`` of ``alarm_window``: the alarm rule (EI-20). ``lead_time``:
    the warning rule (EI-21), in the data's time unit. ``stale_after``: seconds of calendar
    time without an acquisition before a component is stale (``None``: never).
    """

    estimator: str = "auto"
    time_unit: str = ""
    interval: float = 0.90
    alarm_hi: float = 1.0
    alarm_hits: int = 1
    alarm_window: int = 1
    lead_time: float = 100.0
    stale_after: float | None = None

    def __post_init__(self) -> None:
        if self.estimator not in ESTIMATORS:
            raise ValueError(f"MonitoringRules.estimator: expected one of {ESTIMATORS}, got "
                             f"{self.estimator!r}")
        if not (0.0 < self.interval < 1.0):
            raise ValueError(f"MonitoringRules.interval: expected a probability in (0, 1), "
                             f"got {self.interval!r}")
        for name in ("alarm_hi", "lead_time"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (math.isfinite(v) and v >= 0):
                raise ValueError(f"MonitoringRules.{name}: expected a number >= 0, got {v!r}")
        k, n = self.alarm_hits, self.alarm_window
        if not (isinstance(k, int) and isinstance(n, int) and 1 <= k <= n <= MAX_WINDOW):
            raise ValueError(f"MonitoringRules: alarm persistence {k!r} of {n!r}: expected "
                             f"1 <= hits <= window <= {MAX_WINDOW}")
        if self.stale_after is not None and not (
                math.isfinite(self.stale_after) and self.stale_after > 0):
            raise ValueError(f"MonitoringRules.stale_after: expected seconds > 0 or None, got "
                             f"{self.stale_after!r}")

    @property
    def levels(self) -> tuple[float, float, float]:
        """The RUL quantiles shown: (median, low, high)."""
        tail = round(0.5 * (1.0 - self.interval), 12)  # 0.05, not 0.04999999999999999
        return 0.5, tail, 1.0 - tail

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> MonitoringRules:
        """Inverse of :meth:`to_dict` (unknown keys are an error)."""
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"MonitoringRules: unknown keys {sorted(unknown)}")
        return cls(**d)

    def alarm_text(self) -> str:
        """The alarm rule in words."""
        return f"measured HI >= {self.alarm_hi:g} in {self.alarm_hits} of the last " \
               f"{self.alarm_window} acquisition" + ("s" if self.alarm_window > 1 else "")

    def warning_text(self, unit: str = "") -> str:
        """The warning rule in words."""
        low = 100.0 * (0.5 * (1.0 - self.interval))
        return f"RUL {low:g} % quantile < lead time {self.lead_time:g}" + (
            f" {unit}" if unit else "")


@dataclass
class RuleState:
    """Per component: ``hits`` the crossings of its last :data:`MAX_WINDOW` acquisitions as
    bits (bit 0 the latest), ``failed_at`` the time the alarm rule first held (NaN: not
    failed), ``max_level`` the highest level reached (alerts are raised above it)."""

    hits: NDArray[np.int64]
    failed_at: FloatArray
    max_level: NDArray[np.int8]

    @classmethod
    def empty(cls, size: int) -> RuleState:
        """B components without an acquisition."""
        return cls(hits=np.zeros(size, dtype=np.int64), failed_at=np.full(size, np.nan),
                   max_level=np.zeros(size, dtype=np.int8))


@dataclass(frozen=True)
class RuleRows:
    """:func:`apply_rules` per row: ``level``, the RUL ``median, low, high`` (0 once failed),
    ``previous`` the highest level before the row (an alert where ``level > previous``)."""

    level: NDArray[np.int8]
    median: FloatArray
    low: FloatArray
    high: FloatArray
    previous: NDArray[np.int8]


def _window_counts(crossed: np.ndarray, seg: np.ndarray, hits0: np.ndarray, window: int
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Crossings among each row's last ``window`` acquisitions (its own included; earlier
    ones from the stored bits ``hits0``), and each component's bits after its last row."""
    m, b = crossed.size, seg.size - 1
    counts = np.diff(seg)
    unit = np.repeat(np.arange(b), counts)
    rank = np.arange(m) - seg[:-1][unit]
    cs = np.concatenate([[0], np.cumsum(crossed.astype(np.int64))])
    lo = np.maximum(np.arange(m) + 1 - window, seg[:-1][unit])
    in_batch = cs[np.arange(m) + 1] - cs[lo]
    older = np.maximum(window - rank - 1, 0)  # stored bits still inside the window
    mask = (np.int64(1) << older) - 1
    stored = hits0[unit] & mask
    n_stored = np.zeros(m, dtype=np.int64)
    for k in range(window):
        n_stored += (stored >> k) & 1
    batch = np.zeros(b, dtype=np.int64)  # bit j: the crossing of the j-th newest row
    for j in range(min(int(counts.max(initial=0)), MAX_WINDOW)):
        has = counts > j
        batch[has] |= crossed[seg[1:][has] - 1 - j].astype(np.int64) << j
    shift = np.minimum(counts, MAX_WINDOW)
    full = (np.int64(1) << MAX_WINDOW) - 1
    return in_batch + n_stored, ((hits0 << shift) | batch) & full


def apply_rules(rules: MonitoringRules, seg: np.ndarray, t: np.ndarray, hi: np.ndarray,
                median: np.ndarray, low: np.ndarray, high: np.ndarray, state: RuleState
                ) -> tuple[RuleState, RuleRows]:
    """The rules over the rows ``seg[c]:seg[c + 1]`` of each component c (in time order),
    with its RUL quantiles per row and its stored :class:`RuleState`. Returns the new state
    and the per-row :class:`RuleRows` (EI-20, EI-21)."""
    seg = np.asarray(seg, dtype=np.int64)
    m = t.size
    counts = np.diff(seg)
    unit = np.repeat(np.arange(seg.size - 1), counts)
    crossed = hi >= rules.alarm_hi
    n_hits, bits = _window_counts(crossed, seg, state.hits, rules.alarm_window)
    alarm_now = n_hits >= rules.alarm_hits
    # failed from the first row where the rule holds on (or before the batch)
    first = np.full(seg.size - 1, m, dtype=np.int64)
    np.minimum.at(first, unit[alarm_now], np.flatnonzero(alarm_now))
    failed = np.isfinite(state.failed_at)[unit] | (np.arange(m) >= first[unit])
    with np.errstate(invalid="ignore"):
        warn = np.isfinite(median) & (low < rules.lead_time)
    level = np.where(failed, LEVEL_ALARM, np.where(warn, LEVEL_WARNING, LEVEL_NONE)
                     ).astype(np.int8)
    zero = np.zeros(m)
    med, lo, hi_q = (np.where(failed, zero, v) for v in (median, low, high))
    # the highest level before each row: the stored maximum, then the running one
    run = np.maximum.accumulate(unit * 4 + level) - unit * 4
    previous = np.empty(m, dtype=np.int64)
    previous[1:] = run[:-1]
    previous[seg[:-1][counts > 0]] = -1
    previous = np.maximum(previous, state.max_level[unit])
    new_failed = np.where(np.isfinite(state.failed_at), state.failed_at,
                          np.where(first < m, t[np.minimum(first, m - 1)], np.nan))
    last = seg[1:] - 1
    max_level = np.where(counts > 0, np.maximum(state.max_level, run[np.maximum(last, 0)]),
                         state.max_level).astype(np.int8) if m else state.max_level
    return (RuleState(hits=bits, failed_at=new_failed, max_level=max_level),
            RuleRows(level=level, median=med, low=lo, high=hi_q,
                     previous=previous.astype(np.int8)))


def stale(seen: np.ndarray, now: float, rules: MonitoringRules) -> NDArray[np.bool_]:
    """Components whose last acquisition is more than ``stale_after`` seconds before ``now``
    (EI-22; both seconds since 1970); unknown ``seen`` (NaN) is not stale."""
    seen = np.asarray(seen, dtype=np.float64)
    if rules.stale_after is None:
        return np.zeros(seen.shape, dtype=bool)
    with np.errstate(invalid="ignore"):
        return (now - seen) > rules.stale_after


def due_time(seen: np.ndarray, median: np.ndarray, unit: str) -> FloatArray:
    """The calendar time (seconds since 1970) at which the RUL median runs out (EI-23):
    ``seen + median * seconds per unit``; NaN where the unit is not a duration, the median is
    unknown or infinite."""
    scale = unit_seconds(unit)
    seen = np.asarray(seen, dtype=np.float64)
    if scale is None:
        return np.full(seen.shape, np.nan)
    with np.errstate(invalid="ignore", over="ignore"):
        due = seen + np.asarray(median, dtype=np.float64) * scale
    return np.where(np.isfinite(due), due, np.nan)


__all__ = [
    "ESTIMATORS",
    "MAX_WINDOW",
    "UNIT_SECONDS",
    "MonitoringRules",
    "RuleRows",
    "RuleState",
    "apply_rules",
    "due_time",
    "parse_duration",
    "stale",
    "unit_seconds",
]
