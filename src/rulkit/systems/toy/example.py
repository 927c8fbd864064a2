"""End-to-end example on the 2-state toy degradation model (engine-api.md).

telemetry (simulated noisy damage) -> particle filter (posterior of [damage, rate]) ->
Monte Carlo propagation to the failure threshold -> RUL distributions at several prediction
times -> prognostic metrics (Saxena et al. 2010) against the true failure time.

The model is linear-Gaussian, so the exact Kalman filter is run beside the particle filter and
its posterior is reported next to the particle filter's (an oracle, not a tuning target).
The true end of life is the interpolated first crossing of damage = 1 by the simulated truth,
continued past the observation window with the same process noise.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rulkit.metrics import (
    alpha_lambda,
    crps_samples,
    cumulative_relative_accuracy,
    interval_coverage,
    prognostic_horizon,
    relative_accuracy,
)
from rulkit.prognosis.rul import RULDistribution, propagate_to_threshold
from rulkit.systems.toy.model import ToyDegradation

FloatArray = NDArray[np.float64]

__all__ = ["ToyConfig", "ToyResult", "plot_result", "run", "simulate_truth", "write_report"]


@dataclass(frozen=True)
class ToyConfig:
    """Settings of the example (all documented defaults; no hidden tuning).

    ``x0_true`` is the true initial state; the filter starts from independent normal priors
    ``prior_mean``/``prior_std`` per state. RUL is predicted at the step indices
    ``prediction_steps`` (times ``k dt``) with ``prognosis_dt`` steps up to ``horizon``.
    """

    n_steps: int = 60
    n_particles: int = 2000
    dt: float = 1.0
    sigma_d: float = 1e-3
    sigma_r: float = 1e-4
    sigma_y: float = 0.02
    x0_true: tuple[float, float] = (0.0, 0.012)
    prior_mean: tuple[float, float] = (0.0, 0.01)
    prior_std: tuple[float, float] = (0.02, 0.004)
    prediction_steps: tuple[int, ...] = (20, 30, 40, 50, 60)
    prognosis_dt: float = 1.0
    horizon: float = 400.0
    interval_level: float = 0.9
    alpha: float = 0.2
    lam: float = 0.5
    ph_alpha: float = 0.1
    seed: int = 0

    def model(self) -> ToyDegradation:
        """The toy degradation model with this configuration's noise levels and step."""
        return ToyDegradation(
            sigma_d=self.sigma_d, sigma_r=self.sigma_r, sigma_y=self.sigma_y, dt=self.dt
        )


@dataclass(frozen=True)
class ToyResult:
    """Everything the example produces, as arrays (convert to tables on request)."""

    config: ToyConfig
    t: FloatArray  # (T+1,) times of the true states
    x_true: FloatArray  # (T+1, 2)
    ys: FloatArray  # (T,) measurements of x_true[1:]
    t_eol: float  # true end of life
    pf_mean: FloatArray  # (T, 2)
    pf_std: FloatArray  # (T, 2)
    kf_mean: FloatArray  # (T, 2)
    kf_std: FloatArray  # (T, 2)
    prediction_times: FloatArray  # (P,)
    rul_true: FloatArray  # (P,)
    ruls: tuple[RULDistribution, ...]
    metrics: dict[str, Any] = field(default_factory=dict)

    def table(self) -> list[dict[str, float]]:
        """One row per prediction time: truth, mean, median, interval, censoring, RA, CRPS."""
        lvl = self.config.interval_level
        rows = []
        for tp, rt, d in zip(self.prediction_times, self.rul_true, self.ruls, strict=True):
            lo, hi = d.interval(lvl)
            rows.append(
                {
                    "t_pred": float(tp),
                    "rul_true": float(rt),
                    "rul_mean": d.mean,
                    "rul_median": d.median,
                    "lower": lo,
                    "upper": hi,
                    "fraction_censored": d.fraction_censored,
                    "relative_accuracy": float(relative_accuracy(d.median, rt)),
                    "crps": float(crps_samples(d.samples, rt, d.weights)),
                }
            )
        return rows


