"""Seed 002 reproduction: multi-scale EKF life prediction of a reaction-wheel motor.

Composes :mod:`rulkit.systems.motor_damping.motor` (physics, synthetic life test), the micro EKF
(:mod:`.micro`, seed eqs. 2-3), the macro EKF and RUL (:mod:`.macro`,
seed eqs. 4-7) and :mod:`rulkit.metrics` over many seeded runs (docs/systems/motor-damping.md §7).
:func:`run` returns the tables as data; :func:`rulkit.systems.motor_damping.report.write_report`
writes CSV tables, ``report.md`` (the seed's values beside ours) and figures like the seed's Figs.
8-17.

Scenarios (each over ``runs`` seeded runs; run r uses ``SeedSequence(seed).spawn(runs)[r]``):

- ``linear``: linear damping trend (c0 = 1e-5, a = 2e-6 / cycle, scatter sd 2e-6; EOL 68.5),
  macro EKF with the seed's linear law (q_a = 0), truth = trend crossing.
- ``linear-micro-var-only``: the same data, macro measurement variance = micro variance only.
- ``linear-first-crossing``: truth = first cycle whose noisy damping reaches c_fail; predictive
  intervals include the future scatter.
- ``accelerating``: c = c0 + a n + b n^2 (b = 2e-8; EOL 46.7) filtered with the linear law.
- ``accelerating-qa-ml``: the same data with a random-walk slope whose density q_a is chosen
  after every cycle by maximum marginal likelihood over a grid (``q_a_grid``).
- ``linear-qa-ml``: the linear data with that same adaptive q_a (what it costs when not needed).

A sweep over fixed q_a values (covariance method) shows the sensitivity (``qa_sweep`` table).

Macro model comparison (``macro_models`` table): the linear law (state [c, a]) against the
quadratic, constant-acceleration law (state [c, a, j], :mod:`.macro`) on BOTH the
linear and the accelerating data (same runs as above; the scenario of the configured
``macro.model`` is reused, the other model is run as ``<truth>-<model>-macro`` with its own Monte
Carlo generator ``SeedSequence([seed, 3])``, so adding it leaves every other number unchanged):
coverage of the 90 % intervals, alpha-lambda (alpha = 0.2), relative accuracy and median
interval width, over all prediction cycles and split into the first and second half of life.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from rulkit.systems.motor_damping.macro import (
    MACRO_MODELS,
    MacroSettings,
    MacroTrack,
    macro_track,
    rul_covariance_quantiles,
    rul_monte_carlo,
)
from rulkit.systems.motor_damping.micro import MicroEKFSettings, micro_ekf
from rulkit.systems.motor_damping.motor import (
    LifeTest,
    LifeTestConfig,
    MotorConstants,
    characteristic_curve_slope,
    damping_trend,
    failure_cycle,
    failure_damping,
    failure_damping_from_curves,
    simulate_life_test,
)

FloatArray = NDArray[np.float64]

__all__ = [
    "SEED_VALUES",
    "MotorDampingConfig",
    "MotorDampingResult",
    "ScenarioResult",
    "run",
]

# The seed's reported values (002, sections 4.2-4.3).
SEED_VALUES = {
    "slope_per_cycle": 2.67e-6,
    "c_fail": 0.000147,
    "curve_slope_at_failure": 0.1428,
    "n_cycles": 58,
}
LEVELS = np.array([0.05, 0.5, 0.95])


@dataclass(frozen=True)
class MotorDampingConfig:
    """Settings of the reproduction (defaults = the full run; :meth:`quick` for a short one).

    ``q_a_grid``: candidate slope random-walk densities for the ``*-qa-ml`` scenarios (sds
    0, 3e-8, 1e-7, 3e-7, 1e-6 per cycle; the choice is by marginal likelihood, not by the
    truth). ``qa_sweep_sd``: fixed sds of the sensitivity sweep. ``n_min``: first cycle with a
    RUL prediction (the scatter needs >= 1 residual degree of freedom). ``variant_runs``: runs
    for the micro-EKF variants table. ``chunk_runs``: runs per micro-EKF batch (memory).
    ``j_prior_sweep_sd``: curvature prior sds of the quadratic law's sensitivity sweep
    (covariance method; the accelerating truth has j = 2 * accel_curvature = 4e-8).
    """

    runs: int = 100
    seed: int = 0
    life: LifeTestConfig = field(default_factory=LifeTestConfig)
    accel_curvature: float = 2.0e-8
    micro: MicroEKFSettings = field(default_factory=MicroEKFSettings)
    macro: MacroSettings = field(default_factory=MacroSettings)
    q_a_grid: tuple[float, ...] = (0.0, 3e-8**2, 1e-7**2, 3e-7**2, 1e-6**2)
    qa_sweep_sd: tuple[float, ...] = (0.0, 5e-8, 1e-7, 2e-7, 4e-7)
    j_prior_sweep_sd: tuple[float, ...] = (1e-8, 3e-8, 1e-7, 3e-7, 1e-6)
    n_min: int = 3
    mc_samples: int = 400
    horizon: float = 300.0
    variant_runs: int = 10
    chunk_runs: int = 20
    prediction_cycles: tuple[int, ...] = (20, 40, 58)

    @classmethod
    def quick(cls, **kw: Any) -> MotorDampingConfig:
        """The ``--quick`` size: 20 runs, 100 Monte Carlo samples, 2 runs per micro variant."""
        base: dict[str, Any] = {"runs": 20, "mc_samples": 100, "variant_runs": 2}
        base.update(kw)
        return cls(**base)

    def __post_init__(self) -> None:
        if self.runs < 1:
            raise ValueError(f"runs: expected >= 1, got {self.runs}")
        if self.n_min < 3:
            raise ValueError(f"n_min: expected >= 3, got {self.n_min}")


def study_for_motor(consts: MotorConstants, life: LifeTestConfig | None = None,
                    accel_curvature: float = 2.0e-8) -> dict[str, Any]:
    """``MotorDampingConfig`` fields for another motor (a machine file): the life test of
    docs/systems/motor-damping.md §5 with its constants ``consts``, and the damping trend, its
    scatter and the accelerating scenario's curvature scaled by ``c_fail(consts) /
    c_fail(synthetic motor)`` (both at the design point, docs/systems/motor-damping.md §4),
    so the trend still crosses the failure damping at the same cycle and every scenario keeps
    its meaning (docs/systems/motor-damping.md §7)."""
    base = life or LifeTestConfig()
    ratio = failure_damping(consts) / failure_damping(base.consts)
    scaled = replace(base, consts=consts, c0=base.c0 * ratio, slope=base.slope * ratio,
                     scatter_sd=base.scatter_sd * ratio, curvature=base.curvature * ratio)
    return {"life": scaled, "accel_curvature": accel_curvature * ratio}


@dataclass
class ScenarioResult:
    """One scenario over all runs: cycles (n,), estimates ``z``/``r`` (R, n), true damping
    (R, n), the macro track, the RUL predictions at cycles ``pred_cycles`` (K,) -
    ``cov_q`` / ``mc_q`` (R, K, 3) quantiles (5 %, 50 %, 95 %), ``mc_mean`` (R, K) - the truth
    ``rul_true`` (R, K) (NaN after failure) and ``eol`` (R,), per-run metrics ``metrics``."""

    name: str
    cycles: FloatArray
    z: FloatArray
    r: FloatArray
    damping: FloatArray
    trend: FloatArray
    track: MacroTrack
    macro: MacroSettings
    pred_cycles: FloatArray
    cov_q: FloatArray
    mc_q: FloatArray
    mc_mean: FloatArray
    rul_true: FloatArray
    eol: FloatArray
    c_fail: float
    mc_run0: list[tuple[FloatArray, NDArray[np.bool_]]]
    metrics: dict[str, dict[str, FloatArray]]


@dataclass
class MotorDampingResult:
    """Everything the report needs: tables (pandas DataFrames), scenarios, run-0 life test.

    ``seeds`` holds the run indices r, not seeds: run r's generator is
    ``default_rng(SeedSequence(config.seed).spawn(runs)[r])`` (``config.seed + 1`` for the
    accelerating scenarios).
    """

    config: MotorDampingConfig
    tables: dict[str, Any]
    scenarios: dict[str, ScenarioResult]
    life_run0: LifeTest
    c_fail: float
    c_fail_from_curves: float
    curve_slopes_run0: FloatArray
    seeds: list[int]
    micro_history_run0: dict[str, Any]


# ---------------------------------------------------------------------------------------------
# simulation + micro EKF over runs
# ---------------------------------------------------------------------------------------------


def _run_rngs(seed: int, runs: int) -> list[np.random.Generator]:
    return [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(runs)]


def _simulate_and_estimate(
    life: LifeTestConfig,
    runs: int,
    seed: int,
    micro: MicroEKFSettings,
    chunk: int,
    *,
    est_consts: MotorConstants | None = None,
    future_cycles: int = 150,
) -> tuple[list[LifeTest], FloatArray, FloatArray, FloatArray]:
    """Simulate ``runs`` life tests and run the micro EKF on all cycles, ``chunk`` runs at a
    time. Returns the life tests, ``z`` and ``r`` (R, n) and the first-crossing cycle (R,)
    (future cycles' damping drawn from the run's generator after its signals)."""
    consts = est_consts or life.consts
    rngs = _run_rngs(seed, runs)
    tests: list[LifeTest] = []
    first = np.empty(runs)
    for i, rng in enumerate(rngs):
        lt = simulate_life_test(life, rng)
        tests.append(lt)
        n_f = np.arange(life.n_cycles + 1, life.n_cycles + 1 + future_cycles, dtype=np.float64)
        c_f = damping_trend(n_f, life.c0, life.slope, life.curvature)
        c_f = c_f + life.scatter_sd * rng.standard_normal(n_f.shape)
        c_all = np.concatenate([lt.damping, c_f])
        n_all = np.concatenate([lt.cycle, n_f])
        hit = np.flatnonzero(c_all >= lt.c_fail)
        first[i] = n_all[hit[0]] if hit.size else np.inf
    n = life.n_cycles
    z = np.empty((runs, n))
    r = np.empty((runs, n))
    for s0 in range(0, runs, chunk):
        part = tests[s0 : s0 + chunk]
        acc = None if not micro.use_acceleration else np.concatenate([t.acceleration for t in part])
        res = micro_ekf(
            part[0].time,
            np.concatenate([t.current for t in part]),
            np.concatenate([t.speed for t in part]),
            acc,
            consts,
            micro,
        )
        z[s0 : s0 + len(part)] = res.c.reshape(len(part), n)
        r[s0 : s0 + len(part)] = res.c_var.reshape(len(part), n)
    return tests, z, r, first


# ---------------------------------------------------------------------------------------------
# RUL over cycles + metrics
# ---------------------------------------------------------------------------------------------


def _rul_predictions(
    track: MacroTrack,
    macro: MacroSettings,
    c_fail: float,
    n_min: int,
    rng: np.random.Generator,
    *,
    first_crossing: bool,
    mc_samples: int,
    horizon: float,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, list]:
    """RUL quantiles from the covariance and by Monte Carlo after each cycle >= n_min."""
    cycles = track.cycles
    ks = np.flatnonzero(cycles >= n_min)
    do_mc = mc_samples > 0
    n_runs = track.x.shape[1]
    cov_q = np.empty((n_runs, ks.size, 3))
    mc_q = np.full((n_runs, ks.size, 3), np.nan)
    mc_mean = np.full((n_runs, ks.size), np.nan)
    run0: list = []
    for j, k in enumerate(ks):
        x, P, s2, qa = track.x[k], track.P[k], track.scatter_var[k], track.q_a[k]
        extra = s2 if first_crossing else 0.0
        cov_q[:, j] = rul_covariance_quantiles(
            x, P, c_fail, LEVELS, q_a=qa, extra_var=extra, horizon=horizon
        )
        if not do_mc:
            continue
        smp, cen = rul_monte_carlo(
            x, P, c_fail, rng, n_samples=mc_samples, q_a=qa,
            scatter_var=s2 if first_crossing else None, horizon=horizon, t0=float(cycles[k]),
        )
        keyed = np.where(cen, np.inf, smp)
        mc_q[:, j] = np.quantile(keyed, LEVELS, axis=1, method="inverted_cdf").T
        mc_mean[:, j] = smp.mean(axis=1)  # restricted mean (censored at the horizon)
        run0.append((smp[0].copy(), cen[0].copy()))
    return cycles[ks], cov_q, mc_q, mc_mean, run0


def _metrics(
    pred_cycles: FloatArray,
    q: FloatArray,
    rul_true: FloatArray,
    eol: FloatArray,
    horizon: float,
) -> dict[str, FloatArray]:
    """Per-run prognostic metrics of the median prediction (rulkit.metrics, Saxena et al.).

    A median beyond the prediction horizon (more than half the mass censored) enters the point
    metrics as the horizon itself (its lower bound); intervals keep their infinite bounds."""
    from rulkit.metrics import (
        alpha_lambda,
        interval_coverage,
        prognostic_horizon,
        relative_accuracy,
    )

    n_runs = q.shape[0]
    out: dict[str, list[float]] = {
        "alpha_lambda_0.25": [], "alpha_lambda_0.5": [], "alpha_lambda_0.75": [],
        "ph": [], "ra_0.5": [], "coverage_90": [], "coverage_90_late": [],
    }
    for i in range(n_runs):
        ok = np.isfinite(rul_true[i]) & (rul_true[i] > 0)
        t = pred_cycles[ok]
        med = np.minimum(q[i, ok, 1], horizon)
        for lam in (0.25, 0.5, 0.75):
            res = alpha_lambda(t, med, float(eol[i]), alpha=0.2, lam=lam)
            out[f"alpha_lambda_{lam}"].append(float(res.passed))
            if lam == 0.5:
                out["ra_0.5"].append(
                    float(np.asarray(relative_accuracy(np.array([res.rul_pred]),
                                                       np.array([res.rul_true])))[0])
                )
        # Saxena et al. 2010: PH = EOL - first time the prediction is within +- alpha EOL
        ph = prognostic_horizon(t, med, float(eol[i]), alpha=0.05, bounds="absolute")
        out["ph"].append(ph.horizon)
        out["coverage_90"].append(interval_coverage(q[i, ok, 0], q[i, ok, 2], rul_true[i, ok]))
        late = t >= 10
        out["coverage_90_late"].append(
            interval_coverage(q[i, ok, 0][late], q[i, ok, 2][late], rul_true[i, ok][late])
        )
    return {k: np.asarray(v, dtype=np.float64) for k, v in out.items()}


def _scenario(
    name: str,
    tests: list[LifeTest],
    z: FloatArray,
    r: FloatArray,
    first: FloatArray,
    macro: MacroSettings,
    cfg: MotorDampingConfig,
    rng: np.random.Generator,
    *,
    first_crossing: bool = False,
    monte_carlo: bool = True,
) -> ScenarioResult:
    cycles = tests[0].cycle
    c_fail = tests[0].c_fail
    track = macro_track(cycles, z, r, macro)
    pc, cov_q, mc_q, mc_mean, run0 = _rul_predictions(
        track, macro, c_fail, cfg.n_min, rng, first_crossing=first_crossing,
        mc_samples=cfg.mc_samples if monte_carlo else 0, horizon=cfg.horizon,
    )
    eol = first if first_crossing else np.array([t.eol for t in tests])
    rul_true = eol[:, None] - pc[None, :]
    rul_true = np.where(rul_true > 0, rul_true, np.nan)
    metrics = {"covariance": _metrics(pc, cov_q, rul_true, eol, cfg.horizon)}
    if monte_carlo:
        metrics["monte-carlo"] = _metrics(pc, mc_q, rul_true, eol, cfg.horizon)
    return ScenarioResult(
        name=name, cycles=cycles, z=z, r=r,
        damping=np.stack([t.damping for t in tests]), trend=tests[0].trend, track=track,
        macro=macro, pred_cycles=pc, cov_q=cov_q, mc_q=mc_q, mc_mean=mc_mean,
        rul_true=rul_true, eol=eol, c_fail=c_fail, mc_run0=run0, metrics=metrics,
    )


def _interval_width(q: FloatArray) -> FloatArray:
    """Width of the 90 % intervals (R, K); ``inf`` when the upper bound is beyond the horizon
    (both bounds beyond it give NaN from inf - inf: also ``inf``)."""
    with np.errstate(invalid="ignore"):
        w = q[..., 2] - q[..., 0]
    return np.where(np.isnan(w), np.inf, w)


def _model_comparison_rows(
    truth: str, model: str, sres: ScenarioResult, cfg: MotorDampingConfig
) -> list[dict[str, Any]]:
    """Rows of the ``macro_models`` table: one per RUL method, metrics over all prediction
    cycles and over the first / second half of life (prediction cycle < or >= EOL / 2)."""
    def over(fn: Any, values: np.ndarray) -> float:
        """``fn`` of the selected values; NaN (no prediction in that part of life) if empty."""
        return float(fn(values)) if values.size else np.nan

    rows = []
    for method, q in (("covariance", sres.cov_q), ("monte-carlo", sres.mc_q)):
        if method not in sres.metrics:
            continue
        m = sres.metrics[method]
        ok = np.isfinite(sres.rul_true)
        hit = (q[..., 0] <= sres.rul_true) & (sres.rul_true <= q[..., 2])
        early = ok & (sres.pred_cycles[None, :] < 0.5 * sres.eol[:, None])
        late = ok & ~early
        width = _interval_width(q)
        abs_err = np.abs(np.minimum(q[..., 1], cfg.horizon) - sres.rul_true)
        rows.append({
            "truth": truth, "macro_model": model, "method": method, "runs": cfg.runs,
            "coverage_90": m["coverage_90"].mean(),
            "coverage_90_first_half": over(np.mean, hit[early]),
            "coverage_90_second_half": over(np.mean, hit[late]),
            "alpha_lambda_pass_0.25": m["alpha_lambda_0.25"].mean(),
            "alpha_lambda_pass_0.5": m["alpha_lambda_0.5"].mean(),
            "alpha_lambda_pass_0.75": m["alpha_lambda_0.75"].mean(),
            "ra_0.5_median": float(np.median(m["ra_0.5"])),
            "median_abs_error_first_half": over(np.median, abs_err[early]),
            "median_abs_error_second_half": over(np.median, abs_err[late]),
            "median_width": over(np.median, width[ok]),
            "median_width_first_half": over(np.median, width[early]),
            "median_width_second_half": over(np.median, width[late]),
            "unbounded_fraction_first_half": over(np.mean, np.isinf(width[early])),
            "unbounded_fraction_second_half": over(np.mean, np.isinf(width[late])),
        })
    return rows


# ---------------------------------------------------------------------------------------------
# the experiment
# ---------------------------------------------------------------------------------------------


def _micro_variants(cfg: MotorDampingConfig) -> Any:
    """Micro-EKF error over cycles for the discretisations, channels and constant errors."""
    import pandas as pd

    life = cfg.life
    base = cfg.micro
    rows = []
    variants: list[tuple[str, LifeTestConfig, MicroEKFSettings, MotorConstants | None]] = [
        ("rk4, speed + measured acceleration (default)", life, base, None),
        ("rk4, speed only", life, replace(base, use_acceleration=False), None),
        ("seed eq. 3 (lagged Euler), speed + acceleration", life,
         replace(base, scheme="seed-euler"), None),
        ("rk4, acceleration by differencing speed, used as if independent",
         replace(life, acceleration="differenced"),
         replace(base, sigma_dw=life.sigma_w / (math.sqrt(2.0) * life.dt)), None),
        ("rk4, acceleration by differencing speed, speed channel only",
         replace(life, acceleration="differenced"), replace(base, use_acceleration=False), None),
        ("rk4, K known +1 %", life, base, life.consts.scaled(K=1.01)),
        ("rk4, J known +2 %", life, base, life.consts.scaled(J=1.02)),
        ("rk4, T_L known +10 %", life, base, life.consts.scaled(T_L=1.10)),
    ]
    for label, lcfg, mset, est in variants:
        tests, z, r, _ = _simulate_and_estimate(
            lcfg, cfg.variant_runs, cfg.seed, mset, cfg.chunk_runs, est_consts=est
        )
        truth = np.stack([t.damping for t in tests])
        e = z - truth
        sd = np.sqrt(r)
        rows.append({
            "variant": label,
            "runs": cfg.variant_runs,
            "cycles": e.size,
            "bias": e.mean(),
            "rmse": math.sqrt(np.mean(e**2)),
            "mean_stated_sd": sd.mean(),
            "nees_mean": np.mean(e**2 / r),
            "coverage_95": np.mean(np.abs(e) <= 1.96 * sd),
            "bias_in_cycles_of_slope": e.mean() / lcfg.slope,
        })
    return pd.DataFrame(rows)


class _Runs(NamedTuple):
    """Simulated life tests of one truth and their micro-EKF damping (see
    :func:`_simulate_and_estimate`)."""

    tests: list[LifeTest]
    z: FloatArray
    r: FloatArray
    first: FloatArray


def run(
    config: MotorDampingConfig | None = None, progress: Callable[[str], None] | None = None
) -> MotorDampingResult:
    """Run every scenario of the reproduction and return tables + data for the figures.

    ``progress``: optional callable ``progress(message)`` for the CLI. Draw order (and so
    every number) is fixed by the seed: the linear runs, then the accelerating runs, each
    from their own seed sequence; the macro-RUL Monte Carlo of the main scenarios from
    ``SeedSequence([seed, 2])``, that of the model comparison from ``SeedSequence([seed, 3])``.
    """
    cfg = config or MotorDampingConfig()
    say = progress or (lambda _m: None)
    rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, 2]))

    say("linear damping: simulate + micro EKF")
    linear = _Runs(*_simulate_and_estimate(
        cfg.life, cfg.runs, cfg.seed, cfg.micro, cfg.chunk_runs
    ))
    say("linear damping: macro EKF + RUL")
    scen = _linear_scenarios(linear, cfg, rng)
    say("accelerating damping: simulate + micro EKF + macro EKF")
    accel = _simulate_accelerating(cfg, linear.tests[0].c_fail)
    _add_adaptive_scenarios(scen, linear, accel, cfg, rng)
    say("macro model comparison: linear vs quadratic law on linear and accelerating truth")
    model_tab, jprior_tab = _macro_model_tables(scen, {"linear": linear, "accelerating": accel},
                                                cfg)
    say("q_a sensitivity sweep (covariance method)")
    sweep_tab = _qa_sweep_table({"linear": linear, "accelerating": accel}, cfg, rng)
    say("micro EKF variants")
    micro_tab = _micro_variants(cfg)

    lt0 = linear.tests[0]
    c_fail_curves, slopes, thr_tab = _threshold(lt0, linear.z[0], cfg)
    tables = {
        "micro_main": _micro_main_table(linear, cfg), "micro_variants": micro_tab,
        "slope": _slope_table(scen["linear"], cfg), "rul_metrics": _rul_metrics_table(scen, cfg),
        "qa_sweep": sweep_tab, "threshold": thr_tab, "macro_models": model_tab,
        "macro_j_prior_sweep": jprior_tab,
    }
    return MotorDampingResult(
        config=cfg, tables=tables, scenarios=scen, life_run0=lt0, c_fail=lt0.c_fail,
        c_fail_from_curves=c_fail_curves, curve_slopes_run0=slopes, seeds=list(range(cfg.runs)),
        micro_history_run0=_micro_history(lt0, cfg),
    )


def _linear_scenarios(
    linear: _Runs, cfg: MotorDampingConfig, rng: np.random.Generator
) -> dict[str, ScenarioResult]:
    """The seed's linear law on the linear truth: main, micro variance only, first crossing."""
    scen = {"linear": _scenario("linear", *linear, cfg.macro, cfg, rng)}
    scen["linear-micro-var-only"] = _scenario(
        "linear-micro-var-only", *linear, replace(cfg.macro, include_scatter=False), cfg, rng,
    )
    scen["linear-first-crossing"] = _scenario(
        "linear-first-crossing", *linear, cfg.macro, cfg, rng, first_crossing=True
    )
    return scen


