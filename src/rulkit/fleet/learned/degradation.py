"""Random-effects degradation models learned from fleet histories (docs/fleet-models.md).

All three models are Gaussian random-effects state-space models of a transformed HI
(docs/fleet-models.md eq. (1)):

    z(x) = g(hi) = a_u + b_u x + sigma_w W_u(x) + e,   e ~ N(0, sigma_e^2) i.i.d.,
    (a_u, b_u) ~ N(mu, Sigma),

with x = t / tau the unit's age in units of a fleet time scale tau (for conditioning; rates are
reported back in the file's time unit), W_u a standard Brownian motion (the path's wander about
its straight line: model error that correlates neighbouring residuals) and failure when z
reaches g(1):

* ``linear`` (Lu & Meeker 1993): g(h) = h;
* ``exponential`` (Gebraeel et al. 2005: Brownian error, plus measurement noise):
  g(h) = ln(h - phi), phi a fleet offset below every healthy HI;
* ``paris`` (seed 004's growth law dh/dt = c h^(m/2), integrated): the Box-Cox transform
  g(h) = (h^lam - 1) / lam with lam = 1 - m/2 (g = ln h at m = 2) makes the solution
  h(t)^lam = h_0^lam + lam c t linear in t, with b_u = c_u per unit and m a fleet constant.

A unit's state is the Gaussian posterior of (level z(x), rate b) at its last acquisition:
mean (2) and covariance (3), updated per acquisition by the exact Kalman filter of this linear
Gaussian model (eq. (2), :func:`update_state`, vectorised over units; with sigma_w = 0 it is the
conjugate Bayesian linear regression). The fleet prior (mu, Sigma), sigma_e and sigma_w are
learned by maximising the marginal likelihood of *all* units' acquisitions (failed and
censored: fitting failed units only biases the prior towards fast degraders; a test stopped at
failure is an ignorable stopping rule for this likelihood), eq. (3), by the prediction-error
decomposition of the same filter; the transform's shape (phi, or m) by profile likelihood on a
grid, including the Jacobian of g so that likelihoods of different shapes compare (eq. (4)).

RUL (eq. (5)): at horizon r the transformed HI is Gaussian with mean m_z + m_b r and variance
P_zz + 2 r P_zb + r^2 P_bb + sigma_w^2 r; with S(r) the probability that it is still below
g(1), the RUL given that the unit has not failed has survival function S(r) / S(0), r >= 0
(the exceedance form of Lu & Meeker; it neglects a Brownian path that crosses and comes back
before r). The mass with b <= 0 never fails (censored mass): quantiles in it are +inf.
Quantiles in closed form (a quadratic, eq. (6)). RUL is 0 once the measured hi >= 1.

Usage::

    hist = read_histories("fleet.csv")
    model = fit_model(hist, "paris")
    state = UnitState.empty(model, 3)
    state = update_state(state, model, t, hi)          # one acquisition per unit
    med, lo, hi90 = model.rul_quantiles(state, (0.5, 0.05, 0.95))
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any, Protocol, cast

import numpy as np
from numpy.typing import NDArray

from rulkit.fleet.learned.growth_fit import (
    FitDiagnostics,
    GrowthFit,
    OptimResult,
    minimize_bounded,
    profile_shape,
    two_stage_start,
)
from rulkit.fleet.learned.histories import Histories

FloatArray = NDArray[np.float64]
KINDS = ("linear", "exponential", "paris")
HI_MIN = 1e-6
"""HI values below this are evaluated at it by the log / power transforms (defined behaviour)."""


class GrowthLaw(Protocol):
    """What the RUL of eq. (5) reads from a model: the random walk, the failure level g(1)
    and the time scale."""

    @property
    def walk_sd(self) -> float:
        """sigma_w, per sqrt of scaled age."""

    @property
    def threshold(self) -> float:
        """g(1), the failure level on the growth scale."""

    @property
    def time_scale(self) -> float:
        """tau, the scaled age's unit in the file's time unit."""


class GrowthPrior(GrowthLaw, Protocol):
    """A :class:`GrowthLaw` with the fleet prior a unit state starts from."""

    @property
    def mean(self) -> tuple[float, float]:
        """Prior mean of (level at age 0, rate)."""

    @property
    def cov(self) -> tuple[float, float, float]:
        """Prior covariance (S_aa, S_ab, S_bb)."""


STATE_COLUMNS = ("m_z", "m_b", "p_zz", "p_zb", "p_bb", "t", "hi", "n")
"""The per-unit state of the Gaussian models, as stored (:meth:`UnitState.columns`)."""


# ------------------------------------------------------------------------------ unit state
@dataclass
class UnitState:
    """Posterior of B units (struct of arrays), eq. (2).

    ``m (B, 2)`` mean of (level z, rate b) at the last acquisition, ``p (B, 3)`` covariance
    (P_zz, P_zb, P_bb), ``t (B,)`` age of the last acquisition (file unit, NaN before the
    first: the prior then sits at age 0), ``hi (B,)`` the last measured HI, ``n (B,)``
    acquisitions assimilated. 7 numbers per unit plus book-keeping.
    """

    m: FloatArray
    p: FloatArray
    t: FloatArray
    hi: FloatArray
    n: NDArray[np.int64]

    @classmethod
    def empty(cls, model: GrowthPrior, size: int) -> UnitState:
        return cls(m=np.tile(np.asarray(model.mean, dtype=np.float64), (size, 1)),
                   p=np.tile(np.asarray(model.cov, dtype=np.float64), (size, 1)),
                   t=np.full(size, np.nan), hi=np.full(size, np.nan),
                   n=np.zeros(size, dtype=np.int64))

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def take(self, idx: np.ndarray) -> UnitState:
        """The states of the units ``idx`` (an index array or boolean mask)."""
        return UnitState(m=self.m[idx], p=self.p[idx], t=self.t[idx], hi=self.hi[idx],
                         n=self.n[idx])

    def columns(self) -> dict[str, np.ndarray]:
        return {"m_z": self.m[:, 0], "m_b": self.m[:, 1], "p_zz": self.p[:, 0],
                "p_zb": self.p[:, 1], "p_bb": self.p[:, 2], "t": self.t, "hi": self.hi,
                "n": self.n}

    @classmethod
    def from_columns(cls, c: dict[str, Any]) -> UnitState:
        f = lambda k: np.asarray(c[k], dtype=np.float64)  # noqa: E731
        return cls(m=np.column_stack([f("m_z"), f("m_b")]),
                   p=np.column_stack([f("p_zz"), f("p_zb"), f("p_bb")]), t=f("t"), hi=f("hi"),
                   n=np.asarray(c["n"], dtype=np.int64))


def _inv2(a: FloatArray, b: FloatArray, d: FloatArray) -> tuple[FloatArray, ...]:
    """Inverse and log-determinant of symmetric 2x2 [[a, b], [b, d]] (vectorised)."""
    det = a * d - b * b
    return d / det, -b / det, a / det, np.log(det)


# ------------------------------------------------------------------------------ the model
@dataclass(frozen=True)
class DegradationModel:
    """A learned fleet model (module docstring; numbers in scaled time x = t / tau).

    ``kind`` linear | exponential | paris; ``shape`` phi (exponential), lam = 1 - m/2 (paris),
    0 (linear); ``mean`` (m_a, m_b) and ``cov`` (S_aa, S_ab, S_bb) of the prior over the
    intercept at age 0 and the rate; ``noise_sd`` sigma_e; ``walk_sd`` sigma_w (per sqrt of
    scaled time); ``time_scale`` tau in the file's time unit (``time_unit`` is a label,
    ``time_axis`` the :class:`~rulkit.fleet.time_axis.TimeAxis` as a dict).
    ``n_units``/``n_failed`` and ``log_likelihood`` (of the HI, Jacobian included) describe the
    fit; ``warnings`` are what the fit's checks found (stored with the model, shown by
    ``rulkit status``).
    """

    kind: str
    shape: float
    mean: tuple[float, float]
    cov: tuple[float, float, float]
    noise_sd: float
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

    @property
    def name(self) -> str:
        """The candidate's name (``linear``, ``exponential``, ``paris``)."""
        return self.kind

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"DegradationModel.kind: expected one of {KINDS}, got {self.kind!r}")
        saa, sab, sbb = self.cov
        if not (saa > 0 and sbb > 0 and abs(sab) <= math.sqrt(saa * sbb)):
            raise ValueError(f"DegradationModel.cov: not a covariance: {self.cov}")
        if not (self.noise_sd > 0 and self.walk_sd >= 0 and self.time_scale > 0):
            raise ValueError("DegradationModel: noise_sd > 0, walk_sd >= 0, time_scale > 0 "
                             "expected")

    def transform(self, hi: np.ndarray) -> FloatArray:
        """z = g(hi) (module docstring)."""
        return transform(self.kind, self.shape, np.asarray(hi, dtype=np.float64))

    @property
    def threshold(self) -> float:
        """g(1): the failure level in the transformed space."""
        return float(transform(self.kind, self.shape, np.array([1.0]))[0])

    @property
    def measured_var(self) -> float:
        """sigma_e^2: the variance of a measurement on the transformed scale, where a reading
        is >= 1 exactly when it is >= g(1) (the RUL's first measured crossing, eq. (5b))."""
        return self.noise_sd**2

    @property
    def paris_exponent(self) -> float:
        """m = 2 (1 - lam) for the paris model (NaN otherwise)."""
        return 2.0 * (1.0 - self.shape) if self.kind == "paris" else math.nan

    def rul_quantiles(self, state: UnitState, levels: tuple[float, ...] = (0.5, 0.05, 0.95),
                      *, method: str = "compiled", one_reading: bool = False
                      ) -> tuple[FloatArray, ...]:
        """RUL quantiles (file time unit) per unit at its last acquisition, eq. (5b) (with
        ``one_reading`` eq. (5) of one measurement).

        >= 0 always; +inf where the level lies in the never-failing (censored) mass; 0 once the
        last measured hi >= 1; NaN for units without an acquisition.
        """
        return rul_quantiles(self, state, levels, method=method, one_reading=one_reading)

    def rul_cdf(self, state: UnitState, r: FloatArray) -> FloatArray:
        """P(RUL <= r), ``r (B, K)`` in the file's time unit (eq. (5b))."""
        return rul_cdf(self, state, r)

    def empty_state(self, size: int) -> UnitState:
        """``size`` units before their first acquisition (the prior)."""
        return UnitState.empty(self, size)

    def state_from_columns(self, c: dict[str, Any]) -> UnitState:
        """A state from its stored columns (:data:`STATE_COLUMNS`)."""
        return UnitState.from_columns(c)

    def update(self, state: UnitState, t: np.ndarray, hi: np.ndarray) -> UnitState:
        """One acquisition per unit (:func:`update_state`); ``t`` is the unit's age."""
        return update_state(state, self, t, hi)

    def log_likelihood_of(self, hist: Histories) -> float:
        """Log-likelihood of ``hist``'s HI under this model's prior (eq. (3) with the
        Jacobian of eq. (4)): how well the model predicts units it was not fitted on."""
        x = hist.t / self.time_scale
        z = self.transform(hist.hi)
        nll = _nll_kernel(np.asarray(self.mean, dtype=np.float64),
                          np.asarray(self.cov, dtype=np.float64), self.walk_sd**2,
                          self.noise_sd**2, x, z, hist.start.astype(np.int64))
        return -nll + log_jacobian(self.kind, self.shape, hist.hi)

    def replay(self, hist: Histories) -> UnitState:
        """The state after each row of ``hist`` (:func:`filtered_states`)."""
        return filtered_states(self, hist)

    def to_dict(self) -> dict[str, Any]:
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "diagnostics"}
        d["mean"], d["cov"] = list(self.mean), list(self.cov)
        d["warnings"] = list(self.warnings)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DegradationModel:
        d = dict(d)
        d.pop("type", None)
        d["mean"], d["cov"] = tuple(d["mean"]), tuple(d["cov"])
        d["warnings"] = tuple(d.get("warnings", ()))
        return cls(**d)

    def describe(self) -> str:
        """One paragraph with every learned number, rates in the file's time unit."""
        u = f" {self.time_unit}" if self.time_unit else " time unit (of the file)"
        tau = self.time_scale
        sd_a, sd_b = math.sqrt(self.cov[0]), math.sqrt(self.cov[2])
        corr = self.cov[1] / (sd_a * sd_b)
        shape = {"linear": "hi",
                 "exponential": f"ln(hi - {self.shape:.4g})",
                 "paris": f"Box-Cox(hi), Paris exponent m = {self.paris_exponent:.3f}"}[self.kind]
        return (f"{self.kind} model, z = {shape}: prior intercept {self.mean[0]:.4g} "
                f"(sd {sd_a:.3g}), rate {self.mean[1] / tau:.4g} per{u} (sd {sd_b / tau:.3g}), "
                f"corr {corr:.2f}; measurement noise sd {self.noise_sd:.3g}, random-walk sd "
                f"{self.walk_sd / math.sqrt(tau):.3g} per sqrt({u.strip()}) (in z); learned "
                f"from {self.n_units} units ({self.n_failed} failed), log-likelihood "
                f"{self.log_likelihood:.2f}")


