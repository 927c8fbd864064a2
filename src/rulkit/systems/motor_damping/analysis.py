"""Multi-scale EKF on a user's own pull-up test data (``rulkit motor damping FILE``).

Per-cycle damping by the micro EKF (all cycles as one batch), the trend by the macro EKF after
every cycle, and the RUL in cycles (from the EKF covariance and by Monte Carlo) until the
damping reaches ``c_fail`` from the design point (seed 002 sections 3-4;
docs/systems/motor-damping.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from rulkit.systems.motor_damping.macro import (
    MacroSettings,
    MacroTrack,
    macro_track,
    quadratic_crossing,
    rul_covariance_quantiles,
    rul_monte_carlo,
)
from rulkit.systems.motor_damping.micro import MicroEKFResult, MicroEKFSettings, micro_ekf
from rulkit.systems.motor_damping.motor import MotorConstants, failure_damping
from rulkit.systems.motor_damping.pullup import PullupData, PullupDataError, estimate_noise_sd

__all__ = ["IMPOSSIBLE_SDS", "NegativeDampingError", "PullupAnalysis", "analyse_pullup",
           "check_damping_physical", "steady_current"]

IMPOSSIBLE_SDS = 5.0
"""A cycle's damping estimate more than this many of its standard deviations below zero is
physically impossible (viscous damping dissipates energy: c >= 0), not a chance draw."""


class NegativeDampingError(PullupDataError):
    """The micro EKF found a clearly negative damping: the record and the machine file
    disagree with the physics (MD-1), usually through a unit (speed in rpm, time in ms) or a
    wrong motor constant."""


def check_damping_physical(cycles: np.ndarray, c: np.ndarray, c_var: np.ndarray,
                           source: str = "") -> None:
    """Raise :class:`NegativeDampingError` when some cycle's damping ``c`` lies more than
    :data:`IMPOSSIBLE_SDS` standard deviations below zero (docs/systems/motor-damping.md §8),
    naming the first such cycle, how many there are and what to check."""
    sd = np.sqrt(np.maximum(c_var, 0.0))
    bad = np.flatnonzero(c + IMPOSSIBLE_SDS * sd < 0)
    if bad.size:
        k = int(bad[0])
        where = f"{source}: " if source else ""
        raise NegativeDampingError(
            f"{where}cycle {cycles[k]:g}: estimated damping c = {c[k]:.4g} N m s (sd "
            f"{sd[k]:.2g}) is negative, which is physically impossible ({bad.size} of "
            f"{c.size} cycles); check the units (speed in rad/s, not rpm; time in s; current "
            "in A) and the motor constants K, J, T_L ([motor] of the machine file)")


@dataclass(frozen=True)
class PullupAnalysis:
    """Result of :func:`analyse_pullup`: ``table`` (pandas DataFrame, one row per cycle),
    the macro ``track``, ``c_fail``, the noise sds and steady current used, how the
    acceleration was obtained, and the Monte Carlo RUL samples after the last cycle."""

    table: Any
    track: MacroTrack
    c_fail: float
    sigma_w: float
    sigma_dw: float
    steady_current: float
    acceleration_source: str
    last_rul_samples: np.ndarray
    last_rul_censored: np.ndarray
    horizon: float


def steady_current(data: PullupData, tail_fraction: float = 0.5) -> float:
    """Median current over the last ``tail_fraction`` of every cycle's samples (the steady
    current of the pull-up, after the initial spike)."""
    n = data.n_samples[:, None]
    idx = np.arange(data.current.shape[1])[None, :]
    tail = (idx >= np.floor((1.0 - tail_fraction) * n)) & (idx < n)
    return float(np.median(data.current[tail]))


def analyse_pullup(
    data: PullupData,
    consts: MotorConstants | None = None,
    *,
    design_speed: float = 300.0,
    design_torque: float = 16e-3,
    c_fail: float | None = None,
    i_steady: float | None = None,
    sigma_w: float | None = None,
    sigma_dw: float | None = None,
    q_a: float = 0.0,
    macro_model: str = "linear",
    mc_samples: int = 2000,
    horizon: float = 1000.0,
    n_min: int = 3,
    rng: np.random.Generator | None = None,
    micro: MicroEKFSettings | None = None,
) -> PullupAnalysis:
    """Run the multi-scale EKF on validated pull-up data.

    A clearly negative damping in any cycle raises :class:`NegativeDampingError`
    (:func:`check_damping_physical`) before any trend or RUL is computed.

    Motor constants default to :class:`MotorConstants` (the synthetic motor: pass your own).
    ``c_fail`` defaults to the design-point algebra with the steady current measured in the
    file. Noise sds default to robust estimates from the data (second differences,
    :func:`estimate_noise_sd`; an estimate of 0, from a noise-free channel, is raised to 1e-6 to
    keep the filter well posed); given values must be positive (``ValueError`` otherwise, as for
    ``mc_samples`` < 1). ``q_a``: slope random-walk density (0: the seed's linear law).
    ``macro_model``: ``"linear"`` (seed eq. 4, state [c, a]) or ``"quadratic"`` (state
    [c, a, j], :mod:`.macro`; ``q_a`` is then the curvature's random-walk
    density). The table's ``trend_crossing`` is the analytic crossing of the posterior-mean
    trend with ``c_fail`` (:func:`quadratic_crossing`), ``curvature_per_cycle2`` the curvature
    j (NaN for the linear law).
    """
    import pandas as pd

    for name, v in (("sigma_w", sigma_w), ("sigma_dw", sigma_dw), ("c_fail", c_fail),
                    ("i_steady", i_steady)):
        if v is not None and not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name}: expected a positive finite value, got {v!r}")
    if isinstance(mc_samples, bool) or int(mc_samples) != mc_samples or mc_samples < 1:
        raise ValueError(f"mc_samples: expected a positive integer, got {mc_samples!r}")
    if not (np.isfinite(horizon) and horizon > 0):
        raise ValueError(f"horizon: expected a positive number of cycles, got {horizon!r}")
    if int(n_min) != n_min or n_min < 3:
        raise ValueError(f"n_min: expected an integer >= 3 (the scatter needs a residual), "
                         f"got {n_min!r}")
    consts = consts or MotorConstants()
    rng = rng or np.random.default_rng(0)
    i_s = steady_current(data) if i_steady is None else float(i_steady)
    cf = (
        failure_damping(consts, design_speed, design_torque, steady_current=i_s)
        if c_fail is None else float(c_fail)
    )
    sw = estimate_noise_sd(data.speed) if sigma_w is None else float(sigma_w)
    sdw = (
        estimate_noise_sd(data.acceleration)
        if sigma_dw is None and data.acceleration_measured
        else (1.0 if sigma_dw is None else float(sigma_dw))
    )
    # a perfectly smooth (noise-free) channel would give sd 0: keep the filter well posed
    sw = max(sw, 1e-6)
    sdw = max(sdw, 1e-6)
    base = micro or MicroEKFSettings()
    settings = replace(
        base, sigma_w=sw, sigma_dw=sdw,
        use_acceleration=base.use_acceleration and data.acceleration_measured,
    )
    res = micro_ekf(
        data.time, data.current, data.speed,
        data.acceleration if settings.use_acceleration else None, consts, settings,
    )
    check_damping_physical(data.cycle, res.c, res.c_var, data.source)
    z = res.c[None, :]
    r = res.c_var[None, :]
    macro = MacroSettings(q_a=q_a, model=macro_model)
    track = macro_track(data.cycle, z, r, macro)
    rows, last_s, last_c = _cycle_rows(data, res, track, macro, cf, rng,
                                       (q_a, mc_samples, horizon, n_min))
    return PullupAnalysis(
        table=pd.DataFrame(rows), track=track, c_fail=cf, sigma_w=sw, sigma_dw=sdw,
        steady_current=i_s, acceleration_source=data.acceleration_source,
        last_rul_samples=last_s, last_rul_censored=last_c, horizon=horizon,
    )


def _cycle_rows(data: PullupData, res: MicroEKFResult, track: MacroTrack, macro: MacroSettings,
                cf: float, rng: np.random.Generator, rul: tuple[float, int, float, int]
                ) -> tuple[list[dict[str, Any]], np.ndarray, np.ndarray]:
    """One row per cycle of :func:`analyse_pullup`'s table (the damping, the trend after the
    cycle and, from cycle ``n_min`` on, the RUL quantiles from the covariance and by Monte
    Carlo), and the Monte Carlo samples after the last cycle. ``rul``: ``(q_a, mc_samples,
    horizon, n_min)``."""
    q_a, mc_samples, horizon, n_min = rul
    n = data.n_cycles
    rows = []
    last_s = np.array([])
    last_c = np.array([], dtype=bool)
    for k in range(n):
        x, P = track.x[k], track.P[k]
        row = {
            "cycle": int(data.cycle[k]),
            "n_samples": int(data.n_samples[k]),
            "damping": res.c[k],
            "damping_sd": float(np.sqrt(res.c_var[k])),
            "trend_damping": x[0, 0],
            "slope_per_cycle": x[0, 1],
            "slope_sd": float(np.sqrt(P[0, 1, 1])),
            "curvature_per_cycle2": x[0, 2] if macro.dim == 3 else np.nan,
            "curvature_sd": float(np.sqrt(P[0, 2, 2])) if macro.dim == 3 else np.nan,
            "trend_crossing": float(quadratic_crossing(
                x[0, 0], x[0, 1], x[0, 2] if macro.dim == 3 else 0.0, cf
            )),
            "scatter_sd": float(np.sqrt(track.scatter_var[k, 0])),
            "gated": int(res.n_gated[k]) if res.n_gated is not None else 0,
        }
        if k + 1 >= n_min:
            q = rul_covariance_quantiles(
                x, P, cf, np.array([0.05, 0.5, 0.95]), q_a=q_a, horizon=horizon
            )[0]
            smp, cen = rul_monte_carlo(
                x, P, cf, rng, n_samples=mc_samples, q_a=q_a, horizon=horizon,
                t0=float(data.cycle[k]),
            )
            keyed = np.where(cen[0], np.inf, smp[0])
            mq = np.quantile(keyed, [0.05, 0.5, 0.95], method="inverted_cdf")
            row.update({
                "rul_median": q[1], "rul_p05": q[0], "rul_p95": q[2],
                "rul_mc_median": mq[1], "rul_mc_p05": mq[0], "rul_mc_p95": mq[2],
                "rul_mc_fraction_censored": float(cen[0].mean()),
            })
            last_s, last_c = smp[0], cen[0]
        else:
            row.update({k2: np.nan for k2 in (
                "rul_median", "rul_p05", "rul_p95", "rul_mc_median", "rul_mc_p05",
                "rul_mc_p95", "rul_mc_fraction_censored")})
        rows.append(row)
    return rows, last_s, last_c
