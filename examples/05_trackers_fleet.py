"""Alpha-beta and alpha-beta-gamma trackers over a fleet of units, gains from the tracking index.

Shows: ``tracking_index`` -> ``alpha_beta_gains`` / ``alpha_beta_gamma_gains`` with per-unit
(B,) gains (units differ in measurement noise), and the vectorised ``alpha_beta_update`` /
``alpha_beta_gamma_update`` stepping all B units at once (a NaN measurement skips a unit's
correction). The trackers are the steady-state Kalman filters of the constant-velocity and
constant-acceleration models (module docstring of ``rulkit.estimation.trackers``), which gives
two independent oracles computed with ``scipy.linalg.solve_discrete_are``:

1. the Kalman gain ``[alpha, beta/dt(, gamma/dt^2)]`` (printed: largest relative difference);
2. the steady-state posterior covariance ``(I - K H) P``: the empirical variances of the
   trackers' position/velocity(/acceleration) errors across the units of each group, after the
   transient, are printed as ratios to it (1 within the sampling error: the standard error of
   a variance ratio over 10,000 units is sqrt(2/10000) = 1.4 %, so the 20 printed ratios
   spread over about 0.96-1.04).

Run:  python examples/05_trackers_fleet.py [--seed 0] [--units 40000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.linalg import solve_discrete_are

from rulkit.estimation.trackers import (
    alpha_beta_gains,
    alpha_beta_gamma_gains,
    alpha_beta_gamma_update,
    alpha_beta_update,
    tracking_index,
)

DT = 1.0
SIGMA_W = 0.1
SIGMA_V_GROUPS = (0.5, 1.0, 2.0, 4.0)  # measurement noise std of the unit groups


def model(order: int) -> tuple[np.ndarray, np.ndarray]:
    """F and G of the constant-velocity (order 2) or constant-acceleration (order 3) model."""
    if order == 2:
        return np.array([[1.0, DT], [0.0, 1.0]]), np.array([DT**2 / 2, DT])
    F = np.array([[1.0, DT, DT**2 / 2], [0.0, 1.0, DT], [0.0, 0.0, 1.0]])
    return F, np.array([DT**2 / 2, DT, 1.0])


def steady_state(order: int, sigma_v: float) -> tuple[np.ndarray, np.ndarray]:
    """Kalman gain and posterior covariance from the discrete algebraic Riccati equation."""
    F, G = model(order)
    H = np.zeros((1, order))
    H[0, 0] = 1.0
    Qd = np.outer(G, G) * SIGMA_W**2
    Rm = np.array([[sigma_v**2]])
    P = solve_discrete_are(F.T, H.T, Qd, Rm)  # predicted covariance
    K = P @ H.T / (H @ P @ H.T + Rm)
    return K[:, 0], (np.eye(order) - K @ H) @ P


def check(ok: bool, what: str) -> None:
    """Exit with status 1 when a printed check fails (tests/test_examples.py runs this script)."""
    if not ok:
        raise SystemExit(f"CHECK FAILED: {what}")


def run(order: int, B: int, T: int, rng: np.random.Generator) -> None:
    F, G = model(order)
    group = np.arange(B) % len(SIGMA_V_GROUPS)
    sigma_v = np.asarray(SIGMA_V_GROUPS)[group]  # (B,)
    lam = tracking_index(SIGMA_W, sigma_v, DT)  # (B,)
    if order == 2:
        gains = alpha_beta_gains(lam)
        update = alpha_beta_update
    else:
        gains = alpha_beta_gamma_gains(lam)
        update = alpha_beta_gamma_update
    name = "alpha-beta" if order == 2 else "alpha-beta-gamma"

    # oracle 1: the gains are the steady-state Kalman gains
    worst = 0.0
    for g, sv in enumerate(SIGMA_V_GROUPS):
        K, _ = steady_state(order, sv)
        ours = np.array([gi[g] / DT**i for i, gi in enumerate(gains)])
        worst = max(worst, float(np.abs(ours / K - 1).max()))
    print(f"[{name}] lambda {np.unique(lam).round(4).tolist()}: gains vs solve_discrete_are "
          f"Kalman gains, max relative difference {worst:.1e}")
    check(worst < 1e-10, f"{name}: gains equal the steady-state Kalman gains")

    # simulate B units, track them; in the first half 1% of the measurements are missing (NaN)
    truth = np.zeros((B, order))
    truth[:, 1] = 1.0
    est = truth.copy()  # started at the truth; the transient is dropped below
    t_upd = 0.0
    for k in range(T):
        truth = truth @ F.T + np.outer(SIGMA_W * rng.standard_normal(B), G)
        z = truth[:, 0] + sigma_v * rng.standard_normal(B)
        if k < T // 2:
            z[rng.random(B) < 0.01] = np.nan
        t0 = time.perf_counter()
        est = update(est, z, DT, *gains)
        t_upd += time.perf_counter() - t0
    # final step without missing data, so every unit holds a posterior
    truth = truth @ F.T + np.outer(SIGMA_W * rng.standard_normal(B), G)
    est = update(est, truth[:, 0] + sigma_v * rng.standard_normal(B), DT, *gains)
    err = est - truth

    # oracle 2: error variances vs the steady-state posterior covariance
    labels = ("pos", "vel", "acc")[:order]
    parts = []
    for g, sv in enumerate(SIGMA_V_GROUPS):
        _, Ppost = steady_state(order, sv)
        ratio = err[group == g].var(axis=0) / np.diag(Ppost)
        # sample variance of 10,000 errors: s.e. ~1.4 %; 15 % leaves room for the NaN half
        check(bool(np.all(np.abs(ratio - 1) < 0.15)), f"{name}: error variances match Riccati")
        parts.append(f"sigma_v={sv}: " + " ".join(f"{lb} {r:.3f}" for lb, r in
                                                   zip(labels, ratio, strict=True)))
    print(f"[{name}] error variance / Riccati posterior variance, {B // len(SIGMA_V_GROUPS)} "
          f"units per group:\n    " + "\n    ".join(parts))
    print(f"[{name}] {B} units x {T} steps in {t_upd:.2f} s of update calls "
          f"({B * T / t_upd:.3g} unit-updates/s)")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--units", type=int, default=40_000)
    ap.add_argument("--steps", type=int, default=120)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    run(2, args.units, args.steps, rng)
    run(3, args.units, args.steps, rng)


if __name__ == "__main__":
    main()
