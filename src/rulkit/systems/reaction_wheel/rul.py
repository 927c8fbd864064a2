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
(:func:`rulkit.systems.reaction_wheel.lubrication.path_quadrature`).
``X_total`` and ``X_bearing`` are not in the seeds [R]: they are set so that the expected truth
fails ``failure_day`` days after the start. The true RUL uses the true parameters from the same
measured ``X_k`` on the same path. Metrics: RUL % error (Table 7: min / max / mean over runs),
alpha-lambda, prognostic horizon and coverage of the stated interval (:mod:`rulkit.metrics`).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rulkit.systems.reaction_wheel.lubrication import (
    DAY_S,
    PATHS,
    SAMPLE_DT,
    SCENARIOS,
    WINDOW_S,
    path_quadrature,
)

FloatArray = NDArray[np.float64]

#: Paper values, seed 001 Table 7 (RUL % error LB / UB / mean; scenario 1 | scenario 2).
PAPER_TABLE7: dict[str, tuple[float, ...]] = {
    "APF + two-step PF": (0.137, 0.552, 0.346, 0.308, 4.322, 2.343),
    "PF + two-step PF": (0.868, 2.088, 1.578, 0.428, 4.780, 2.453),
    "APF + one-step PF": (2.308, 8.561, 6.137, 6.675, 16.442, 11.602),
}


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


# ---------------------------------------------------------------------------------------------
# Expected truth and thresholds
# ---------------------------------------------------------------------------------------------

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


# ---------------------------------------------------------------------------------------------
# Forecast by the engine's propagate_to_threshold
# ---------------------------------------------------------------------------------------------


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


# ---------------------------------------------------------------------------------------------
# The Table 7 experiment
# ---------------------------------------------------------------------------------------------


@dataclass
class MethodRUL:
    """RUL predictions of one method (row label) in one scenario, per prediction time and run."""

    label: str
    scenario_id: int
    days: FloatArray  # prediction times (days)
    dists: list[list[Any]]  # [time][run] RULDistribution (days)
    truth: FloatArray  # (times, runs) true RUL (days)
    pred_mean: FloatArray  # (times, runs)
    lower: FloatArray
    upper: FloatArray
    metrics: dict[str, Any] = field(default_factory=dict)

    @property
    def abs_error_pct(self) -> FloatArray:
        """``100 |RUL^ - RUL| / RUL`` per (time, run) with RUL^ the posterior mean."""
        from rulkit.metrics import rul_percentage_error

        return np.abs(rul_percentage_error(self.pred_mean, self.truth))


def rul_for_method(scenario_id: int, label: str,
                   snapshots: dict[int, tuple[FloatArray, FloatArray]],
                   X_at: dict[int, FloatArray], settings: RULConfig, seed: int,
                   true_params: tuple[float, float]) -> MethodRUL:
    """RUL distributions of every run at every snapshot window, and the truth on the same path."""
    from rulkit.systems.reaction_wheel.degradation import unit_rng

    ks = sorted(snapshots)
    days = np.array([(k + 1) * WINDOW_S / DAY_S for k in ks])
    dists: list[list[Any]] = []
    rows_t, rows_m, rows_l, rows_h = [], [], [], []
    for ik, k in enumerate(ks):
        parts, w = snapshots[k]
        R, N, _ = parts.shape
        fc = Forecaster.build(scenario_id, (k + 1) * WINDOW_S, settings)
        ind0 = fc.initial_indicator(X_at[k])
        g = unit_rng(seed, "forecast", scenario_id, ik, 0)
        d_all = fc.rul(parts[..., 0].ravel(), parts[..., 1].ravel(), np.repeat(ind0, N), g)
        tr = fc.rul(np.full(R, true_params[0]), np.full(R, true_params[1]), ind0, g)
        from rulkit.prognosis.rul import RULDistribution

        per_run = []
        for r in range(R):
            sl = slice(r * N, (r + 1) * N)
            per_run.append(RULDistribution(d_all.samples[sl] / DAY_S, weights=w[r],
                                           censored=d_all.censored[sl],
                                           horizon=d_all.horizon / DAY_S))
        dists.append(per_run)
        rows_t.append(tr.samples / DAY_S)
        rows_m.append([d.mean for d in per_run])
        ivs = [d.interval(settings.interval_level) for d in per_run]
        rows_l.append([iv[0] for iv in ivs])
        rows_h.append([iv[1] for iv in ivs])
    truth, mean = np.array(rows_t), np.array(rows_m)
    lo, hi = np.array(rows_l), np.array(rows_h)
    out = MethodRUL(label, scenario_id, days, dists, truth, mean, lo, hi)
    out.metrics = prognostic_metrics(out, settings)
    return out


