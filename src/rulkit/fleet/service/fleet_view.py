"""What the API and the dashboard read: one RUL per component, the counts per level, the HI
forecast (docs/service.md; docs/systems/embedded-rul.md §6-7).

Every reader takes a connection inside one read snapshot and the estimator in force
(:func:`rulkit.fleet.store.prognosis.current_estimator`), so the fleet table, a component's
page, its chart and the alerts list show the same RUL (the median and the interval of one
estimator) and the same level. Numbers that are not finite are ``null`` in JSON; ``rul_state``
says what a ``null`` RUL means (``pending``: too few acquisitions; ``failed``; ``estimated``:
then a ``null`` quantile is unbounded, it lies in the never-failing mass).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rulkit.fleet.monitoring.estimators import (
    ComponentStates,
    Estimator,
    forecast_horizons,
    hi_forecast,
)
from rulkit.fleet.monitoring.rules import due_time, stale, unit_seconds
from rulkit.fleet.monitoring.unit_trend import TrendState
from rulkit.fleet.store.prognosis import TREND_COLUMNS
from rulkit.fleet.tracking.tracker_chain import LEVEL_NAMES

FIELDS = ("component", "t", "n", "hi", "fhi", "frul", "valid", "level", "rul_median",
          "rul_low", "rul_high", "failed_at", "seen")
"""The ``components`` columns a component item is made of."""
LEVEL_CODES = {name: code for code, name in LEVEL_NAMES.items()}
_KEY = "COALESCE(rul_median, 1e308)"  # unknown RULs last; the indexed expression
ORDERS = {"worst": f"level DESC, {_KEY}, component", "rul": f"{_KEY}, component"}
SORTS = ("worst", "rul", "due")
INDEXES = (f"CREATE INDEX IF NOT EXISTS components_worst ON components (level DESC, {_KEY}, "
           "component)",
           f"CREATE INDEX IF NOT EXISTS components_rul ON components ({_KEY}, component)",
           "DROP INDEX IF EXISTS components_rank")
"""The indexes of the orders above (the same expressions; both dialects)."""


def num(v: Any) -> Any:
    """JSON-safe number: NaN, infinities and None become None."""
    if v is None:
        return None
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    f = float(v)
    return f if math.isfinite(f) else None


def _float(v: Any) -> float:
    return math.nan if v is None else float(v)


def component_item(row: tuple, est: Estimator, now: float) -> dict[str, Any]:
    """One component as the API returns it (a row of :data:`FIELDS`)."""
    d = dict(zip(FIELDS, row, strict=True))
    med, seen = _float(d["rul_median"]), _float(d["seen"])
    failed = d["failed_at"] is not None
    state = "failed" if failed else ("pending" if math.isnan(med) else "estimated")
    due = math.nan if failed else due_time(np.array([seen]), np.array([med]), est.time_unit)[0]
    return {"component": d["component"], "level": LEVEL_NAMES[int(d["level"])],
            "failed": failed, "failed_at": num(d["failed_at"]),
            "stale": bool(stale(np.array([seen]), now, est.rules)[0]),
            "rul_state": state, "rul": num(med), "rul_low": num(d["rul_low"]),
            "rul_high": num(d["rul_high"]), "due": num(due), "hi": num(d["hi"]),
            "fhi": num(d["fhi"]), "last_time": num(d["t"]), "last_seen": num(d["seen"]),
            "n": int(d["n"])}


def _where(level: str | None, est: Estimator, now: float) -> tuple[str, list[Any]]:
    if level is None:
        return "", []
    if level == "stale":
        after = est.rules.stale_after
        if after is None:
            return " WHERE 1 = 0", []
        return " WHERE seen < ?", [now - after]
    return " WHERE level = ?", [LEVEL_CODES[level]]


def _order(sort: str, est: Estimator) -> str:
    if sort != "due":
        return ORDERS[sort]
    scale = unit_seconds(est.time_unit)
    if scale is None:  # no calendar: no due dates, the id decides
        return "component"
    return f"COALESCE(seen + rul_median * {scale!r}, 1e308), component"


def list_components(conn: Any, est: Estimator, *, limit: int, offset: int,
                    level: str | None, sort: str, now: float
                    ) -> tuple[int, list[dict[str, Any]]]:
    """(total matching, one page in the order ``sort`` of :data:`SORTS`); ``level`` one of
    ok, warning, alarm or stale (``None``: all)."""
    where, params = _where(level, est, now)
    total = conn.execute(f"SELECT COUNT(*) FROM components{where}", params).fetchone()[0]
    rows = conn.execute(
        f"SELECT {', '.join(FIELDS)} FROM components{where} ORDER BY {_order(sort, est)} "
        "LIMIT ? OFFSET ?", [*params, limit, offset]).fetchall()
    return int(total), [component_item(r, est, now) for r in rows]


def summary(conn: Any, est: Estimator, now: float) -> dict[str, Any]:
    """Counts per level (and of stale components), what gives the RUL, the rules, the fitted
    model's warnings and the calendar time ``now`` the staleness is judged at."""
    counts = {name: 0 for name in LEVEL_NAMES.values()}
    for level, n in conn.execute("SELECT level, COUNT(*) FROM components GROUP BY level"):
        counts[LEVEL_NAMES[int(level)]] = int(n)
    where, params = _where("stale", est, now)
    counts["stale"] = int(conn.execute(f"SELECT COUNT(*) FROM components{where}",
                                       params).fetchone()[0])
    rules = est.rules
    return {"total": sum(counts[n] for n in LEVEL_NAMES.values()), "counts": counts,
            "estimator": est.kind, "estimator_label": est.label, "time_unit": est.time_unit,
            "calendar": unit_seconds(est.time_unit) is not None, "interval": rules.interval,
            "rules": {"alarm": rules.alarm_text(), "warning": rules.warning_text(est.time_unit),
                      "alarm_hi": rules.alarm_hi, "lead_time": rules.lead_time,
                      "stale_after": rules.stale_after},
            "model_warnings": list(est.warnings), "now": now}


