"""Why the mixed-noise fleets' late intervals are too wide: a ladder of oracles.

docs/fleet-models.md section 7. On one goal fleet (``GOAL_FLEETS``, drawn as ``rulkit
fleet-data`` and ``fleet_goals.py`` draw it) every failed unit's acquisitions are predicted by
each rung, and each rung's 90 % intervals are scored against the same truths (the measured
crossing of hi = 1):

a. ``oracle``: the generator's own law per unit, brute-force Monte Carlo of the first measured
   crossing (``fleet_oracle.py``), with the generator's exponential gaps and with a regular
   cadence of the same mean (eq. (5b)'s assumption);
b. ``exact Bayes``: the exact Bayesian predictive with the generator's population as the
   prior (each unit's rate posterior on a grid from the exact density of its readings, then
   the generator's futures), the best any model that must learn the rate can do;
   ``true-law``: the model's filter and RUL (eq. (5b)) with each unit's true level and rate as
   its prior (a point mass), the generator's noise, no walk: eq. (5b)'s event alone;
c. ``true-prior``: the same with the generator's population (the level all units start from,
   the mean and variance of its log-normal rates), the generator's noise, no walk: the filter
   and RUL with the true parameters; ``sample-prior``: with the mean and variance of this
   fleet's own 40 rates instead (what a perfect fit of this fleet would learn); beside them the
   filter's posterior of each unit's rate against the exact one of rung b (``exact Bayes``);
c'. ``true-prior, brute-force event``: the same model and posterior, its RUL by brute force
   (the model's own futures, the first reading >= 1, its crossing interpolated as the
   truth's) instead of eq. (5b), at a regular cadence (eq. (5b)'s assumption) and with
   exponential gaps (the generator's): what an exact event would give;
d. ``paris-mixed``, ``paris-mixed-iid``, ``paris-multiplicative``: the fitted models (on all
   units, the scored one included; ``fleet_goals.py`` prints their leave-one-unit-out),
   then ``... walk 0``: the same fitted model with its random walk set to 0, and ``...
   true noise``: with the generator's noise sds in place of the fitted ones.

First, eq. (5b)'s event on a known straight path, per rise c between readings (in noise sds):
the truth's CDF at (5b)'s 5 % and 95 % quantiles with a regular cadence and with exponential
gaps, against the event of a full-noise reading at the horizon (:func:`event_errors`). Then,
per rung: the coverage over all predictions and over the last half of life, the median width
of the late intervals relative to the truth, the shares of late truths before the interval
(optimistic) and after it (pessimistic), the late median relative error; and each rung's
parameters beside the generator's (on the file's time unit):

    .venv/bin/python benchmarks/mixed_ladder.py                    # mixed, seeds 0 to 4
    .venv/bin/python benchmarks/mixed_ladder.py --dataset additive --seeds 0
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import dataclasses
import math
import time

import numpy as np
import pandas as pd

from fleet_oracle import (
    N_ACQ,
    FleetTruth,
    draw_quantiles,
    fleet_law,
    fleet_truth,
    oracle_quantiles,
)
from fleet_oracle import measured_crossing as fleet_oracle_crossing
from rulkit.fleet.learned.datasets import paris_curve, paris_life
from rulkit.fleet.learned.degradation import time_scale_of
from rulkit.fleet.learned.growth_filter import boxcox
from rulkit.fleet.learned.hi_noise import HiNoiseModel, fit_hi_noise
from rulkit.fleet.learned.histories import Histories
from rulkit.fleet.learned.scoring import truth_rul

LEVELS = (0.5, 0.05, 0.95)
LIFE_MEDIAN, LIFE_CV = 300.0, 0.25
"""``synthetic_growth_fleet``'s defaults, which the goal fleets keep: the growth time from h0
to 1 is log-normal with this median and sd of its log."""
POINT_VAR = 1e-12
"""The prior variance of a known level or rate (scaled units): a point mass the filter accepts."""


def population_rate(name: str) -> tuple[float, float]:
    """Mean and sd of the generator's growth rates c = paris_life(h0, 1, m) / grow (grow
    log-normal: :data:`LIFE_MEDIAN`, :data:`LIFE_CV`), per time unit."""
    m, h0, _, _ = fleet_law(name)
    med = float(paris_life(h0, np.ones(1), m)[0]) / LIFE_MEDIAN
    mean = med * math.exp(0.5 * LIFE_CV**2)
    return mean, mean * math.sqrt(math.expm1(LIFE_CV**2))


def true_model(name: str, hist: Histories, level_var: float, rate_mean: float,
               rate_var: float) -> HiNoiseModel:
    """The model of eq. (7) with the generator's shape, start level, noise and no walk, and
    the given rate prior (per time unit) and level variance (scaled units)."""
    m, h0, add, mult = fleet_law(name)
    lam = 1.0 - 0.5 * m
    tau = time_scale_of(hist)
    return HiNoiseModel(noise="mixed" if add and mult else
                        ("additive" if add else "multiplicative"),
                        shape=lam, mean=(float(boxcox(np.array(h0), lam)), rate_mean * tau),
                        cov=(level_var, 0.0, rate_var * tau * tau), hi_noise_sd=add,
                        log_noise_sd=mult, walk_sd=0.0, time_scale=tau)


def model_rows(model: HiNoiseModel, hist: Histories) -> np.ndarray:
    """RUL quantiles (``LEVELS``) after every row of ``hist``."""
    return np.column_stack(model.rul_quantiles(model.replay(hist), LEVELS))


def true_law_rows(name: str, fleet: FleetTruth) -> np.ndarray:
    """Rung b: each unit through the model with its own true rate as a point-mass prior."""
    hist = fleet.hist
    out = np.full((hist.t.size, len(LEVELS)), np.nan)
    for u in np.flatnonzero(hist.failed):
        one = hist.select([int(u)])
        c = float(fleet.c[fleet.law_index(int(u))])
        model = true_model(name, hist, POINT_VAR, c, POINT_VAR / time_scale_of(hist) ** 2)
        out[hist.rows(int(u))] = model_rows(model, one)
    return out


def oracle_rows(name: str, fleet: FleetTruth, seed: int, draws: int, regular: bool = False
                ) -> np.ndarray:
    """Rung a: the generator's first measured crossing per prediction (``fleet_oracle.py``;
    ``regular``: its future acquisitions at a regular cadence, eq. (5b)'s assumption)."""
    hist, out = fleet.hist, np.full((fleet.hist.t.size, len(LEVELS)), np.nan)
    rng = np.random.default_rng([seed, 99])
    for u in np.flatnonzero(hist.failed):
        s, g = hist.rows(int(u)), fleet.law_index(int(u))
        out[s] = oracle_quantiles(name, hist.t[s], hist.hi[s], float(fleet.c[g]),
                                  float(fleet.onset[g]), float(fleet.life[g]), rng, draws,
                                  regular)
    return out


