"""Unscented Kalman filter: exactness checks and a comparison with the EKF.

Shows:
1. the unscented transform behind ``UnscentedKalmanFilter.predict`` is exact for a quadratic
   map: for ``y = x^2`` with ``x ~ N(mu, P)`` the closed forms are ``E y = mu^2 + P`` and
   ``Var y = 4 mu^2 P + 2 P^2``; the EKF's linearisation gives ``mu^2`` and ``4 mu^2 P``;
2. on a linear-Gaussian model (the toy degradation model) the UKF equals the exact Kalman
   filter (printed: largest difference of means and covariances, relative);
3. on the nonlinear pendulum of example 02 with a wide prior (angle std 0.5 rad) the UKF and
   the EKF filter the same B units in one batched call each; their errors against the truth
   and their NEES (chi-square with 2 degrees of freedom for a consistent filter: median and
   the fraction beyond the 99 % quantile) are printed side by side. Neither filter is exactly
   consistent with this much nonlinearity; the UKF is closer.

Run:  python examples/03_ukf.py [--seed 0] [--units 300]
"""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path

import numpy as np
from scipy import stats

from rulkit.estimation.ekf import ExtendedKalmanFilter
from rulkit.estimation.kalman import KalmanFilter
from rulkit.estimation.ukf import UnscentedKalmanFilter
from rulkit.systems.toy.model import ToyDegradation

# reuse the pendulum model of example 02 (same folder)
_spec = importlib.util.spec_from_file_location(
    "ex02", Path(__file__).with_name("02_ekf_jacobians_nis.py"))
ex02 = importlib.util.module_from_spec(_spec)  # type: ignore[arg-type]
_spec.loader.exec_module(ex02)  # type: ignore[union-attr]


def check(ok: bool, what: str) -> None:
    """Exit with status 1 when a printed check fails (tests/test_examples.py runs this script)."""
    if not ok:
        raise SystemExit(f"CHECK FAILED: {what}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--units", type=int, default=300)
    ap.add_argument("--steps", type=int, default=100)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)

    # 1. unscented transform of y = x^2 vs closed form (and vs the EKF's linearisation)
    mu = np.array([[0.7], [-1.3]])
    P = np.array([[[0.3]], [[2.0]]])
    square = UnscentedKalmanFilter(lambda x, u, k: x**2, lambda x, u, k: x,
                                   Q=np.zeros((1, 1)), R=np.eye(1))
    ym, yP = square.predict(mu, P, 0)
    exact_m = mu[:, 0] ** 2 + P[:, 0, 0]
    exact_v = 4 * mu[:, 0] ** 2 * P[:, 0, 0] + 2 * P[:, 0, 0] ** 2
    ekf = ExtendedKalmanFilter(lambda x, u, k: x**2, lambda x, u, k: x,
                               Q=np.zeros((1, 1)), R=np.eye(1))
    em, eP = ekf.predict(mu, P, 0)
    print(f"y = x^2, x ~ N({mu[:, 0].tolist()}, {P[:, 0, 0].tolist()}): UKF mean "
          f"{ym[:, 0].tolist()} var {yP[:, 0, 0].tolist()}; exact mean {exact_m.tolist()} "
          f"var {exact_v.tolist()}; EKF mean {em[:, 0].tolist()} var {eP[:, 0, 0].tolist()}")
    rel = max(np.abs(ym[:, 0] / exact_m - 1).max(), np.abs(yP[:, 0, 0] / exact_v - 1).max())
    print(f"UKF vs closed form: max relative error {rel:.1e}")
    check(rel < 1e-8, "UKF mean and variance of x^2 equal the closed form")

    # 2. linear model: UKF == exact KF
    model = ToyDegradation()
    F, H = model.transition_matrix(), model.observation_matrix()
    B = 50
    x0 = np.tile([0.0, 0.01], (B, 1))
    P0 = np.diag([0.02, 0.004]) ** 2
    _, _, ys = model.simulate_units(np.tile([0.0, 0.012], (B, 1)), 60, rng)
    kr = KalmanFilter(F, H, model.noise.Q, model.noise.R).filter(ys, x0, P0)
    ukf_lin = UnscentedKalmanFilter(lambda x, u, k: x @ F.T, lambda x, u, k: x @ H.T,
                                    model.noise.Q, model.noise.R)
    ur = ukf_lin.filter(ys, x0, P0)
    dx = np.abs(ur.x - kr.x).max(axis=(0, 1)) / np.sqrt(kr.P[..., [0, 1], [0, 1]].min(axis=(0, 1)))
    dP = np.abs(ur.P - kr.P).max() / np.abs(kr.P).max()
    print(f"linear model, {B} units x 60 steps: max |UKF x - KF x| / min KF std = "
          f"{dx.max():.1e}; max |UKF P - KF P| / max |KF P| = {dP:.1e}; "
          f"loglik difference {np.abs(ur.loglik - kr.loglik).max():.1e}")
    check(dx.max() < 1e-5 and dP < 1e-8 and np.abs(ur.loglik - kr.loglik).max() < 1e-5,
          "UKF equals the exact Kalman filter on a linear model")

    # 3. nonlinear pendulum with a wide prior: UKF vs EKF against the truth
    Bn, T = args.units, args.steps
    x0n = np.array([0.5, 0.0])
    P0n = np.diag([0.5, 0.3]) ** 2
    xs, ysn = ex02.simulate(Bn, T, x0n, P0n, rng)
    x0b = np.broadcast_to(x0n, (Bn, 2))
    for name, flt in (
        ("EKF", ExtendedKalmanFilter(ex02.f, ex02.h, ex02.Q, ex02.R,
                                     jac_f=ex02.jac_f, jac_h=ex02.jac_h)),
        ("UKF", UnscentedKalmanFilter(ex02.f, ex02.h, ex02.Q, ex02.R, alpha=1e-3)),
    ):
        r = flt.filter(ysn, x0b, P0n)
        err = xs[1:] - r.x
        nees = np.einsum("tbi,tbi->tb", err, np.linalg.solve(r.P, err[..., None])[..., 0])
        rmse = np.sqrt(np.mean(err[:10] ** 2, axis=(0, 1)))
        out99 = np.mean(nees > stats.chi2.ppf(0.99, df=2))
        print(f"pendulum, {Bn} units: {name} RMSE over steps 1-10: angle {rmse[0]:.4f}, "
              f"rate {rmse[1]:.4f}; median NEES {np.median(nees):.2f} (chi-square median "
              f"{stats.chi2.median(df=2):.2f}); NEES beyond its 99% quantile in "
              f"{100 * out99:.1f}% of unit-steps (expected 1%)")
        if name == "UKF":
            check(out99 < 0.05, "UKF NEES beyond its 99 % quantile in < 5 % of unit-steps")


if __name__ == "__main__":
    main()