def prognostic_metrics(m: MethodRUL, settings: RULConfig) -> dict[str, Any]:
    """Alpha-lambda pass rate, prognostic horizon (median over runs) and interval coverage.

    Per run: ``t_EoL`` = median over prediction times of ``t_p + RUL_true`` (the truth differs
    between times only through the measurement noise in ``X_k``); alpha-lambda with
    ``alpha``, ``lambda`` of the settings and the distribution criterion (mass >= 0.5);
    prognostic horizon with absolute bounds ``+- ph_alpha t_EoL``; coverage = fraction of
    (time, run) pairs whose true RUL lies in the stated ``interval_level`` interval.
    """
    from rulkit.metrics import alpha_lambda, interval_coverage, prognostic_horizon

    R = m.truth.shape[1]
    al, ph = [], []
    for r in range(R):
        t_eol = float(np.median(m.days + m.truth[:, r]))
        ds = [m.dists[i][r] for i in range(len(m.days))]
        if len(m.days) >= 1 and t_eol > m.days[0]:
            try:
                al.append(alpha_lambda(m.days, ds, t_eol, alpha=settings.alpha_lambda_alpha,
                                       lam=settings.alpha_lambda_lambda).passed)
            except ValueError:
                al.append(False)
            res = prognostic_horizon(m.days, ds, t_eol, alpha=settings.ph_alpha)
            ph.append(res.horizon)
    cov = interval_coverage(m.lower.ravel(), m.upper.ravel(), m.truth.ravel())
    return {"alpha_lambda_pass_rate": float(np.mean(al)) if al else float("nan"),
            "prognostic_horizon_days_median": float(np.nanmedian(ph)) if ph and not
            np.all(np.isnan(ph)) else float("nan"),
            "interval_coverage": cov,
            "mean_abs_error_pct": float(m.abs_error_pct.mean())}


@dataclass
class Step3Result:
    """Table 7 (ours beside the paper's) and the per-method predictions behind it."""

    table: Any
    metrics: Any
    methods: list[MethodRUL]
    settings: RULConfig
    thresholds: dict[int, float]


def run_table7(table6: Any, settings: RULConfig) -> Step3Result:
    """RUL of every step-2 method and scenario from the Table 6 snapshots
    (docs/systems/reaction-wheel.md §5, docs/systems/reaction-wheel.md §6).

    ``table6`` a :class:`rulkit.systems.reaction_wheel.degradation_study.Table6Result` run with
    ``snapshot_windows=settings.prediction_windows(W)``. Table 7 at the prediction time closest
    to ``table7_day``: min / max / mean over runs of ``100 |RUL^ - RUL| / RUL``.
    """
    import pandas as pd

    from rulkit.systems.reaction_wheel.degradation_study import ROW_LABELS

    methods: list[MethodRUL] = []
    for case in table6.cases:
        sc = SCENARIOS[case.scenario_id]
        for meth, snaps in case.snapshots.items():
            if not snaps:
                continue
            label = ROW_LABELS[(case.source, meth)]
            methods.append(rul_for_method(case.scenario_id, label, snaps, case.X_at, settings,
                                          table6.seed, (sc.b_fault, sc.beta0_fault)))
    rows: dict[str, dict[str, Any]] = {}
    mrows = []
    for m in methods:
        i = int(np.argmin(np.abs(m.days - settings.table7_day)))
        err = m.abs_error_pct[i]
        row = rows.setdefault(m.label, {"method": m.label})
        s = m.scenario_id
        paper = PAPER_TABLE7.get(m.label)
        for j, (name, v) in enumerate((("LB", err.min()), ("UB", err.max()),
                                       ("mean", err.mean()))):
            row[f"S{s} {name} ours"] = float(v)
            row[f"S{s} {name} paper"] = paper[3 * (s - 1) + j] if paper else np.nan
        row[f"S{s} day"] = float(m.days[i])
        row[f"S{s} true RUL (d)"] = float(m.truth[i].mean())
        mrows.append({"scenario": s, "method": m.label, **m.metrics,
                      "prediction_days": " ".join(f"{d:g}" for d in m.days)})
    table = pd.DataFrame(list(rows.values()))
    table["runs"] = table6.n_runs
    table["seed"] = table6.seed
    thr = {s: failure_threshold(s, settings) for s in (1, 2)}
    return Step3Result(table, pd.DataFrame(mrows), methods, settings, thr)


# ---------------------------------------------------------------------------------------------
# Figures
# ---------------------------------------------------------------------------------------------


