"""What a perfect predictive scores on the goal fleets: the coverage goals' sampling spread.

``benchmarks/fleet_goals.py`` scores a model's 90 % intervals on one draw of each synthetic goal
fleet (``rulkit.fleet.learned.datasets.GOAL_FLEETS``, 40 units). This script scores the
*oracle*: the RUL distribution each prediction would have if the model knew the unit's true
growth law and onset (``growth_fleet_laws``), computed by brute-force Monte Carlo from the
generator itself (future acquisitions at the generator's cadence, its HI noise, the event that
ends a history and defines the truth: the first measured HI >= 1, the time interpolated from the
acquisition before it, however late it comes). It is calibrated by construction: over many
fleets its coverage is 90 %. On one fleet its predictions share each unit's one future, so its
coverage varies from fleet to fleet; the script prints it for the fleet of the goals (seed 0,
as ``rulkit fleet-data`` writes it) and for ``--fleets`` other seeds, with the same columns as
the goals table:

    .venv/bin/python benchmarks/fleet_oracle.py                       # 20 fleets of each kind
    .venv/bin/python benchmarks/fleet_oracle.py --datasets multiplicative --fleets 50
    .venv/bin/python benchmarks/fleet_oracle.py --event exceedance --fleets 5

``--event exceedance`` scores instead the RUL of eq. (5)'s event (one measurement at the horizon
still below 1, docs/fleet-models.md section 2) computed with each unit's true law: the models'
event without their fit, beside the oracle's first measured crossing.

A model scores its intervals against the same truths with less knowledge (wider intervals), so
a goal fleet on which even the oracle falls outside [0.85, 0.95] says more about the fleet than
about the model.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass

import numpy as np
import pandas as pd

from rulkit.fleet.learned.datasets import (
    GOAL_FLEETS,
    goal_fleet,
    growth_fleet_laws,
    paris_curve,
    paris_life,
)
from rulkit.fleet.learned.histories import Histories, histories_from_frame
from rulkit.fleet.learned.scoring import truth_rul

LEVELS = (0.5, 0.05, 0.95)
N_ACQ = 50.0  # synthetic_growth_fleet's default acquisitions per life


def measured_crossing(t0: np.ndarray, hi0: np.ndarray, times: np.ndarray, his: np.ndarray
                      ) -> np.ndarray:
    """Time from ``t0`` to the first ``his >= 1`` along each row of ``times (N, J)``,
    interpolated from the acquisition before it (``t0``, ``hi0`` for the first), as
    :meth:`~rulkit.fleet.learned.histories.Histories.failure_time` does; +inf if none."""
    above = his >= 1.0
    j = np.argmax(above, axis=1)
    rows = np.arange(his.shape[0])
    tp = np.where(j > 0, times[rows, j - 1], t0)
    hp = np.where(j > 0, his[rows, j - 1], hi0)
    tj, hj = times[rows, j], his[rows, j]
    crossing = tp + (1.0 - hp) * (tj - tp) / (hj - hp)
    return np.where(above.any(axis=1), crossing - t0, np.inf)


def fleet_law(name: str) -> tuple[float, float, float, float]:
    """The goal fleet's Paris exponent, h0, additive HI noise sd and log-scale noise sd."""
    kw = GOAL_FLEETS[name]
    add = float(kw.get("hi_noise_sd", 0.02)) if kw["noise"] != "multiplicative" else 0.0
    mult = float(kw.get("log_noise_sd", 0.05)) if kw["noise"] != "additive" else 0.0
    return float(kw["m"]), float(kw["h0"]), add, mult


def draw_quantiles(r: np.ndarray) -> np.ndarray:
    """``LEVELS`` quantiles of RUL draws ``r``, +inf where a level falls in the draws that
    never cross (np.quantile alone gives NaN between two infinite draws)."""
    big = np.finfo(np.float64).max
    q = np.quantile(np.where(np.isinf(r), big, r), LEVELS)
    return np.where(q >= 1e300, np.inf, q)


