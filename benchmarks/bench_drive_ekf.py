"""Benchmark: the augmented EKF of the friction drive on one record, compiled (``rulkit drive``)
against the engine's ExtendedKalmanFilter (the reproduction's filter, one Python step per
sample), and against a hardware estimate.

Record: the seed's jump scenario (0/20 A square wave, m 0.01 -> 0.02 halfway), sampled every
1 ms, seed noise. Both filters: midpoint Jacobian, process noise on the speeds and on m (the
command's defaults), no gate; the compiled one is held to the engine's numbers by
tests/systems/friction_drive/test_deterioration.py.

Lines:

- ``engine EKF`` vs ``compiled EKF``: median wall time per sample over ``--repeats`` runs on
  ``--engine-seconds`` of record (the engine is slow) and ``--seconds`` (compiled), both per
  sample; ``ratio=`` engine / compiled;
- ``compiled EKF`` vs hardware estimate: the flops of one step (an 8 x 8 exponential by a
  16-term Taylor polynomial, two 4 x 4 covariance products, RK4, a 2 x 2 update: counted below)
  at 1 flop per cycle of ``--ghz`` GHz; ``ratio=`` ours / estimate (how far from one core's
  scalar peak);
- a one-hour record at 1 kHz extrapolated from the compiled time per sample.

Usage: ``python benchmarks/bench_drive_ekf.py [--quick]``. BLAS pinned to one thread. Prints
the load average: on a shared machine the absolute times move, the ratio less.
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402

from rulkit.systems.friction_drive import drive  # noqa: E402
from rulkit.systems.friction_drive import reproduce as fr  # noqa: E402
from rulkit.systems.friction_drive.deterioration import EKFSettings, track  # noqa: E402
from rulkit.systems.friction_drive.machine import DRIVE_Q_RATE  # noqa: E402
from timing import median_time  # noqa: E402

# flops of one step: expm of 8 x 8 (16 Horner matmuls of 2 * 8^3 plus ~2 squarings), Phi P
# Phi^T and Phi E12 (3 x 2 * 4^3), the Joseph update (4 x 2 * 4^3), RK4 (2 x 4 stages x ~30)
FLOPS_PER_STEP = 16 * 2 * 8**3 + 2 * 2 * 8**3 + 3 * 2 * 4**3 + 4 * 2 * 4**3 + 2 * 4 * 30


def _record(seconds: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    sc = replace(fr.SCENARIOS["jump"], duration=seconds, t_jump=seconds / 2)
    truth = fr.simulate_truth(sc, 1e-3, 10)
    rng = np.random.default_rng(seed)
    ys = truth.X[:, :2] + rng.standard_normal((truth.t.size, 2)) * np.sqrt(np.diag(drive.SEED_R))
    cur = np.append(truth.currents, truth.currents[-1])
    return ys, cur, truth.X[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="shorter records, fewer repeats")
    ap.add_argument("--seconds", type=float, default=None, help="record for the compiled EKF")
    ap.add_argument("--engine-seconds", type=float, default=None)
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--ghz", type=float, default=2.5, help="clock of the hardware estimate")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    seconds = a.seconds or (5.0 if a.quick else 20.0)
    eng_seconds = a.engine_seconds or (0.5 if a.quick else 2.0)
    repeats = a.repeats or (3 if a.quick else 5)
    print(f"load average {os.getloadavg()[0]:.2f} (1 min), {os.cpu_count()} cores")

    q = np.array([*drive.SPEED_Q_RATE, 0.0, DRIVE_Q_RATE])
    st = EKFSettings(1e-3, 1, 0.0, 0.0, True)
    ys, cur, x0 = _record(seconds, a.seed)
    track(ys[:10], cur[:10], x0, drive.SEED_P0, st, drive.DEFAULT_PARAMS, q, drive.SEED_R)
    t_ours = median_time(lambda: track(ys, cur, x0, drive.SEED_P0, st, drive.DEFAULT_PARAMS, q,
                                       drive.SEED_R), repeats) / (ys.shape[0] - 1)
    n_eng = round(eng_seconds / 1e-3)
    ekf = fr.make_ekf(np.array([q[3]]), np.zeros(1), drive.SEED_R[None], 1e-3,
                      q_speed=q[:2][None], midpoint=np.array([True]))
    t_eng = median_time(lambda: fr.run_filter(ekf, ys[1:n_eng + 1, None, :],
                                              cur[:n_eng, None], x0[None], drive.SEED_P0),
                        repeats) / n_eng
    print(f"engine EKF {t_eng * 1e6:.1f} us/sample ({eng_seconds:g} s of record) vs compiled "
          f"EKF {t_ours * 1e6:.2f} us/sample ({seconds:g} s of record): "
          f"ratio={t_eng / t_ours:.1f}")
    t_hw = FLOPS_PER_STEP / (a.ghz * 1e9)
    print(f"compiled EKF {t_ours * 1e6:.2f} us/sample vs hardware estimate {t_hw * 1e6:.2f} "
          f"us/sample ({FLOPS_PER_STEP} flops at 1 flop/cycle, {a.ghz:g} GHz): "
          f"ratio={t_ours / t_hw:.1f}")
    print(f"one hour at 1 kHz (3.6e6 samples): compiled {3.6e6 * t_ours:.0f} s, engine "
          f"{3.6e6 * t_eng / 60:.0f} min (extrapolated)")


if __name__ == "__main__":
    main()