def transform(kind: str, shape: float, hi: FloatArray) -> FloatArray:
    """g(hi) of a model kind (module docstring); HI below the transform's domain is clipped."""
    if kind == "linear":
        return hi.astype(np.float64, copy=True)
    if kind == "exponential":
        return np.log(np.maximum(hi - shape, HI_MIN))
    h = np.maximum(hi, HI_MIN)
    if abs(shape) < 1e-12:
        return np.log(h)
    return (h**shape - 1.0) / shape


def log_jacobian(kind: str, shape: float, hi: FloatArray) -> float:
    """sum log |g'(hi)| (eq. (4)): turns a likelihood of z into one of hi."""
    if kind == "linear":
        return 0.0
    if kind == "exponential":
        return float(-np.log(np.maximum(hi - shape, HI_MIN)).sum())
    return float((shape - 1.0) * np.log(np.maximum(hi, HI_MIN)).sum())


# ------------------------------------------------------------------------------ online update
def update_state(state: UnitState, model: DegradationModel, t: np.ndarray,
                 hi: np.ndarray) -> UnitState:
    """Assimilate one acquisition per unit: the Kalman filter of eq. (2), vectorised.

    Predict from the last age (0 before the first acquisition) to ``t``: level += rate dx,
    P_zz += 2 dx P_zb + dx^2 P_bb + sigma_w^2 |dx|, P_zb += dx P_bb; then update with
    z = g(hi) and variance sigma_e^2. ``t``, ``hi`` (B,); NaN = no acquisition for that unit
    (state kept). Time must increase per unit (``ValueError`` naming the first offending index).
    """
    t = np.asarray(t, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    have = np.isfinite(t) & np.isfinite(hi)
    back = have & (state.t >= t)
    if back.any():
        i = int(np.flatnonzero(back)[0])
        raise ValueError(f"unit index {i}: time {t[i]!r} is not after its last acquisition "
                         f"{state.t[i]!r}")
    tau = model.time_scale
    x_prev = np.where(state.n > 0, state.t, 0.0) / tau
    dx = np.where(have, t / tau - x_prev, 0.0)
    z = model.transform(np.where(have, hi, 1.0))
    m, p = _kf_step(state.m, state.p, dx, z, model.walk_sd**2, model.noise_sd**2)
    keep = ~have
    if keep.any():
        m = np.where(keep[:, None], state.m, m)
        p = np.where(keep[:, None], state.p, p)
    return UnitState(m=m, p=p, t=np.where(have, t, state.t), hi=np.where(have, hi, state.hi),
                     n=state.n + have)


def _kf_step(m: FloatArray, p: FloatArray, dx: FloatArray, z: FloatArray, q: float,
             r: float) -> tuple[FloatArray, FloatArray]:
    mz = m[:, 0] + m[:, 1] * dx
    pzz = p[:, 0] + 2.0 * dx * p[:, 1] + dx * dx * p[:, 2] + q * np.abs(dx)
    pzb = p[:, 1] + dx * p[:, 2]
    s = pzz + r
    innov = z - mz
    kz, kb = pzz / s, pzb / s
    out_m = np.column_stack([mz + kz * innov, m[:, 1] + kb * innov])
    out_p = np.column_stack([pzz - kz * pzz, pzb - kz * pzb, p[:, 2] - kb * pzb])
    return out_m, out_p


def _filter_rows(model: DegradationModel, hist: Histories) -> UnitState:
    """State after every acquisition of every unit (one row per history row): the replay."""
    x = hist.t / model.time_scale
    z = model.transform(hist.hi)
    n_rows = len(x)
    m_out, p_out = np.empty((n_rows, 2)), np.empty((n_rows, 3))
    _filter_kernel(x, z, hist.start, np.asarray(model.mean, dtype=np.float64),
                   np.asarray(model.cov, dtype=np.float64), model.walk_sd**2,
                   model.noise_sd**2, m_out, p_out)
    counts = np.arange(n_rows) - hist.start[hist.unit] + 1
    return UnitState(m=m_out, p=p_out, t=hist.t.copy(), hi=hist.hi.copy(),
                     n=counts.astype(np.int64))


def filtered_states(model: DegradationModel, hist: Histories) -> UnitState:
    """Replay: the state after each acquisition (rows of ``hist``), eq. (2)."""
    return _filter_rows(model, hist)


def final_states(model: DegradationModel, hist: Histories) -> UnitState:
    """Each unit's state after its whole history."""
    st = _filter_rows(model, hist)
    last = hist.start[1:] - 1
    return UnitState(m=st.m[last], p=st.p[last], t=st.t[last], hi=st.hi[last], n=st.n[last])


def _nll_kernel(*args: Any) -> float:
    """-log-likelihood of eq. (3) (compiled, :mod:`rulkit.fleet.learned.filter_kernels`)."""
    from rulkit.fleet.learned.filter_kernels import kf_nll

    return float(kf_nll(*args))


def _filter_kernel(*args: Any) -> None:
    from rulkit.fleet.learned.filter_kernels import kf_replay

    kf_replay(*args)


# ------------------------------------------------------------------------------ RUL
def _event(model: Any, state: UnitState, one_reading: bool = False
           ) -> tuple[float, FloatArray]:
    """The measurement sd at the threshold (``model.measured_var``; 0 for a model without
    one: eq. (5) of the latent level) and each unit's cadence in scaled time, derived from its
    state: its mean interval since age 0, t / n (inf before two acquisitions, at age <= 0 or
    with ``one_reading``: eq. (5) of one measurement)."""
    s = math.sqrt(float(getattr(model, "measured_var", 0.0)))
    with np.errstate(invalid="ignore", divide="ignore"):
        d = state.t / np.maximum(state.n, 1) / model.time_scale
    return s, np.where((state.n >= 2) & (d > 0) & (not one_reading), d, np.inf)


def growth_scale_of(model: Any) -> FloatArray:
    """The model's growth scale g as the compiled kernels read it (kind 0 linear, 1
    ln(h - shape), 2 Box-Cox of shape; the clip of h): the first step of eq. (5b)
    interpolates the last reading and the next on the HI scale and maps the bound on the next
    reading through g (:func:`~rulkit.fleet.learned.filter_kernels.growth_scale`)."""
    from rulkit.fleet.learned.growth_filter import HI_HI, HI_LO

    kind = getattr(model, "kind", "paris")
    shape = float(getattr(model, "shape", 0.0))
    if not hasattr(model, "transform"):  # the models measuring the HI itself: boxcox
        return np.array([2.0, shape, HI_LO, HI_HI])
    return np.array([{"linear": 0.0, "exponential": 1.0}.get(kind, 2.0), shape, HI_MIN,
                     np.inf])


def _growth(model: Any) -> Callable[[FloatArray], FloatArray]:
    """g(h) of the model (its transform, or the Box-Cox of its shape)."""
    from rulkit.fleet.learned.growth_filter import boxcox

    if hasattr(model, "transform"):
        return cast(Callable[[FloatArray], FloatArray], model.transform)
    shape = float(model.shape)
    return lambda h: boxcox(h, shape)


def _log_surv(model: Any, state: UnitState, w: FloatArray, s: float,
              delta: FloatArray) -> FloatArray:
    """log S(w): log P(the interpolated crossing comes after the scaled horizon w) (eq.
    (5b))."""
    from scipy.special import log_ndtr

    from rulkit.fleet.learned.first_passage import level_terms

    g = _growth(model) if s > 0 else None
    num, sd = level_terms(state.m, state.p, model.walk_sd**2, model.threshold, s, delta, w,
                          state.hi, g)
    return np.asarray(log_ndtr(-num / sd))


def _reference(model: Any, state: UnitState, s: float, delta: FloatArray) -> FloatArray:
    """log of the survival the RUL's is relative to: 0 for the first measured crossing over a
    known cadence (the posterior already holds the last reading < 1; eq. (5b)); log S(0) for
    the latent level (s = 0) or one reading (no cadence), eq. (5)'s S(r) / S(0)."""
    ls0 = _log_surv(model, state, np.zeros(len(state)), s, delta)
    return np.where((s > 0) & np.isfinite(delta), 0.0, ls0)


def rul_cdf(model: GrowthLaw, state: UnitState, r: FloatArray) -> FloatArray:
    """P(RUL <= r) (eq. (5b)); ``r (B, K)`` in the file's time unit; 1 once hi >= 1."""
    w = np.asarray(r, dtype=np.float64) / model.time_scale
    s, delta = _event(model, state)
    ref = _reference(model, state, s, delta)
    out = np.empty_like(w)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):  # NaN horizons stay
        for k in range(w.shape[1]):
            ls = _log_surv(model, state, w[:, k], s, delta)
            out[:, k] = -np.expm1(np.minimum(ls - ref, 0.0))
    out = np.maximum.accumulate(out, axis=1)
    return np.where((state.hi >= 1.0)[:, None], 1.0, out)


