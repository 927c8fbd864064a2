"""Engine micro-benchmarks: ratio lines ``... ratio=<reference time / our time>``.

Every comparison is timed in this one run, ours and the reference interleaved, as the median of
``--repeats`` (default 5) repeats after a warm-up call; results of both sides are compared so
that the two timed computations are the same:

1. batched ``KalmanFilter.filter`` over B = 2000 units (T = 100, 2-state toy degradation model)
   vs a per-unit Python loop calling the same filter with B = 1. The loop is timed on a subset
   of units (``--loop-units``, default 100) and extrapolated linearly to 2000 (said in the
   line); the estimates of the subset must agree with the batched ones.
2. ``ParticleFilter.filter`` (systematic resampling at ESS < N/2; mean and covariance per step,
   run with and without the default per-step quantiles) vs a minimal hand-written NumPy SIR
   loop with the same transition, likelihood, resampling rule and per-step mean/covariance,
   N = 1,000 and 10,000, T = 50. Reported per step; ratio < 1 means ours is slower (the cost of
   validation, flags and summaries).
3. ``alpha_beta_update`` and ``alpha_beta_gamma_update`` at B = 1,000,000 units: unit-updates
   per second, vs the same formulas written inline in NumPy (ratio = inline time / ours), and
   vs a memory-traffic floor (a ``np.copyto`` moving as many bytes as an update must read and
   write; ratio = floor / ours, the fraction of the copy bandwidth reached).

Usage: ``python benchmarks/bench_engine.py [--quick] [--repeats 5] [--seed 0]``. ``main(argv)``
returns the printed lines, so another script (e.g. benchmarks/run.py) can import and call it.
BLAS is pinned to one thread unless already set (small shared machine).
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402

import numpy as np  # noqa: E402

from rulkit.estimation.kalman import KalmanFilter  # noqa: E402
from rulkit.estimation.particle import ParticleFilter  # noqa: E402
from rulkit.estimation.trackers import (  # noqa: E402
    alpha_beta_gains,
    alpha_beta_gamma_gains,
    alpha_beta_gamma_update,
    alpha_beta_update,
)
from rulkit.systems.toy.model import ToyDegradation  # noqa: E402


def interleaved(fns: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """Median wall time of each function over ``repeats`` rounds, called in turn each round."""
    for fn in fns.values():  # warm-up
        fn()
    times: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t0)
    return {k: statistics.median(v) for k, v in times.items()}


def fmt(s: float) -> str:
    if s < 1e-3:
        return f"{s * 1e6:.1f} us"
    return f"{s * 1e3:.2f} ms" if s < 1 else f"{s:.2f} s"


# ----------------------------------------------------------------------------------- 1. KF
def bench_kf(B: int, T: int, loop_units: int, repeats: int, rng: np.random.Generator) -> str:
    model = ToyDegradation()
    x0 = np.tile([0.0, 0.01], (B, 1))
    _, _, ys = model.simulate_units(np.tile([0.0, 0.012], (B, 1)), T, rng)  # (T, B, 1)
    P0 = np.diag([0.02, 0.004]) ** 2
    kf = KalmanFilter(model.transition_matrix(), model.observation_matrix(),
                      model.noise.Q, model.noise.R)
    sub = min(loop_units, B)

    def batched() -> np.ndarray:
        return kf.filter(ys, x0, P0).x

    def loop() -> np.ndarray:
        return np.concatenate([kf.filter(ys[:, b:b + 1], x0[b:b + 1], P0).x
                               for b in range(sub)], axis=1)

    xb, xl = batched(), loop()
    diff = float(np.abs(xb[:, :sub] - xl).max())
    if diff > 1e-12:
        raise AssertionError(f"batched and per-unit KF differ by {diff}")
    t = interleaved({"ours": batched, "loop": loop}, repeats)
    loop_full = t["loop"] * B / sub
    return (f"KF batched over B={B} units, T={T}: ours {fmt(t['ours'])}, per-unit loop "
            f"{fmt(loop_full)} (timed on {sub} units, extrapolated x{B / sub:g}; max |diff| "
            f"{diff:.0e}; median of {repeats}) ratio={loop_full / t['ours']:.1f}")


# ----------------------------------------------------------------------------------- 2. PF
def minimal_sir(transition: Callable, loglik: Callable, ys: np.ndarray, x0: np.ndarray,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Hand-written SIR: log-weights, ESS < N/2 systematic resampling, mean/cov per step."""
    x = x0.copy()
    n = x.shape[0]
    logw = np.full(n, -math.log(n))
    T = ys.shape[0]
    means = np.empty((T, x.shape[1]))
    covs = np.empty((T, x.shape[1], x.shape[1]))
    for k in range(T):
        x = transition(x, k, rng)
        lw = logw + loglik(x, ys[k], k)
        m = lw.max()
        w = np.exp(lw - m)
        w /= w.sum()
        logw = np.log(w)
        mu = w @ x
        xc = x - mu
        means[k] = mu
        covs[k] = (xc.T * w) @ xc
        if 1.0 / np.dot(w, w) < 0.5 * n:
            c = np.cumsum(w)
            idx = np.searchsorted(c, (rng.random() + np.arange(n)) / n * c[-1], side="right")
            x = x[np.minimum(idx, n - 1)]
            logw = np.full(n, -math.log(n))
    return means, covs