def _simulate_accelerating(cfg: MotorDampingConfig, c_fail: float) -> _Runs:
    """Life tests with an accelerating trend (seed ``cfg.seed + 1``), up to its failure."""
    acc_life = replace(cfg.life, curvature=cfg.accel_curvature)
    eol_acc = failure_cycle(c_fail, acc_life.c0, acc_life.slope, acc_life.curvature)
    acc_life = replace(acc_life, n_cycles=math.floor(eol_acc))
    return _Runs(*_simulate_and_estimate(
        acc_life, cfg.runs, cfg.seed + 1, cfg.micro, cfg.chunk_runs
    ))


def _add_adaptive_scenarios(
    scen: dict[str, ScenarioResult], linear: _Runs, accel: _Runs, cfg: MotorDampingConfig,
    rng: np.random.Generator,
) -> None:
    """The accelerating truth under the linear law, then both truths with an ML-chosen q_a."""
    scen["accelerating"] = _scenario("accelerating", *accel, cfg.macro, cfg, rng)
    ml = replace(cfg.macro, q_a_grid=cfg.q_a_grid)
    scen["accelerating-qa-ml"] = _scenario("accelerating-qa-ml", *accel, ml, cfg, rng)
    scen["linear-qa-ml"] = _scenario("linear-qa-ml", *linear, ml, cfg, rng)