def simulate_truth(
    model: ToyDegradation, x0: FloatArray, n_steps: int, rng: np.random.Generator,
    max_steps: int = 100_000,
) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """Simulate the true unit: ``(t, X (n_steps+1, 2), ys (n_steps,), t_eol)``.

    The path is continued (same noise model) after the observed window until damage reaches 1;
    ``t_eol`` is the linearly interpolated crossing time (the convention of
    :func:`propagate_to_threshold`). Raises ``RuntimeError`` if no crossing occurs within
    ``max_steps`` steps.
    """
    t, xs, ys = model.simulate_units(np.asarray(x0, dtype=np.float64), n_steps, rng)
    x = xs[:, 0, :]
    d = x[:, 0]
    hit = np.flatnonzero(d >= model.threshold)
    dt = model.dt
    if hit.size:
        k = int(hit[0])
        if k == 0:
            return t, x, ys[:, 0, 0], 0.0
        frac = (model.threshold - d[k - 1]) / (d[k] - d[k - 1])
        return t, x, ys[:, 0, 0], float((k - 1 + frac) * dt)
    cur = x[-1:].copy()
    for k in range(n_steps, max_steps):
        nxt = model.step(cur, None, k * dt, dt, rng)
        if nxt[0, 0] >= model.threshold:
            frac = (model.threshold - cur[0, 0]) / (nxt[0, 0] - cur[0, 0])
            return t, x, ys[:, 0, 0], float((k + frac) * dt)
        cur = nxt
    raise RuntimeError(f"the true unit did not fail within {max_steps} steps")


def run(config: ToyConfig | None = None) -> ToyResult:
    """Run the example: simulate, filter (PF and exact KF), predict RUL, score it."""
    from rulkit.estimation.kalman import KalmanFilter
    from rulkit.estimation.particle import ParticleFilter

    cfg = ToyConfig() if config is None else config
    if any(not 1 <= k <= cfg.n_steps for k in cfg.prediction_steps):
        raise ValueError(f"prediction_steps: each must be in [1, n_steps={cfg.n_steps}]")
    model = cfg.model()
    ss = np.random.SeedSequence(cfg.seed)
    rng_truth, rng_pf, rng_prog = (np.random.default_rng(s) for s in ss.spawn(3))
    dt = cfg.dt

    t, x_true, ys, t_eol = simulate_truth(model, np.asarray(cfg.x0_true), cfg.n_steps, rng_truth)

    m0 = np.asarray(cfg.prior_mean, dtype=np.float64)
    s0 = np.asarray(cfg.prior_std, dtype=np.float64)
    particles0 = m0 + s0 * rng_pf.standard_normal((cfg.n_particles, 2))

    def transition(x: FloatArray, k: int, rng: np.random.Generator) -> FloatArray:
        return model.step(x, None, k * dt, dt, rng)

    def loglik(x: FloatArray, y: Any, k: int) -> FloatArray:
        return model.log_likelihood(x, y)

    pf = ParticleFilter(transition, loglik)
    res = pf.filter(ys[:, None], particles0, rng_pf, keep_particles=True, quantiles=None)
    pf_std = np.sqrt(np.einsum("tii->ti", res.cov))

    kf = KalmanFilter(
        F=model.transition_matrix(), H=model.observation_matrix(), Q=model.noise.Q,
        R=model.noise.R,
    )
    kres = kf.filter(ys[:, None, None], m0[None, :], np.diag(s0**2))
    kf_mean = kres.x[:, 0, :]
    kf_std = np.sqrt(np.einsum("tii->ti", kres.P[:, 0]))

    steps = [k for k in cfg.prediction_steps if k * dt < t_eol]
    ruls = [propagate_to_threshold(res.posterior(k - 1), model=model, t0=k * dt,
                                   dt=cfg.prognosis_dt, horizon=cfg.horizon, rng=rng_prog)
            for k in steps]
    tp = np.array([k * dt for k in steps], dtype=np.float64)
    rul_true = t_eol - tp

    result = ToyResult(
        config=cfg, t=t, x_true=x_true, ys=ys, t_eol=t_eol, pf_mean=res.mean, pf_std=pf_std,
        kf_mean=kf_mean, kf_std=kf_std, prediction_times=tp, rul_true=rul_true,
        ruls=tuple(ruls),
    )
    object.__setattr__(result, "metrics", _score(result))
    return result


def _score(r: ToyResult) -> dict[str, Any]:
    cfg = r.config
    if len(r.ruls) == 0:
        return {"note": "no prediction time before the true end of life"}
    medians = np.array([d.median for d in r.ruls])
    lows, highs = zip(*(d.interval(cfg.interval_level) for d in r.ruls), strict=True)
    out: dict[str, Any] = {
        "t_eol": r.t_eol,
        "cumulative_relative_accuracy": cumulative_relative_accuracy(medians, r.rul_true),
        f"coverage_{cfg.interval_level:g}": interval_coverage(
            np.array(lows), np.array(highs), r.rul_true
        ),
        "mean_crps": float(np.mean([crps_samples(d.samples, y, d.weights)
                                    for d, y in zip(r.ruls, r.rul_true, strict=True)])),
    }
    if len(r.ruls) >= 1 and r.t_eol > r.prediction_times[0]:
        al = alpha_lambda(r.prediction_times, list(r.ruls), r.t_eol, alpha=cfg.alpha,
                          lam=cfg.lam)
        out["alpha_lambda"] = {"alpha": cfg.alpha, "lambda": cfg.lam, "t_lambda": al.t_lambda,
                               "prob_mass": al.prob_mass, "passed": al.passed}
        ph = prognostic_horizon(r.prediction_times, list(r.ruls), r.t_eol, alpha=cfg.ph_alpha)
        out["prognostic_horizon"] = {"alpha": cfg.ph_alpha, "bounds": "absolute",
                                     "horizon": ph.horizon}
    # posterior agreement with the exact Kalman filter at the last step
    out["pf_vs_kf_last"] = {
        "pf_mean": r.pf_mean[-1].tolist(), "kf_mean": r.kf_mean[-1].tolist(),
        "pf_std": r.pf_std[-1].tolist(), "kf_std": r.kf_std[-1].tolist(),
    }
    return out


