"""Per-unit regression: each unit's own recent trend, extrapolated to the threshold.

docs/fleet-models.md section 6, eq. (11). The baseline a practitioner writes in ten lines: fit
g(hi) = a + b x by least squares on the unit's own recent acquisitions (no fleet prior on the
rate) and extrapolate to g(1). Recent means exponentially forgotten: acquisition j back gets the
weight rho^j, rho = 1 - 1/W for a window of about W acquisitions, so the state is six weighted
sums (O(1) per unit and update):

    S = rho S + (1, x, x^2, z, x z, z^2),   z = g(hi) (Box-Cox, hi clipped at a floor).

The weighted fit gives (a, b) and, with the residual variance pooled with the fleet's
(``noise_var`` with ``prior_dof`` pseudo-observations), the Gaussian of (a, b); the level at the
unit's age and the rate then have the same closed-form RUL as eq. (5)-(6) (no random walk). A
unit with fewer than three acquisitions, or a non-positive fitted rate, has RUL +inf where its
failing mass ends (censored mass). ``fit_regression`` picks the shape (Paris exponent m in
{0, 1, 2, 3}) and W in {5, 10, 20, 40} that give the training units' best scores (the
prediction score of :mod:`rulkit.fleet.learned.scoring`), each unit scored on its own data only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from rulkit.fleet.learned.degradation import UnitState, rul_cdf, rul_quantiles, time_scale_of
from rulkit.fleet.learned.growth_filter import boxcox, growth_hi_quantiles
from rulkit.fleet.learned.hi_noise import check_forward
from rulkit.fleet.learned.histories import Histories

FloatArray = NDArray[np.float64]
SUM_COLUMNS = ("s_1", "s_x", "s_xx", "s_z", "s_xz", "s_zz")
WINDOWS = (5.0, 10.0, 20.0, 40.0)
EXPONENTS = (0.0, 1.0, 2.0, 3.0)
HI_FLOOR = 1e-3


@dataclass
class SumsState:
    """Per unit: forgotten weighted sums ``s (B, K)`` named :attr:`NAMES` (this module's
    :data:`SUM_COLUMNS`; a subclass names others) and ``t``, ``hi``, ``n`` as
    :class:`~rulkit.fleet.learned.degradation.UnitState`'s."""

    NAMES: ClassVar[tuple[str, ...]] = SUM_COLUMNS
    s: FloatArray
    t: FloatArray
    hi: FloatArray
    n: NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def take(self, idx: np.ndarray) -> SumsState:
        """The states of the units ``idx``."""
        return type(self)(s=self.s[idx], t=self.t[idx], hi=self.hi[idx], n=self.n[idx])

    def columns(self) -> dict[str, np.ndarray]:
        """Named columns, as stored."""
        out: dict[str, np.ndarray] = {c: self.s[:, j] for j, c in enumerate(self.NAMES)}
        out.update({"t": self.t, "hi": self.hi, "n": self.n})
        return out

    @classmethod
    def from_columns(cls, c: dict[str, Any], width: int = 6) -> SumsState:
        """Inverse of :meth:`columns` (``width`` sums named ``s_...``)."""
        names = [k for k in c if k.startswith("s_")][:width]
        return cls(s=np.column_stack([np.asarray(c[k], dtype=np.float64) for k in names]),
                   t=np.asarray(c["t"], dtype=np.float64),
                   hi=np.asarray(c["hi"], dtype=np.float64),
                   n=np.asarray(c["n"], dtype=np.int64))