def _macro_model_tables(
    scen: dict[str, ScenarioResult], truths: dict[str, _Runs], cfg: MotorDampingConfig
) -> tuple[Any, Any]:
    """``macro_models`` (linear vs quadratic law on each truth; adds the scenarios it runs to
    ``scen``) and ``macro_j_prior_sweep`` (the quadratic law's curvature prior)."""
    import pandas as pd

    cmp_rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, 3]))
    model_rows: list[dict[str, Any]] = []
    jprior_rows: list[dict[str, Any]] = []
    for truth_name, data in truths.items():
        for model in MACRO_MODELS:
            if model == cfg.macro.model:
                sres = scen[truth_name]
            else:
                name = f"{truth_name}-{model}-macro"
                sres = _scenario(name, *data, replace(cfg.macro, model=model), cfg, cmp_rng)
                scen[name] = sres
            model_rows += _model_comparison_rows(truth_name, model, sres, cfg)
        for jsd in cfg.j_prior_sweep_sd:
            sres = _scenario(
                f"{truth_name}-quadratic-j{jsd:g}", *data,
                replace(cfg.macro, model="quadratic", j_prior_sd=jsd), cfg, cmp_rng,
                monte_carlo=False,
            )
            row = _model_comparison_rows(truth_name, "quadratic", sres, cfg)[0]
            jprior_rows.append({"j_prior_sd": jsd, **row})
    return pd.DataFrame(model_rows), pd.DataFrame(jprior_rows)


