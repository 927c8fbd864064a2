"""Step 3 of the reaction-wheel study: RUL under the two lubrication faults
(docs/systems/reaction-wheel.md §5, Table 7).

At a prediction time ``t_k`` (end of window k) every step-2 posterior particle ``[b, beta0]`` is
propagated along the assumed future temperature path (the scenario path, known [R]) with
:func:`rulkit.prognosis.rul.propagate_to_threshold`:

* scenario 1 (excessive loss): ``X^(t) = X_k + beta0 sum exp(-b/T_f) dt``; failure when
  ``X^`` reaches ``X_total`` (seed 001 eq. 35);
* scenario 2 (insufficient injection): ``HI(t) = X_healthy(t) - X^(t)`` (the printed eq. 36 has
  the sign reversed, docs/systems/reaction-wheel.md §5); failure when HI reaches ``X_bearing``.

The forecast advances over windows of ``forecast_window_h`` hours whose sums use the Gauss
quadrature of ``1/T_f`` within each window
(:func:`rulkit.systems.reaction_wheel.degradation.quadrature.path_quadrature`).
``X_total`` and ``X_bearing`` are not in the seeds [R]: they are set so that the expected truth
fails ``failure_day`` days after the start. The true RUL uses the true parameters from the same
measured ``X_k`` on the same path. Metrics: RUL % error (Table 7: min / max / mean over runs),
alpha-lambda, prognostic horizon and coverage of the stated interval (:mod:`rulkit.metrics`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rulkit.systems.reaction_wheel.degradation.quadrature import path_quadrature
from rulkit.systems.reaction_wheel.lubrication import DAY_S, PATHS, SAMPLE_DT, SCENARIOS, WINDOW_S

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class RULConfig:
    """Settings of the RUL prediction (step 3); every one is ours [R] (the seeds give none)."""

    failure_day: float = 60.0
    prediction_days: tuple[float, ...] = (2.0, 5.0, 10.0, 20.0, 30.0, 45.0)
    table7_day: float = 10.0
    forecast_window_h: float = 6.0
    forecast_horizon_days: float = 150.0
    interval_level: float = 0.9
    n_nodes: int = 5
    alpha_lambda_alpha: float = 0.2
    alpha_lambda_lambda: float = 0.5
    ph_alpha: float = 0.05

    def prediction_windows(self, n_windows: int) -> tuple[int, ...]:
        """Window indices k whose end ``(k+1) * 240 s`` is the prediction day (within horizon)."""
        ks = [round(d * DAY_S / WINDOW_S) - 1 for d in self.prediction_days]
        return tuple(k for k in ks if 0 <= k < n_windows and (k + 1) * WINDOW_S
                     < self.failure_day * DAY_S)


_GRID_S = 5.0  # resolution of the expected cumulative loss (thresholds, X_healthy) [R]


_CUM_CACHE: dict[tuple[int, bool, float], tuple[FloatArray, FloatArray]] = {}


def expected_cumulative(scenario_id: int, t: FloatArray, *, healthy: bool = False) -> FloatArray:
    """Expected cumulative loss ``int_0^t beta0(s) exp(-b(s)/T(s)) ds`` (mL) at times ``t``.

    Trapezoid rule on a 5 s grid of the scenario path (relative error ~1e-7: the orbit period is
    5,700 s; far below every other error), cached per process; ``healthy=True`` keeps the
    healthy parameters throughout (the ``X_healthy`` of scenario 2).
    """
    t = np.atleast_1d(np.asarray(t, dtype=np.float64))
    span = 30.0 * DAY_S  # grids cover whole multiples of 30 days
    key = (scenario_id, healthy, span * max(1.0, np.ceil(float(t.max()) / span)))
    if key not in _CUM_CACHE:
        grid = np.arange(0.0, key[2] + 2 * _GRID_S, _GRID_S)
        sc = SCENARIOS[scenario_id]
        if healthy:
            b, beta0 = np.full(grid.size, sc.b_healthy), np.full(grid.size, sc.beta0_healthy)
        else:
            b, beta0 = sc.parameters(grid)
        rate = beta0 * np.exp(-b / PATHS[scenario_id](grid))
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * _GRID_S)])
        _CUM_CACHE[key] = (grid, cum)
    grid, cum = _CUM_CACHE[key]
    return np.interp(t, grid, cum)


def failure_threshold(scenario_id: int, settings: RULConfig) -> float:
    """``X_total`` (scenario 1) or ``X_bearing`` (scenario 2) [R]: the expected indicator at
    ``failure_day`` on the scenario path with the true parameters."""
    t = np.array([settings.failure_day * DAY_S])
    if scenario_id == 1:
        return float(expected_cumulative(1, t)[0])
    return float(expected_cumulative(2, t, healthy=True)[0] - expected_cumulative(2, t)[0])


@dataclass(frozen=True)
class Forecaster:
    """Forecast machinery for one scenario from one prediction time ``t_k`` (s).

    ``quad`` the Gauss rule of ``1/T_f`` per forecast window; ``healthy_inc`` the healthy
    expected loss per window (scenario 2); ``threshold`` X_total or X_bearing.
    """

    scenario_id: int
    t_k: float
    window_s: float
    n_windows: int
    threshold: float
    quad: Any
    healthy_inc: FloatArray

    @classmethod
    def build(cls, scenario_id: int, t_k: float, settings: RULConfig) -> Forecaster:
        """Forecaster for ``(scenario, t_k)`` (cached: every method shares it)."""
        return _build_forecaster(scenario_id, float(t_k), settings)

    @classmethod
    def _build(cls, scenario_id: int, t_k: float, settings: RULConfig) -> Forecaster:
        window_s = settings.forecast_window_h * 3600.0
        n = int(np.ceil(settings.forecast_horizon_days * DAY_S / window_s))
        q = path_quadrature(PATHS[scenario_id], t_k, n, window_s, n_nodes=settings.n_nodes)
        sc = SCENARIOS[scenario_id]
        # healthy expected loss per window, all windows at once: sums over (n, 1) -> (n,)
        hinc = sc.beta0_healthy * q.sums(np.array([sc.b_healthy]), slice(None))[:, 0] * SAMPLE_DT
        return cls(scenario_id, t_k, window_s, n, failure_threshold(scenario_id, settings), q,
                   hinc)

    def increments(self, b: FloatArray, beta0: FloatArray, j: int) -> FloatArray:
        """Indicator increment of forecast window j for particles ``(b, beta0)``."""
        loss = beta0 * self.quad.sums(b, j) * SAMPLE_DT
        return loss if self.scenario_id == 1 else self.healthy_inc[j] - loss

    def initial_indicator(self, X_k: FloatArray) -> FloatArray:
        """Indicator at ``t_k`` from the measured cumulative loss: X_k, or X_healthy(t_k) - X_k."""
        if self.scenario_id == 1:
            return np.asarray(X_k, dtype=np.float64)
        xh = expected_cumulative(2, np.array([self.t_k]), healthy=True)[0]
        return xh - np.asarray(X_k, dtype=np.float64)

    def rul(self, b: FloatArray, beta0: FloatArray, indicator0: FloatArray,
            rng: np.random.Generator, weights: FloatArray | None = None) -> Any:
        """RUL distribution (days) of particles by ``propagate_to_threshold`` (engine)."""
        from rulkit.estimation.base import Posterior
        from rulkit.prognosis.rul import propagate_to_threshold

        x0 = np.column_stack([b, beta0, indicator0])

        def step(x: FloatArray, u: Any, t: float, dt: float, g: np.random.Generator
                 ) -> FloatArray:
            j = min(round(t / self.window_s), self.n_windows - 1)
            out = x.copy()
            out[:, 2] += self.increments(x[:, 0], x[:, 1], j)
            return out

        start = x0 if weights is None else Posterior.from_samples(x0, weights)
        return propagate_to_threshold(start, step, lambda x: x[:, 2], self.threshold, t0=0.0,
                                      dt=self.window_s, horizon=self.n_windows * self.window_s,
                                      rng=rng)

    def trajectories(self, b: FloatArray, beta0: FloatArray, indicator0: FloatArray
                     ) -> FloatArray:
        """Indicator at the end of every forecast window, (M, n_windows + 1): vectorised cumsum
        (an independent path to the same numbers, used for figures and to check ``rul``)."""
        inc = np.stack([self.increments(b, beta0, j) for j in range(self.n_windows)], axis=1)
        return np.concatenate([indicator0[:, None], indicator0[:, None]
                               + np.cumsum(inc, axis=1)], axis=1)


@functools.lru_cache(maxsize=64)
def _build_forecaster(scenario_id: int, t_k: float, settings: RULConfig) -> Forecaster:
    return Forecaster._build(scenario_id, t_k, settings)
