"""Benchmark of step 2 of the reaction-wheel study (docs/systems/reaction-wheel.md).

1. Window sums S_k(b) for N particles: the direct sum (4,800 exponentials per particle per
   window) against the Gauss quadrature on the window's distribution of 1/T^ (building the rule
   once per window + n exponentials per particle), on the same windows, medians of repeats;
   prints the speedup and the largest relative error.
2. The 20-run, three-month Table 6 experiment (both scenarios): wall time of the seed's three
   rows (APF + two-step, PF + two-step, APF + one-step) and of all rows with our RB-PF, and the
   extrapolated time of the same experiment with direct sums.

    .venv/bin/python benchmarks/bench_rw_degradation.py [--runs 20] [--days 90] [--workers 1]
                                                  [--skip-table6]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from timing import median_time


def bench_window_sums(n_particles: int = 150, n_windows: int = 20, n_nodes: int = 4,
                      repeats: int = 5) -> dict[str, float]:
    """Direct vs quadrature window sums on 0.05 s T^ windows (true path + AR(1) error)."""
    from rulkit.systems.reaction_wheel.degradation.quadrature import (
        direct_log_sums,
        window_quadrature,
    )
    from rulkit.systems.reaction_wheel.degradation.shortcut import EstimateErrorProcess
    from rulkit.systems.reaction_wheel.lubrication import PATH_SCENARIO_1

    rng = np.random.default_rng(0)
    err = EstimateErrorProcess(std_c=1.0, tau_s=60.0, hold_samples=1)
    T_hat, _ = err.estimate_blocks(PATH_SCENARIO_1, 100, n_windows, [rng])
    u = 1.0 / T_hat[0]  # (W, 4800): every 0.05 s sample distinct
    b = rng.uniform(10.0, 80.0, n_particles)
    window_quadrature(u[:2], n_nodes)  # compile

    def direct() -> np.ndarray:
        return direct_log_sums(u, b)

    def quad() -> np.ndarray:
        q = window_quadrature(u, n_nodes)
        return np.stack([q.log_sums(b, k) for k in range(n_windows)])

    ref, got = direct(), quad()
    t_direct = median_time(direct, repeats)
    t_quad = median_time(quad, repeats)
    q = window_quadrature(u, n_nodes)
    t_eval = median_time(lambda: [q.log_sums(b, k) for k in range(n_windows)], repeats)
    return {"t_direct_per_window": t_direct / n_windows, "t_quad_per_window": t_quad / n_windows,
            "t_eval_per_window": t_eval / n_windows, "speedup": t_direct / t_quad,
            "max_rel_err": float(np.max(np.abs(np.expm1(got - ref)))),
            "n_particles": n_particles, "n_nodes": n_nodes}


def bench_table6(runs: int, days: float, workers: int) -> dict[str, float]:
    from dataclasses import replace

    from rulkit.runner import run_independent
    from rulkit.systems.reaction_wheel.degradation.study import (
        CaseTask,
        measure_temperature_errors,
        run_case,
    )
    from rulkit.systems.reaction_wheel.degradation.trackers import DegradationConfig

    st = DegradationConfig(horizon_days=days)
    errors = {s: measure_temperature_errors(s, 3, 0) for s in ("APF", "PF")}
    out: dict[str, float] = {"windows": st.n_windows, "particles": st.n_particles}
    paper = {"APF": ("two_step", "one_step"), "PF": ("two_step",)}
    allm = {"APF": ("two_step", "one_step", "rbpf"), "PF": ("two_step", "rbpf")}
    for label, methods in (("paper rows", paper), ("all rows incl. RB-PF", allm)):
        tasks = [CaseTask(sid, src, tuple(range(runs)), 0, st, replace(errors[src]),
                          methods=methods[src], keep_traces=False)
                 for sid in (1, 2) for src in ("APF", "PF")]
        t0 = time.perf_counter()
        res = run_independent(run_case, tasks, seed=0, workers=workers)
        out[label] = time.perf_counter() - t0
        out[label + " filter s"] = sum(v for c in res for k, v in c.seconds.items()
                                       if k != "data")
        out[label + " data s"] = sum(c.seconds["data"] for c in res)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--days", type=float, default=90.0)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--skip-table6", action="store_true")
    a = ap.parse_args()
    ws = bench_window_sums()
    print(f"window sums, N = {ws['n_particles']} particles, {ws['n_nodes']} Gauss nodes, "
          "4800 samples per window (medians of 5):")
    print(f"  direct sum        {1e3 * ws['t_direct_per_window']:8.3f} ms per window")
    print(f"  quadrature total  {1e3 * ws['t_quad_per_window']:8.3f} ms per window "
          f"(rule build + evaluation; evaluation alone {1e3 * ws['t_eval_per_window']:.3f} ms)")
    print(f"  speedup {ws['speedup']:.0f}x, max relative error {ws['max_rel_err']:.2e}")
    if a.skip_table6:
        return
    r = bench_table6(a.runs, a.days, a.workers)
    print(f"Table 6, {a.runs} runs x {a.days:g} days ({r['windows']} windows), both scenarios, "
          f"N = {r['particles']}, workers = {a.workers}:")
    for label in ("paper rows", "all rows incl. RB-PF"):
        print(f"  {label:22s} {r[label]:7.1f} s wall (filters {r[label + ' filter s']:.1f} s, "
              f"data {r[label + ' data s']:.1f} s)")
    n_sums = 2 * a.runs * r["windows"] * r["particles"] * (2 + 1 + 2)  # PF1 two sums per window
    t_direct = n_sums * ws["t_direct_per_window"] / ws["n_particles"]
    print(f"  the paper rows with direct sums would need ~{t_direct / 60:.0f} min for the sums "
          f"alone ({t_direct / r['paper rows']:.0f}x the measured wall time)")


if __name__ == "__main__":
    main()