def _qa_sweep_table(
    truths: dict[str, _Runs], cfg: MotorDampingConfig, rng: np.random.Generator
) -> Any:
    """Covariance-method interval coverage and width for fixed slope random-walk sds."""
    import pandas as pd

    sweep_rows = []
    for truth_name, data in truths.items():
        for sd in cfg.qa_sweep_sd:
            sres = _scenario(
                f"{truth_name}-qa{sd:g}", *data, replace(cfg.macro, q_a=sd * sd), cfg,
                rng, monte_carlo=False,
            )
            m = sres.metrics["covariance"]
            late = sres.pred_cycles >= 10
            width = sres.cov_q[:, late, 2] - sres.cov_q[:, late, 0]
            width = np.where(np.isnan(width), np.inf, width)  # both bounds beyond the horizon
            sweep_rows.append({
                "truth": truth_name, "q_a_sd_per_cycle": sd, "runs": cfg.runs,
                "coverage_90": m["coverage_90"].mean(),
                "coverage_90_from_cycle_10": np.nanmean(m["coverage_90_late"]),
                "alpha_lambda_pass_0.5": m["alpha_lambda_0.5"].mean(),
                "median_interval_width_from_cycle_10": float(np.median(width)),
            })
    return pd.DataFrame(sweep_rows)