def bench_pf(N: int, T: int, repeats: int, seed: int) -> list[str]:
    model = ToyDegradation()
    rng = np.random.default_rng(seed)
    _, _, ys = model.simulate_units(np.array([0.0, 0.012]), T, rng)
    ys = ys[:, 0, :]
    x0 = np.array([0.0, 0.01]) + np.array([0.02, 0.004]) * rng.standard_normal((N, 2))

    def transition(x: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
        return model.step(x, None, float(k), 1.0, rng)

    def loglik(x: np.ndarray, y: np.ndarray, k: int) -> np.ndarray:
        return model.log_likelihood(x, y)

    pf = ParticleFilter(transition, loglik)

    def ours_q() -> object:
        return pf.filter(ys, x0, np.random.default_rng(seed))

    def ours_noq() -> object:
        return pf.filter(ys, x0, np.random.default_rng(seed), quantiles=None)

    def ref() -> object:
        return minimal_sir(transition, loglik, ys, x0, np.random.default_rng(seed))

    # same random stream and same arithmetic up to round-off: the means must agree closely
    r_ours, (m_ref, _) = ours_noq(), ref()
    diff = float(np.abs(r_ours.mean - m_ref).max() / np.abs(m_ref).max())  # type: ignore[attr-defined]
    t = interleaved({"q": ours_q, "noq": ours_noq, "ref": ref}, repeats)
    lines = []
    for key, what in (("noq", "quantiles=None"), ("q", "default quantiles")):
        lines.append(
            f"PF per step N={N} ({what}): ours {fmt(t[key] / T)}, minimal numpy SIR "
            f"{fmt(t['ref'] / T)} (T={T}, median of {repeats}; rel. mean diff {diff:.0e}) "
            f"ratio={t['ref'] / t[key]:.2f}")
    return lines


# ----------------------------------------------------------------------------- 3. trackers
def bench_trackers(B: int, repeats: int, rng: np.random.Generator) -> list[str]:
    dt = 1.0
    lam = rng.uniform(0.01, 1.0, B)
    a2, b2 = alpha_beta_gains(lam)
    a3, b3, g3 = alpha_beta_gamma_gains(lam)
    s2 = rng.standard_normal((B, 2))
    s3 = rng.standard_normal((B, 3))
    z = rng.standard_normal(B)

    def inline_ab() -> np.ndarray:
        xp = s2[:, 0] + s2[:, 1] * dt
        r = z - xp
        return np.column_stack([xp + a2 * r, s2[:, 1] + b2 * r / dt])

    def inline_abg() -> np.ndarray:
        x, v, a = s3[:, 0], s3[:, 1], s3[:, 2]
        xp = x + v * dt + 0.5 * a * dt * dt
        r = z - xp
        return np.column_stack([xp + a3 * r, v + a * dt + b3 * r / dt, a + g3 * r / dt**2])

    out: list[str] = []
    for name, ours, ref, state, gains in (
        ("alpha-beta", lambda: alpha_beta_update(s2, z, dt, a2, b2), inline_ab, s2, (a2, b2)),
        ("alpha-beta-gamma", lambda: alpha_beta_gamma_update(s3, z, dt, a3, b3, g3),
         inline_abg, s3, (a3, b3, g3)),
    ):
        diff = float(np.abs(ours() - ref()).max())
        if diff > 1e-12:
            raise AssertionError(f"{name}: ours and inline differ by {diff}")
        # memory floor: an update reads state, z and the per-unit gains and writes a new
        # state; a copy of half that many bytes moves the same traffic (read + write)
        n_read = state.size + z.size + sum(g.size for g in gains)
        src = rng.standard_normal((n_read + state.size) // 2)
        dst = np.empty_like(src)

        def floor(src: np.ndarray = src, dst: np.ndarray = dst) -> None:
            np.copyto(dst, src)

        t = interleaved({"ours": ours, "ref": ref, "floor": floor}, repeats)
        out.append(f"{name} update B={B}: ours {fmt(t['ours'])} ({B / t['ours']:.3g} "
                   f"unit-updates/s), inline numpy {fmt(t['ref'])} (median of {repeats}) "
                   f"ratio={t['ref'] / t['ours']:.2f}")
        out.append(f"{name} update B={B} vs memory floor (a copy moving the same "
                   f"{2 * src.nbytes / 1e6:.0f} MB): floor {fmt(t['floor'])} "
                   f"ratio={t['floor'] / t['ours']:.2f}")
    return out


def main(argv: list[str] | None = None) -> list[str]:
    ap = argparse.ArgumentParser(description="rulkit engine micro-benchmarks (ratio lines)")
    ap.add_argument("--quick", action="store_true", help="smaller sizes, 3 repeats")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--loop-units", type=int, default=100)
    args = ap.parse_args(argv)
    reps = 3 if args.quick else args.repeats
    rng = np.random.default_rng(args.seed)
    print(f"# rulkit bench_engine: python {platform.python_version()}, numpy {np.__version__}, "
          f"{os.cpu_count()} CPUs, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}",
          flush=True)
    lines: list[str] = []

    def emit(s: str) -> None:
        print(s, flush=True)
        lines.append(s)

    emit(bench_kf(2000, 100, 20 if args.quick else args.loop_units, reps, rng))
    for N in (1000, 10_000):
        for s in bench_pf(N, 20 if args.quick else 50, reps, args.seed):
            emit(s)
    for s in bench_trackers(100_000 if args.quick else 1_000_000, reps, rng):
        emit(s)
    return lines


if __name__ == "__main__":
    main()