@dataclass(frozen=True)
class RegressionModel:
    """Per-unit forgotten least squares on the Box-Cox scale (module docstring)."""

    shape: float
    window: float
    noise_var: float
    time_scale: float
    prior_dof: float = 2.0
    time_unit: str = ""
    n_units: int = 0
    n_failed: int = 0
    log_likelihood: float = math.nan
    warnings: tuple[str, ...] = ()
    time_axis: dict[str, Any] | None = None

    state_columns = (*SUM_COLUMNS, "t", "hi", "n")
    threshold = 0.0
    walk_sd = 0.0

    @property
    def name(self) -> str:
        """The candidate's name, ``regression``."""
        return "regression"

    @property
    def paris_exponent(self) -> float:
        """m = 2 (1 - lam) of the shape the trends are fitted on."""
        return 2.0 * (1.0 - self.shape)

    def empty_state(self, size: int) -> SumsState:
        """``size`` units without acquisitions."""
        return SumsState(s=np.zeros((size, 6)), t=np.full(size, np.nan),
                         hi=np.full(size, np.nan), n=np.zeros(size, dtype=np.int64))

    def state_from_columns(self, c: dict[str, Any]) -> SumsState:
        """A state from its stored columns."""
        return SumsState.from_columns(c)

    def _rows(self, t: FloatArray, hi: FloatArray) -> FloatArray:
        x = t / self.time_scale
        z = boxcox(np.maximum(hi, HI_FLOOR), self.shape)
        return np.stack([np.ones_like(x), x, x * x, z, x * z, z * z], axis=-1)

    def update(self, state: SumsState, t: np.ndarray, hi: np.ndarray) -> SumsState:
        """One acquisition per unit (NaN = none): S = rho S + row."""
        t = np.asarray(t, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        check_forward(np.where(state.n > 0, state.t, np.nan), t)
        have = np.isfinite(t) & np.isfinite(hi)
        rho = 1.0 - 1.0 / self.window
        rows = self._rows(np.where(have, t, 0.0), np.where(have, hi, 1.0))
        s = np.where(have[:, None], rho * state.s + rows, state.s)
        return SumsState(s=s, t=np.where(have, t, state.t), hi=np.where(have, hi, state.hi),
                         n=state.n + have)

    def replay(self, hist: Histories) -> SumsState:
        """The state after each row of ``hist`` (a recursion per unit, vectorised over units)."""
        rows = self._rows(hist.t, hist.hi)
        rho = 1.0 - 1.0 / self.window
        k = np.arange(len(hist.t)) - hist.start[hist.unit]  # rank within the unit
        s = np.empty_like(rows)
        for u in range(hist.n_units):
            sl = hist.rows(u)
            s[sl] = forgotten_sums(rows[sl], rho)
        return SumsState(s=s, t=hist.t.copy(), hi=hist.hi.copy(), n=(k + 1).astype(np.int64))

    def gaussian(self, state: SumsState) -> UnitState:
        """The Gaussian of (level at the unit's age, rate) from the sums (eq. (11))."""
        n, sx, sxx, sz, sxz, szz = state.s.T
        with np.errstate(divide="ignore", invalid="ignore"):
            det = n * sxx - sx * sx
            ok = (state.n >= 3) & (det > 1e-12 * np.maximum(n * sxx, 1e-300))
            b = np.where(ok, (n * sxz - sx * sz) / det, 0.0)
            a = np.where(ok, (sz - b * sx) / n, 0.0)
            rss = np.maximum(szz - a * sz - b * sxz, 0.0)
            dof = np.maximum(n - 2.0, 0.0)
            var = (self.prior_dof * self.noise_var + rss) / (self.prior_dof + dof)
            caa, cab, cbb = var * sxx / det, -var * sx / det, var * n / det
            x0 = np.where(state.n > 0, state.t, 0.0) / self.time_scale
            mz = a + b * x0
            pzz = caa + 2.0 * x0 * cab + x0 * x0 * cbb
            pzb = cab + x0 * cbb
        # no trend yet: the level is the last measurement, the rate unknown (centred at 0,
        # so half the mass never fails and the interval is [small, inf])
        z_last = boxcox(np.maximum(np.nan_to_num(state.hi, nan=1.0), HI_FLOOR), self.shape)
        m = np.column_stack([np.where(ok, mz, z_last), np.where(ok, b, 0.0)])
        p = np.column_stack([np.where(ok, pzz, self.noise_var), np.where(ok, pzb, 0.0),
                             np.where(ok, cbb, 1e6 * self.noise_var)])
        return UnitState(m=m, p=p, t=state.t, hi=state.hi, n=state.n)

    def rul_quantiles(self, state: SumsState, levels: tuple[float, ...] = (0.5, 0.05, 0.95)
                      ) -> tuple[FloatArray, ...]:
        """RUL quantiles per unit (eq. (5)-(6) on :meth:`gaussian`)."""
        return rul_quantiles(self, self.gaussian(state), levels)

    def hi_quantiles(self, state: SumsState, horizons: FloatArray,
                     levels: tuple[float, ...]) -> tuple[FloatArray, ...]:
        """The HI forecast ``horizons (B, K)`` after the last acquisition: each unit's line."""
        g = self.gaussian(state)
        return growth_hi_quantiles(g.m, g.p, 0.0, self.time_scale, self.shape, horizons,
                                   levels)

    def rul_cdf(self, state: SumsState, r: FloatArray) -> FloatArray:
        """P(RUL <= r), ``r (B, K)``."""
        return rul_cdf(self, self.gaussian(state), r)

    def to_dict(self) -> dict[str, Any]:
        """The model as JSON-ready numbers."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["warnings"] = list(self.warnings)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RegressionModel:
        """Inverse of :meth:`to_dict`."""
        d = {k: v for k, v in d.items() if k != "type"}
        d["warnings"] = tuple(d.get("warnings", ()))
        return cls(**d)

    def describe(self) -> str:
        """One line with the chosen settings."""
        return (f"regression baseline: each unit's own Box-Cox trend (Paris exponent m = "
                f"{self.paris_exponent:g}) over about its last {self.window:g} acquisitions, "
                f"extrapolated to hi = 1; pooled residual sd {math.sqrt(self.noise_var):.3g} "
                f"(growth scale); chosen on {self.n_units} units ({self.n_failed} failed)")


def forgotten_sums(rows: FloatArray, rho: float) -> FloatArray:
    """S_k = rho S_{k-1} + row_k (S_-1 = 0) down the rows of one unit (a first-order
    recursive filter per column)."""
    from scipy.signal import lfilter

    return np.asarray(lfilter([1.0], [1.0, -rho], rows, axis=0))


def pooled_noise_var(hist: Histories, shape: float) -> float:
    """Residual variance of per-unit straight lines of g(hi) on age, pooled over units."""
    z = boxcox(np.maximum(hist.hi, HI_FLOOR), shape)
    rss, dof = 0.0, 0
    for u in range(hist.n_units):
        sl = hist.rows(u)
        if sl.stop - sl.start >= 3:
            coef = np.polyfit(hist.t[sl], z[sl], 1)
            rss += float(np.sum((z[sl] - np.polyval(coef, hist.t[sl])) ** 2))
            dof += sl.stop - sl.start - 2
    return rss / dof if dof > 0 and rss > 0 else 1e-4


def fit_regression(hist: Histories, *, shape: float | None = None,
                   window: float | None = None) -> RegressionModel:
    """Choose the shape and window on the training units (module docstring)."""
    from rulkit.fleet.learned.scoring import replay_scores

    tau = time_scale_of(hist)
    shapes = [1.0 - m / 2.0 for m in EXPONENTS] if shape is None else [shape]
    windows = list(WINDOWS) if window is None else [window]
    models = [RegressionModel(shape=sh, window=w, noise_var=pooled_noise_var(hist, sh),
                              time_scale=tau, n_units=hist.n_units,
                              n_failed=int(hist.failed.sum()))
              for sh in shapes for w in windows]
    if len(models) == 1:
        return models[0]
    return min(models, key=lambda m: replay_scores(m, hist).score)


__all__ = ["EXPONENTS", "SUM_COLUMNS", "WINDOWS", "RegressionModel", "SumsState",
           "fit_regression", "forgotten_sums", "pooled_noise_var"]
