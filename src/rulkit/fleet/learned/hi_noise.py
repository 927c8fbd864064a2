"""Growth models measured with additive noise, multiplicative noise, or both.

docs/fleet-models.md section 6, eq. (7)-(8). A historian's HI is often ``true + noise``: a model
that puts all noise on a log-like scale reads the noise at low HI as huge relative jumps and
learns a wrong shape; other sensors give noise proportional to the HI. :class:`HiNoiseModel`
keeps the Paris (Box-Cox) growth law of eq. (1) for the hidden level and rate, and measures the
HI itself with additive noise (``additive``), multiplicative noise on the log scale
(``multiplicative``) or both (``mixed``), through the filter of
:mod:`rulkit.fleet.learned.growth_filter`. Its unit state is the same Gaussian (level, rate) as
the transformed models' (:class:`~rulkit.fleet.learned.degradation.UnitState`, 7 numbers), so
its RUL is the closed form of eq. (5)-(6) with the failure level g(1) = 0.

Usage::

    model = fit_hi_noise(hist, "additive")
    state = model.update(model.empty_state(3), t, hi)
    med, lo, hi90 = model.rul_quantiles(state, (0.5, 0.05, 0.95))
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from rulkit.fleet.learned.degradation import (
    STATE_COLUMNS,
    UnitState,
    rul_cdf,
    rul_quantiles,
    time_scale_of,
)
from rulkit.fleet.learned.growth_filter import GrowthParams, growth_hi_quantiles
from rulkit.fleet.learned.growth_fit import (
    FitDiagnostics,
    GrowthFit,
    GrowthSpec,
    fit_growth,
    profile_shape,
)
from rulkit.fleet.learned.histories import Histories

NOISES = ("additive", "multiplicative", "mixed")


def check_forward(last_t: np.ndarray, t: np.ndarray) -> None:
    """Refuse an acquisition not after the unit's last one (``ValueError`` naming the first
    offending unit index)."""
    back = np.isfinite(t) & np.isfinite(last_t) & (last_t >= t)
    if back.any():
        i = int(np.flatnonzero(back)[0])
        raise ValueError(f"unit index {i}: time {t[i]!r} is not after its last acquisition "
                         f"{last_t[i]!r}")


@dataclass(frozen=True)
class HiNoiseModel:
    """A fitted Box-Cox growth law with HI-scale noise (module docstring).

    ``shape`` lam = 1 - m/2; ``mean``/``cov`` the prior of (level at age 0, rate) on the growth
    scale, per unit of scaled age x = t / ``time_scale``; ``hi_noise_sd`` the additive HI noise
    (0 for ``multiplicative``), ``log_noise_sd`` the multiplicative noise's sd on the log scale
    (0 for ``additive``), ``walk_sd`` the random walk per sqrt of scaled age (0: independent
    errors only). The other fields as
    :class:`~rulkit.fleet.learned.degradation.DegradationModel`'s.
    """

    noise: str
    shape: float
    mean: tuple[float, float]
    cov: tuple[float, float, float]
    hi_noise_sd: float
    log_noise_sd: float
    walk_sd: float
    time_scale: float
    time_unit: str = ""
    n_units: int = 0
    n_failed: int = 0
    log_likelihood: float = math.nan
    warnings: tuple[str, ...] = ()
    time_axis: dict[str, Any] | None = None
    diagnostics: FitDiagnostics | None = field(default=None, compare=False, repr=False)

    state_columns = STATE_COLUMNS
    threshold = 0.0  # g(1) for every Box-Cox shape

    def __post_init__(self) -> None:
        if self.noise not in NOISES:
            raise ValueError(f"HiNoiseModel.noise: expected one of {NOISES}, got {self.noise!r}")
        saa, sab, sbb = self.cov
        if not (saa > 0 and sbb > 0 and abs(sab) <= math.sqrt(saa * sbb)):
            raise ValueError(f"HiNoiseModel.cov: not a covariance: {self.cov}")
        if not (self.hi_noise_sd >= 0 and self.log_noise_sd >= 0
                and self.hi_noise_sd + self.log_noise_sd > 0 and self.walk_sd >= 0
                and self.time_scale > 0):
            raise ValueError("HiNoiseModel: noise sds >= 0 (not both 0), walk_sd >= 0, "
                             "time_scale > 0 expected")

    @property
    def name(self) -> str:
        """``paris-additive``, ``paris-multiplicative`` or ``paris-mixed`` (``-iid`` without
        the random walk)."""
        return f"paris-{self.noise}" + ("" if self.walk_sd > 0 else "-iid")

    @property
    def paris_exponent(self) -> float:
        """m = 2 (1 - lam)."""
        return 2.0 * (1.0 - self.shape)

    @property
    def measured_var(self) -> float:
        """Variance of a measurement at hi = 1 (both noises; dhi/dz = 1 there, so also on the
        growth scale): the RUL is that of the first measurement >= 1 (eq. (5) on the measured
        HI)."""
        return self.hi_noise_sd**2 + self.log_noise_sd**2

    def params(self) -> GrowthParams:
        """The parameters as :class:`~rulkit.fleet.learned.growth_filter.GrowthParams`."""
        return GrowthParams(mean=self.mean, cov=self.cov, r_log=self.log_noise_sd**2,
                            r_hi=self.hi_noise_sd**2, q=self.walk_sd**2, onset_mean=0.0,
                            onset_sd=1.0)

    # -- the unit state (same layout as the transformed models')
    def empty_state(self, size: int) -> UnitState:
        """``size`` units before their first acquisition (the prior)."""
        return UnitState.empty(self, size)

    def state_from_columns(self, c: dict[str, Any]) -> UnitState:
        """A state from its stored columns."""
        return UnitState.from_columns(c)

    def update(self, state: UnitState, t: np.ndarray, hi: np.ndarray) -> UnitState:
        """One acquisition per unit (eq. (8)); ``t`` ages, NaN = none for that unit."""
        t = np.asarray(t, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        check_forward(np.where(state.n > 0, state.t, np.nan), t)
        tau = self.time_scale
        m, p = state.m[:, None, :].copy(), state.p[:, None, :].copy()
        lw = np.zeros((len(state), 1))
        x_prev = np.where(state.n > 0, state.t, 0.0) / tau
        from rulkit.fleet.learned.filter_kernels import step_units

        step_units(m, p, lw, x_prev, t / tau, hi, self.shape, self.params(), np.zeros(1))
        have = np.isfinite(t) & np.isfinite(hi)
        return UnitState(m=m[:, 0], p=p[:, 0], t=np.where(have, t, state.t),
                         hi=np.where(have, hi, state.hi), n=state.n + have)

    def log_likelihood_of(self, hist: Histories) -> float:
        """Log-likelihood of ``hist``'s HI under this model's prior (eq. (7)-(8))."""
        from rulkit.fleet.learned.filter_kernels import negative_log_likelihood

        return -negative_log_likelihood(self.params().theta(), hist.t / self.time_scale,
                                        hist.hi, hist.start.astype(np.int64), self.shape,
                                        np.zeros(1))

    def replay(self, hist: Histories) -> UnitState:
        """The state after each row of ``hist``."""
        from rulkit.fleet.learned.filter_kernels import replay

        m, p, _ = replay(self.params().theta(), hist.t / self.time_scale, hist.hi,
                         hist.start.astype(np.int64), self.shape, np.zeros(1))
        counts = np.arange(len(hist.t)) - hist.start[hist.unit] + 1
        return UnitState(m=m[:, 0], p=p[:, 0], t=hist.t.copy(), hi=hist.hi.copy(),
                         n=counts.astype(np.int64))

    # -- RUL (eq. (5)-(6))
    def rul_quantiles(self, state: UnitState, levels: tuple[float, ...] = (0.5, 0.05, 0.95),
                      *, one_reading: bool = False) -> tuple[np.ndarray, ...]:
        """RUL quantiles per unit (>= 0; inf in the never-failing mass; 0 once hi >= 1), eq.
        (5b) (with ``one_reading`` eq. (5) of one measurement, the exported C's event)."""
        return rul_quantiles(self, state, levels, one_reading=one_reading)

    def hi_quantiles(self, state: UnitState, horizons: np.ndarray,
                     levels: tuple[float, ...]) -> tuple[np.ndarray, ...]:
        """The HI forecast ``horizons (B, K)`` after the last acquisition (latent HI)."""
        return growth_hi_quantiles(state.m, state.p, self.walk_sd, self.time_scale,
                                   self.shape, horizons, levels)

    def rul_cdf(self, state: UnitState, r: np.ndarray) -> np.ndarray:
        """P(RUL <= r), ``r (B, K)`` in the file's time unit (eq. (5b))."""
        return rul_cdf(self, state, r)

    # -- storage and text
    def to_dict(self) -> dict[str, Any]:
        """The model as JSON-ready numbers (no diagnostics)."""
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "diagnostics"}
        d["mean"], d["cov"], d["warnings"] = list(self.mean), list(self.cov), list(self.warnings)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> HiNoiseModel:
        """Inverse of :meth:`to_dict`."""
        d = {k: v for k, v in d.items() if k != "type"}
        d["mean"], d["cov"] = tuple(d["mean"]), tuple(d["cov"])
        d["warnings"] = tuple(d.get("warnings", ()))
        return cls(**d)

    def describe(self) -> str:
        """One paragraph with every learned number, rates in the file's time unit."""
        u = self.time_unit or "time unit"
        tau = self.time_scale
        sd_a, sd_b = math.sqrt(self.cov[0]), math.sqrt(self.cov[2])
        noise = ", ".join(
            [f"additive HI noise sd {self.hi_noise_sd:.3g}"] * (self.noise != "multiplicative")
            + [f"multiplicative noise sd {self.log_noise_sd:.3g} (log scale)"]
            * (self.noise != "additive"))
        return (f"{self.name} model, Box-Cox growth, Paris exponent m = "
                f"{self.paris_exponent:.2f}: prior level {self.mean[0]:.4g} (sd {sd_a:.3g}), "
                f"rate {self.mean[1] / tau:.4g} per {u} (sd {sd_b / tau:.3g}); {noise}; "
                f"random-walk sd {self.walk_sd / math.sqrt(tau):.3g} per sqrt({u}); learned "
                f"from {self.n_units} units ({self.n_failed} failed), log-likelihood "
                f"{self.log_likelihood:.2f}")


