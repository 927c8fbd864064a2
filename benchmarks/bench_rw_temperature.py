"""Benchmark: the step-1 particle filter on the reaction-wheel model (spec rw-lubrication.md
section 3), one core, N = 350, the Table 3 path (dt = 0.05 s).

Prints particle-steps per second (N x steps / time; median of repeats; wall and process CPU
time, since the machine may be shared) for

1. the fused numba kernel (whole time loop compiled: T random walk, RK4 per particle per step,
   Gaussian likelihood, log-sum-exp weights, ESS, systematic resampling, mean/std),
2. the numpy reference path (the engine's ParticleFilter with numpy plug-ins; same numbers),
3. the Rao-Blackwellised PF (:mod:`rulkit.systems.reaction_wheel.temperature.rbpf`, beyond
   the seeds; a Kalman filter on [I, w] per particle): its fused kernel and its numpy
   reference, and the wall time of one Table-5-sized grid of it (7 N x 2 noise levels x
   ``--rbpf-runs`` runs) extrapolated from the measured rate,
4. optionally ProgPy 1.9.0's ParticleFilter on the same wheel written as a vectorised ProgPy
   model (``--progpy``; needs ``pip install progpy==1.9.0``),

the ratios, and the fraction of the hardware limit: flops per particle-step (counted below)
x rate / peak flops of one core, the peak measured by a single-threaded float64 matrix
product (numpy/BLAS, 2 n^3 flops) and also stated from the clock (2.6 GHz x 32 flops/cycle
for 2 AVX-512 FMA units, an upper bound).

    .venv/bin/python benchmarks/bench_rw_temperature.py [--repeats 5] [--progpy]
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import replace  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from rulkit.systems.reaction_wheel.temperature.particle import (  # noqa: E402
    TemperatureConfig,
    filter_temperature,
)
from rulkit.systems.reaction_wheel.temperature.rbpf import RBPF_DESIGNS, run_rbpf  # noqa: E402
from rulkit.systems.reaction_wheel.temperature.study import TABLE5_N  # noqa: E402
from rulkit.systems.reaction_wheel.wheel import IthacoParams, simulate_table3  # noqa: E402

# Flops per particle-step of the F2 filter, counted from the kernel source (an add, multiply,
# compare-select, min or abs each count 1; exp counted as 1):
#   wheel derivative 43 (I_bus 10, V_h 8, f3 1, f5 4, sign 3, abs 2, dI 5, dw 7, b 3 ... )
#   RK4: 4 derivatives 172 + stage inputs 12 + combination 14 + b(T) 2          = 200
#   likelihood (residuals 2, quadratic form 9, constant 2)                       = 13
#   T random walk 2, log-sum-exp weights 4, mean 2, variance 3, ESS 2            = 13
FLOPS_PER_PARTICLE_STEP = 226


def _time(fn: Callable[[], Any], repeats: int) -> tuple[float, float]:
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu)


def peak_flops(n: int = 1500, repeats: int = 3) -> float:
    """Single-threaded float64 GEMM rate (flops/s), best of ``repeats``."""
    a = np.random.default_rng(0).standard_normal((n, n))
    b = np.random.default_rng(1).standard_normal((n, n))
    a @ b
    best = min(_time(lambda: a @ b, 1)[1] for _ in range(repeats))
    return 2.0 * n**3 / best


def progpy_filter_rate(data: Any, N: int, steps: int, repeats: int) -> tuple[float, float]:
    """ProgPy 1.9.0 ParticleFilter on the wheel (states I, w, T; T a random walk through
    ProgPy's process noise, whose std per step is process_noise x dt)."""
    from progpy import PrognosticsModel
    from progpy.state_estimators import ParticleFilter
    from progpy.uncertain_data import UnweightedSamples

    from rulkit.systems.reaction_wheel.wheel import wheel_derivatives

    p = IthacoParams()
    dt = data.dt

    class WheelProgPy(PrognosticsModel):
        states = ["I", "w", "T"]  # noqa: RUF012 - ProgPy's declaration style
        inputs = ["V", "t"]  # noqa: RUF012
        outputs = ["w_m", "I_m"]  # noqa: RUF012
        is_vectorized = True
        default_parameters = {  # noqa: RUF012
            "x0": {"I": 0.0, "w": 0.0, "T": 30.0},
            "process_noise": {"I": 0.0, "w": 0.0, "T": 0.02 / dt},
            "measurement_noise": {"w_m": data.sigma_w, "I_m": data.sigma_I},
        }

        def next_state(self, x, u, dt):  # type: ignore[no-untyped-def]
            X = np.column_stack([np.atleast_1d(x["I"]), np.atleast_1d(x["w"])])
            T = np.atleast_1d(x["T"])
            t = float(np.atleast_1d(u["t"])[0])
            V = float(np.atleast_1d(u["V"])[0])
            h = 0.5 * dt
            k1 = wheel_derivatives(X, V, T, t, p)
            k2 = wheel_derivatives(X + h * k1, V, T, t + h, p)
            k3 = wheel_derivatives(X + h * k2, V, T, t + h, p)
            k4 = wheel_derivatives(X + dt * k3, V, T, t + dt, p)
            Xn = X + dt / 6.0 * (k1 + 2 * (k2 + k3) + k4)
            return self.StateContainer(np.array([Xn[:, 0], Xn[:, 1], T]))

        def output(self, x):  # type: ignore[no-untyped-def]
            return self.OutputContainer(
                np.array([np.atleast_1d(x["w"]), np.atleast_1d(x["I"])])
            )

    model = WheelProgPy()
    rng = np.random.default_rng(0)
    x0 = {"I": data.y[0, 1] + data.sigma_I * rng.standard_normal(N),
          "w": data.y[0, 0] + data.sigma_w * rng.standard_normal(N),
          "T": rng.uniform(15, 45, N)}

    def run() -> None:
        filt = ParticleFilter(model, UnweightedSamples(x0), t0=0.0, num_particles=N,
                              measurement_noise={"w_m": data.sigma_w, "I_m": data.sigma_I})
        for k in range(1, steps + 1):
            filt.estimate(k * dt, {"V": data.V[k - 1], "t": (k - 1) * dt},
                          {"w_m": data.y[k, 0], "I_m": data.y[k, 1]})

    wall, cpu = _time(run, repeats)
    return N * steps / wall, N * steps / cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--n", type=int, default=350)
    ap.add_argument("--numpy-steps", type=int, default=1000)
    ap.add_argument("--progpy", action="store_true", help="also time ProgPy 1.9.0")
    ap.add_argument("--progpy-steps", type=int, default=200)
    ap.add_argument("--rbpf-runs", type=int, default=20)
    args = ap.parse_args()
    N = args.n
    data = simulate_table3(np.random.default_rng(0), "low")
    K = data.y.shape[0]
    print(f"# step-1 PF on the Ithaco wheel, N = {N}, Table 3 path, dt = {data.dt} s; "
          f"medians of {args.repeats} repeats; one core")
    sig = (data.sigma_w, data.sigma_I)
    results: dict[str, tuple[float, float]] = {}
    for design in ("F2", "F1"):
        cfg = TemperatureConfig(design=design, variant="pf", n_particles=N)
        filter_temperature(data.y[:50], data.V[:50], np.random.default_rng(0), cfg,
                           sigma=sig)  # compile
        w, c = _time(lambda cfg=cfg: filter_temperature(data.y, data.V,
                                                        np.random.default_rng(1), cfg,
                                               sigma=sig, quantiles=False), args.repeats)
        results[f"numba {design}"] = (N * (K - 1) / w, N * (K - 1) / c)
    cfg = TemperatureConfig(design="F2", variant="pf", n_particles=N)
    w, c = _time(lambda: filter_temperature(data.y, data.V, np.random.default_rng(1), cfg,
                                            sigma=sig,
                                   quantiles=True), max(1, args.repeats // 2))
    results["numba F2 + per-step quantiles"] = (N * (K - 1) / w, N * (K - 1) / c)
    Kn = args.numpy_steps + 1
    w, c = _time(lambda: filter_temperature(data.y[:Kn], data.V[:Kn], np.random.default_rng(1), cfg,
                                   sigma=sig, backend="numpy", quantiles=False),
                 max(1, args.repeats // 2))
    results["numpy reference F2"] = (N * (Kn - 1) / w, N * (Kn - 1) / c)
    # same numbers check on the numpy horizon
    a = filter_temperature(data.y[:Kn], data.V[:Kn], np.random.default_rng(7), cfg, sigma=sig)
    b = filter_temperature(data.y[:Kn], data.V[:Kn], np.random.default_rng(7), cfg, sigma=sig,
                  backend="numpy")
    diff = float(np.max(np.abs(a.T_mean - b.T_mean)))
    rcfg = replace(RBPF_DESIGNS["RB05"], n_particles=N)
    run_rbpf(data.y[:50], data.V[:50], np.random.default_rng(0), rcfg, sigma=sig)  # compile
    w, c = _time(lambda: run_rbpf(data.y, data.V, np.random.default_rng(1), rcfg, sigma=sig,
                                  quantiles=False), args.repeats)
    results["numba RBPF (RB05)"] = (N * (K - 1) / w, N * (K - 1) / c)
    w, c = _time(lambda: run_rbpf(data.y, data.V, np.random.default_rng(1), rcfg, sigma=sig,
                                  quantiles=True), max(1, args.repeats // 2))
    results["numba RBPF + per-step quantiles"] = (N * (K - 1) / w, N * (K - 1) / c)
    w, c = _time(lambda: run_rbpf(data.y[:Kn], data.V[:Kn], np.random.default_rng(1), rcfg,
                                  sigma=sig, backend="numpy", quantiles=False),
                 max(1, args.repeats // 2))
    results["numpy reference RBPF"] = (N * (Kn - 1) / w, N * (Kn - 1) / c)
    ra = run_rbpf(data.y[:Kn], data.V[:Kn], np.random.default_rng(7), rcfg, sigma=sig)
    rb = run_rbpf(data.y[:Kn], data.V[:Kn], np.random.default_rng(7), rcfg, sigma=sig,
                  backend="numpy")
    rdiff = float(np.max(np.abs(ra.T_mean - rb.T_mean)))
    if args.progpy:
        import progpy

        ver = getattr(progpy, "__version__", "?")
        results[f"ProgPy {ver} ParticleFilter"] = progpy_filter_rate(
            data, N, args.progpy_steps, max(1, args.repeats // 2))
    print(f"{'implementation':34} {'p-steps/s (wall)':>17} {'p-steps/s (CPU)':>16}")
    for name, (rw, rc) in results.items():
        print(f"{name:34} {rw:17.3g} {rc:16.3g}")
    ref_w, ref_c = results["numpy reference F2"]
    nb_w, nb_c = results["numba F2"]
    print(f"ratio numba F2 / numpy reference: {nb_w / ref_w:.1f}x (wall), {nb_c / ref_c:.1f}x "
          f"(CPU); max |T_mean difference| over {Kn - 1} steps = {diff:.2e} C")
    rb_w, rb_c = results["numba RBPF (RB05)"]
    rr_w, rr_c = results["numpy reference RBPF"]
    print(f"ratio numba RBPF / numpy reference RBPF: {rb_w / rr_w:.1f}x (wall), "
          f"{rb_c / rr_c:.1f}x (CPU); max |T_mean difference| = {rdiff:.2e} C")
    print(f"ratio RBPF / F2 PF per particle-step (numba): {rb_c / nb_c:.2f} (CPU)")
    grid = sum(TABLE5_N) * 2 * args.rbpf_runs * (K - 1)
    print(f"Table-5-sized RBPF grid (N = {TABLE5_N}, 2 noise levels, {args.rbpf_runs} runs): "
          f"{grid:.3g} particle-steps, ~{grid / rb_c:.0f} s of one core at the measured rate "
          f"(with per-step quantiles for coverage: ~"
          f"{grid / results['numba RBPF + per-step quantiles'][1]:.0f} s)")
    for name, (rw, rc) in results.items():
        if name.startswith("ProgPy"):
            print(f"ratio numba F2 / {name}: {nb_w / rw:.0f}x (wall), {nb_c / rc:.0f}x (CPU)")
    peak = peak_flops()
    clock = 2.6e9 * 32
    print(f"hardware: measured 1-thread float64 GEMM {peak / 1e9:.1f} GFLOP/s; clock bound "
          f"2.6 GHz x 32 flops/cycle = {clock / 1e9:.1f} GFLOP/s")
    fl = FLOPS_PER_PARTICLE_STEP
    print(f"limit at {fl} flops/particle-step: {peak / fl:.3g} p-steps/s (GEMM), "
          f"{clock / fl:.3g} (clock)")
    print(f"numba F2 fraction of the limit (CPU time): {nb_c * fl / peak:.1%} of GEMM peak, "
          f"{nb_c * fl / clock:.1%} of the clock bound")
    print(f"target >= 3e7 p-steps/s on one core: numba F2 {nb_c:.3g} (CPU) / {nb_w:.3g} (wall)")


if __name__ == "__main__":
    main()
