"""Extended Kalman filter on a nonlinear model: analytic vs finite-difference Jacobians and a
NIS / NEES consistency check over many units at once.

Model (a lightly damped pendulum, Euler-discretised, step dt), state x = [angle, rate]::

    angle_{k+1} = angle_k + dt rate_k                                  + w1
    rate_{k+1}  = rate_k  - dt (g/L sin(angle_k) + c rate_k)           + w2
    y_k         = sin(angle_k) + v        (horizontal position of the bob, L = 1)

Shows:
1. ``numerical_jacobian`` (central differences) against the analytic Jacobians (printed error);
2. ``ExtendedKalmanFilter`` with ``jac_f``/``jac_h`` given vs left to finite differences
   (largest difference of the estimates);
3. consistency over B units filtered in one batched call: the time- and unit-averaged NIS and
   NEES against their chi-square expectations (m = 1 and n = 2) and the fraction of steps whose
   unit-averaged NIS lies inside the two-sided 95 % chi-square interval (scipy.stats.chi2, an
   independent oracle). EKF linearisation makes NEES slightly larger than 2 when the angle
   uncertainty is large; here the prior is tight enough for a consistent filter.

Run:  python examples/02_ekf_jacobians_nis.py [--seed 0] [--units 400] [--out DIR]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy import stats

from rulkit.estimation.ekf import ExtendedKalmanFilter
from rulkit.estimation.kalman import numerical_jacobian

DT, G_L, C = 0.05, 9.81, 0.1
Q = np.diag([1e-6, 1e-4])
R = np.array([[0.05**2]])


def f(x: np.ndarray, u: object, k: int) -> np.ndarray:
    """Discrete transition, batched: x (B, 2) -> (B, 2)."""
    a, r = x[:, 0], x[:, 1]
    return np.stack([a + DT * r, r - DT * (G_L * np.sin(a) + C * r)], axis=1)


def h(x: np.ndarray, u: object, k: int) -> np.ndarray:
    """Measurement sin(angle), (B, 1)."""
    return np.sin(x[:, :1])


def jac_f(x: np.ndarray, u: object, k: int) -> np.ndarray:
    B = x.shape[0]
    J = np.empty((B, 2, 2))
    J[:, 0, 0] = 1.0
    J[:, 0, 1] = DT
    J[:, 1, 0] = -DT * G_L * np.cos(x[:, 0])
    J[:, 1, 1] = 1.0 - DT * C
    return J


def jac_h(x: np.ndarray, u: object, k: int) -> np.ndarray:
    J = np.zeros((x.shape[0], 1, 2))
    J[:, 0, 0] = np.cos(x[:, 0])
    return J


def simulate(B: int, T: int, x0: np.ndarray, P0: np.ndarray, rng: np.random.Generator):
    """True states (T+1, B, 2) drawn from the prior and the model, measurements (T, B, 1)."""
    xs = np.empty((T + 1, B, 2))
    xs[0] = x0 + rng.standard_normal((B, 2)) @ np.linalg.cholesky(P0).T
    for k in range(T):
        xs[k + 1] = f(xs[k], None, k) + rng.standard_normal((B, 2)) @ np.sqrt(Q)
    ys = h(xs[1:].reshape(-1, 2), None, 0).reshape(T, B, 1)
    ys = ys + np.sqrt(R[0, 0]) * rng.standard_normal(ys.shape)
    return xs, ys


def check(ok: bool, what: str) -> None:
    """Exit with status 1 when a printed check fails (tests/test_examples.py runs this script)."""
    if not ok:
        raise SystemExit(f"CHECK FAILED: {what}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--units", type=int, default=400)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--out", type=Path, default=None, help="directory for a figure (optional)")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    B, T = args.units, args.steps

    # 1. finite differences vs analytic Jacobians at random states
    xr = rng.uniform(-2.0, 2.0, size=(1000, 2))
    err_f = np.abs(numerical_jacobian(lambda x: f(x, None, 0), xr) - jac_f(xr, None, 0)).max()
    err_h = np.abs(numerical_jacobian(lambda x: h(x, None, 0), xr) - jac_h(xr, None, 0)).max()
    print(f"numerical_jacobian vs analytic at 1000 random states: max |error| "
          f"f {err_f:.1e}, h {err_h:.1e}")
    check(max(err_f, err_h) < 1e-7, "finite-difference Jacobians agree with the analytic ones")

    # 2. same filter with analytic and with finite-difference Jacobians (B units at once)
    x0 = np.array([0.5, 0.0])
    P0 = np.diag([0.05, 0.05]) ** 2
    xs, ys = simulate(B, T, x0, P0, rng)
    x0b = np.broadcast_to(x0, (B, 2))
    ekf_a = ExtendedKalmanFilter(f, h, Q, R, jac_f=jac_f, jac_h=jac_h)
    ekf_n = ExtendedKalmanFilter(f, h, Q, R)  # Jacobians by central differences
    ra = ekf_a.filter(ys, x0b, P0)
    rn = ekf_n.filter(ys, x0b, P0)
    print(f"EKF analytic vs finite-difference Jacobians, B={B} units x T={T} steps: "
          f"max |x diff| {np.abs(ra.x - rn.x).max():.1e}, "
          f"max |P diff| {np.abs(ra.P - rn.P).max():.1e}")
    check(np.abs(ra.x - rn.x).max() < 1e-7 and np.abs(ra.P - rn.P).max() < 1e-7,
          "EKF with analytic and with finite-difference Jacobians agree")

    # 3. consistency: NIS (innovations vs S) and NEES (true error vs P), chi-square oracles
    m, n = 1, 2
    nis = ra.nis  # (T, B)
    err = xs[1:] - ra.x  # (T, B, 2)
    nees = np.einsum("tbi,tbi->tb", err, np.linalg.solve(ra.P, err[..., None])[..., 0])
    lo, hi = stats.chi2.ppf([0.025, 0.975], df=B * m) / B
    inside = np.mean((nis.mean(axis=1) >= lo) & (nis.mean(axis=1) <= hi))
    print(f"mean NIS {nis.mean():.3f} (chi-square expectation {m}); "
          f"mean NEES {nees.mean():.3f} (expectation {n})")
    print(f"unit-averaged NIS inside its 95% chi-square interval [{lo:.3f}, {hi:.3f}] "
          f"at {100 * inside:.0f}% of the {T} steps (expected about 95%)")
    # s.e. of the mean of B T chi2_m values: sqrt(2 m / (B T)) (0.007 for NIS, 0.01 for NEES)
    check(abs(nis.mean() - m) < 5 * np.sqrt(2 * m / nis.size), "mean NIS near m")
    check(abs(nees.mean() - n) < 0.1 * n, "mean NEES within 10 % of n (EKF linearisation)")
    check(inside >= 0.85, "unit-averaged NIS inside its 95 % interval at >= 85 % of steps")
    rmse = np.sqrt(np.mean(err[-1] ** 2, axis=0))
    print(f"RMSE at the last step over the {B} units: angle {rmse[0]:.4f} rad, "
          f"rate {rmse[1]:.4f} rad/s; filter std "
          f"{np.sqrt(ra.P[-1, :, 0, 0].mean()):.4f}, {np.sqrt(ra.P[-1, :, 1, 1].mean()):.4f}")

    if args.out is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        args.out.mkdir(parents=True, exist_ok=True)
        t = np.arange(1, T + 1) * DT
        fig, ax = plt.subplots(figsize=(6, 3))
        ax.plot(t, nis.mean(axis=1), label="unit-averaged NIS")
        ax.axhline(lo, color="k", ls="--", lw=0.8)
        ax.axhline(hi, color="k", ls="--", lw=0.8, label="95% chi-square bounds")
        ax.set_xlabel("time [s]")
        ax.legend(fontsize=8)
        fig.tight_layout()
        path = args.out / "ekf_nis.png"
        fig.savefig(path, dpi=100)
        print(f"figure: {path}")


if __name__ == "__main__":
    main()