def _states(conn: Any, est: Estimator, component: str, row: dict[str, Any]
            ) -> ComponentStates:
    """The one component's estimator states (trend sums, fitted model state, tracker)."""
    sums = conn.execute(f"SELECT {', '.join(TREND_COLUMNS)} FROM components WHERE "
                        "component = ?", (component,)).fetchone()
    trend = TrendState(t=np.array([_float(row["t"])]), hi=np.array([_float(row["hi"])]),
                       n=np.array([int(row["n"])]),
                       s=np.array([[_float(v) for v in sums]]))
    model = None
    if est.kind == "model":
        from rulkit.fleet.store.learned_state import model_states

        model = model_states(conn, est.model, [component])
    return ComponentStates(trend=trend, model=model, fhi=np.array([_float(row["fhi"])]),
                           frul=np.array([_float(row["frul"])]))


def forecast(conn: Any, est: Estimator, component: str, item: dict[str, Any],
             t_first: float) -> dict[str, Any] | None:
    """The HI forecast from the last acquisition to the end of the RUL interval: times, the
    median path and the band (``None`` once failed, while pending, or when the estimator
    offers none)."""
    if item["rul_state"] != "estimated":
        return None
    row = dict(zip(FIELDS, conn.execute(f"SELECT {', '.join(FIELDS)} FROM components WHERE "
                                        "component = ?", (component,)).fetchone(),
                   strict=True))
    states = _states(conn, est, component, row)
    t_last = _float(row["t"])
    span = np.array([max(t_last - t_first, 1.0)])
    hz = forecast_horizons(np.array([_float(row["rul_median"])]),
                           np.array([_float(row["rul_low"])]),
                           np.array([_float(row["rul_high"])]), span)
    got = hi_forecast(est, states, hz)
    if got is None:
        return None
    med, low, high = (np.asarray(g)[0] for g in got)
    return {"t": (t_last + hz[0]).tolist(), "hi": [num(v) for v in med],
            "hi_low": [num(v) for v in low], "hi_high": [num(v) for v in high]}


def time_origin(item: dict[str, Any], est: Estimator) -> float | None:
    """The calendar time (seconds since 1970) of t = 0 for this component, when its time unit
    is a duration and its last acquisition has a calendar time; ``None`` otherwise."""
    scale = unit_seconds(est.time_unit)
    if scale is None or item["last_seen"] is None or item["last_time"] is None:
        return None
    return float(item["last_seen"] - item["last_time"] * scale)


__all__ = ["FIELDS", "INDEXES", "ORDERS", "SORTS", "component_item", "forecast",
           "list_components", "num", "summary", "time_origin"]