def plot_result(r: ToyResult, path: str | Path) -> Path:
    """Two panels: damage (truth, measurements, PF mean +- 2 sd, KF mean) and the RUL densities
    at the prediction times with the true RUL marked. Written with the Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    tt = r.t[1:]
    ax1.plot(r.t, r.x_true[:, 0], "k-", lw=1.5, label="true damage")
    ax1.plot(tt, r.ys, ".", color="0.6", ms=3, label="measurements")
    ax1.plot(tt, r.pf_mean[:, 0], "C0-", label="particle filter mean")
    ax1.fill_between(tt, r.pf_mean[:, 0] - 2 * r.pf_std[:, 0],
                     r.pf_mean[:, 0] + 2 * r.pf_std[:, 0], color="C0", alpha=0.25,
                     label="PF +- 2 sd")
    ax1.plot(tt, r.kf_mean[:, 0], "C3--", lw=1, label="exact Kalman filter mean")
    ax1.set_xlabel("time")
    ax1.set_ylabel("damage")
    ax1.legend(fontsize=8)
    ax1.set_title("State estimation")

    for i, (tp, rt, d) in enumerate(zip(r.prediction_times, r.rul_true, r.ruls, strict=True)):
        color = f"C{i % 10}"
        unc = d.samples[~np.asarray(d.censored, dtype=bool)]
        if unc.size >= 2 and np.ptp(unc) > 0:
            lo, hi = float(unc.min()), float(unc.max())
            pad = 0.1 * (hi - lo) + 1e-9
            grid = np.linspace(max(0.0, lo - pad), hi + pad, 300)
            ax2.plot(tp + grid, d.pdf(grid), color=color, label=f"RUL pdf at t={tp:g}")
        ax2.axvline(tp + rt, color=color, ls=":", lw=0.8)
    ax2.axvline(r.t_eol, color="k", lw=1.5, label=f"true end of life {r.t_eol:.1f}")
    ax2.set_xlabel("predicted failure time (t_pred + RUL)")
    ax2.set_ylabel("density")
    ax2.legend(fontsize=8)
    ax2.set_title("RUL distributions")
    fig.tight_layout()
    p = Path(path)
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p



def _json_safe(v: Any) -> Any:
    """Replace non-finite floats by None (strict JSON) recursively."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: _json_safe(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_json_safe(x) for x in v]
    return v


def write_report(result: ToyResult, out: str | Path) -> Path:
    """Write the example's outputs into ``out`` and return the path of ``report.md``.

    - ``rul.json``: the RUL distribution at the last prediction time
      (``RULDistribution.from_json`` reads it back);
    - ``summary.json``: configuration, one row per prediction time, metrics, file names;
    - ``toy_degradation.png``: state estimates and RUL densities (:func:`plot_result`);
    - ``report.md``: the per-prediction table (:func:`rulkit.reporting.markdown_table`).
    """
    import pandas as pd

    from rulkit.reporting import markdown_table

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = result.config
    rows = result.table()
    files: dict[str, str] = {}
    if result.ruls:
        files["rul"] = str(result.ruls[-1].to_json(out / "rul.json"))
    files["figure"] = str(plot_result(result, out / "toy_degradation.png"))
    files["summary"] = str(out / "summary.json")
    report = out / "report.md"
    files["report"] = str(report)
    summary = {"example": "toy_degradation", "seed": cfg.seed, "config": asdict(cfg),
               "rows": rows, "metrics": result.metrics, "files": files}
    (out / "summary.json").write_text(json.dumps(_json_safe(summary), indent=2, allow_nan=False))
    lines = [
        "# Toy degradation: particle filter and Monte Carlo RUL",
        "",
        f"Seed {cfg.seed}, {cfg.n_particles} particles; true end of life {result.t_eol:.4g}. "
        f"One row per prediction time ({cfg.interval_level:.0%} interval; RA = relative "
        "accuracy of the median, CRPS of the samples against the true RUL).",
        "",
        markdown_table(pd.DataFrame(rows)) if rows else
        "No prediction time before the true end of life.",
        "",
    ]
    report.write_text("\n".join(lines))
    return report