def model_of(fit: GrowthFit, noise: str, hist: Histories, tau: float, edge: bool
             ) -> HiNoiseModel:
    """The model of a fitted parameter vector."""
    p = GrowthParams.from_theta(fit.theta)
    return HiNoiseModel(
        noise=noise, shape=fit.lam, mean=p.mean, cov=p.cov, hi_noise_sd=math.sqrt(p.r_hi),
        log_noise_sd=math.sqrt(p.r_log), walk_sd=math.sqrt(p.q), time_scale=tau,
        n_units=hist.n_units, n_failed=int(hist.failed.sum()),
        log_likelihood=fit.log_likelihood, diagnostics=FitDiagnostics(fit.optim, edge))


def fit_hi_noise(hist: Histories, noise: str = "additive", *, walk: bool = True,
                 shape: float | None = None, start: HiNoiseModel | None = None
                 ) -> HiNoiseModel:
    """Learn a :class:`HiNoiseModel` from histories (all units): maximum likelihood of eq. (7)
    over the prior, the noise and the walk, the shape by profile likelihood (or ``shape``
    fixed; ``start`` warm-starts from a fitted model and searches m locally)."""
    if noise not in NOISES:
        raise ValueError(f"noise: expected one of {NOISES}, got {noise!r}")
    tau = time_scale_of(hist)
    x = hist.t / tau
    setup = GrowthSpec(noise=noise, walk=walk)
    theta0 = None if start is None else start.params().theta()

    def at(lam: float) -> GrowthFit:
        return fit_growth(hist, x, lam, setup, theta0)

    if shape is not None:
        return model_of(at(shape), noise, hist, tau, False)
    best, edge = profile_shape(at, None if start is None else start.paris_exponent)
    return model_of(best, noise, hist, tau, edge)


__all__ = ["NOISES", "HiNoiseModel", "check_forward", "fit_hi_noise", "model_of"]