def _micro_main_table(linear: _Runs, cfg: MotorDampingConfig) -> Any:
    """Micro-EKF damping error over every cycle of every linear run."""
    import pandas as pd

    e = linear.z - np.stack([t.damping for t in linear.tests])
    r = linear.r
    return pd.DataFrame([{
        "runs": cfg.runs, "cycles": e.size, "bias": e.mean(), "rmse": math.sqrt(np.mean(e**2)),
        "p05_error": np.quantile(e, 0.05), "p95_error": np.quantile(e, 0.95),
        "mean_stated_sd": np.sqrt(r).mean(), "nees_mean": np.mean(e**2 / r),
        "coverage_95": np.mean(np.abs(e) <= 1.96 * np.sqrt(r)),
        "error_over_one_cycle_of_slope": math.sqrt(np.mean(e**2)) / cfg.life.slope,
    }])


def _slope_table(lin: ScenarioResult, cfg: MotorDampingConfig) -> Any:
    """Convergence of the macro EKF's slope estimate over runs (Fig. 16)."""
    import pandas as pd

    slope_rows = []
    for n in sorted({*(c for c in cfg.prediction_cycles if c <= cfg.life.n_cycles),
                     cfg.life.n_cycles}):
        k = int(np.flatnonzero(lin.cycles == n)[0])
        a_est = lin.track.x[k, :, 1]
        a_sd = np.sqrt(lin.track.P[k, :, 1, 1])
        slope_rows.append({
            "cycle": n, "true_slope": cfg.life.slope, "mean_estimate": a_est.mean(),
            "sd_over_runs": a_est.std(ddof=1) if a_est.size > 1 else np.nan,
            "mean_stated_sd": a_sd.mean(),
            "coverage_95": np.mean(np.abs(a_est - cfg.life.slope) <= 1.96 * a_sd),
            "run0_estimate": a_est[0],
        })
    return pd.DataFrame(slope_rows)