def rul_quantiles(model: GrowthLaw, state: UnitState,
                  levels: tuple[float, ...] = (0.5, 0.05, 0.95), *,
                  method: str = "compiled", iterations: int = 200,
                  one_reading: bool = False) -> tuple[FloatArray, ...]:
    """Quantiles of eq. (5b); see :meth:`DegradationModel.rul_quantiles`.

    A level p is reached where log S(w) = log S_ref + log(1 - p) (:func:`_reference`).
    ``method="compiled"`` (the default): per unit, Newton's steps on (5b)'s margin from eq.
    (6)'s closed-form root, safeguarded by a bracket, at most ``iterations`` steps
    (:func:`~rulkit.fleet.learned.filter_kernels.first_passage_quantiles`);
    ``method="bisect"``: bisection on u in (0, 1), w = W u / (1 - u), W = max(age, 1),
    ``iterations`` halvings, vectorised over units in numpy on the CDF of :func:`rul_cdf`
    (the reference of the tests). A level beyond the failing mass
    1 - S(inf)/S_ref, S(inf) = Phi(-m_b / sqrt(P_bb)), is +inf. ``one_reading``: eq. (5) of
    one measurement instead (the exported C's optional event, docs/rul-on-the-device.md).
    """
    if method not in ("compiled", "bisect"):
        raise ValueError(f"method: expected 'compiled' or 'bisect', got {method!r}")
    tau = model.time_scale
    s, delta = _event(model, state, one_reading)
    if method == "bisect":
        w = _bisect_levels(model, state, levels, iterations)
    else:
        from rulkit.fleet.learned.filter_kernels import first_passage_quantiles
        from rulkit.fleet.learned.first_passage import kernel_table

        w = np.empty((len(levels), len(state)))
        first_passage_quantiles(np.ascontiguousarray(state.m), np.ascontiguousarray(state.p),
                                np.asarray(state.hi, dtype=np.float64),
                                growth_scale_of(model), delta, model.walk_sd**2, model.threshold, s,
                                np.asarray(levels, dtype=np.float64), *kernel_table(),
                                iterations, w)
    r = np.where(state.hi >= 1.0, 0.0, np.maximum(w, 0.0) * tau)
    r[:, state.n == 0] = np.nan
    return monotone_in_level(levels, list(r))