def oracle_quantiles(name: str, t: np.ndarray, hi: np.ndarray, c: float | np.ndarray,
                     onset: float, life: float, rng: np.random.Generator, draws: int,
                     regular: bool = False) -> np.ndarray:
    """RUL quantiles (``LEVELS``) after each acquisition ``(t, hi)`` of one unit whose true law
    is (``c``, ``onset``) and whose law reaches hi = 1 at ``life`` (its cadence is ``life /
    N_ACQ``): ``draws`` futures from the generator (``regular``: acquisitions at a regular
    cadence of the same mean instead of the generator's exponential gaps). ``c`` may be an
    array ``(t.size, draws)``: a rate per prediction and future (a posterior's draws)."""
    m, h0, add, mult = fleet_law(name)
    steps = int(3 * N_ACQ)  # three lives of acquisitions: past any crossing
    if isinstance(c, np.ndarray):  # three of the slowest drawn law's lives
        slowest = float(paris_life(h0, np.array([c.min()]), m)[0]) + onset
        steps = int(3 * N_ACQ * max(slowest / life, 1.0))
    out = np.empty((t.size, len(LEVELS)))
    for i in range(t.size):
        gaps = (np.full((draws, steps), life / N_ACQ) if regular
                else rng.exponential(life / N_ACQ, (draws, steps)))
        times = t[i] + np.cumsum(gaps, axis=1)
        ci = c[i][:, None] if isinstance(c, np.ndarray) else c
        h = np.minimum(paris_curve(h0, ci, m, np.maximum(times - onset, 0.0)), 10.0)
        e1 = mult * rng.standard_normal(h.shape)
        e2 = add * rng.standard_normal(h.shape)
        his = np.maximum(h * np.exp(e1) + e2, 0.0)
        r = measured_crossing(np.full(draws, t[i]), np.full(draws, hi[i]), times, his)
        out[i] = draw_quantiles(r)
    return out


def exceedance_quantiles(name: str, t: np.ndarray, hi: np.ndarray, c: float, onset: float,
                         life: float, rng: np.random.Generator, draws: int,
                         n_grid: int = 800) -> np.ndarray:
    """The same unit's RUL quantiles for eq. (5)'s event (docs/fleet-models.md section 2)
    with its true law: S(r) the probability that one measurement at horizon r is below 1
    (``draws`` noise draws), F(r) = 1 - S(r) / S(0) on a grid of r up to 2 ``life``. What
    the models' RUL would be if they knew the law: it isolates the event from the fit."""
    m, h0, add, mult = fleet_law(name)
    noise_log, noise_hi = mult * rng.standard_normal(draws), add * rng.standard_normal(draws)
    r = np.linspace(0.0, 2.0 * life, n_grid)
    out = np.empty((t.size, len(LEVELS)))
    for i in range(t.size):
        h = np.minimum(paris_curve(h0, c, m, np.maximum(t[i] + r - onset, 0.0)), 10.0)
        below = (h[:, None] * np.exp(noise_log) + noise_hi < 1.0).mean(axis=1)
        cdf = np.maximum.accumulate(np.clip(1.0 - below / max(below[0], 1e-12), 0.0, 1.0))
        out[i] = r[np.minimum(np.searchsorted(cdf, LEVELS), n_grid - 1)]
    return out


@dataclass(frozen=True)
class FleetTruth:
    """A goal fleet as ``rulkit fleet-data`` and ``fleet_goals.py`` draw it, with each unit's
    true law: growth rate ``c`` on the Box-Cox scale (per time unit), ``onset`` and the age
    ``life`` at which the law reaches hi = 1 (indexed by the generator's unit number)."""

    hist: Histories
    c: np.ndarray
    onset: np.ndarray
    life: np.ndarray

    def law_index(self, u: int) -> int:
        """The generator's number of the histories' unit ``u`` (named ``g{number:04d}``)."""
        return int(self.hist.names[u][1:])


