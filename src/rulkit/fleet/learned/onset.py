"""Degradation after an onset: a healthy, flat period per unit, then Box-Cox growth.

docs/fleet-models.md section 6, eq. (9)-(10). Turbofan and bearing HIs are flat, then grow. The
growth law of eq. (7) runs in max(x - s, 0): the unit's level stays put until its onset s, then
grows at its rate. s is unknown per unit; it takes the values of a fixed grid s_1..s_K (from 0
to past the longest observed life, in scaled age) with fleet probabilities pi_k from a normal
density (mean and sd learned). Each grid value runs its own filter (eq. (8)); a unit's
posterior is their mixture with weights pi_k L_k (normalised).

RUL (eq. (10)): with w_k the posterior weights, x0 the unit's scaled age and
e_k(r) = max(x0 + r - s_k, 0) - max(x0 - s_k, 0) the growth time the horizon r adds under
s_k, the survival is S(r) = sum_k w_k S_k(e_k(r)) / sum_k w_k S_k(0), S_k the Gaussian exceedance
of eq. (5) for component k. Quantiles by bisection (compiled, per unit);
a level beyond the failing mass sum_k w_k (S_k(0) - S_k(inf)) is +inf (censored mass).

Usage::

    model = fit_onset(hist)
    state = model.update(model.empty_state(3), t, hi)
    med, lo, hi90 = model.rul_quantiles(state, (0.5, 0.05, 0.95))
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rulkit.fleet.learned.degradation import time_scale_of
from rulkit.fleet.learned.growth_filter import GrowthParams, onset_prior
from rulkit.fleet.learned.growth_fit import (
    FitDiagnostics,
    GrowthFit,
    GrowthSpec,
    fit_growth,
    profile_shape,
)
from rulkit.fleet.learned.hi_noise import HiNoiseModel, check_forward, fit_hi_noise
from rulkit.fleet.learned.histories import Histories

FloatArray = NDArray[np.float64]
ONSET_GRID_SIZE = 12
"""Onset values of the first grid; :func:`fit_onset` refines it until the likelihood converges."""
ONSET_GRID_TOL = 1.0
"""Nats: a grid is fine enough when halving its step changes the fleet's log-likelihood at the
fitted parameters by less than this (the quadrature of eq. (9) has converged)."""
ONSET_GRID_MAX = 96
"""A bound on the grid :func:`fit_onset` refines to (89 values: 12 with the step halved three
times)."""


@dataclass
class MixtureState:
    """Posterior of B units over the K onset values (struct of arrays): ``lw (B, K)``
    normalised log-weights, ``m (B, K, 2)`` means of (level, rate), ``p (B, K, 3)``
    covariances, ``t``/``hi``/``n`` as :class:`~rulkit.fleet.learned.degradation.UnitState`'s.
    """

    lw: FloatArray
    m: FloatArray
    p: FloatArray
    t: FloatArray
    hi: FloatArray
    n: NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def take(self, idx: np.ndarray) -> MixtureState:
        """The states of the units ``idx``."""
        return MixtureState(lw=self.lw[idx], m=self.m[idx], p=self.p[idx], t=self.t[idx],
                            hi=self.hi[idx], n=self.n[idx])

    def columns(self) -> dict[str, np.ndarray]:
        """Flat named columns (``lw_k``, ``m_z_k``, ``m_b_k``, ``p_zz_k``, ``p_zb_k``,
        ``p_bb_k`` per grid value k, then ``t``, ``hi``, ``n``)."""
        out: dict[str, np.ndarray] = {}
        for k in range(self.lw.shape[1]):
            out[f"lw_{k}"] = self.lw[:, k]
            out[f"m_z_{k}"], out[f"m_b_{k}"] = self.m[:, k, 0], self.m[:, k, 1]
            for j, name in enumerate(("p_zz", "p_zb", "p_bb")):
                out[f"{name}_{k}"] = self.p[:, k, j]
        out.update({"t": self.t, "hi": self.hi, "n": self.n})
        return out


def mixture_columns(k: int) -> tuple[str, ...]:
    """Stored column names of a :class:`MixtureState` with ``k`` grid values."""
    names = []
    for j in range(k):
        names += [f"lw_{j}", f"m_z_{j}", f"m_b_{j}", f"p_zz_{j}", f"p_zb_{j}", f"p_bb_{j}"]
    return (*names, "t", "hi", "n")


@dataclass(frozen=True)
class OnsetModel:
    """A fitted onset model (module docstring): the growth of
    :class:`~rulkit.fleet.learned.hi_noise.HiNoiseModel` (``noise`` additive or mixed) in
    max(x - s, 0), with the onset grid ``grid`` (scaled age) and its normal prior
    (``onset_mean``, ``onset_sd``, scaled age)."""

    noise: str
    shape: float
    mean: tuple[float, float]
    cov: tuple[float, float, float]
    hi_noise_sd: float
    log_noise_sd: float
    walk_sd: float
    time_scale: float
    grid: tuple[float, ...]
    onset_mean: float
    onset_sd: float
    time_unit: str = ""
    n_units: int = 0
    n_failed: int = 0
    log_likelihood: float = math.nan
    warnings: tuple[str, ...] = ()
    time_axis: dict[str, Any] | None = None
    diagnostics: FitDiagnostics | None = field(default=None, compare=False, repr=False)

    threshold = 0.0

    @property
    def name(self) -> str:
        """The candidate's name, ``onset``."""
        return "onset"

    @property
    def paris_exponent(self) -> float:
        """m = 2 (1 - lam)."""
        return 2.0 * (1.0 - self.shape)

    @property
    def measured_var(self) -> float:
        """Variance of a measurement at hi = 1 on the growth scale (see
        :attr:`rulkit.fleet.learned.hi_noise.HiNoiseModel.measured_var`)."""
        return self.hi_noise_sd**2 + self.log_noise_sd**2

    @property
    def state_columns(self) -> tuple[str, ...]:
        """The stored state columns (:func:`mixture_columns`)."""
        return mixture_columns(len(self.grid))

    def params(self) -> GrowthParams:
        """The parameters as :class:`~rulkit.fleet.learned.growth_filter.GrowthParams`."""
        return GrowthParams(mean=self.mean, cov=self.cov, r_log=self.log_noise_sd**2,
                            r_hi=self.hi_noise_sd**2, q=self.walk_sd**2,
                            onset_mean=self.onset_mean, onset_sd=self.onset_sd)

    # -- the unit state
    def empty_state(self, size: int) -> MixtureState:
        """``size`` units before their first acquisition (the prior mixture)."""
        k = len(self.grid)
        prior = np.array([*self.mean, *self.cov])
        lw = onset_prior(np.asarray(self.grid), self.onset_mean, self.onset_sd)
        return MixtureState(lw=np.tile(lw, (size, 1)),
                            m=np.tile(prior[:2], (size, k, 1)),
                            p=np.tile(prior[2:], (size, k, 1)), t=np.full(size, np.nan),
                            hi=np.full(size, np.nan), n=np.zeros(size, dtype=np.int64))

    def state_from_columns(self, c: dict[str, Any]) -> MixtureState:
        """A state from its stored columns (:func:`mixture_columns`)."""
        k = len(self.grid)
        f = lambda name: np.asarray(c[name], dtype=np.float64)  # noqa: E731
        lw = np.column_stack([f(f"lw_{j}") for j in range(k)])
        m = np.stack([np.column_stack([f(f"m_z_{j}"), f(f"m_b_{j}")]) for j in range(k)], 1)
        p = np.stack([np.column_stack([f(f"p_zz_{j}"), f(f"p_zb_{j}"), f(f"p_bb_{j}")])
                      for j in range(k)], 1)
        return MixtureState(lw=lw, m=m, p=p, t=f("t"), hi=f("hi"),
                            n=np.asarray(c["n"], dtype=np.int64))

    def update(self, state: MixtureState, t: np.ndarray, hi: np.ndarray) -> MixtureState:
        """One acquisition per unit (eq. (8) per grid value); ``t`` ages, NaN = none."""
        from rulkit.fleet.learned.filter_kernels import step_units

        t = np.asarray(t, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        check_forward(np.where(state.n > 0, state.t, np.nan), t)
        tau = self.time_scale
        m, p, lw = state.m.copy(), state.p.copy(), state.lw.copy()
        x_prev = np.where(state.n > 0, state.t, 0.0) / tau
        step_units(m, p, lw, x_prev, t / tau, hi, self.shape, self.params(),
                   np.asarray(self.grid))
        have = np.isfinite(t) & np.isfinite(hi)
        return MixtureState(lw=lw, m=m, p=p, t=np.where(have, t, state.t),
                            hi=np.where(have, hi, state.hi), n=state.n + have)

    def log_likelihood_of(self, hist: Histories) -> float:
        """Log-likelihood of ``hist``'s HI under this model's prior (eq. (9))."""
        from rulkit.fleet.learned.filter_kernels import negative_log_likelihood

        return -negative_log_likelihood(self.params().theta(), hist.t / self.time_scale,
                                        hist.hi, hist.start.astype(np.int64), self.shape,
                                        np.asarray(self.grid))

    def replay(self, hist: Histories) -> MixtureState:
        """The state after each row of ``hist``."""
        from rulkit.fleet.learned.filter_kernels import replay

        m, p, lw = replay(self.params().theta(), hist.t / self.time_scale, hist.hi,
                          hist.start.astype(np.int64), self.shape, np.asarray(self.grid))
        counts = np.arange(len(hist.t)) - hist.start[hist.unit] + 1
        return MixtureState(lw=lw, m=m, p=p, t=hist.t.copy(), hi=hist.hi.copy(),
                            n=counts.astype(np.int64))

    # -- RUL (eq. (10))
    def _log_surv(self, state: MixtureState, w: FloatArray) -> FloatArray:
        """log of sum_k w_k S_k(e_k(w)) per unit, ``w (B,)`` scaled horizon."""
        from scipy.special import log_ndtr, logsumexp

        grid = np.asarray(self.grid)[None, :]
        x0 = (np.where(state.n > 0, state.t, 0.0) / self.time_scale)[:, None]
        e = np.maximum(x0 + w[:, None] - grid, 0.0) - np.maximum(x0 - grid, 0.0)
        num = state.m[:, :, 0] + state.m[:, :, 1] * e
        var = (state.p[:, :, 0] + self.measured_var + 2.0 * e * state.p[:, :, 1]
               + e * e * state.p[:, :, 2] + self.walk_sd**2 * e)
        ls = log_ndtr(-num / np.sqrt(np.maximum(var, 1e-300)))
        return np.asarray(logsumexp(state.lw + ls, axis=1))

    def _log_surv_inf(self, state: MixtureState) -> FloatArray:
        from scipy.special import log_ndtr, logsumexp

        ls = log_ndtr(-state.m[:, :, 1] / np.sqrt(state.p[:, :, 2]))
        return np.asarray(logsumexp(state.lw + ls, axis=1))

    def rul_cdf(self, state: MixtureState, r: FloatArray) -> FloatArray:
        """P(RUL <= r) (eq. (10)), ``r (B, K)`` in the file's time unit; 1 once hi >= 1."""
        w = np.asarray(r, dtype=np.float64) / self.time_scale
        ls0 = self._log_surv(state, np.zeros(len(state)))
        out = np.empty_like(w)
        with np.errstate(invalid="ignore"):
            for j in range(w.shape[1]):
                out[:, j] = 1.0 - np.exp(np.minimum(self._log_surv(state, w[:, j]) - ls0, 0.0))
        out = np.maximum.accumulate(out, axis=1)
        return np.where((state.hi >= 1.0)[:, None], 1.0, out)

    def rul_quantiles(self, state: MixtureState, levels: tuple[float, ...] = (0.5, 0.05, 0.95),
                      iterations: int = 40) -> tuple[FloatArray, ...]:
        """RUL quantiles per unit (bisection on eq. (10), compiled): >= 0, +inf in the
        censored mass, 0 once the measured hi >= 1, NaN before the first acquisition."""
        from rulkit.fleet.learned.filter_kernels import onset_quantiles

        b = len(state)
        x0 = np.where(state.n > 0, state.t, 0.0) / self.time_scale
        out = np.empty((len(levels), b))
        onset_quantiles(np.ascontiguousarray(state.lw), np.ascontiguousarray(state.m),
                        np.ascontiguousarray(state.p), np.ascontiguousarray(x0),
                        np.asarray(self.grid, dtype=np.float64), self.walk_sd**2,
                        self.measured_var, np.asarray(levels, dtype=np.float64), iterations,
                        out)
        r = out * self.time_scale
        r = np.where(state.hi >= 1.0, 0.0, r)
        return tuple(np.where(state.n == 0, np.nan, r))

    # -- storage and text
    def to_dict(self) -> dict[str, Any]:
        """The model as JSON-ready numbers (no diagnostics)."""
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "diagnostics"}
        for k in ("mean", "cov", "grid", "warnings"):
            d[k] = list(d[k])
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> OnsetModel:
        """Inverse of :meth:`to_dict`."""
        d = {k: v for k, v in d.items() if k != "type"}
        for k in ("mean", "cov", "grid", "warnings"):
            d[k] = tuple(d.get(k, ()))
        return cls(**d)

    def describe(self) -> str:
        """One paragraph with every learned number, in the file's time unit."""
        u = self.time_unit or "time unit"
        tau = self.time_scale
        sd_b = math.sqrt(self.cov[2])
        return (f"onset model ({self.noise} noise): healthy until an onset of mean "
                f"{self.onset_mean * tau:.4g} {u} (sd {self.onset_sd * tau:.3g}; grid of "
                f"{len(self.grid)} values up to {self.grid[-1] * tau:.4g}), then Box-Cox "
                f"growth with Paris exponent m = {self.paris_exponent:.2f}, rate "
                f"{self.mean[1] / tau:.4g} per {u} (sd {sd_b / tau:.3g}); HI noise sd "
                f"{self.hi_noise_sd:.3g}" + (f", multiplicative noise sd {self.log_noise_sd:.3g}"
                                             if self.noise == "mixed" else "")
                + f"; learned from {self.n_units} units ({self.n_failed} failed), "
                f"log-likelihood {self.log_likelihood:.2f}")