def _bisect_levels(model: GrowthLaw, state: UnitState, levels: tuple[float, ...],
                   iterations: int) -> FloatArray:
    """Each level's horizon (scaled) by bisection of :func:`rul_cdf` over all units at once;
    +inf beyond the failing mass."""
    from scipy.special import log_ndtr

    tau = model.time_scale
    x0 = np.where(state.n > 0, state.t, 0.0) / tau
    scale = np.maximum(np.abs(x0), 1.0)
    s, delta = _event(model, state)
    ls_inf = log_ndtr(-state.m[:, 1] / np.sqrt(state.p[:, 2]))
    ref = _reference(model, state, s, delta)
    out = np.empty((len(levels), len(state)))
    for k, lev in enumerate(levels):
        lo, hi = np.zeros(len(state)), np.ones(len(state))
        with np.errstate(divide="ignore"):  # u = 1 (the never-failing mass): w = inf
            for _ in range(iterations):
                u = 0.5 * (lo + hi)
                w = scale * u / (1.0 - u)
                below = rul_cdf(model, state, (w * tau)[:, None])[:, 0] < lev
                lo, hi = np.where(below, u, lo), np.where(below, hi, u)
            u = 0.5 * (lo + hi)
            w = scale * u / (1.0 - u)
        never = ref + math.log1p(-lev) <= ls_inf
        out[k] = np.where(never, np.inf, w)
    return out


