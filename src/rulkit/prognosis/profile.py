"""Prognosis profile: estimation over a measurement record, RUL predicted at chosen times, and
every prognostic metric of those predictions in one object (docs/engine-api.md, "Profile").

One call, :func:`prognosis_profile`, runs a filter built from the model (or given) over the
whole record through the estimator contract (``initialise``, ``step``, ``posterior``:
:mod:`rulkit.estimation.base`, the same code for every filter), takes the
:class:`~rulkit.estimation.base.Posterior` at each prediction time ``t_i`` (a measurement time),
and predicts the RUL from there (Monte Carlo or unscented transform, :mod:`.predictors`). The
:class:`PrognosisProfile` it returns holds the RUL distributions per time and the metrics of
Saxena et al. (2010) against the true end of life: alpha-lambda at every time (probability mass
inside ``(1 -+ alpha) r*``), the prognostic horizon, relative accuracy and its cumulative form,
convergence, interval coverage and CRPS; ``to_pandas()`` gives one row per time.

Censoring throughout: a predicted RUL beyond the prediction horizon is censored in its
distribution (rulkit's convention, :mod:`.rul`); a record that ends before failure
(``failed=False``) gives only a lower bound ``r* > t_end - t_i`` of the true RUL, so the
metrics that need r* itself (alpha-lambda, RA, PH, convergence, coverage) are NaN and the CRPS
is the censored CRPS of :func:`rulkit.metrics.crps_rul`.

Usage::

    prof = prognosis_profile(model, sim.y, "pf", prior, times=[10, 20, 30],
                             t_eol=sim.event_time, horizon=100.0, rng=rng)
    prof.to_pandas(); prof.prognostic_horizon().horizon; prof.cra
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rulkit.estimation.base import Estimator, Posterior
from rulkit.estimation.ekf import ExtendedKalmanFilter
from rulkit.estimation.particle import ParticleFilter
from rulkit.estimation.ukf import UnscentedKalmanFilter
from rulkit.metrics import (
    AlphaLambdaResult,
    PrognosticHorizonResult,
    alpha_lambda,
    convergence,
    crps_rul,
    mass_inside,
    prognostic_horizon,
)
from rulkit.model import check_covariance, check_measurements, model_dt, plain
from rulkit.prognosis.predictors import monte_carlo_rul, unscented_rul
from rulkit.prognosis.rul import RULDistribution

FloatArray = NDArray[np.float64]

__all__ = ["PrognosisProfile", "prognosis_profile"]


@dataclass(frozen=True, eq=False)
class PrognosisProfile:
    """RUL predictions at ``times`` of one unit and their metrics (module docstring).

    ``distributions[i]`` is the RUL distribution predicted at ``times[i]``; ``t_eol`` the true
    end of life (``failed=True``) or the end of the record of a unit still running
    (``failed=False``), None when unknown; ``estimate`` the filter's posteriors over the record
    (one :class:`Posterior` per measurement, ``estimate[k]`` at ``measurement_times[k]``);
    ``alpha``, ``beta``: the accuracy cone ``(1 -+ alpha) r*`` and the probability mass needed
    inside it; ``level``: the central interval of ``lower``/``upper`` and of the coverage.
    """

    times: FloatArray
    distributions: tuple[RULDistribution, ...]
    t_eol: float | None
    failed: bool
    estimate: tuple[Posterior, ...]
    measurement_times: FloatArray
    predictor: str
    alpha: float = 0.2
    beta: float = 0.5
    level: float = 0.9

    @property
    def dists(self) -> tuple[RULDistribution, ...]:
        """Alias of :attr:`distributions` (the name :func:`rulkit.plot.plot_profile` reads)."""
        return self.distributions

    def plot(self, **kwargs: Any) -> Any:
        """The alpha-lambda cone and the RUL densities over time
        (:func:`rulkit.plot.plot_profile` with this profile's ``alpha`` and ``level``)."""
        from rulkit.plot import plot_profile

        kwargs.setdefault("alpha", self.alpha)
        kwargs.setdefault("level", self.level)
        return plot_profile(self, **kwargs)

    # -- per time ---------------------------------------------------------------------------
    @property
    def truth_known(self) -> bool:
        """True when the end of life is known (a run-to-failure record)."""
        return self.t_eol is not None and self.failed

    @property
    def rul_true(self) -> FloatArray:
        """``t_eol - t_i`` (NaN when unknown; a lower bound when ``failed`` is False)."""
        if self.t_eol is None:
            return np.full(self.times.shape, np.nan)
        return float(self.t_eol) - self.times

    @property
    def _valid(self) -> NDArray[np.bool_]:
        """Times with a known, positive true RUL (before the end of life)."""
        r = self.rul_true
        return np.isfinite(r) & (r > 0) & self.truth_known

    @property
    def median(self) -> FloatArray:
        return np.array([d.median for d in self.distributions])

    @property
    def mean(self) -> FloatArray:
        """Restricted means (rulkit's censoring convention)."""
        return np.array([d.mean for d in self.distributions])

    @property
    def lower(self) -> FloatArray:
        return np.array([d.interval(self.level)[0] for d in self.distributions])

    @property
    def upper(self) -> FloatArray:
        return np.array([d.interval(self.level)[1] for d in self.distributions])

    @property
    def fraction_censored(self) -> FloatArray:
        return np.array([d.fraction_censored for d in self.distributions])

    @property
    def alpha_lambda_mass(self) -> FloatArray:
        """Probability mass inside ``[(1 - alpha) r*, (1 + alpha) r*]`` at every time (NaN
        where r* is unknown or not positive)."""
        r, ok = self.rul_true, self._valid
        return np.array([mass_inside(d, (1 - self.alpha) * ri, (1 + self.alpha) * ri) if v
                         else np.nan for d, ri, v in zip(self.distributions, r, ok, strict=True)])

    @property
    def alpha_lambda_pass(self) -> NDArray[np.bool_]:
        """``alpha_lambda_mass >= beta`` at every time (False where r* is unknown)."""
        m = self.alpha_lambda_mass
        return np.where(np.isnan(m), False, m >= self.beta)

    @property
    def relative_accuracy(self) -> FloatArray:
        """``RA = 1 - |r* - median| / r*`` per time (NaN where r* is unknown)."""
        r = self.rul_true
        with np.errstate(invalid="ignore", divide="ignore"):
            ra = 1.0 - np.abs(r - self.median) / r
        return np.where(self._valid & np.isfinite(self.median), ra, np.nan)

    @property
    def crps(self) -> FloatArray:
        """CRPS per time (:func:`rulkit.metrics.crps_rul`: censored forecasts and, for a record
        without failure, the censored truth handled); NaN where nothing is known."""
        r = self.rul_true
        out = np.full(self.times.shape, np.nan)
        for i, (d, ri) in enumerate(zip(self.distributions, r, strict=True)):
            if np.isfinite(ri) and ri > 0:
                out[i] = crps_rul(d, float(ri), truth_censored=not self.failed)
        return out

    # -- over the record --------------------------------------------------------------------
    @property
    def cra(self) -> float:
        """Cumulative relative accuracy: mean RA over the times with a known r* (NaN if none)."""
        ra = self.relative_accuracy
        ra = ra[np.isfinite(ra)]
        return float(ra.mean()) if ra.size else math.nan

    @property
    def coverage(self) -> float:
        """Fraction of times (with known r*) whose ``level`` interval holds r*."""
        ok = self._valid
        if not ok.any():
            return math.nan
        r = self.rul_true[ok]
        return float(np.mean((self.lower[ok] <= r) & (r <= self.upper[ok])))

    @property
    def convergence(self) -> float:
        """Convergence ([S2010]) of the absolute error ``|r* - median|`` (NaN if undefined:
        fewer than two times with known r*, an infinite median, or zero error throughout)."""
        ok = self._valid & np.isfinite(self.median)
        if ok.sum() < 2:
            return math.nan
        err = np.abs(self.rul_true[ok] - self.median[ok])
        try:
            return convergence(self.times[ok], err)
        except ValueError:
            return math.nan

    def alpha_lambda(self, lam: float = 0.5) -> AlphaLambdaResult:
        """[S2010]'s alpha-lambda test at ``t_lambda = t_P + lam (t_EoL - t_P)`` (see
        :func:`rulkit.metrics.alpha_lambda`). Note: ``lam`` is a *fraction* of the time from the
        first prediction to end of life; ProgPy's ``alpha_lambda`` takes the time itself."""
        self._need_truth()
        ok = self._valid
        dists = [d for d, v in zip(self.distributions, ok, strict=True) if v]
        return alpha_lambda(self.times[ok], dists, float(self.t_eol),  # type: ignore[arg-type]
                            alpha=self.alpha, lam=lam, beta=self.beta)

    def prognostic_horizon(self, alpha: float | None = None,
                           bounds: Literal["absolute", "relative"] = "relative",
                           stay: bool = False) -> PrognosticHorizonResult:
        """Prognostic horizon ([S2010]) with the profile's cone (``bounds="relative"``, the
        alpha-lambda cone) or [S2010]'s constant-width one (``"absolute"``, ``alpha t_EoL``)."""
        self._need_truth()
        ok = self._valid
        dists = [d for d, v in zip(self.distributions, ok, strict=True) if v]
        return prognostic_horizon(self.times[ok], dists, float(self.t_eol),  # type: ignore[arg-type]
                                  alpha=self.alpha if alpha is None else alpha, beta=self.beta,
                                  bounds=bounds, stay=stay)

    def _need_truth(self) -> None:
        if not self.truth_known or not self._valid.any():
            raise ValueError("this metric needs the true end of life: pass t_eol= (and "
                             "failed=True) with a prediction time before it")

    def summary(self) -> dict[str, float]:
        """Scalar metrics: CRA, coverage, convergence, mean CRPS, prognostic horizon,
        alpha-lambda at lambda = 0.5 (NaN where undefined)."""
        ph = al = math.nan
        if self.truth_known and self._valid.any():
            ph = self.prognostic_horizon().horizon
            try:
                al = float(self.alpha_lambda(0.5).passed)
            except ValueError:
                al = math.nan
        crps = self.crps
        return {"n_times": float(self.times.size), "cra": self.cra, "coverage": self.coverage,
                "convergence": self.convergence,
                "crps_mean": float(np.nanmean(crps)) if np.isfinite(crps).any() else math.nan,
                "prognostic_horizon": ph, "alpha_lambda_0.5_passed": al}

    def to_pandas(self) -> Any:
        """One row per prediction time: t, true RUL, mean, median, interval, censored fraction,
        alpha-lambda mass and pass, RA, CRPS."""
        import pandas as pd

        lo_name = f"q{(1 - self.level) / 2:.3g}"
        hi_name = f"q{(1 + self.level) / 2:.3g}"
        return pd.DataFrame({
            "t": self.times, "rul_true": self.rul_true, "mean": self.mean,
            "median": self.median, lo_name: self.lower, hi_name: self.upper,
            "fraction_censored": self.fraction_censored,
            "alpha_lambda_mass": self.alpha_lambda_mass,
            "alpha_lambda_pass": self.alpha_lambda_pass,
            "relative_accuracy": self.relative_accuracy, "crps": self.crps,
        })


def _build(estimator: Any, model: Any, dt: float, t0: float, u: Any) -> Estimator:
    if isinstance(estimator, str):
        makers = {"pf": ParticleFilter, "ekf": ExtendedKalmanFilter,
                  "ukf": UnscentedKalmanFilter}
        if estimator not in makers:
            raise ValueError(f"estimator: expected 'pf', 'ekf', 'ukf' or a filter, got "
                             f"{estimator!r}")
        return makers[estimator].from_model(model, dt=dt, t0=t0, u=u)  # type: ignore[attr-defined, no-any-return]
    if not isinstance(estimator, Estimator):
        raise TypeError(f"estimator: expected 'pf', 'ekf', 'ukf' or a rulkit filter, got "
                        f"{type(estimator).__name__}")
    return estimator


def _prior(prior: Any, P0: ArrayLike | None) -> Posterior:
    """The prior as a :class:`Posterior`: given as one, as particles (N, n_x) (equally
    weighted) or as a mean (n_x,) with ``P0``."""
    if isinstance(prior, Posterior):
        if P0 is not None:
            raise ValueError("P0: the prior posterior carries its own covariance")
        return prior
    arr = np.asarray(prior, dtype=np.float64)
    if arr.ndim == 2:
        if P0 is not None:
            raise ValueError("P0: particles (N, n_x) were given as the prior; give P0 with a "
                             "mean (n_x,) only")
        return Posterior.from_samples(arr)
    if P0 is None:
        raise ValueError("P0: a prior mean (n_x,) needs its covariance P0 (or give particles "
                         "(N, n_x) or a Posterior)")
    if arr.ndim != 1 or not np.all(np.isfinite(arr)):
        raise ValueError(f"prior: expected a finite mean (n_x,), particles (N, n_x) or a "
                         f"Posterior, got {plain(prior)}")
    return Posterior(arr, check_covariance(P0, arr.size, "P0"))


def _step_index(times: FloatArray, t_meas: FloatArray) -> NDArray[np.intp]:
    """Index of the measurement at each prediction time (must coincide with one)."""
    idx = np.searchsorted(t_meas, times - 1e-9 * np.maximum(1.0, np.abs(times)))
    idx = np.minimum(idx, t_meas.size - 1)
    bad = np.abs(t_meas[idx] - times) > 1e-9 * np.maximum(1.0, np.abs(times))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"times: {plain(times[i])} is not a measurement time (measurement k is "
                         f"at t0 + (k + 1) dt: {plain(t_meas[0])}, "
                         f"{plain(t_meas[min(1, t_meas.size - 1)])}, ..., {plain(t_meas[-1])})")
    return idx


