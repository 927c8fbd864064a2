"""Monte Carlo RUL to a threshold with censoring; RULDistribution summary, JSON round trip and
prognostic metrics.

Shows:
1. ``propagate_to_threshold`` on a case with a closed form: the toy degradation model without
   process noise, damage d0 = 0.2 and an uncertain rate r ~ N(0.01, 0.003^2), threshold 1,
   horizon 100. Then RUL = (1 - d0) / r exactly (the damage is linear in time, so the linear
   interpolation of the crossing is exact), a sample is censored iff r < (1 - d0) / 100
   (probability Phi((0.008 - 0.01) / 0.003) = 0.2525), and the q-quantile of RUL is
   (1 - d0) / r_(1-q). Printed: sample-wise error, censored fraction and quantiles vs the
   closed forms.
2. ``RULDistribution``: summary (restricted mean, median, 90 % interval, censoring), the KDE
   sub-density integrating to the uncensored mass, and an exact JSON round trip.
3. metrics: ``crps_samples`` of normal samples against the closed-form ``crps_normal``, then a
   prognosis run (exact Kalman filter on noisy measurements, its Gaussian posteriors sampled and
   propagated with process noise by ``monte_carlo_rul``) scored with ``alpha_lambda``,
   ``prognostic_horizon`` and CRPS against the true end of life of the simulated unit.

Run:  python examples/04_rul_monte_carlo.py [--seed 0] [--samples 4000] [--out DIR]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from scipy import stats

from rulkit.estimation.kalman import KalmanFilter
from rulkit.metrics import alpha_lambda, crps_normal, crps_samples, prognostic_horizon
from rulkit.prognosis.predictors import monte_carlo_rul
from rulkit.prognosis.rul import RULDistribution, propagate_to_threshold
from rulkit.systems.toy.model import ToyDegradation


def check(ok: bool, what: str) -> None:
    """Exit with status 1 when a printed check fails (tests/test_examples.py runs this script)."""
    if not ok:
        raise SystemExit(f"CHECK FAILED: {what}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--samples", type=int, default=4000)
    ap.add_argument("--out", type=Path, default=None, help="directory for a figure (optional)")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    N = args.samples

    # 1. closed-form case: no process noise, uncertain rate, finite horizon
    quiet = ToyDegradation(sigma_d=0.0, sigma_r=0.0)
    d0, r_mu, r_sd, horizon = 0.2, 0.01, 0.003, 100.0
    x0 = np.column_stack([np.full(N, d0), r_mu + r_sd * rng.standard_normal(N)])

    def step(x: np.ndarray, u: object, t: float, dt: float, rng: np.random.Generator
             ) -> np.ndarray:
        return quiet.step(x, None, t, dt, rng=None)  # deterministic

    dist = propagate_to_threshold(x0, step, quiet.health, quiet.threshold,
                                  t0=0.0, dt=1.0, horizon=horizon, rng=rng)
    exact = quiet.rul_noise_free(x0)  # (1 - d0) / r, inf where r <= 0
    unc = ~dist.censored
    print(f"[closed form] N={N}: max |RUL - (1-d0)/r| over uncensored samples "
          f"{np.abs(dist.samples[unc] - exact[unc]).max():.1e}; censored exactly where "
          f"(1-d0)/r > horizon: {np.array_equal(dist.censored, exact > horizon)}")
    check(np.abs(dist.samples[unc] - exact[unc]).max() < 1e-9
          and np.array_equal(dist.censored, exact > horizon), "RUL equals (1 - d0) / r")
    p_cens = stats.norm.cdf(((1 - d0) / horizon - r_mu) / r_sd)
    se = np.sqrt(p_cens * (1 - p_cens) / N)
    print(f"[closed form] censored fraction {dist.fraction_censored:.4f} vs "
          f"Phi(...) = {p_cens:.4f} (binomial s.e. {se:.4f})")
    check(abs(dist.fraction_censored - p_cens) < 5 * se, "censored fraction within 5 s.e.")
    qs = np.array([0.1, 0.5, 0.7])
    q_exact = (1 - d0) / stats.norm.ppf(1 - qs, r_mu, r_sd)
    print(f"[closed form] quantiles {qs.tolist()}: sample {np.round(dist.quantile(qs), 2).tolist()}"
          f" vs exact {np.round(q_exact, 2).tolist()}; quantile(0.9) = {dist.quantile(0.9)} "
          f"(inside the censored mass)")
    check(bool(np.all(np.abs(dist.quantile(qs) / q_exact - 1) < 0.03))
          and dist.quantile(0.9) == np.inf, "quantiles within 3 % of the exact ones")

    # 2. summary, density, JSON round trip
    s = dist.summary(level=0.9)
    print("[summary] " + ", ".join(f"{k}={v:.4g}" for k, v in s.items()))
    grid = np.linspace(-50.0, 200.0, 2001)
    mass = np.trapezoid(dist.pdf(grid), grid)
    print(f"[pdf] integral of the KDE sub-density {mass:.4f} = 1 - fraction_censored "
          f"{1 - dist.fraction_censored:.4f}")
    with tempfile.TemporaryDirectory() as tmp:
        back = RULDistribution.from_json(dist.to_json(Path(tmp) / "rul.json"))
    same = (np.array_equal(back.samples, dist.samples)
            and np.array_equal(back.weights, dist.weights)
            and np.array_equal(back.censored, dist.censored) and back.horizon == dist.horizon)
    print(f"[json] round trip exact: {same}")
    check(same, "JSON round trip is exact")

    # 3a. CRPS of samples vs the closed form for a normal forecast
    z = rng.standard_normal(200_000)
    print(f"[crps] N(3, 2^2) at y=4: samples {crps_samples(3 + 2 * z, 4.0):.4f}, "
          f"closed form {crps_normal(3.0, 2.0, 4.0):.4f}")
    check(abs(crps_samples(3 + 2 * z, 4.0) - crps_normal(3.0, 2.0, 4.0)) < 0.01,
          "sample CRPS within 0.01 of the closed form")

    # 3b. a prognosis scored against the truth
    model = ToyDegradation()  # with process noise
    T_obs = 60
    _, xs, ys = model.simulate_units(np.array([0.0, 0.012]), 200, rng)
    d = xs[:, 0, 0]
    k = int(np.flatnonzero(d >= 1.0)[0])
    t_eol = (k - 1) + (1.0 - d[k - 1]) / (d[k] - d[k - 1])  # dt = 1, interpolated
    kr = KalmanFilter(model.transition_matrix(), model.observation_matrix(),
                      model.noise.Q, model.noise.R).filter(
        ys[:T_obs], np.array([[0.0, 0.01]]), np.diag([0.02, 0.004]) ** 2)

    times, dists = [], []
    for kp in (20, 30, 40, 50, 60):
        post = kr.posterior(kp - 1)  # Gaussian posterior after ys[kp-1], time kp
        dists.append(monte_carlo_rul(post, model, n_samples=N, t0=float(kp), dt=1.0,
                                     horizon=300.0, rng=rng, after_crossing="hold"))
        times.append(float(kp))
    al = alpha_lambda(times, dists, t_eol, alpha=0.2, lam=0.5)
    ph = prognostic_horizon(times, dists, t_eol, alpha=0.1, beta=0.5)
    for t, dd in zip(times, dists, strict=True):
        lo, hi = dd.interval(0.9)
        print(f"[prognosis] t={t:.0f}: true RUL {t_eol - t:.1f}, median {dd.median:.1f}, "
              f"90% interval [{lo:.1f}, {hi:.1f}], CRPS {crps_samples(dd.samples, t_eol - t):.2f}")
    print(f"[metrics] alpha-lambda (alpha=0.2, lambda=0.5): t_lambda={al.t_lambda:.1f}, "
          f"mass inside {al.prob_mass:.2f}, passed={al.passed}; prognostic horizon "
          f"(alpha=0.1): {ph.horizon:.1f}")

    if args.out is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        args.out.mkdir(parents=True, exist_ok=True)
        fig, ax = plt.subplots(figsize=(6, 3))
        g = np.linspace(0, 150, 600)
        ax.plot(g, dist.pdf(g), label=f"KDE ({100 * dist.fraction_censored:.0f}% censored)")
        r = (1 - d0) / g[1:]  # change of variables: p(t) = p_r((1-d0)/t) (1-d0)/t^2
        ax.plot(g[1:], stats.norm.pdf(r, r_mu, r_sd) * (1 - d0) / g[1:] ** 2, "k--",
                label="closed form")
        ax.axvline(horizon, color="grey", lw=0.8)
        ax.set_xlabel("RUL")
        ax.legend(fontsize=8)
        fig.tight_layout()
        path = args.out / "rul_closed_form.png"
        fig.savefig(path, dpi=100)
        print(f"figure: {path}")


if __name__ == "__main__":
    main()