def reading_log_density(y: np.ndarray, h: np.ndarray, add: float, mult: float,
                        nodes: int = 24) -> np.ndarray:
    """log density of a reading y = max(h exp(e1) + e2, 0) given the law's h (broadcast),
    e1 ~ N(0, mult^2), e2 ~ N(0, add^2), by Gauss-Hermite quadrature over e1 (no reading of
    these fleets is clipped at 0: their HI starts at 0.1 or more, 5 noise sds up)."""
    x, wts = np.polynomial.hermite_e.hermegauss(nodes)
    wts = wts / wts.sum()
    if mult == 0.0:
        x, wts = np.zeros(1), np.ones(1)
    if add == 0.0:  # log-normal: the density of y itself
        ly = np.log(np.maximum(y, 1e-300))
        return (-0.5 * ((ly - np.log(h)) / mult) ** 2 - ly - math.log(mult)
                - 0.5 * math.log(2 * math.pi))
    mu = h[..., None] * np.exp(mult * x)
    dens = np.exp(-0.5 * ((y[..., None] - mu) / add) ** 2) @ wts
    return np.log(np.maximum(dens, 1e-300)) - math.log(add) - 0.5 * math.log(2 * math.pi)


def rate_posterior(name: str, t: np.ndarray, y: np.ndarray, grid: int = 400
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The exact posterior of one unit's rate after each of its readings ``(t, y)``, with
    the generator's population as the prior (log-normal rates) and its start level and
    noise known: (log-rate grid, posterior weights ``(t.size, grid)``), by brute force from
    the exact reading density."""
    m, h0, add, mult = fleet_law(name)
    med = float(paris_life(h0, np.ones(1), m)[0]) / LIFE_MEDIAN
    lc = math.log(med) + LIFE_CV * np.linspace(-6.0, 6.0, grid)
    log_prior = -0.5 * ((lc - math.log(med)) / LIFE_CV) ** 2
    h = np.minimum(paris_curve(h0, np.exp(lc)[None, :], m, t[:, None]), 10.0)
    post = log_prior + np.cumsum(reading_log_density(y[:, None], h, add, mult), axis=0)
    w = np.exp(post - post.max(axis=1, keepdims=True))
    return lc, w / w.sum(axis=1, keepdims=True)


def bayes_rows(name: str, fleet: FleetTruth, seed: int, draws: int) -> np.ndarray:
    """Rung b: the exact Bayesian predictive with the generator's population as the prior:
    each unit's rate posterior (:func:`rate_posterior`), then ``draws`` futures of the
    generator with rates drawn from it (``fleet_oracle.oracle_quantiles``)."""
    hist, out = fleet.hist, np.full((fleet.hist.t.size, len(LEVELS)), np.nan)
    rng = np.random.default_rng([seed, 98])
    for u in np.flatnonzero(hist.failed):
        s, g = hist.rows(int(u)), fleet.law_index(int(u))
        t, y = hist.t[s], hist.hi[s]
        lc, w = rate_posterior(name, t, y)
        cdf = np.cumsum(w, axis=1)
        c = np.exp(np.stack([np.interp(rng.random(draws), cdf[i], lc) for i in range(t.size)]))
        out[s] = oracle_quantiles(name, t, y, c, float(fleet.onset[g]), float(fleet.life[g]),
                                  rng, draws)
    return out


def posterior_check(name: str, fleet: FleetTruth, model: HiNoiseModel) -> str:
    """The filter's posterior of the rate (``model``: the true prior) against the exact one
    (:func:`rate_posterior`) over the failed units' late predictions: median ratios of the
    means and of the sds, and the 5-95 % range of the sd ratio."""
    hist = fleet.hist
    state = model.replay(hist)
    mean, sd = [], []
    for u in np.flatnonzero(hist.failed):
        s = hist.rows(int(u))
        t = hist.t[s]
        late = t >= t[0] + 0.5 * (t[-1] - t[0])
        lc, w = rate_posterior(name, t, hist.hi[s])
        mu = w @ np.exp(lc)
        sdv = np.sqrt(np.maximum(w @ np.exp(2 * lc) - mu * mu, 0.0))
        mean.append((state.m[s, 1] / model.time_scale / mu)[late])
        sd.append((np.sqrt(state.p[s, 2]) / model.time_scale / sdv)[late])
    rm, rs = np.concatenate(mean), np.concatenate(sd)
    lo, hi = np.quantile(rs, (0.05, 0.95))
    return (f"the filter's rate posterior with the true prior against the exact one (late "
            f"predictions): mean ratio {np.median(rm):.4f}, sd ratio {np.median(rs):.3f} "
            f"(5-95 % {lo:.3f} - {hi:.3f})")


def model_event_rows(model: HiNoiseModel, hist: Histories, draws: int, seed: int,
                     regular: bool) -> np.ndarray:
    """The model's own predictive by brute force instead of eq. (5b): after each failed
    unit's row, ``draws`` (level, rate) from the filter's posterior, the path on the growth
    scale, readings by eq. (7) with the model's noise at the unit's cadence t / n (``regular``,
    (5b)'s assumption; else exponential gaps of that mean), the first reading >= 1 and its
    crossing interpolated from the reading before, as the truth is (at a unit's first row,
    which has no cadence, eq. (5b))."""
    from rulkit.fleet.learned.growth_filter import boxcox_inverse

    state, tau = model.replay(hist), model.time_scale
    rng = np.random.default_rng([seed, 97])
    out = model_rows(model, hist)  # eq. (5b) kept at a unit's first row: no cadence yet
    rows = np.flatnonzero(hist.failed[hist.unit] & (state.n >= 2))
    steps = int(3 * N_ACQ)
    for i in rows:
        d = state.t[i] / state.n[i]
        chol = np.linalg.cholesky(np.array([[state.p[i, 0], state.p[i, 1]],
                                            [state.p[i, 1], state.p[i, 2]]]) + 1e-15 * np.eye(2))
        zb = state.m[i] + rng.standard_normal((draws, 2)) @ chol.T
        gaps = np.full((draws, steps), d) if regular else rng.exponential(d, (draws, steps))
        ahead = np.cumsum(gaps, axis=1)
        z = zb[:, :1] + zb[:, 1:] * ahead / tau + (
            model.walk_sd * np.cumsum(np.sqrt(gaps / tau) * rng.standard_normal(gaps.shape),
                                      axis=1) if model.walk_sd > 0 else 0.0)
        his = (boxcox_inverse(z, model.shape) * np.exp(model.log_noise_sd * rng.standard_normal(
            z.shape)) + model.hi_noise_sd * rng.standard_normal(z.shape))
        r = fleet_oracle_crossing(np.zeros(draws), np.full(draws, hist.hi[i]), ahead, his)
        out[i] = draw_quantiles(r)
    return out


def score(hist: Histories, q: np.ndarray) -> dict[str, float]:
    """Coverage (all, last half), late width / truth, late optimistic / pessimistic shares,
    late median relative error, over the failed units' predictions."""
    y = truth_rul(hist)
    t_first = hist.t[hist.start[:-1]][hist.unit]
    late = hist.t >= t_first + 0.5 * (hist.failure_time()[hist.unit] - t_first)
    ok = np.isfinite(y)
    lt = ok & late
    cov = (q[:, 1] <= y) & (y <= q[:, 2])
    return {"n": int(ok.sum()), "n_late": int(lt.sum()),
            "coverage": float(cov[ok].mean()), "coverage_late": float(cov[lt].mean()),
            "width_late": float(np.median((q[lt, 2] - q[lt, 1]) / y[lt])),
            "optimistic": float((y[lt] < q[lt, 1]).mean()),
            "pessimistic": float((y[lt] > q[lt, 2]).mean()),
            "error_late": float(np.median(np.abs(q[lt, 0] - y[lt]) / y[lt]))}


def params(model: HiNoiseModel | None, name: str, fleet: FleetTruth) -> dict[str, float]:
    """A rung's parameters on the file's time unit (the generator's when ``model`` is None):
    Paris exponent, start level and its sd, rate mean and sd, noise sds at hi = 1, walk sd."""
    if model is None:
        m, h0, add, mult = fleet_law(name)
        mean, sd = population_rate(name)
        return {"m": m, "level": float(boxcox(np.array(h0), 1.0 - 0.5 * m)), "level_sd": 0.0,
                "rate": mean, "rate_sd": sd, "hi_noise_sd": add, "log_noise_sd": mult,
                "walk_sd": 0.0}
    tau = model.time_scale
    return {"m": model.paris_exponent, "level": model.mean[0],
            "level_sd": math.sqrt(model.cov[0]), "rate": model.mean[1] / tau,
            "rate_sd": math.sqrt(model.cov[2]) / tau, "hi_noise_sd": model.hi_noise_sd,
            "log_noise_sd": model.log_noise_sd, "walk_sd": model.walk_sd / math.sqrt(tau)}


def event_errors(rises: tuple[float, ...] = (0.3, 0.6, 1.2, 2.5, 5.0), draws: int = 100_000,
                 seed: int = 0) -> pd.DataFrame:
    """Eq. (5b) on a known straight path (linear growth, additive noise s, cadence d, no
    parameter uncertainty, the level 10 s below the threshold), per rise c = b d / s between
    readings: the truth's CDF (the first reading >= 1, its crossing interpolated from the
    reading before; brute force) at eq. (5b)'s 5 % and 95 % quantiles, with readings at a
    regular cadence (eq. (5b)'s assumption) and with exponential gaps of the same mean (the
    synthetic fleets'), and the widths of the 90 % intervals; beside them (``event_F``) the
    CDF of the event of one full-noise reading at the horizon r and readings at r - d,
    r - 2d, ... (brute force) at the same quantiles: how far that event, which ignores the
    interpolation, is from (5b)'s."""
    from rulkit.fleet.learned.degradation import UnitState

    rng, s, d, n = np.random.default_rng(seed), 0.04, 1.0, 50
    model = HiNoiseModel(noise="additive", shape=1.0, mean=(0.0, 0.0),
                         cov=(1e-12, 0.0, 1e-12), hi_noise_sd=s, log_noise_sd=0.0,
                         walk_sd=0.0, time_scale=1.0)
    rows = []
    for c in rises:
        b = c * s / d
        state = UnitState(m=np.array([[-10.0 * s, b]]), p=np.array([[1e-12, 0.0, 1e-12]]),
                          t=np.array([n * d]), hi=np.array([1.0 - 10.0 * s]), n=np.array([n]))
        q = np.array([x[0] for x in model.rul_quantiles(state, (0.05, 0.95))])
        row: dict[str, float] = {"c": c, "law_rul": 10.0 * s / b, "5b_width": q[1] - q[0]}
        k = int(4 * (10.0 * s / b) / d + 40)
        for cadence in ("regular", "exponential"):
            gaps = (np.full((draws, k), d) if cadence == "regular"
                    else rng.exponential(d, (draws, k)))
            tk = np.cumsum(gaps, axis=1)
            h = 1.0 - 10.0 * s + b * tk + s * rng.standard_normal((draws, k))
            truth = fleet_oracle_crossing(np.zeros(draws), np.full(draws, 1.0 - 10.0 * s),
                                          tk, h)
            row[f"{cadence}_F(q05)"] = float((truth <= q[0]).mean())
            row[f"{cadence}_F(q95)"] = float((truth <= q[1]).mean())
            row[f"{cadence}_width"] = float(np.diff(np.quantile(truth, (0.05, 0.95)))[0])
        for p, r in zip(("05", "95"), q, strict=True):
            back = r - d * np.arange(int(r / d) + 1)
            back = back[back > 0]
            y = 1.0 - 10.0 * s + b * back + s * rng.standard_normal((draws, back.size))
            row[f"event_F(q{p})"] = float((y >= 1.0).any(axis=1).mean())
        rows.append(row)
    return pd.DataFrame(rows).set_index("c")


def fitted_rungs(name: str, hist: Histories) -> list[tuple[str, HiNoiseModel]]:
    """Rung d: the fitted models, each also with its walk at 0 and with the true noise."""
    _, _, add, mult = fleet_law(name)
    out: list[tuple[str, HiNoiseModel]] = []
    for noise, walk in (("mixed", True), ("mixed", False), ("multiplicative", True)):
        model = fit_hi_noise(hist, noise, walk=walk)
        kind = model.name
        out.append((kind, model))
        if model.walk_sd > 0:
            out.append((f"{kind} walk 0", dataclasses.replace(model, walk_sd=0.0)))
        out.append((f"{kind} true noise", dataclasses.replace(
            model, hi_noise_sd=add, log_noise_sd=mult, noise="mixed")))
    return out


def ladder(name: str, seed: int, units: int, draws: int) -> pd.DataFrame:
    """Print one fleet's ladder (module docstring) and return its table."""
    t0 = time.perf_counter()
    fleet = fleet_truth(name, seed, units)
    hist = fleet.hist
    print(f"\n== {name}, seed {seed}: {hist.n_units} units, {int(hist.failed.sum())} failed, "
          f"{hist.t.size} acquisitions", flush=True)
    rows: list[dict[str, object]] = []

    def rung(label: str, q: np.ndarray, model: HiNoiseModel | None, seconds: float) -> None:
        rows.append({"rung": label, **score(hist, q), **params(model, name, fleet),
                     "seconds": round(seconds, 1)})

    t = time.perf_counter()
    rung("a oracle", oracle_rows(name, fleet, seed, draws), None, time.perf_counter() - t)
    t = time.perf_counter()
    rung("a' oracle, regular cadence", oracle_rows(name, fleet, seed, draws, True), None,
         time.perf_counter() - t)
    t = time.perf_counter()
    rung("b exact Bayes, true prior", bayes_rows(name, fleet, seed, draws), None,
         time.perf_counter() - t)
    t = time.perf_counter()
    rung("b true-law", true_law_rows(name, fleet), None, time.perf_counter() - t)
    mean, sd = population_rate(name)
    prior = true_model(name, hist, POINT_VAR, mean, sd * sd)
    t = time.perf_counter()
    rung("c true-prior", model_rows(prior, hist), prior, time.perf_counter() - t)
    print(posterior_check(name, fleet, prior), flush=True)
    for regular, what in ((True, "regular cadence"), (False, "exponential gaps")):
        t = time.perf_counter()
        rung(f"c' true-prior, brute-force event, {what}",
             model_event_rows(prior, hist, draws, seed, regular), prior,
             time.perf_counter() - t)
    sample = true_model(name, hist, POINT_VAR, float(fleet.c.mean()), float(fleet.c.var(ddof=1)))
    t = time.perf_counter()
    rung("c sample-prior", model_rows(sample, hist), sample, time.perf_counter() - t)
    for label, model in fitted_rungs(name, hist):
        t = time.perf_counter()
        rung(f"d {label}", model_rows(model, hist), model, time.perf_counter() - t)
    table = pd.DataFrame(rows).set_index("rung")
    with pd.option_context("display.width", 200, "display.max_columns", 30):
        print(table.iloc[:, :8].round(3).to_string())
        print(table.iloc[:, 8:].to_string(float_format=lambda v: f"{v:.4g}"))
    print(f"(the generator's parameters on rungs a and b; scored on {int(hist.failed.sum())} "
          f"failed units; {time.perf_counter() - t0:.0f} s)", flush=True)
    return table.assign(seed=seed)


def print_over_seeds(tables: list[pd.DataFrame]) -> None:
    """Each rung's late coverage and width over the fleets: mean +- standard error, and the
    rung's paired difference from the oracle and from the exact Bayesian predictive."""
    if len(tables) < 2:
        return
    both = pd.concat(tables)
    late = both.pivot_table(index="rung", columns="seed", values="coverage_late", sort=False)
    width = both.pivot_table(index="rung", columns="seed", values="width_late", sort=False)
    k = math.sqrt(late.shape[1])

    def mse(x: pd.DataFrame) -> pd.Series:
        return x.mean(axis=1).map("{:.3f}".format) + " +- " + (x.std(axis=1) / k).map(
            "{:.3f}".format)

    out = pd.DataFrame({
        "coverage_late": mse(late), "width_late": mse(width),
        "minus_oracle": mse(late - late.loc["a oracle"]),
        "minus_exact_bayes": mse(late - late.loc["b exact Bayes, true prior"])})
    print(f"\n== over {late.shape[1]} fleets (seeds {', '.join(map(str, late.columns))}): "
          "late coverage and width, mean +- standard error; paired differences")
    print(out.to_string())


def phase_errors(rises: tuple[float, ...] = (0.1, 0.3, 0.6, 1.2, 2.5, 5.0, 10.0)) -> None:
    """:func:`event_errors` with the table of a known phase theta between readings (the
    models') and with the theta-averaged one (``first_passage.ystar_table(phase="averaged")``,
    a horizon of unknown phase), the table swapped for the second run."""
    import functools

    import rulkit.fleet.learned.first_passage as fp

    known = fp.kernel_table
    for phase in ("known", "averaged"):
        fp.kernel_table = functools.partial(known, phase)  # type: ignore[assignment]
        try:
            print(f"== {phase}")
            with pd.option_context("display.width", 250, "display.max_columns", 30):
                print(event_errors(rises).round(3).to_string(), flush=True)
        finally:
            fp.kernel_table = known  # type: ignore[assignment]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", default="mixed", choices=["additive", "multiplicative",
                                                           "mixed"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--units", type=int, default=40)
    ap.add_argument("--draws", type=int, default=400, help="the oracle's futures per prediction")
    ap.add_argument("--phases", action="store_true",
                    help="only eq. (5b)'s event per rise, known theta against theta-averaged")
    a = ap.parse_args()
    if a.phases:
        phase_errors()
        return
    print(f"load average {os.getloadavg()[0]:.1f} at the start")
    t0 = time.perf_counter()
    t = time.perf_counter()
    print("\n== eq. (5b) on a known straight path: the truth's CDF at its 5 % and 95 % "
          "quantiles, per rise c between readings (in noise sds)")
    with pd.option_context("display.width", 200, "display.max_columns", 30):
        print(event_errors().round(3).to_string())
    print(f"({time.perf_counter() - t:.0f} s)", flush=True)
    print_over_seeds([ladder(a.dataset, seed, a.units, a.draws) for seed in a.seeds])
    print(f"\ntotal {time.perf_counter() - t0:.0f} s; load average {os.getloadavg()[0]:.1f} "
          "at the end")


if __name__ == "__main__":
    main()