def plot_rul_densities(res: Step3Result, path: Any, *, run: int = 0) -> None:
    """RUL densities of every method at the Table 7 time, per scenario (like thesis Fig 4.13)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, s in zip(axes, (1, 2), strict=True):
        truth = None
        for m in (m for m in res.methods if m.scenario_id == s):
            i = int(np.argmin(np.abs(m.days - res.settings.table7_day)))
            d = m.dists[i][run]
            finite = d.samples[~d.censored] if d.censored is not None else d.samples
            if finite.size < 2:
                continue
            grid = np.linspace(max(0.0, finite.min() * 0.9), finite.max() * 1.1, 400)
            ax.plot(grid, d.pdf(grid), label=m.label)
            truth = m.truth[i, run]
            day = m.days[i]
        if truth is not None:
            ax.axvline(truth, color="k", ls="--", label="true RUL")
            ax.set_title(f"Scenario {s}: RUL pdf at day {day:g} (run {run})")
        ax.set_xlabel("RUL (days)")
        ax.set_ylabel("density")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_forecasts(res: Step3Result, table6: Any, scenario_id: int, path: Any, *,
                   run: int = 0, labels: Sequence[str] | None = None) -> None:
    """Measured indicator, forecast median and 90 % band per method, threshold and truth
    (like seed 001 Figs 19 and 21) at the Table 7 prediction time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from rulkit.systems.reaction_wheel.degradation_study import ROW_LABELS, measurements

    ms = [m for m in res.methods if m.scenario_id == scenario_id
          and (labels is None or m.label in labels)]
    if not ms:
        return
    ncol = min(3, len(ms))
    nrow = -(-len(ms) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.6 * ncol, 3.8 * nrow), squeeze=False)
    for ax in axes.ravel()[len(ms):]:
        ax.set_visible(False)
    sc = SCENARIOS[scenario_id]
    inv = {v: k for k, v in ROW_LABELS.items()}
    for ax, m in zip(axes.ravel()[:len(ms)], ms, strict=True):
        i = int(np.argmin(np.abs(m.days - res.settings.table7_day)))
        src, meth = inv[m.label]
        case = table6.case(scenario_id, src)
        k = sorted(case.snapshots[meth])[i]
        parts, w = case.snapshots[meth][k]
        fc = Forecaster.build(scenario_id, (k + 1) * WINDOW_S, res.settings)
        ind0 = fc.initial_indicator(case.X_at[k])
        rng = np.random.default_rng(run)
        pick = rng.choice(parts.shape[1], size=min(200, parts.shape[1]), p=w[run] / w[run].sum())
        tr = fc.trajectories(parts[run, pick, 0], parts[run, pick, 1], np.full(pick.size,
                                                                                ind0[run]))
        t_days = (fc.t_k + np.arange(fc.n_windows + 1) * fc.window_s) / DAY_S
        q = np.quantile(tr, [0.05, 0.5, 0.95], axis=0)
        ax.fill_between(t_days, q[0], q[2], alpha=0.3, label="90 % band")
        ax.plot(t_days, q[1], label="forecast median")
        true_tr = fc.trajectories(np.array([sc.b_fault]), np.array([sc.beta0_fault]),
                                  np.array([ind0[run]]))[0]
        ax.plot(t_days, true_tr, "k--", lw=1, label="truth (true parameters)")
        task_y, _ = measurements(_one_run_task(case, table6, scenario_id, src))
        X = np.cumsum(task_y[0, :k + 1])
        tw = (np.arange(k + 1) + 1) * WINDOW_S
        hist = X if scenario_id == 1 else expected_cumulative(2, tw, healthy=True) - X
        ax.plot(tw / DAY_S, hist, color="tab:green", label="measured")
        ax.axhline(fc.threshold, color="r", lw=1, label="threshold")
        ax.set_xlim(0, min(t_days[-1], res.settings.failure_day * 1.6))
        ax.set_title(m.label, fontsize=9)
        ax.set_xlabel("time (days)")
        ax.set_ylabel("cumulative loss X (mL)" if scenario_id == 1 else "HI = X_healthy - X (mL)")
        ax.legend(fontsize=6)
    fig.suptitle(f"Scenario {scenario_id}: forecast from day {m.days[i]:g} (run {run})")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _one_run_task(case: Any, table6: Any, scenario_id: int, source: str) -> Any:
    from rulkit.systems.reaction_wheel.degradation_study import CaseTask

    return CaseTask(scenario_id, source, (case.runs[0],), table6.seed, table6.settings,
                    table6.errors[source])
