"""Step 3 on a user's record: the RUL distribution from the step-2 posterior along a future
temperature profile the user gives, to a loss threshold the user gives
(docs/systems/reaction-wheel.md §5, §7.3).

The future is a **cycle** of windows repeated until the threshold: either a temperature
profile (``time_s`` since the prediction time, ``T_C``; a file, repeated after its end), cut
into windows of ``window_s`` whose Gauss rules are built on the profile sampled every
:data:`PROFILE_STEP_S`, or the last days of the step-1 estimate itself (their loss windows'
rules, the default: "the next week is like the last one"). Per particle ``(b, beta0)`` the loss
of window j is ``beta0 S_j(b) dt`` (RW-24); the loss over a cycle ``C`` and the cumulative
losses within it give the crossing of ``X_total`` in closed form: ``n`` whole cycles, then the
window where the remaining loss is reached, linearly interpolated within it (as
:func:`rulkit.prognosis.rul.propagate_to_threshold` does, tested equal on the same windows).
A particle that would need longer than ``horizon_days`` is censored there.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rulkit.systems.reaction_wheel.degradation.quadrature import (
    WindowQuadrature,
    window_quadrature,
)
from rulkit.systems.reaction_wheel.lubrication import DAY_S, SAMPLE_DT, T_MIN_C

FloatArray = np.ndarray
#: Sampling of a future temperature profile inside a forecast window (s).
PROFILE_STEP_S = 60.0


class ProfileError(ValueError):
    """A future temperature profile that cannot be used (names the file, column and row)."""


@dataclass(frozen=True)
class FutureCycle:
    """Future windows repeated in a cycle: ``quad`` the Gauss rule of ``1/T`` per window
    (arrays (W, n) and ``count`` (W,): the 0.05 s samples of each window), ``duration_s``
    (W,), and a ``description`` for the report."""

    quad: WindowQuadrature
    duration_s: FloatArray
    description: str

    @property
    def period_s(self) -> float:
        """Length of the cycle (s)."""
        return float(self.duration_s.sum())


def cycle_from_profile(t_s: FloatArray, T_C: FloatArray, window_s: float, n_nodes: int = 5,
                       description: str = "the given profile") -> FutureCycle:
    """The cycle of a temperature profile ``T_C`` at times ``t_s`` (s since the prediction
    time, increasing, starting at 0) in windows of ``window_s`` (the last one shortened to the
    profile's end), the temperature interpolated every :data:`PROFILE_STEP_S` within each."""
    t_s, T_C = np.asarray(t_s, dtype=np.float64), np.asarray(T_C, dtype=np.float64)
    end = float(t_s[-1])
    if not end > 0:
        raise ProfileError("the future profile must span a positive time")
    edges = np.append(np.arange(0.0, end, window_s), end)
    dur = np.diff(edges)
    m = max(2, int(np.ceil(window_s / PROFILE_STEP_S)))
    pts = edges[:-1, None] + (np.arange(m) + 0.5)[None, :] / m * dur[:, None]
    T = np.interp(pts, t_s, T_C)
    if T.min() < T_MIN_C:
        raise ProfileError(f"the future profile reaches {T.min():.4g} C; the loss law needs "
                           f"T >= {T_MIN_C:g} C (docs/systems/reaction-wheel.md §4)")
    q = window_quadrature(1.0 / T, n_nodes, count=dur / SAMPLE_DT)
    return FutureCycle(q, dur, description)


def cycle_from_windows(quad: WindowQuadrature, start_s: FloatArray, end_s: FloatArray,
                       last_s: float) -> FutureCycle:
    """The cycle of the loss windows of the record's last ``last_s`` seconds (their rules from
    the step-1 estimate; ``quad`` of one unit, arrays (1, W, n), count (1, W) or (W,))."""
    take = np.flatnonzero(end_s > end_s[-1] - last_s)
    count = np.broadcast_to(np.asarray(quad.count, dtype=np.float64), quad.center.shape)
    q = WindowQuadrature(quad.center[0, take], quad.scale[0, take], quad.nodes[0, take],
                         quad.weights[0, take], count[0, take])
    span = (end_s[take[-1]] - start_s[take[0]]) / DAY_S
    return FutureCycle(q, (end_s - start_s)[take],
                       f"the last {span:.3g} days of the step-1 estimate, repeated")


def read_profile(path: str | Path) -> tuple[FloatArray, FloatArray]:
    """A future temperature profile file: ``time_s`` (s since the prediction time, increasing,
    from 0) and ``T_C`` (deg C), CSV or Parquet; checked, named errors."""
    from rulkit.tables import numeric_columns, read_table

    df = read_table(path, error=ProfileError, expected_columns=("time_s", "T_C"))
    missing = [c for c in ("time_s", "T_C") if c not in df.columns]
    if missing:
        raise ProfileError(f"{path}: missing column(s) {missing}; a profile has time_s (s since "
                           f"the prediction time) and T_C (columns found: {list(df.columns)})")
    v = numeric_columns(df, ("time_s", "T_C"), error=ProfileError, source=str(path))
    t, T = v["time_s"], v["T_C"]
    if t[0] != 0.0:
        raise ProfileError(f"{path}: column 'time_s', row 1: the profile starts at the "
                           f"prediction time, time_s = 0, got {t[0]:g}")
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size or t.size < 2:
        r = int(bad[0]) + 2 if bad.size else 2
        raise ProfileError(f"{path}: column 'time_s', row {r}: at least 2 rows, times strictly "
                           "increasing")
    return t, T


def cycle_increments(b: FloatArray, beta0: FloatArray, cycle: FutureCycle) -> FloatArray:
    """The loss (mL) of every cycle window for every particle, (N, W): ``beta0 S_j(b) dt``."""
    q = cycle.quad
    lc = np.log(np.broadcast_to(np.asarray(q.count, dtype=np.float64), q.center.shape))
    inner = (q.weights[None] * np.exp(-(b[:, None] * q.scale[None])[..., None]
                                      * q.nodes[None])).sum(axis=-1)
    return beta0[:, None] * np.exp(lc[None] - b[:, None] * q.center[None]
                                   + np.log(inner)) * SAMPLE_DT


def predict_rul(particles: FloatArray, weights: FloatArray, X_k: float, cycle: FutureCycle,
                threshold_mL: float, horizon_days: float) -> Any:
    """The RUL distribution (days) of the posterior ``particles`` (N, 2) of [b, beta0] with
    ``weights``, from the cumulative loss ``X_k`` (mL) along the repeated ``cycle`` to
    ``threshold_mL`` (module docstring); censored at ``horizon_days``."""
    from rulkit.prognosis.rul import RULDistribution

    b, beta0 = particles[:, 0], particles[:, 1]
    need = float(threshold_mL) - float(X_k)
    horizon_s = horizon_days * DAY_S
    if need <= 0:
        return RULDistribution(np.zeros(b.size), weights, horizon=horizon_days)
    inc = cycle_increments(b, beta0, cycle)
    cum = np.cumsum(inc, axis=1)
    C = cum[:, -1]
    n_full = np.floor(need / C)
    rest = need - n_full * C
    at_edge = rest <= 0  # exactly a whole number of cycles
    n_full = np.where(at_edge, n_full - 1, n_full)
    rest = np.where(at_edge, C, rest)
    j = np.minimum((cum < rest[:, None]).sum(axis=1), cum.shape[1] - 1)
    rows = np.arange(b.size)
    before = np.where(j > 0, cum[rows, np.maximum(j - 1, 0)], 0.0)
    frac = np.clip((rest - before) / inc[rows, j], 0.0, 1.0)
    starts = np.concatenate([[0.0], np.cumsum(cycle.duration_s)[:-1]])
    t = n_full * cycle.period_s + starts[j] + frac * cycle.duration_s[j]
    censored = ~(t <= horizon_s)
    t = np.where(censored, horizon_s, t)
    return RULDistribution(t / DAY_S, weights, censored=censored, horizon=horizon_days)
