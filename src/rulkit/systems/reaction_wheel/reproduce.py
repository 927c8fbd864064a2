"""Reaction-wheel lubrication prognostics, all three steps (docs/systems/reaction-wheel.md; seed
001).

:func:`run` runs step 1 (Table 5, :mod:`rulkit.systems.reaction_wheel.temperature.study`),
measures the error statistics of the step-1 estimators, runs step 2 (Table 6,
:mod:`rulkit.systems.reaction_wheel.degradation.study`) and step 3 (Table 7,
:mod:`rulkit.systems.reaction_wheel.rul.study`), validates the T^ shortcut and runs the
sensitivity study; :func:`rulkit.systems.reaction_wheel.report.write_report` writes the tables,
figures and ``report.md`` putting our numbers beside the paper's and listing every choice made
where the seeds are silent.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from rulkit.systems.reaction_wheel.degradation.shortcut import EstimateErrorProcess
from rulkit.systems.reaction_wheel.degradation.study import (
    SOURCES,
    STEP1_VARIANTS,
    measure_temperature_errors,
    run_table6,
    sensitivity_study,
    validate_shortcut,
)
from rulkit.systems.reaction_wheel.degradation.trackers import DegradationConfig
from rulkit.systems.reaction_wheel.rul.forecast import RULConfig
from rulkit.systems.reaction_wheel.rul.study import run_table7

Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class ReproductionConfig:
    """Size and settings of a reproduction; ``quick`` is the < 3 min demo."""

    quick: bool = False
    n_runs: int = 20
    seed: int = 0
    step2: DegradationConfig = field(default_factory=DegradationConfig)
    step3: RULConfig = field(default_factory=RULConfig)
    table5: bool = True
    table5_particles: tuple[int, ...] | None = None  # None: the step-1 module's default list
    table5_ekf: bool = True
    # Beyond the seeds: the Rao-Blackwellised PF design(s) shown beside the paper's rows, and
    # 90 % interval coverage of the truth (a sort per step: slower, estimates unchanged).
    table5_extra_designs: tuple[str, ...] = ("RBJ",)
    table5_coverage: bool = True
    step1_error_runs: int = 5
    step1_particles: int = 200
    error_on: str = "path"  # [R] where the T^ error statistics are measured ("path"/"table3")
    error_hours: float = 2.0
    table6_alt: bool = True  # also Table 6 with the error statistics of the Table 3 path
    validation_hours: float = 3.0
    validation_runs: int = 3
    sensitivity_runs: int = 5
    sensitivity_days: float = 10.0
    # The seeds' filters complete (docs/systems/reaction-wheel.md §3.2): all five weightings
    # in both designs (None: N = 50, 200, 350), and eq. 28's effect on the weights measured
    # over this many seconds of the Table 3 path (0: not measured).
    seed_filters: bool = True
    seed_filter_particles: tuple[int, ...] | None = None
    eq28_seconds: float = 500.0
    # Runs of the real step-1 estimator (the IMM) over the whole step-2 horizon, against the
    # T^ shortcut (docs/systems/reaction-wheel.md §7.4); 0: not run.
    real_step1_runs: int = 2
    workers: int = 1
    scheduler: str | None = None

    @classmethod
    def quick_config(cls, seed: int = 0, n_runs: int | None = None, **kw: Any
                     ) -> ReproductionConfig:
        """The ``--quick`` size: 5 runs, 10-day horizon, 150 particles, predictions at days
        2, 5 and 10, Table 5 quick at N = 200 only, T^ error statistics from 2 one-hour
        step-1 runs, no shortcut validation, no sensitivity, no second Table 6."""
        kw.setdefault("step2", DegradationConfig(n_particles=150, horizon_days=10.0))
        kw.setdefault("step3", RULConfig(prediction_days=(2.0, 5.0, 10.0)))
        kw.setdefault("table5_particles", (200,))
        kw.setdefault("error_hours", 1.0)
        kw.setdefault("eq28_seconds", 150.0)
        kw.setdefault("real_step1_runs", 0)
        return cls(quick=True, n_runs=n_runs or 5, seed=seed, step1_error_runs=2,
                   validation_hours=0.0, sensitivity_runs=0, table6_alt=False, **kw)

    @property
    def alt_error_on(self) -> str:
        """Where the second Table 6's T^ error statistics are measured (the other of
        path/table3)."""
        return "table3" if self.error_on == "path" else "path"


@dataclass
class Reproduction:
    """Everything a reproduction produced (tables as DataFrames, paths of written files)."""

    config: ReproductionConfig
    table5: Any
    errors: dict[str, EstimateErrorProcess]
    table6: Any
    table7: Any
    step3: Any
    validation: dict[str, Any]
    sensitivity: Any
    files: list[Path]
    timings: dict[str, float]
    notes: list[str]
    errors_alt: dict[str, EstimateErrorProcess] = field(default_factory=dict)
    table6_alt: Any = None
    seed_filters: Any = None  # all five weightings in F1 and F2 (a DataFrame)
    eq28: Any = None  # eq. 28 against Bayes on the same weights (a DataFrame)
    one_vs_two: Any = None  # one-step against two-step on every T^ source (a DataFrame)
    real_step1: Any = None  # the real IMM over the whole horizon against the shortcut


def run(config: ReproductionConfig, *, progress: Progress | None = None,
        log: Callable[[str], None] = print) -> Reproduction:
    """Run the three steps of ``config`` (tables, error statistics, validation, sensitivity);
    writes nothing (:func:`write_report` does). ``log`` gets one line per stage."""
    cfg = config
    timings: dict[str, float] = {}
    t = time.perf_counter()
    table5 = _run_table5(cfg, log) if cfg.table5 else None
    timings["step 1 (Table 5)"] = time.perf_counter() - t

    t = time.perf_counter()
    errors, errors_alt = _measure_errors(cfg, log)
    timings["step-1 error statistics"] = time.perf_counter() - t

    t = time.perf_counter()
    log(f"step 2: Table 6 ({cfg.n_runs} runs, {cfg.step2.horizon_days:g} days, "
        f"{cfg.step2.n_windows} windows)")
    snaps = cfg.step3.prediction_windows(cfg.step2.n_windows)
    t6 = run_table6(cfg.n_runs, cfg.seed, cfg.step2, errors, workers=cfg.workers,
                    scheduler=cfg.scheduler, snapshot_windows=snaps,
                    progress=True if progress is not None else None)
    timings["step 2 (Table 6)"] = time.perf_counter() - t
    t6_alt = None
    if cfg.table6_alt:
        t = time.perf_counter()
        alt_on = cfg.alt_error_on
        log(f"step 2: Table 6 again with the T^ error statistics of the {alt_on} runs")
        t6_alt = run_table6(cfg.n_runs, cfg.seed, cfg.step2, errors_alt, workers=cfg.workers,
                            scheduler=cfg.scheduler)
        timings[f"step 2 (Table 6, {alt_on} error statistics)"] = time.perf_counter() - t

    t = time.perf_counter()
    log("step 3: RUL (Table 7)")
    s3 = run_table7(t6, cfg.step3)
    timings["step 3 (Table 7)"] = time.perf_counter() - t

    validation: dict[str, Any] = {}
    if cfg.validation_hours > 0:
        t = time.perf_counter()
        for src in SOURCES:
            log(f"validation of the T^ shortcut against the real step-1 estimator ({src})")
            validation[src] = validate_shortcut(errors[src], src, hours=cfg.validation_hours,
                                                n_runs=cfg.validation_runs, seed=cfg.seed,
                                                settings=cfg.step2,
                                                n_particles_step1=cfg.step1_particles)
        timings["shortcut validation"] = time.perf_counter() - t
    sens = None
    if cfg.sensitivity_runs > 0:
        t = time.perf_counter()
        log("sensitivity of Table 6 to the unstated settings")
        sens = sensitivity_study(cfg.step2, errors["APF"], n_runs=cfg.sensitivity_runs,
                                 horizon_days=cfg.sensitivity_days, seed=cfg.seed)
        timings["sensitivity"] = time.perf_counter() - t
    rep = Reproduction(cfg, table5, errors, t6, s3.table, s3, validation, sens, [], timings,
                       [], errors_alt, t6_alt)
    _beyond_the_tables(cfg, rep, log)
    return rep


def _beyond_the_tables(cfg: ReproductionConfig, rep: Reproduction,
                       log: Callable[[str], None]) -> None:
    """The seeds' filters complete, eq. 28 analysed, one-step against two-step on every T^,
    and the real step 1 over the whole horizon against the shortcut."""
    from rulkit.systems.reaction_wheel.degradation.study import one_vs_two_step
    from rulkit.systems.reaction_wheel.temperature.study import (
        eq28_weight_analysis,
        run_seed_filters,
    )

    t = time.perf_counter()
    if cfg.seed_filters:
        log("step 1: all five weightings in designs F1 and F2")
        ns = cfg.seed_filter_particles or cfg.table5_particles or (50, 200, 350)
        rep.seed_filters = run_seed_filters(min(cfg.n_runs, 20), cfg.seed, ns,
                                            workers=cfg.workers, scheduler=cfg.scheduler)
    if cfg.eq28_seconds > 0:
        log("step 1: eq. 28 against Bayes on the same weights")
        rep.eq28 = eq28_weight_analysis(cfg.seed, t_end=cfg.eq28_seconds)
    rep.timings["seed filters and eq. 28"] = time.perf_counter() - t
    rep.one_vs_two = one_vs_two_step(rep.table6)
    if cfg.real_step1_runs > 0 and "IMM" in rep.errors:
        from rulkit.systems.reaction_wheel.degradation.real_step1 import (
            compare_real_and_shortcut,
        )

        t = time.perf_counter()
        log(f"the real step 1 (IMM) over {cfg.step2.horizon_days:g} days against the shortcut")
        rep.real_step1 = compare_real_and_shortcut(cfg.real_step1_runs, cfg.seed, cfg.step2,
                                                   rep.errors["IMM"], workers=cfg.workers,
                                                   scheduler=cfg.scheduler)
        rep.timings["real step 1 over the horizon"] = time.perf_counter() - t


def _run_table5(cfg: ReproductionConfig, log: Callable[[str], None]) -> Any:
    """Step 1: Table 5 (the temperature estimators' study)."""
    from rulkit.systems.reaction_wheel.temperature.study import run_table5

    log("step 1: Table 5 (temperature estimation)")
    return run_table5(runs=min(cfg.n_runs, 20), seed=cfg.seed, quick=cfg.quick,
                      workers=cfg.workers, scheduler=cfg.scheduler,
                      n_particles=cfg.table5_particles, ekf=cfg.table5_ekf,
                      designs=("F1", *cfg.table5_extra_designs),
                      coverage=cfg.table5_coverage)


def _measure_errors(cfg: ReproductionConfig, log: Callable[[str], None]
                    ) -> tuple[dict[str, EstimateErrorProcess], dict[str, EstimateErrorProcess]]:
    """The T^ error statistics of every step-1 source (and on the other path if
    ``table6_alt``)."""
    errors: dict[str, EstimateErrorProcess] = {}
    errors_alt: dict[str, EstimateErrorProcess] = {}

    def measure(src: str, on: str) -> EstimateErrorProcess:
        return measure_temperature_errors(
            src, cfg.step1_error_runs, cfg.seed, on=on, n_particles=cfg.step1_particles,
            hold_samples=cfg.step2.hold_samples, hours=cfg.error_hours)

    for src in SOURCES:
        log(f"step 1 -> 2: error statistics of {src} ({STEP1_VARIANTS[src]})")
        errors[src] = measure(src, cfg.error_on)
        if cfg.table6_alt:
            errors_alt[src] = measure(src, cfg.alt_error_on)
    return errors, errors_alt


def with_overrides(cfg: ReproductionConfig, **kw: Any) -> ReproductionConfig:
    """A copy of ``cfg`` with fields replaced (``None`` values ignored)."""
    return replace(cfg, **{k: v for k, v in kw.items() if v is not None})