def onset_grid(hist: Histories, tau: float, size: int = ONSET_GRID_SIZE) -> tuple[float, ...]:
    """Onset values in scaled age: 0 to the longest observed age, ``size`` evenly spaced."""
    t_max = float(np.max(hist.t[hist.start[1:] - 1]))
    return tuple(float(v) for v in np.linspace(0.0, t_max / tau, size))


def halved(grid: tuple[float, ...]) -> tuple[float, ...]:
    """The grid with a value inserted midway between each pair of neighbours (2K - 1 values,
    the old ones among them)."""
    return tuple(float(v) for v in np.linspace(grid[0], grid[-1], 2 * len(grid) - 1))


def grid_error(theta: FloatArray, hist: Histories, x: FloatArray, lam: float,
               grid: tuple[float, ...]) -> float:
    """|log-likelihood on :func:`halved` ``grid`` - on ``grid``| at ``theta`` (nats): the
    quadrature error of eq. (9)'s sum over the onset grid, estimated by halving its step."""
    from rulkit.fleet.learned.filter_kernels import negative_log_likelihood

    start = hist.start.astype(np.int64)
    coarse, fine = (negative_log_likelihood(theta, x, hist.hi, start, lam, np.asarray(g))
                    for g in (grid, halved(grid)))
    return abs(fine - coarse)


