"""The real step-1 estimator over the whole step-2 horizon, against the T^ shortcut
(docs/systems/reaction-wheel.md §4, §7.4).

The reproduction's step 2 feeds the trackers a synthetic T^ (the true path plus an error
process measured on short step-1 runs) because the seeds' particle filters cannot run over
three months of 20 Hz telemetry. The compiled IMM EKF can: :func:`real_estimate_quadrature`
simulates the wheel along the scenario's temperature path at a constant command (the compiled
RK4 of :mod:`rulkit.systems.reaction_wheel.wheel_kernels`, one day at a time), adds the
measurement noise, filters it, and sums the estimate into the 4-minute windows
(:class:`rulkit.systems.reaction_wheel.degradation.windows.WindowAccumulator`): memory holds one
day. :func:`compare_real_and_shortcut` runs the same trackers, on the same measured losses and
with the same streams, on that real T^ and on the shortcut's, and reports both with the cost of
a run.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any

import numpy as np

from rulkit.systems.reaction_wheel.degradation.quadrature import WindowQuadrature
from rulkit.systems.reaction_wheel.degradation.study import (
    SOURCES,
    CaseTask,
    run_case,
    track_case,
    unit_rng,
)
from rulkit.systems.reaction_wheel.degradation.trackers import DegradationConfig
from rulkit.systems.reaction_wheel.degradation.windows import LossRecord, WindowAccumulator
from rulkit.systems.reaction_wheel.lubrication import DAY_S, PATHS, SAMPLE_DT, WINDOW_S

#: The command the wheel runs at along the step-2 path [R] (as the shortcut's measurements).
V_COMM = 2.0


def real_estimate_quadrature(scenario_id: int, run: int, seed: int, settings: DegradationConfig,
                             *, noise: str = "low", day_s: float = DAY_S) -> WindowQuadrature:
    """The window rules (arrays (1, W, n)) of the IMM's estimate of one simulated run of the
    wheel along the scenario path over ``settings.horizon_days`` (module docstring); the noise
    from ``unit_rng(seed, "estimate", 20 + scenario, IMM, run)``."""
    from rulkit.systems.reaction_wheel.temperature.ekf import EKFConfig, ekf_start, ekf_steps
    from rulkit.systems.reaction_wheel.wheel import NOISE_LEVELS, IthacoParams, ReactionWheel
    from rulkit.systems.reaction_wheel.wheel_kernels import pack_params, simulate_states

    W = settings.n_windows
    end = (np.arange(W) + 1.0) * WINDOW_S
    acc = WindowAccumulator(LossRecord(end - WINDOW_S, end, np.zeros(W), "loss", "windows"),
                            settings.n_nodes)
    p, path = IthacoParams(), PATHS[scenario_id]
    P = pack_params(p)
    sigma = NOISE_LEVELS[noise]
    cfg = EKFConfig()
    st, s, q = ekf_start(len(cfg.q_T)), cfg.settings(SAMPLE_DT, sigma), np.array(cfg.q_T)
    rng = unit_rng(seed, "estimate", 20 + scenario_id, SOURCES.index("IMM"), run)
    n_total = round(W * WINDOW_S / SAMPLE_DT)
    per = round(day_s / SAMPLE_DT)
    x0 = np.asarray(ReactionWheel(p).steady_state(V_COMM, float(path(0.0))), dtype=np.float64)
    for a in range(0, n_total + 1, per):  # samples 0 .. n_total; 0 is the record's start
        n = min(a + per, n_total + 1) - a
        t = np.arange(a, a + n + 1, dtype=np.float64) * SAMPLE_DT  # and the next chunk's first
        x = simulate_states(x0, np.full(n + 1, V_COMM), np.asarray(path(t)), t[0], SAMPLE_DT, P)
        x0 = x[-1].copy()
        noise_ = rng.standard_normal((n, 2)) * np.asarray(sigma)
        y = np.column_stack([x[:n, 1] + noise_[:, 0], x[:n, 0] + noise_[:, 1]])
        m, _, _ = ekf_steps(t[:n], np.full(n, V_COMM), y, st, s, q, P)
        acc.add(t[:n], m, SAMPLE_DT)
    return acc.finish().quad


def _real_case(task: tuple[int, int, int, DegradationConfig, Any]) -> Any:
    sid, run, seed, settings, error = task
    t0 = time.perf_counter()
    quad = real_estimate_quadrature(sid, run, seed, settings)
    cost = time.perf_counter() - t0
    case = CaseTask(sid, "IMM", (run,), seed, settings, error, keep_traces=False)
    return track_case(case, quad, {"step 1": cost}), run_case(case)


def _real_task(task: Any, rng: np.random.Generator) -> Any:
    return _real_case(task)


def compare_real_and_shortcut(n_runs: int, seed: int, settings: DegradationConfig, error: Any,
                              *, workers: int = 1, scheduler: str | None = None) -> Any:
    """RMSPE (%) of b and beta0 per tracker and scenario with the real IMM estimate over the
    whole horizon and with the shortcut built from ``error`` (the IMM source's measured error
    process), for runs ``0 .. n_runs - 1`` (same measured losses, same tracker streams), and
    the wall time of the real step 1 per run (one row per scenario and tracker)."""
    import pandas as pd

    from rulkit.runner import run_independent

    tasks = [(sid, r, seed, settings, error) for sid in (1, 2) for r in range(n_runs)]
    outs = run_independent(_real_task, tasks, seed=seed, workers=workers, scheduler=scheduler)
    rows = []
    for sid in (1, 2):
        pairs = [o for t, o in zip(tasks, outs, strict=True) if t[0] == sid]
        for meth in pairs[0][0].rmspe_b:
            rows.append({
                "scenario": sid, "tracker": meth, "runs": n_runs, "seed": seed,
                "b real": float(np.mean([r.rmspe_b[meth][0] for r, _ in pairs])),
                "b shortcut": float(np.mean([s.rmspe_b[meth][0] for _, s in pairs])),
                "beta real": float(np.mean([r.rmspe_beta0[meth][0] for r, _ in pairs])),
                "beta shortcut": float(np.mean([s.rmspe_beta0[meth][0] for _, s in pairs])),
                "step-1 s per run": float(np.mean([r.seconds["step 1"] for r, _ in pairs])),
                "days": settings.horizon_days})
    return pd.DataFrame(rows)


def horizon_settings(settings: DegradationConfig, days: float) -> DegradationConfig:
    """``settings`` over ``days`` (a shorter check)."""
    return replace(settings, horizon_days=days)
