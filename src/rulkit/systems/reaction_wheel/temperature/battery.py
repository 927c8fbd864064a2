"""A battery of simulated wheel records with known temperature, to measure the step-1
estimators' accuracy and the calibration of their intervals (docs/systems/reaction-wheel.md
§3.4): temperature steps, ramps and sines under piecewise-constant commands, the seed's Table 3
path, on the seed's wheel and on other wheels (constants drawn around the seed's, another
viscous law), at both noise levels of seed Table 5, clean or with the corruptions of
:func:`rulkit.systems.reaction_wheel.simulate.corrupt`.

Every record is drawn from ``SeedSequence([seed, kind, wheel, noise, run])`` alone, so a case
is the same whatever else is run. :func:`score` gives the RMSPE of T and the coverage of the
interval over the samples after ``t_min`` (200 s: the time constant of the wheel is ~200 s,
before it the estimate is still the prior's).

    cases = battery_cases(seed=0, runs=2)
    df, params, sigma = battery_record(cases[0])
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from rulkit.systems.reaction_wheel.simulate import simulate_telemetry
from rulkit.systems.reaction_wheel.wheel import (
    NOISE_LEVELS,
    IthacoParams,
    table3_temperature,
    table3_voltage,
)

#: Temperature paths of the battery.
KINDS = ("step", "ramp", "sine", "table3")
#: Wheels: the seed's, and others drawn around it.
WHEELS = ("seed", "other")
#: Length of a record (s) and the start of the scored part.
DURATION_S = 800.0
T_MIN_S = 200.0


@dataclass(frozen=True)
class BatteryCase:
    """One record of the battery: a temperature path ``kind``, a ``wheel``, a ``noise`` level,
    a ``run`` index and the battery's ``seed``."""

    kind: str
    wheel: str
    noise: str
    run: int
    seed: int

    def rng(self) -> np.random.Generator:
        """The case's own generator (independent of every other case)."""
        return np.random.default_rng(np.random.SeedSequence(
            [self.seed, KINDS.index(self.kind), WHEELS.index(self.wheel),
             sorted(NOISE_LEVELS).index(self.noise), self.run]))


def battery_cases(seed: int, runs: int, *, kinds: tuple[str, ...] = KINDS,
                  wheels: tuple[str, ...] = WHEELS,
                  noises: tuple[str, ...] = ("low", "high")) -> list[BatteryCase]:
    """Every (kind, wheel, noise, run) case; the Table 3 path only on the seed's wheel."""
    return [BatteryCase(k, w, n, r, seed) for k in kinds for w in wheels for n in noises
            for r in range(runs) if not (k == "table3" and w != "seed")]


def other_wheel(rng: np.random.Generator) -> IthacoParams:
    """A wheel around the seed's: inertia x0.6-1.6, torque/back-EMF constants, driver gain x0.8-
    1.25, bandwidth x0.7-1.4, Coulomb friction x0.5-2, a linear viscous law whose level and
    slope are x0.7-1.4 and x0.5-1.5 the seed's."""
    p = IthacoParams()
    k = rng.uniform(0.8, 1.25)
    return replace(p, J=p.J * rng.uniform(0.6, 1.6), K_t=p.K_t * k, K_e=p.K_e * k,
                   G_d=p.G_d * rng.uniform(0.8, 1.25), w_d=p.w_d * rng.uniform(0.7, 1.4),
                   tau_c=p.tau_c * rng.uniform(0.5, 2.0), friction_law="linear",
                   viscous_at_0C=p.viscous_at_0C * rng.uniform(0.7, 1.4),
                   viscous_per_C=p.viscous_per_C * rng.uniform(0.5, 1.5))


def battery_paths(kind: str, rng: np.random.Generator, dt: float = 0.05
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The temperature (C) and command (V) of a record of ``kind``, every ``dt`` s over
    :data:`DURATION_S`: a step of 2-8 C (either sign) at 100-500 s, a ramp of 3-10 C over the
    record, a sine of 1-5 C and 300-2000 s period, from 18-35 C; commands held at 1-3 V for
    60-300 s each; or the seed's Table 3 path (RW-8, RW-9)."""
    t = np.arange(0.0, DURATION_S, dt)
    if kind == "table3":
        return np.asarray(table3_temperature(t)), np.asarray(table3_voltage(t))
    T0 = rng.uniform(18.0, 35.0)
    if kind == "step":
        at, size = rng.uniform(100.0, 500.0), rng.choice([-1.0, 1.0]) * rng.uniform(2.0, 8.0)
        T = np.where(t < at, T0, T0 + size)
    elif kind == "ramp":
        T = T0 + rng.choice([-1.0, 1.0]) * rng.uniform(3.0, 10.0) * t / DURATION_S
    elif kind == "sine":
        A, period, phase = rng.uniform(1.0, 5.0), rng.uniform(300.0, 2000.0), rng.uniform(0, 7)
        T = T0 + A * np.sin(2.0 * np.pi * t / period + phase)
    else:
        raise ValueError(f"kind: expected one of {KINDS}, got {kind!r}")
    V = np.empty_like(t)
    i = 0
    while i < t.size:
        n = int(rng.uniform(60.0, 300.0) / dt)
        V[i:i + n] = rng.uniform(1.0, 3.0)
        i += n
    return T, V


def battery_record(case: BatteryCase) -> tuple[Any, IthacoParams, tuple[float, float]]:
    """The simulated record of ``case`` (telemetry columns plus the true ``T_lub_C``), its
    wheel and its noise (sigma_w, sigma_I)."""
    rng = case.rng()
    T, V = battery_paths(case.kind, rng)
    params = other_wheel(rng) if case.wheel == "other" else IthacoParams()
    sigma = NOISE_LEVELS[case.noise]
    df = simulate_telemetry(T, V, rng, params=params, sigma=sigma,
                            initial="rest" if case.kind == "table3" else "equilibrium")
    return df, params, sigma


def score(truth: Any, est: Any, t_min: float = T_MIN_S) -> dict[str, float]:
    """RMSPE of T (%) and coverage of ``[T_lo, T_hi]`` over the rows of ``est`` whose time since
    the record's start is at least ``t_min`` (matched to ``truth`` by ``time_s``)."""
    from rulkit.metrics import rmspe

    T = truth.set_index("time_s")["T_lub_C"].reindex(est["time_s"]).to_numpy()
    t = est["time_s"].to_numpy() - float(truth["time_s"].iloc[0])
    late = t >= t_min
    m, lo, hi = (est[c].to_numpy()[late] for c in ("T_mean", "T_lo", "T_hi"))
    return {"rmspe": float(rmspe(m, T[late])),
            "coverage": float(np.mean((lo <= T[late]) & (T[late] <= hi)))}