def _rul_metrics_table(scen: dict[str, ScenarioResult], cfg: MotorDampingConfig) -> Any:
    """Prognostic metrics of every scenario and RUL method (Fig. 17)."""
    import pandas as pd

    met_rows = []
    for sname, sres in scen.items():
        for method, m in sres.metrics.items():
            ph = m["ph"]
            met_rows.append({
                "scenario": sname, "method": method, "runs": cfg.runs,
                "macro_model": sres.macro.model,
                "macro_q_a": "ML grid" if sres.macro.q_a_grid else f"{sres.macro.q_a:g}",
                "q_a_sd_chosen_median": float(np.median(np.sqrt(sres.track.q_a[-1]))),
                "eol_mean": float(np.mean(sres.eol)),
                "alpha_lambda_pass_0.25": m["alpha_lambda_0.25"].mean(),
                "alpha_lambda_pass_0.5": m["alpha_lambda_0.5"].mean(),
                "alpha_lambda_pass_0.75": m["alpha_lambda_0.75"].mean(),
                "ph_mean": np.nanmean(ph) if np.isfinite(ph).any() else np.nan,
                "ph_none_fraction": np.mean(~np.isfinite(ph)),
                "ra_0.5_median": np.median(m["ra_0.5"]),
                "coverage_90": m["coverage_90"].mean(),
                "coverage_90_from_cycle_10": np.nanmean(m["coverage_90_late"]),
            })
    return pd.DataFrame(met_rows)