def prognosis_profile(
    model: Any,
    ys: ArrayLike,
    estimator: Any,
    prior: Any,
    *,
    times: Sequence[float] | ArrayLike,
    horizon: float,
    rng: np.random.Generator,
    P0: ArrayLike | None = None,
    t_eol: float | None = None,
    failed: bool = True,
    predictor: Literal["monte_carlo", "unscented"] = "monte_carlo",
    n_samples: int = 1000,
    t0: float = 0.0,
    dt: float | None = None,
    u: Any = None,
    alpha: float = 0.2,
    beta: float = 0.5,
    level: float = 0.9,
) -> PrognosisProfile:
    """Estimate over the record ``ys`` and predict the RUL at each of ``times`` (module doc).

    ``estimator``: ``"pf"``, ``"ekf"``, ``"ukf"`` (built by ``from_model``) or any rulkit
    filter. ``prior``: the state at ``t0``, one step before ``ys[0]`` (measurement k is at
    ``t0 + (k + 1) dt``, ``dt`` defaulting to ``model.dt``): a :class:`Posterior`, particles
    (N, n_x) (a particle filter needs samples: ``Posterior.with_samples`` draws them), or a
    mean (n_x,) with covariance ``P0``. ``times`` must be measurement times. At each the
    posterior is propagated from that time to the threshold: ``"monte_carlo"`` (the weighted
    particles, or ``n_samples`` draws of a Gaussian posterior, with process noise) or
    ``"unscented"`` (sigma points of the posterior mean and covariance, noise-free).
    ``horizon``: the prediction window (RUL beyond it is censored). ``t_eol``: true end of life
    (``failed=True``), or the time the unit was last seen running (``failed=False``, a censored
    record). ``rng`` drives filter and predictor.
    """
    h = model_dt(model, dt)
    y = check_measurements(ys, model.n_y)
    t_meas = t0 + h * np.arange(1, y.shape[0] + 1)
    tp = np.atleast_1d(np.asarray(times, dtype=np.float64))
    if tp.ndim != 1 or tp.size == 0 or not np.all(np.isfinite(tp)):
        raise ValueError(f"times: expected a non-empty 1-D array of finite times, got "
                         f"{plain(times)}")
    if np.any(np.diff(tp) <= 0):
        raise ValueError("times: expected strictly increasing prediction times")
    if predictor not in ("monte_carlo", "unscented"):
        raise ValueError(f"predictor: expected 'monte_carlo' or 'unscented', got {predictor!r}")
    if t_eol is not None and not math.isfinite(float(t_eol)):
        t_eol = None  # e.g. a simulation whose unit never failed: truth unknown
    idx = _step_index(tp, t_meas)
    filt = _build(estimator, model, h, t0, u)
    state = filt.initialise(_prior(prior, P0), rng)
    posteriors = []
    for yk in y:
        filt.step(state, yk)
        posteriors.append(state.posterior())
    dists = []
    for k, t_i in zip(idx, tp, strict=True):
        common = dict(model=model, horizon=horizon, t0=float(t_i), dt=h, u=u)
        if predictor == "unscented":
            dists.append(unscented_rul(posteriors[k], **common))
        else:
            dists.append(monte_carlo_rul(posteriors[k], rng=rng, n_samples=n_samples, **common))
    return PrognosisProfile(times=tp, distributions=tuple(dists),
                            t_eol=None if t_eol is None else float(t_eol), failed=bool(failed),
                            estimate=tuple(posteriors), measurement_times=t_meas,
                            predictor=predictor, alpha=float(alpha), beta=float(beta),
                            level=float(level))
