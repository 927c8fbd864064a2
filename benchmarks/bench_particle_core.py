"""Benchmark: the batched particle core against the code before it (issue 9 item 3).

Times the pre-change code (the worktree of commit 0445c9b, the last commit before the layout
move, imported in a subprocess with ``PYTHONPATH=<baseline>/src`` under its old module names
``rulkit.experiments.rw_step1`` etc.) and the current code in the same run, alternating the two
processes ``--rounds`` times, and prints for every case the median wall time of each side and
the ratio new / old (below 1: faster now). Cases:

- the step-1 temperature PF kernel (``pf_kernel``), F1 adaptive and F2 adaptive, N = 350 over
  the 500 s Table 3 path, without and with per-step 95 % intervals;
- the Rao-Blackwellised PF kernel over the same path, with intervals;
- the step-2 trackers (one-step PF, two-step PF, RBPF; numba) on 8 units x 2000 windows;
- the engine: ``resampling.systematic`` and ``particle.log_normalise`` at N = 1000 (per call).

Each process compiles (or loads from numba's cache) first, then times ``--repeats`` calls per
case and reports the median. The pre-change code comes from ``--baseline DIR`` (a checkout of
0445c9b) or, by default, from ``git archive 0445c9b src`` of this repository into a temporary
directory; without git history the script says so and exits 0.

    .venv/bin/python benchmarks/bench_particle_core.py [--rounds 3] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

WORKER = r'''
import json, statistics, sys, time
import numpy as np
which, repeats = sys.argv[1], int(sys.argv[2])
if which == "old":
    from rulkit.experiments.rw_step1 import run_step1 as filt, Step1Config as Cfg
    from rulkit.experiments.rw_step1_rbpf import run_rbpf, RBPF_DESIGNS
    from rulkit.models.reaction_wheel import simulate_table3
    from rulkit.experiments import rw_step2 as deg
    from rulkit.models import lubrication as lub
    Deg = deg.Step2Settings
else:
    from rulkit.systems.reaction_wheel.temperature.particle import filter_temperature as filt
    from rulkit.systems.reaction_wheel.temperature.particle import TemperatureConfig as Cfg
    from rulkit.systems.reaction_wheel.temperature.rbpf import run_rbpf, RBPF_DESIGNS
    from rulkit.systems.reaction_wheel.wheel import simulate_table3
    from rulkit.systems.reaction_wheel import degradation as deg
    from rulkit.systems.reaction_wheel import lubrication as lub
    Deg = deg.DegradationConfig
from dataclasses import replace
from rulkit.estimation.weights import log_normalise
from rulkit.estimation.resampling import systematic

def med(fn, n=repeats):
    fn()
    ts = []
    for _ in range(n):
        t = time.perf_counter(); fn(); ts.append(time.perf_counter() - t)
    return statistics.median(ts)

d = simulate_table3(np.random.default_rng(0), "low")
sig = (d.sigma_w, d.sigma_I)
out = {}
for design in ("F1", "F2"):
    cfg = Cfg(design=design, variant="adaptive", n_particles=350)
    for q in (False, True):
        out[f"temperature PF {design} adaptive N=350" + (" + intervals" if q else "")] = med(
            lambda: filt(d.y, d.V, np.random.default_rng(1), cfg, sigma=sig, quantiles=q))
rc = replace(RBPF_DESIGNS["RBJ"], n_particles=350)
out["RBPF (RBJ) N=350 + intervals"] = med(
    lambda: run_rbpf(d.y, d.V, np.random.default_rng(1), rc, sigma=sig))
U, days, sid = 8, 2000 * 240 / 86400, 1
st = Deg(horizon_days=days, n_particles=150)
W = st.n_windows
setup = lub.LubricationSetup(sid, days, st.noise_rel, lub.PATHS[sid])
y_true = lub.true_window_increments(lub.PATHS[sid], lub.SCENARIOS[sid], W)
R = lambda t: [np.random.default_rng([t, r]) for r in range(U)]
y = lub.simulate_measurements(y_true, setup.sigma_y, R(0))
err = lub.EstimateErrorProcess(std_c=0.5, tau_s=30.0)
qd = lub.synthetic_estimate_quadrature(lub.PATHS[sid], err, W, R(1), n_nodes=4)
beta = lub.SCENARIOS[sid].beta0_healthy
h = max(1, repeats // 2)
out["degradation one-step PF 8x2000"] = med(
    lambda: deg.one_step_pf(y, qd, setup.sigma_y, st, R(2), beta_ref=beta), h)
out["degradation two-step PF 8x2000"] = med(
    lambda: deg.two_step_pf(y, qd, setup.sigma_y, st, R(2), R(3), beta_ref=beta), h)
out["degradation RBPF 8x2000"] = med(
    lambda: deg.rbpf(y, qd, setup.sigma_y, st, R(2), beta_ref=beta), h)
w = np.random.default_rng(3).dirichlet(np.ones(1000))
lw = np.log(w) + 5.0
g = np.random.default_rng(4)
out["engine systematic N=1000 (x1000)"] = med(lambda: [systematic(w, g) for _ in range(1000)])
out["engine log_normalise N=1000 (x1000)"] = med(lambda: [log_normalise(lw) for _ in range(1000)])
print(json.dumps(out))
'''


def run_side(src: Path, which: str, repeats: int) -> dict[str, float]:
    env = dict(os.environ, PYTHONPATH=str(src))
    for v in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS", "NUMBA_NUM_THREADS"):
        env[v] = "1"
    res = subprocess.run([sys.executable, "-c", WORKER, which, str(repeats)], env=env,
                         capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise SystemExit(f"{which} side failed:\n{res.stderr[-3000:]}")
    return dict(json.loads(res.stdout.strip().splitlines()[-1]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", type=Path, default=None,
                    help="a checkout of 0445c9b (default: extracted from this repository)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    repo = Path(__file__).resolve().parents[1]
    new_src = repo / "src"
    with tempfile.TemporaryDirectory() as tmp:
        base = args.baseline or _extract_baseline(repo, Path(tmp))
        old_src = base / "src" if base is not None else Path(tmp) / "missing"
        if not (old_src / "rulkit" / "experiments" / "rw_step1.py").exists():
            print(f"bench_particle_core: no pre-change code ({BASELINE_COMMIT}); skipped")
            return
        _compare(old_src, new_src, args.rounds, args.repeats)


BASELINE_COMMIT = "0445c9b"


def _extract_baseline(repo: Path, into: Path) -> Path | None:
    """``git archive BASELINE_COMMIT src`` of ``repo`` unpacked into ``into`` (None if absent)."""
    archive = subprocess.run(["git", "-C", str(repo), "archive", BASELINE_COMMIT, "src"],
                             capture_output=True)
    if archive.returncode != 0:
        return None
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive.stdout, check=True)
    return into


def _compare(old_src: Path, new_src: Path, rounds: int, repeats: int) -> None:
    """Alternate the two sides ``rounds`` times and print the medians and ratios."""
    args = argparse.Namespace(rounds=rounds, repeats=repeats)
    runs: dict[str, list[dict[str, float]]] = {"old": [], "new": []}
    for _ in range(args.rounds):  # alternate: both sides see the same machine load
        for which, src in (("old", old_src), ("new", new_src)):
            runs[which].append(run_side(src, which, args.repeats))
    print(f"batched particle core vs pre-change code (0445c9b): median wall time of "
          f"{args.rounds} rounds x {args.repeats} repeats, one thread")
    print(f"{'case':44} {'before (s)':>11} {'after (s)':>11} {'after/before':>13}")
    ratios = []
    for case in runs["new"][0]:
        old = statistics.median(r[case] for r in runs["old"])
        new = statistics.median(r[case] for r in runs["new"])
        ratios.append(new / old)
        print(f"{case:44} {old:11.4f} {new:11.4f} {new / old:13.3f}")
    print(f"median ratio after/before over the cases: {statistics.median(ratios):.3f} "
          "(< 1: faster after)")


if __name__ == "__main__":
    main()