def fit_onset(hist: Histories, noise: str = "additive", *, start: OnsetModel | None = None,
              base: HiNoiseModel | None = None, grid_size: int = ONSET_GRID_SIZE,
              fixed_shape: bool = False) -> OnsetModel:
    """Learn an :class:`OnsetModel` (all units): maximum likelihood of eq. (9), the shape by a
    local profile from the no-onset fit ``base`` (fitted here when not given), or from
    ``start`` (a warm start: its grid, parameters and exponent; ``fixed_shape`` keeps its
    exponent).

    Without ``start`` the grid starts with ``grid_size`` values and its step is halved, the fit
    warm-started from the coarser one's, until halving it once more changes the log-likelihood
    at the fitted parameters by less than :data:`ONSET_GRID_TOL` (or the grid reaches
    :data:`ONSET_GRID_MAX` values): a coarse grid forces each unit's onset onto a value far from
    its own, and the growth law bends to fit the kink (a lower Paris exponent, a slower rate,
    optimistic RULs; docs/fleet-models.md section 7)."""
    tau = time_scale_of(hist)
    x = hist.t / tau
    if start is not None:
        grid, m0 = start.grid, start.paris_exponent
        theta0 = start.params().theta()
    else:
        base = base or fit_hi_noise(hist, noise)
        grid, m0 = onset_grid(hist, tau, grid_size), base.paris_exponent
        theta0 = base.params().theta()
        theta0[8] = 0.5 * grid[-1]
        theta0[9] = math.log(0.5 * grid[-1])
    setup = GrowthSpec(noise=noise, walk=True, onset_grid=grid)

    def at(lam: float) -> GrowthFit:
        return fit_growth(hist, x, lam, setup, theta0)

    if fixed_shape and start is not None:
        best, edge = at(start.shape), False
    else:
        best, edge = profile_shape(at, m0)
    error = 0.0
    while start is None:
        error = grid_error(best.theta, hist, x, best.lam, grid)
        if error <= ONSET_GRID_TOL or 2 * len(grid) - 1 > ONSET_GRID_MAX:
            break
        # at() reads setup and theta0: the halved grid, warm-started from the coarser fit
        grid, theta0 = halved(grid), best.theta
        setup = GrowthSpec(noise=noise, walk=True, onset_grid=grid)
        best, edge = profile_shape(at, 2.0 * (1.0 - best.lam))
    unconverged = error if error > ONSET_GRID_TOL else 0.0
    p = GrowthParams.from_theta(best.theta)
    return OnsetModel(
        noise=noise, shape=best.lam, mean=p.mean, cov=p.cov, hi_noise_sd=math.sqrt(p.r_hi),
        log_noise_sd=math.sqrt(p.r_log), walk_sd=math.sqrt(p.q), time_scale=tau, grid=grid,
        onset_mean=p.onset_mean, onset_sd=p.onset_sd, n_units=hist.n_units,
        n_failed=int(hist.failed.sum()), log_likelihood=best.log_likelihood,
        diagnostics=FitDiagnostics(best.optim, edge, unconverged))


__all__ = ["ONSET_GRID_MAX", "ONSET_GRID_SIZE", "ONSET_GRID_TOL", "MixtureState", "OnsetModel",
           "fit_onset", "grid_error", "halved", "mixture_columns", "onset_grid"]