def monotone_in_level(levels: tuple[float, ...], quantiles: list[FloatArray]
                      ) -> tuple[FloatArray, ...]:
    """``quantiles`` (one array per level, in the order of ``levels``) made nondecreasing in
    the level, unit by unit. Eq. (6) is a near-double root where the RUL's spread is tiny
    (a unit whose line is known almost exactly): its roundoff, ~1e-8 relative, could put a
    median above its 95 % quantile; a quantile is raised to the largest of the lower levels'."""
    if len(levels) < 2:
        return tuple(quantiles)
    order = np.argsort(np.asarray(levels), kind="stable")
    q = np.maximum.accumulate(np.stack(quantiles)[order], axis=0)
    out = np.empty_like(q)
    out[order] = q
    return tuple(out)


def crps(model: Any, state: Any, y: FloatArray, cap: float,
         n_grid: int = 600) -> FloatArray:
    """CRPS of a model's RUL distribution (``model.rul_cdf``) at the true RUL ``y (B,)``:
    int_0^cap (F(r) - 1{r >= y})^2 dr by the trapezoidal rule on ``n_grid`` points (the
    never-failing mass is inside F's deficit, so the integral is capped at ``cap``, the same
    cap as the baselines' errors)."""
    r = np.linspace(0.0, cap, n_grid)
    rr = np.broadcast_to(r, (len(state), n_grid))
    f = model.rul_cdf(state, rr)
    step = (f - (rr >= np.asarray(y)[:, None])) ** 2
    return cast(FloatArray, np.trapezoid(step, r, axis=1))


