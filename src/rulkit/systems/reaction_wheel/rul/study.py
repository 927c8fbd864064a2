"""The Table 7 study of step 3 (docs/systems/reaction-wheel.md §5, §6): RUL distributions of
every step-2 method and scenario from the Table 6 snapshots, the prognostics metrics, and the
figures (RUL densities like thesis Fig 4.13, forecasts like seed 001 Figs 19 and 21).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rulkit.systems.reaction_wheel.lubrication import DAY_S, SCENARIOS, WINDOW_S
from rulkit.systems.reaction_wheel.rul.forecast import (
    FloatArray,
    Forecaster,
    RULConfig,
    expected_cumulative,
    failure_threshold,
)

#: Paper values, seed 001 Table 7 (RUL % error LB / UB / mean; scenario 1 | scenario 2).
PAPER_TABLE7: dict[str, tuple[float, ...]] = {
    "APF + two-step PF": (0.137, 0.552, 0.346, 0.308, 4.322, 2.343),
    "PF + two-step PF": (0.868, 2.088, 1.578, 0.428, 4.780, 2.453),
    "APF + one-step PF": (2.308, 8.561, 6.137, 6.675, 16.442, 11.602),
}


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
    from rulkit.systems.reaction_wheel.degradation.trackers import unit_rng

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

    ``table6`` a :class:`rulkit.systems.reaction_wheel.degradation.study.Table6Result` run with
    ``snapshot_windows=settings.prediction_windows(W)``. Table 7 at the prediction time closest
    to ``table7_day``: min / max / mean over runs of ``100 |RUL^ - RUL| / RUL``.
    """
    import pandas as pd

    from rulkit.systems.reaction_wheel.degradation.study import ROW_LABELS

    methods: list[MethodRUL] = []
    for case in table6.cases:
        sc = SCENARIOS[case.scenario_id]
        for meth, snaps in case.snapshots.items():
            if not snaps or (case.source, meth) not in ROW_LABELS:
                continue  # Table 7 keeps the rows of Table 6
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

    from rulkit.systems.reaction_wheel.degradation.study import ROW_LABELS, measurements

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
    from rulkit.systems.reaction_wheel.degradation.study import CaseTask

    return CaseTask(scenario_id, source, (case.runs[0],), table6.seed, table6.settings,
                    table6.errors[source])