def fleet_truth(name: str, seed: int, units: int) -> FleetTruth:
    """The goal fleet ``name`` of ``seed`` and its units' true laws (:class:`FleetTruth`)."""
    ss = np.random.SeedSequence(seed).spawn(2 + len(GOAL_FLEETS))
    k = list(GOAL_FLEETS).index(name)
    df, _ = goal_fleet(name, np.random.default_rng(ss[2 + k]), units)
    kw = GOAL_FLEETS[name]
    grow, onset = growth_fleet_laws(np.random.default_rng(ss[2 + k]), units,
                                    onset_frac=float(kw.get("onset_frac", 0.0)))
    c = paris_life(float(kw["h0"]), np.ones(1), float(kw["m"]))[0] / grow
    return FleetTruth(histories_from_frame(df, f"synthetic_{name}"), c, onset, onset + grow)


def oracle_scores(name: str, seed: int, units: int, draws: int,
                  event: str = "first") -> dict[str, float]:
    """The oracle's median relative error over the last half of life and 90 % coverage (all
    predictions, last half) on the goal fleet ``name`` drawn from ``seed`` (as
    ``benchmarks/fleet_goals.py`` and ``rulkit fleet-data`` draw it); ``event`` ``first``:
    the generator's first measured crossing (:func:`oracle_quantiles`), ``exceedance``: eq.
    (5)'s (:func:`exceedance_quantiles`)."""
    quantiles = oracle_quantiles if event == "first" else exceedance_quantiles
    fleet = fleet_truth(name, seed, units)
    hist, c, onset, life = fleet.hist, fleet.c, fleet.onset, fleet.life
    truth = truth_rul(hist)
    rng = np.random.default_rng([seed, list(GOAL_FLEETS).index(name)])
    err, cover, late = [], [], []
    for u in np.flatnonzero(hist.failed):
        s = hist.rows(int(u))
        g = fleet.law_index(int(u))
        ok = np.isfinite(truth[s])
        t, hi, y = hist.t[s][ok], hist.hi[s][ok], truth[s][ok]
        q = quantiles(name, t, hi, float(c[g]), float(onset[g]), float(life[g]), rng, draws)
        err.append(np.abs(q[:, 0] - y) / y)
        cover.append((q[:, 1] <= y) & (y <= q[:, 2]))
        late.append(t >= t[0] + 0.5 * (hist.failure_time()[u] - t[0]))
    e, cv, lt = (np.concatenate(a) for a in (err, cover, late))
    return {"dataset": name, "seed": seed, "failed": len(err),
            "median_rel_err_last_half": float(np.median(e[lt])),
            "coverage_90": float(cv.mean()), "coverage_90_last_half": float(cv[lt].mean())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    names = [n for n in GOAL_FLEETS]
    ap.add_argument("--datasets", nargs="+", default=names, choices=names)
    ap.add_argument("--fleets", type=int, default=20, help="fleets (seeds 0 .. fleets-1)")
    ap.add_argument("--units", type=int, default=40, help="units per fleet")
    ap.add_argument("--draws", type=int, default=400, help="Monte Carlo futures per prediction")
    ap.add_argument("--event", choices=("first", "exceedance"), default="first",
                    help="first: the generator's first measured hi >= 1 (the oracle); "
                         "exceedance: eq. (5)'s one-measurement event with the true law")
    a = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f}; {a.units} units per fleet, "
          f"{a.draws} futures per prediction, event {a.event}")
    t0 = time.perf_counter()
    for name in a.datasets:
        rows = pd.DataFrame([oracle_scores(name, s, a.units, a.draws, a.event)
                             for s in range(a.fleets)])
        first = rows.iloc[0]
        late = rows["coverage_90_last_half"]
        inside = ((late >= 0.85) & (late <= 0.95)).mean()
        print(f"\n== {name}: oracle on the goal fleet (seed 0, {int(first['failed'])} failed): "
              f"error {first['median_rel_err_last_half']:.3f}, coverage "
              f"{first['coverage_90']:.3f} / {first['coverage_90_last_half']:.3f}")
        print(f"over {a.fleets} fleets: coverage (last half) mean {late.mean():.3f}, sd "
              f"{late.std():.3f}, 5-95 % {late.quantile(0.05):.3f} - {late.quantile(0.95):.3f};"
              f" inside [0.85, 0.95] in {inside:.0%}; coverage (all) mean "
              f"{rows['coverage_90'].mean():.3f}, sd {rows['coverage_90'].std():.3f}", flush=True)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