# ------------------------------------------------------------------------------ learning
def _theta_to_params(th: FloatArray) -> tuple[FloatArray, FloatArray, float, float]:
    ma, mb, ll1, l21, ll2, lr, lq = th
    l11, l22 = math.exp(ll1), math.exp(ll2)
    cov = np.array([l11 * l11, l11 * l21, l21 * l21 + l22 * l22])
    return np.array([ma, mb]), cov, math.exp(lq), math.exp(lr)


PRIOR_NAMES = ("m_a", "m_b", "log_l11", "l21", "log_l22", "log_noise_var", "log_walk_var")


def fit_prior(x: FloatArray, z: FloatArray, hist: Histories,
              start: FloatArray | None = None) -> tuple[FloatArray, float, OptimResult]:
    """Maximise eq. (3) over (mu, Sigma, sigma_e^2, sigma_w^2) for transformed data ``z``.

    L-BFGS-B from the two-stage estimate and from a start with a larger random walk (the better
    optimum is kept), or from ``start`` alone (a warm start); log-Cholesky parameters keep Sigma
    positive definite; bounds keep the variances finite. Returns (theta, log-likelihood of z,
    the optimiser's diagnostics).
    """
    start_idx = hist.start.astype(np.int64)
    from rulkit.fleet.learned.filter_kernels import kf_nll_grad as nll_grad

    steps = np.full(7, 1e-5)

    def fg(th: FloatArray) -> tuple[float, FloatArray]:
        f, g = nll_grad(th, steps, x, z, start_idx)
        return float(f), np.asarray(g)

    # variance floors relative to the data's spread (sd(z) * 1e-4): keeps the optimiser off
    # degenerate corners (e.g. zero noise on quantised readings) without biting a real fit
    lz = math.log(max(float(np.std(z)), 1e-12))
    lo_sd, lo_var = lz - 9.2, 2.0 * lz - 18.4
    inf = math.inf
    bounds = [(-inf, inf), (-inf, inf), (lo_sd, lz + 9.2), (-inf, inf), (lo_sd, lz + 9.2),
              (lo_var, 2 * lz + 9.2), (lo_var, 2 * lz + 9.2)]
    if start is not None:
        starts = [np.asarray(start, dtype=np.float64)]
    else:
        x0 = two_stage_start(x, z, hist)
        shifted = x0.copy()
        shifted[6] += 4.0
        starts = [x0, shifted]
    best: OptimResult | None = None
    for st in starts:
        res = minimize_bounded(fg, st, bounds, list(PRIOR_NAMES))
        if best is None or res.fun < best.fun:
            best = res
    assert best is not None
    return best.x, -best.fun, best


