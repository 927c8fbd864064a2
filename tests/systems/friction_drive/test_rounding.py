"""How much the friction drive's EKF amplifies rounding, measured with two OpenBLAS kernels
(``OPENBLAS_CORETYPE``: Haswell and Sandybridge round small matrix products differently).

On the seed's jump scenario (20 s, m jumping at 10 s) the reproduction's ``tuned`` filter
(Jacobian at the start of the step, no process noise on the speeds) moves its states by ~1e-11
relative and its NEES by ~1e-7 between the two kernels (the golden tables' tolerances come from
this). ``rulkit drive``'s tuning (midpoint Jacobian, process noise on the speeds: a far better
conditioned P) moves them by ~1e-15 and ~1e-11, and the compiled filter, which calls no BLAS,
not at all.
Slow: six runs of the filter in subprocesses."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow

SCRIPT = """
import sys
import numpy as np
from rulkit.systems.friction_drive import drive, reproduce as fr
from rulkit.systems.friction_drive.deterioration import EKFSettings, track
truth = fr.simulate_truth(fr.SCENARIOS["jump"], 1e-3, 10)
rng = np.random.default_rng(0)
ys = truth.X[:, :2] + rng.standard_normal((truth.t.size, 2)) * np.sqrt(np.diag(drive.SEED_R))
x0 = truth.X[0] + rng.standard_normal(4) * np.sqrt(np.diag(drive.SEED_P0))
mode, out = sys.argv[1], sys.argv[2]
if mode == "kernel":
    q = np.array([*drive.SPEED_Q_RATE, 0.0, 3e-8])
    t = track(ys, np.append(truth.currents, 0.0), x0, drive.SEED_P0,
              EKFSettings(1e-3, 1, 0.0, 0.0, True), drive.DEFAULT_PARAMS, q, drive.SEED_R)
    np.savez(out, x=t.x, nees=np.ones(1), P=t.P)
else:
    drv = mode == "drive"
    ekf = fr.make_ekf(np.array([3e-8 if drv else drive.TUNED_Q_RATE]), np.zeros(1),
                      drive.SEED_R[None], 1e-3,
                      q_speed=np.array(drive.SPEED_Q_RATE)[None] if drv else None,
                      midpoint=np.array([drv]))
    r = fr.run_filter(ekf, ys[1:, None, :], truth.currents[:, None], x0[None], drive.SEED_P0,
                      truth.X[:, None, :])
    np.savez(out, x=r.x[:, 0], nees=r.nees[:, 0], P=r.P_final[0])
"""


def _openblas() -> bool:
    from threadpoolctl import threadpool_info

    return any(i.get("internal_api") == "openblas" for i in threadpool_info())


@pytest.mark.skipif(platform.machine() != "x86_64", reason="OpenBLAS x86-64 kernels")
def test_rounding_amplification_by_tuning(tmp_path: Path) -> None:
    if not _openblas():
        pytest.skip("numpy is not linked to OpenBLAS")
    res = {}
    for mode in ("tuned", "drive", "kernel"):
        for core in ("Haswell", "Sandybridge"):
            out = tmp_path / f"{mode}-{core}.npz"
            env = {**os.environ, "OPENBLAS_CORETYPE": core, "OPENBLAS_NUM_THREADS": "1"}
            subprocess.run([sys.executable, "-c", SCRIPT, mode, str(out)], env=env,
                           check=True, timeout=1800)
            res[mode, core] = np.load(out)
    moved = {}
    for mode in ("tuned", "drive", "kernel"):
        a, b = res[mode, "Haswell"], res[mode, "Sandybridge"]
        x = float(np.max(np.abs(a["x"] - b["x"]) / np.abs(a["x"]).clip(1e-300)))
        nees = float(np.nanmax(np.abs(a["nees"] - b["nees"]) / np.abs(a["nees"])))
        moved[mode] = (x, nees)
        cond = float(np.linalg.cond(a["P"]))
        print(f"{mode}: states move by {x:.2g} relative, NEES by {nees:.2g}; condition "
              f"number of the last P {cond:.2g}")
        moved[mode + " cond"] = (cond, cond)
    assert moved["kernel"] == (0.0, 0.0)  # no BLAS: the same bits on every kernel
    assert moved["drive"][0] < 1e-13 and moved["drive"][1] < 1e-9
    assert moved["drive"][1] <= moved["tuned"][1]
    assert moved["drive cond"][0] < moved["tuned cond"][0] / 5
