"""Particle filter vs the exact Kalman filter on a linear-Gaussian model.

Shows: the SIR ``ParticleFilter`` (log-weights, ESS-triggered systematic resampling) on the
2-state toy degradation model ``x = [damage, rate]`` (``rulkit.systems.toy.model``),
checked against ``KalmanFilter`` — the exact posterior for this linear-Gaussian model, an
independent oracle. Printed: the largest error of the particle mean in units of the exact
posterior standard deviation, the ratio of particle to exact standard deviations, the
log-likelihood estimate beside the exact one, and how often the filter resampled. A second run
with ``resampler="multinomial"`` shows the other schemes plug in by name.

Run:  python examples/01_pf_vs_kalman.py [--seed 0] [--particles 4000] [--out DIR]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from rulkit.estimation.kalman import KalmanFilter
from rulkit.estimation.particle import ParticleFilter
from rulkit.systems.toy.model import ToyDegradation


def check(ok: bool, what: str) -> None:
    """Exit with status 1 when a printed check fails (tests/test_examples.py runs this script)."""
    if not ok:
        raise SystemExit(f"CHECK FAILED: {what}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--particles", type=int, default=4000)
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--out", type=Path, default=None, help="directory for a figure (optional)")
    args = ap.parse_args(argv)

    rng = np.random.default_rng(args.seed)
    model = ToyDegradation(sigma_d=1e-3, sigma_r=1e-4, sigma_y=0.02, dt=1.0)
    prior_mean = np.array([0.0, 0.01])
    prior_cov = np.diag([0.02, 0.004]) ** 2

    # one simulated unit; ys[k] measures the state after the k-th transition
    _, xs, ys = model.simulate_units(np.array([0.0, 0.012]), args.steps, rng)
    ys = ys[:, 0, :]  # (T, 1)

    # --- the oracle: exact Kalman filter (B = 1 unit) ---
    kf = KalmanFilter(model.transition_matrix(), model.observation_matrix(),
                      model.noise.Q, model.noise.R)
    kr = kf.filter(ys[:, None, :], prior_mean[None, :], prior_cov)
    kf_mean = kr.x[:, 0]  # (T, 2)
    kf_std = np.sqrt(np.diagonal(kr.P[:, 0], axis1=-2, axis2=-1))

    # --- the particle filter: transition = model step with noise, Gaussian likelihood ---
    def transition(x: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
        return model.step(x, None, k * model.dt, model.dt, rng)

    def log_likelihood(x: np.ndarray, y: np.ndarray, k: int) -> np.ndarray:
        return model.log_likelihood(x, y)  # log N(y; damage, sigma_y^2), includes constants

    particles0 = prior_mean + rng.standard_normal((args.particles, 2)) * np.sqrt(
        np.diag(prior_cov))
    for resampler in ("systematic", "multinomial"):
        pf = ParticleFilter(transition, log_likelihood, resampler=resampler, ess_threshold=0.5)
        res = pf.filter(ys, particles0, np.random.default_rng(args.seed + 1))
        pf_std = np.sqrt(np.diagonal(res.cov, axis1=-2, axis2=-1))
        z = np.abs(res.mean - kf_mean) / kf_std  # error in posterior standard deviations
        print(f"[{resampler:11s}] N={args.particles} T={args.steps}: "
              f"max_k |PF mean - KF mean| / KF std = {z[:, 0].max():.3f} (damage), "
              f"{z[:, 1].max():.3f} (rate); Monte Carlo scale 1/sqrt(min ESS) = "
              f"{1 / np.sqrt(res.ess.min()):.3f}")
        print(f"[{resampler:11s}] PF std / KF std at last step: "
              f"damage {pf_std[-1, 0] / kf_std[-1, 0]:.3f}, "
              f"rate {pf_std[-1, 1] / kf_std[-1, 1]:.3f}; "
              f"resampled {res.resampled.sum()}/{args.steps} steps, "
              f"min ESS {res.ess.min():.0f}")
        print(f"[{resampler:11s}] log-likelihood: PF {res.loglik:.3f}, exact KF "
              f"{kr.loglik[0]:.3f} (difference {res.loglik - kr.loglik[0]:+.3f})")
        mc = 1 / np.sqrt(res.ess.min())
        check(z.max() < 10 * mc, f"{resampler}: PF mean within 10 Monte Carlo scales of the KF")
        check(bool(np.all(np.abs(pf_std[-1] / kf_std[-1] - 1) < 0.2)),
              f"{resampler}: PF std within 20 % of the exact std")
        check(abs(res.loglik - kr.loglik[0]) < 2.0, f"{resampler}: log-likelihood within 2")
    print(f"true final state {xs[-1, 0]}, KF mean {kf_mean[-1]}, "
          f"KF std {kf_std[-1]}")

    if args.out is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        args.out.mkdir(parents=True, exist_ok=True)
        t = np.arange(1, args.steps + 1) * model.dt
        fig, ax = plt.subplots(2, 1, sharex=True, figsize=(6, 5))
        for i, name in enumerate(model.state_names):
            ax[i].plot(t, xs[1:, 0, i], "k-", lw=1, label="truth")
            ax[i].plot(t, kf_mean[:, i], "b-", label="Kalman (exact)")
            ax[i].fill_between(t, kf_mean[:, i] - 2 * kf_std[:, i],
                               kf_mean[:, i] + 2 * kf_std[:, i], color="b", alpha=0.15)
            ax[i].plot(t, res.mean[:, i], "r--", label="particle filter")
            ax[i].set_ylabel(name)
        ax[0].plot(t, ys[:, 0], "k.", ms=3, label="measurement")
        ax[0].legend(fontsize=8)
        ax[1].set_xlabel("time")
        fig.tight_layout()
        path = args.out / "pf_vs_kalman.png"
        fig.savefig(path, dpi=100)
        print(f"figure: {path}")


if __name__ == "__main__":
    main()