def shape_grid(kind: str, hist: Histories) -> list[float]:
    """Candidate shapes (profile likelihood, eq. (4)).

    exponential: phi = h_min - d (1 - h_min) for d on a geometric grid from 1e-3 to 10 (below
    the lowest HI; and phi = 0 when h_min > 0); paris: lam = 1 - m/2 for m in [0, 8] in steps
    of 0.25 (m = 2 is the exponential law ln hi, m = 0 linear growth).
    """
    if kind == "linear":
        return [0.0]
    if kind == "paris":
        return [1.0 - m / 2.0 for m in np.arange(0.0, 8.01, 0.25)]
    hmin = float(hist.hi.min())
    span = max(1.0 - hmin, 1e-3)
    grid = [hmin - d * span for d in np.geomspace(1e-3, 10.0, 13)]
    if hmin > 0:
        grid.append(0.0)
    return sorted(set(grid))


def time_scale_of(hist: Histories) -> float:
    """tau: median age at the last acquisition (> 0; 1 if all ages are 0)."""
    last = hist.t[hist.start[1:] - 1]
    tau = float(np.median(np.abs(last)))
    return tau if tau > 0 else 1.0


def fit_model(hist: Histories, kind: str = "linear", *, time_unit: str = "",
              shape: float | None = None, start: DegradationModel | None = None
              ) -> DegradationModel:
    """Learn a model from histories (all units, failed and censored), eqs. (3)-(4).

    ``shape`` fixes phi / lam instead of the profile likelihood; ``start`` warm-starts from a
    fitted model of the same kind (its parameters, and for paris a local search of m from its
    exponent). The optimiser's report is the result's ``diagnostics`` (stalls, parameters at a
    bound, the shape at an end of its range).
    """
    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {KINDS}, got {kind!r}")
    tau = time_scale_of(hist)
    x = hist.t / tau
    theta0 = None if start is None else _params_to_theta(start)
    fits: dict[float, tuple[FloatArray, float, OptimResult]] = {}

    def at(sh: float) -> GrowthFit:
        if sh not in fits:
            z = transform(kind, sh, hist.hi)
            th, ll, res = fit_prior(x, z, hist, theta0)
            fits[sh] = (th, ll + log_jacobian(kind, sh, hist.hi), res)
        th, ll, res = fits[sh]
        return GrowthFit(lam=sh, theta=th, log_likelihood=ll, optim=res)

    edge = False
    if shape is not None:
        best = at(float(shape))
    elif kind == "paris":
        m0 = None if start is None else start.paris_exponent
        best, edge = profile_shape(at, m0)
    else:
        grid = shape_grid(kind, hist)
        for sh in grid:
            at(float(sh))
        best = max((at(float(sh)) for sh in grid), key=lambda f: f.log_likelihood)
        edge = kind == "exponential" and best.lam in (grid[0], grid[-1])
    mu, cov, q, r = _theta_to_params(best.theta)
    model = DegradationModel(
        kind=kind, shape=float(best.lam), mean=(float(mu[0]), float(mu[1])),
        cov=(float(cov[0]), float(cov[1]), float(cov[2])), noise_sd=math.sqrt(r),
        walk_sd=math.sqrt(q), time_scale=tau, time_unit=time_unit, n_units=hist.n_units,
        n_failed=int(hist.failed.sum()), log_likelihood=best.log_likelihood,
        diagnostics=FitDiagnostics(best.optim, edge))
    return model


def _params_to_theta(m: DegradationModel) -> FloatArray:
    saa, sab, sbb = m.cov
    l11 = math.sqrt(saa)
    l21 = sab / l11
    l22 = math.sqrt(max(sbb - l21 * l21, 1e-300))
    return np.array([m.mean[0], m.mean[1], math.log(l11), l21, math.log(l22),
                     2.0 * math.log(m.noise_sd), 2.0 * math.log(max(m.walk_sd, 1e-150))])


__all__ = [
    "HI_MIN",
    "KINDS",
    "PRIOR_NAMES",
    "STATE_COLUMNS",
    "DegradationModel",
    "GrowthLaw",
    "GrowthPrior",
    "UnitState",
    "crps",
    "filtered_states",
    "final_states",
    "fit_model",
    "fit_prior",
    "log_jacobian",
    "rul_cdf",
    "rul_quantiles",
    "shape_grid",
    "time_scale_of",
    "transform",
    "update_state",
]
