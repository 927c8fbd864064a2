"""The RUL estimator in force for a component database, behind one interface
(docs/systems/embedded-rul.md §6).

One posterior per component, one RUL: the point shown is the median of the distribution
whose quantiles give the interval, from the same estimator everywhere (status, API, dashboard,
alerts). Which estimator (:func:`estimator_in_force`):

* ``model``: a model fitted by ``rulkit fit`` (:mod:`rulkit.fleet.learned.degradation`), read
  through its per-unit state and ``rul_quantiles(state, levels)``: the default once fitted;
* ``trend``: the per-unit log-linear trend (:mod:`rulkit.fleet.monitoring.unit_trend`), the
  default without a fitted model;
* ``tracker``: the seed-004 tracker chain, only when chosen (its filtered RUL with limits
  around it, :func:`~rulkit.fleet.tracking.tracker_chain.tracker_rul_interval`; limits, not a
  probability interval, and labelled so).

:func:`hi_forecast` gives the HI each one forecasts to the threshold with its band (the
dashboard's chart).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rulkit.fleet.monitoring.rules import MonitoringRules
from rulkit.fleet.monitoring.unit_trend import (
    TrendConfig,
    TrendState,
    hi_quantiles,
    trend_posterior,
)
from rulkit.fleet.tracking.tracker_chain import TrackerConfig, tracker_hi_forecast

FloatArray = NDArray[np.float64]
KINDS = ("model", "trend", "tracker")


@dataclass(frozen=True)
class Estimator:
    """The estimator in force: ``kind`` (one of :data:`KINDS`), the database's rules, its
    tracker settings, the trend settings and the fitted model (``None`` without one)."""

    kind: str
    rules: MonitoringRules
    tracker: TrackerConfig
    trend: TrendConfig = field(default_factory=TrendConfig)
    model: Any = None

    @property
    def time_unit(self) -> str:
        """The data's time unit: the fitted model's, else the database's (may be empty)."""
        unit = getattr(self.model, "time_unit", "") if self.model is not None else ""
        return str(unit or self.rules.time_unit)

    @property
    def label(self) -> str:
        """What produced the RUL, in words (printed beside it)."""
        tail = 100.0 * 0.5 * (1.0 - self.rules.interval)
        q = f"median [{tail:g} %, {100 - tail:g} %]"
        if self.kind == "model":
            name = getattr(self.model, "name", getattr(self.model, "kind", ""))
            return f"fitted {name} model: {q}".replace("  ", " ")
        if self.kind == "trend":
            why = "chosen" if self.rules.estimator == "trend" else "no model fitted"
            return f"per-unit log-linear trend ({why}): {q}"
        return ("seed-004 tracker chain (chosen): filtered RUL [limits at HI +- "
                f"{self.tracker.hi_sigma:g}, load +- {100 * self.tracker.load_factor:g} %]")

    @property
    def warnings(self) -> tuple[str, ...]:
        """Warnings stored with the fitted model (empty without one)."""
        w = getattr(self.model, "warnings", ()) if self.model is not None else ()
        return tuple(str(x) for x in (w or ()))


def estimator_in_force(rules: MonitoringRules, tracker: TrackerConfig, model: Any = None,
                       trend: TrendConfig | None = None) -> Estimator:
    """``rules.estimator`` resolved: ``auto`` is the fitted model if there is one, else the
    trend."""
    kind = {"auto": "model" if model is not None else "trend", "trend": "trend",
            "tracker": "tracker"}[rules.estimator]
    return Estimator(kind=kind, rules=rules, tracker=tracker, trend=trend or TrendConfig(),
                     model=model if kind == "model" else None)


@dataclass(frozen=True)
class ComponentStates:
    """The states one component's forecast needs, for B components: the trend's, the fitted
    model's (its ``UnitState``, ``None`` without a model) and the tracker's fHI and fRUL."""

    trend: TrendState
    model: Any
    fhi: FloatArray
    frul: FloatArray


def _inverse_transform(kind: str, shape: float, z: FloatArray) -> FloatArray | None:
    """hi = g^-1(z) for the fitted model kinds of docs/fleet-models.md section 2."""
    if kind == "linear":
        return z
    if kind == "exponential":
        return shape + np.exp(z)
    if kind == "paris":
        if abs(shape) < 1e-12:
            return np.exp(z)
        base = 1.0 + shape * z
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            return np.where(base > 0, np.abs(base) ** (1.0 / shape),
                            0.0 if shape > 0 else np.inf)
    return None


def model_hi_quantiles(model: Any, state: Any, horizons: np.ndarray,
                       levels: tuple[float, ...]) -> tuple[FloatArray, ...] | None:
    """Quantiles of a fitted model's HI ``horizons`` (B, K) after the last acquisition: the
    transformed HI is Gaussian with mean m_z + m_b w and variance P_zz + 2 w P_zb + w^2 P_bb +
    sigma_w^2 w, w = r / tau (docs/fleet-models.md eq. (5)); mapped back through g. A model
    that offers ``hi_quantiles(state, horizons, levels)`` itself is asked; ``None`` for a
    model kind without a transformed-Gaussian state."""
    own = getattr(model, "hi_quantiles", None)
    if callable(own):
        return tuple(own(state, horizons, levels))
    if getattr(model, "kind", None) not in ("linear", "exponential", "paris"):
        return None
    from scipy.special import ndtri

    w = np.asarray(horizons, dtype=np.float64) / model.time_scale
    m, p = state.m, state.p
    mean = m[:, :1] + m[:, 1:] * w
    var = p[:, :1] + 2.0 * w * p[:, 1:2] + w * w * p[:, 2:] + model.walk_sd ** 2 * w
    sd = np.sqrt(np.maximum(var, 0.0))
    out = [_inverse_transform(model.kind, model.shape, mean + ndtri(q) * sd) for q in levels]
    return None if any(o is None for o in out) else tuple(np.asarray(o) for o in out)


def hi_forecast(est: Estimator, states: ComponentStates, horizons: np.ndarray
                ) -> tuple[FloatArray, ...] | None:
    """The HI forecast (median, low, high) ``horizons`` (B, K) after each component's last
    acquisition by the estimator in force, at the rules' interval (the band reaches HI = 1
    where the RUL interval lies); ``None`` when the estimator offers none."""
    median, lo, hi = est.rules.levels
    if est.kind == "tracker":
        return tracker_hi_forecast(states.fhi, states.frul, horizons, est.tracker)
    if est.kind == "trend":
        post = trend_posterior(states.trend, est.trend)
        med, upper, lower = hi_quantiles(post, horizons, (median, hi, lo))
        return med, lower, upper
    got = model_hi_quantiles(est.model, states.model, horizons, (median, lo, hi))
    return got


def forecast_horizons(median: FloatArray, low: FloatArray, high: FloatArray,
                      span: FloatArray, points: int = 48) -> FloatArray:
    """Horizons (B, ``points``) from 0 to the end of the RUL interval (its high end; twice
    the median, or ``span`` when that is infinite), for :func:`hi_forecast`."""
    end = np.where(np.isfinite(high), high, np.where(np.isfinite(median), 2.0 * median, span))
    end = np.where(np.isfinite(end) & (end > 0), end, np.maximum(span, 1.0))
    return np.asarray(end)[:, None] * np.linspace(0.0, 1.0, points)[None, :]


__all__ = [
    "KINDS",
    "ComponentStates",
    "Estimator",
    "estimator_in_force",
    "forecast_horizons",
    "hi_forecast",
    "model_hi_quantiles",
]
