"""Benchmark: Monte Carlo RUL of the friction drive, 10,000 trajectories over the full horizon.

Issue #5 / spec friction-drive.md "RUL": from an estimate at t = 20 s (truth state of the jump
scenario, with tuned-filter-sized uncertainty: sigma_alpha = 2e-5, sigma_m = 2.5e-4), 10,000
initial states are drawn from N(x_hat, P) and each is propagated at constant 20 A until
D = 1 - alpha/alpha0 reaches 0.99 (~105 h, i.e. ~3.8e8 steps of 1 ms).

Compared (all timed in this one run; medians of ``--repeats`` repeats):

- ours: ``time_to_failure`` = 10 s of full model (RK4 at ``TRANSIENT_DT`` = 5 ms, numba,
  vectorised) + the quasi-steady closed form; and the whole ``predict_rul`` (sampling, RUL
  distribution, normal fit, optimistic/pessimistic trajectories);
- naive full-model integration, numpy RK4 at 1 ms vectorised over the 10,000 trajectories:
  timed over ``--naive-steps`` steps and extrapolated to the steps the full horizon needs;
- the same with our compiled RK4 kernel (numba), timed and extrapolated the same way;
- adaptive stiff solver (scipy LSODA, rtol 1e-10), one trajectory at a time: timed on
  ``--lsoda-n`` trajectories and extrapolated to 10,000; its RULs are the accuracy oracle.

Each line ends in ``ratio=<their time / our time>``. Usage:
``python benchmarks/bench_friction_rul.py [--quick] [--seed S]``. BLAS pinned to one thread.
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from rulkit.systems.friction_drive import drive as fd  # noqa: E402
from rulkit.systems.friction_drive import reproduce as E  # noqa: E402
from rulkit.systems.friction_drive import rul as RUL  # noqa: E402

HOUR = 3600.0


def _median_time(fn, repeats: int) -> tuple[float, object]:  # type: ignore[no-untyped-def]
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats and reference steps")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n", type=int, default=10_000, help="Monte Carlo trajectories")
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--naive-steps", type=int, default=None)
    ap.add_argument("--lsoda-n", type=int, default=None)
    a = ap.parse_args()
    repeats = a.repeats or (3 if a.quick else 5)
    naive_steps = a.naive_steps or (200 if a.quick else 1000)
    lsoda_n = a.lsoda_n or (10 if a.quick else 30)

    truth = E.simulate_truth(E.SCENARIOS["jump"])
    x_hat = truth.X[-1].copy()
    P = np.diag([1e-8, 1e-10, (2e-5) ** 2, (2.5e-4) ** 2])
    rng = np.random.default_rng(a.seed)
    X0 = RUL.sample_states(x_hat, P, a.n, rng)
    print(f"friction-drive MC RUL benchmark: N = {a.n}, x_hat = {np.round(x_hat, 5).tolist()}, "
          f"sigma_alpha = 2e-5, sigma_m = 2.5e-4, 20 A, D_f = 0.99, seed {a.seed}, "
          f"median of {repeats} repeats")

    RUL.time_to_failure(X0[:2])  # JIT warm-up (numba cache) outside the timing
    t_ours, (tf, _) = _median_time(lambda: RUL.time_to_failure(X0), repeats)
    rul_h = tf / HOUR
    t_full, res = _median_time(
        lambda: RUL.predict_rul(x_hat, P, np.random.default_rng(a.seed), n_samples=a.n,
                              n_validate=0),
        repeats,
    )
    n_steps_full = int(np.ceil(np.max(tf) / 1e-3))
    print(f"ours time_to_failure (10 s RK4 transient at {RUL.TRANSIENT_DT * 1e3:g} ms + closed "
          f"form): {t_ours:.3f} s; "
          f"RUL mean {rul_h.mean():.3f} h, sd {rul_h.std():.3f} h, max {rul_h.max():.3f} h")
    print(f"ours predict_rul (sampling + RUL distribution + fit + extremes): {t_full:.3f} s "
          f"(fit {res.normal_fit[0]:.3f} h, sd {res.normal_fit[1]:.3f} h)")
    print(f"full horizon needs {n_steps_full:.3e} RK4 steps of 1 ms per trajectory")

    # naive numpy RK4, vectorised over all trajectories
    def naive() -> np.ndarray:
        x = X0.copy()
        for _ in range(naive_steps):
            x = fd.rk4_step(x, 20.0, 1e-3)
        return x

    t_np, _ = _median_time(naive, max(1, repeats // 2))
    per_step = t_np / naive_steps
    t_np_full = per_step * n_steps_full
    print(f"naive numpy RK4 1 ms, all {a.n} at once: {per_step * 1e6:.1f} us/step measured over "
          f"{naive_steps} steps -> {t_np_full:.3e} s extrapolated ({t_np_full / 86400:.1f} days) "
          f"ratio={t_np_full / t_ours:.3g}")

    cur = np.full(naive_steps, 20.0)
    fd.integrate_path(X0[:2], cur[:2], 1e-3, store=False)
    t_nb, _ = _median_time(lambda: fd.integrate_path(X0, cur, 1e-3, store=False),
                           max(1, repeats // 2))
    per_step_nb = t_nb / naive_steps
    t_nb_full = per_step_nb * n_steps_full
    print(f"compiled (numba) RK4 1 ms, all {a.n}: {per_step_nb * 1e6:.1f} us/step -> "
          f"{t_nb_full:.3e} s extrapolated ratio={t_nb_full / t_ours:.3g}")

    idx = np.arange(lsoda_n)
    t0 = time.perf_counter()
    ref = RUL.time_to_failure_reference(X0[idx])
    t_ls = time.perf_counter() - t0
    t_ls_full = t_ls / lsoda_n * a.n
    err = np.abs(ref - tf[idx]) / HOUR
    print(f"LSODA (rtol 1e-10) one trajectory at a time: {t_ls / lsoda_n * 1e3:.1f} ms each "
          f"over {lsoda_n} -> {t_ls_full:.1f} s extrapolated to {a.n} "
          f"ratio={t_ls_full / t_ours:.3g}")
    print(f"accuracy vs LSODA on those {lsoda_n}: max |fast - LSODA| = {err.max():.4f} h "
          f"({err.max() * HOUR:.1f} s), mean signed {np.mean(ref - tf[idx]) / HOUR:+.4f} h")
    print(f"verdict: {a.n}-trajectory MC RUL over the full horizon in {t_full:.2f} s "
          f"({'under' if t_full < 10 else 'NOT under'} the 10 s target)")


if __name__ == "__main__":
    main()