def _threshold(lt0: LifeTest, z0: FloatArray, cfg: MotorDampingConfig
               ) -> tuple[float, FloatArray, Any]:
    """Failure damping from run 0's characteristic curves (seed section 4.2) beside the
    design-point algebra: (c_fail from curves, curve slopes, ``threshold`` table)."""
    import pandas as pd

    consts = cfg.life.consts
    steady = lt0.time >= 10.0 * consts.tau_I  # current spike decayed to 1.95 e^-10 A
    torque = consts.J * lt0.acceleration
    c_fail_curves = failure_damping_from_curves(lt0.speed, torque, z0, mask=steady)
    slopes = characteristic_curve_slope(lt0.speed, torque, steady)
    thr_tab = pd.DataFrame([{
        "quantity": "failure damping c_fail [N m s]",
        "seed": SEED_VALUES["c_fail"],
        "ours_algebra": failure_damping(consts),
        "ours_from_curves_run0": c_fail_curves,
        "relative_difference": c_fail_curves / failure_damping(consts) - 1.0,
    }])
    return c_fail_curves, slopes, thr_tab


def _micro_history(lt0: LifeTest, cfg: MotorDampingConfig) -> dict[str, Any]:
    """Micro-EKF history over one cycle of run 0 (Fig. 8)."""
    k8 = min(29, cfg.life.n_cycles - 1)
    h = micro_ekf(
        lt0.time, lt0.current[k8 : k8 + 1], lt0.speed[k8 : k8 + 1],
        lt0.acceleration[k8 : k8 + 1], cfg.life.consts, cfg.micro, keep_history=True,
    )
    assert h.x_hist is not None and h.p_hist is not None  # keep_history=True
    return {"cycle": k8 + 1, "time": lt0.time, "x": h.x_hist[:, 0], "P": h.p_hist[:, 0],
            "speed": lt0.speed[k8], "true_c": lt0.damping[k8]}
