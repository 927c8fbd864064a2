"""The tracker chain made safe: its settings estimated from histories and the time-unit check
of a record against the settings (docs/systems/embedded-rul.md sections 2-3).

The chain itself is :mod:`rulkit.fleet.tracking.tracker_chain`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rulkit.fleet.tracking.tracker_chain import TrackerConfig, track_series


def _quadratic_noise(t: np.ndarray, y: np.ndarray, start: np.ndarray) -> tuple[float, float]:
    """(sigma_v, sigma_w) of series: per unit a least-squares quadratic in t (units with >= 5
    points); sigma_v = the pooled residual standard deviation (degrees of freedom n - 3),
    sigma_w = the root mean square of the units' second derivatives 2 c_2 (the acceleration a
    constant-velocity tracker must follow: the white-acceleration process noise of
    docs/systems/embedded-rul.md §2)."""
    res2, dof, acc = 0.0, 0, []
    for u in range(start.size - 1):
        tt, yy = t[start[u]:start[u + 1]], y[start[u]:start[u + 1]]
        ok = np.isfinite(yy)
        tt, yy = tt[ok], yy[ok]
        if tt.size < 5:
            continue
        c = np.polyfit(tt - tt.mean(), yy, 2)
        r = yy - np.polyval(c, tt - tt.mean())
        res2 += float(r @ r)
        dof += tt.size - 3
        acc.append(2.0 * c[0])
    if dof == 0:
        raise ValueError("estimating tracker noise needs a unit with at least 5 acquisitions")
    return math.sqrt(res2 / dof), float(np.sqrt(np.mean(np.square(acc))))


def fit_tracker_config(hist: Any, **overrides: Any) -> TrackerConfig:
    """The safe chain with its settings estimated from histories (no guessed constants).

    ``hist``: :class:`rulkit.fleet.learned.histories.Histories`. All numbers are in the
    histories' time unit (see :class:`TrackerConfig`):

    * ``dt`` = the median acquisition interval;
    * HI: sigma_v (measurement) and sigma_w (acceleration) by per-unit quadratic fits
      (:func:`_quadratic_noise`), lambda_HI = sigma_w dt^2 / sigma_v (seed eq 12),
      ``hi_sigma`` = sigma_v (confidence limits);
    * RUL: the same estimate on the raw Paris RUL the HI tracker produces on the histories,
      lambda_RUL = sigma_w dt^2 / sigma_v (seed eq 16);
    * ``design_life`` = 100 x the longest observed life (the dHI floor is 1 % of the slowest
      full-life slope), ``warn_rul`` = 10 % of the median failure time, ``valid_d2rul`` =
      10 / median failure time (0.01 per hour for a 1000-hour life, the seed's value);
    * measured initiation and fRUL clipped at 0 (:meth:`TrackerConfig.safe`).

    ``overrides`` replace any field. Tracking indices are clipped to [1e-4, 1e3].
    """
    t, hi, start = hist.t, hist.hi, hist.start
    dts = np.concatenate([np.diff(t[start[u]:start[u + 1]]) for u in range(start.size - 1)])
    dt = float(np.median(dts)) if dts.size else 1.0
    life = hist.failure_time()
    t_last = t[start[1:] - 1]
    t_first = t[start[:-1]]
    longest = float(np.max(t_last - np.minimum(t_first, 0.0)))
    med_life = float(np.nanmedian(life)) if np.isfinite(life).any() else longest
    sv_hi, sw_hi = _quadratic_noise(t, hi, start)
    sv_hi = max(sv_hi, 1e-6)
    lam_hi = float(np.clip(max(sw_hi, 1e-12) * dt * dt / sv_hi, 1e-4, 1e3))
    base = TrackerConfig.safe(
        dt=dt, lambda_hi=lam_hi, lambda_rul=1.0, design_life=100.0 * max(longest, dt),
        hi_sigma=sv_hi, warn_rul=0.1 * med_life, valid_d2rul=10.0 / med_life,
    )
    # raw RUL along the histories under the HI tracker, then its noise
    raw = np.full(t.size, np.nan)
    for u in range(start.size - 1):
        s = slice(start[u], start[u + 1])
        h = track_series(t[s], hi[s][:, None], base)
        raw[s] = np.where(hi[s] < 1.0, h["rul"][:, 0], np.nan)
    try:
        sv_r, sw_r = _quadratic_noise(t, raw, start)
        lam_rul = float(np.clip(max(sw_r, 1e-12) * dt * dt / max(sv_r, 1e-12), 1e-4, 1e3))
    except ValueError:
        lam_rul = 1.0
    d = {**base.to_dict(), "lambda_rul": lam_rul, **overrides}
    return TrackerConfig.from_dict(d)


def check_time_unit(config: TrackerConfig, t: np.ndarray, *, max_floor_step: float = 0.01,
                    source: str = "acquisitions", assume_sorted: bool = False) -> None:
    """Reject a ``design_life`` that is not in the acquisitions' time unit.

    The dHI floor 1/design_life times the median acquisition interval is the HI the floor alone
    adds per acquisition; above ``max_floor_step`` (0.01: fewer than 100 acquisitions take a
    component from healthy to the alarm without any measured degradation) the settings cannot
    be meant for this time unit. Example: the default design_life = 1e5 (hours) with hourly
    acquisitions stamped in epoch seconds (3600 apart) adds 0.036 per acquisition: a false
    ALARM after ~28 hours. ``t`` are acquisition times (only positive differences used);
    ``assume_sorted``: they are already nondecreasing (the sort is skipped).
    """
    t = np.asarray(t, dtype=np.float64)
    d = np.diff(t if assume_sorted else np.sort(t))
    check_intervals(config, d[d > 0], max_floor_step=max_floor_step, source=source)


def check_intervals(config: TrackerConfig, d: np.ndarray, *, max_floor_step: float = 0.01,
                    source: str = "acquisitions") -> None:
    """:func:`check_time_unit` of the positive acquisition intervals ``d`` (in any order;
    reordered in place)."""
    if d.size == 0:
        return
    med = _median(d)
    step = med / config.design_life
    if step > max_floor_step:
        raise ValueError(
            f"{source}: acquisitions are {med:g} time units apart but "
            f"design_life = {config.design_life:g}: the no-healing floor 1/design_life alone "
            f"raises the HI by {step:.3g} per acquisition. design_life, dt, warn_rul and "
            "valid_d2rul are in the database's time unit: give them in that unit (or convert "
            "the time column)"
        )


def _median(d: np.ndarray) -> float:
    """``np.median`` of numbers without NaN (``d`` reordered in place): its partition and its
    mean of the two middle values, without the NaN check that imports ``numpy.ma``."""
    k = d.size // 2
    if d.size % 2:
        d.partition(k)
        return float(d[k])
    d.partition((k - 1, k))
    return float(np.mean(d[k - 1:k + 1]))


__all__ = ["check_intervals", "check_time_unit", "fit_tracker_config"]
