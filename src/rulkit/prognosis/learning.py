"""Parameter learning: maximum likelihood of model parameters from measurement records.

``fit_parameters`` maximises ``sum_r log p(y^r_{1:T_r} | theta)`` over one or many records
(run-to-failure or censored: each is a measurement sequence; a record that stops before failure
simply has fewer measurements), where each record's log-likelihood is the filter's
prediction-error decomposition ``sum_k log p(y_k | y_{1:k-1}, theta)``: exact for a linear-
Gaussian model with the Kalman filter, a first/second-order approximation with the EKF/UKF,
and an unbiased (in ``exp``) Monte Carlo estimate with the particle filter.

Records of different lengths are handled exactly: each record's likelihood stops at its own
end. The Kalman filters run the records as a batch of units in segments between record ends
(a record that has ended leaves the batch: the model is never run past a record's last
measurement, where a degradation model may overflow); the particle filter runs each record.

With the particle filter the estimate is random; every evaluation reuses the same seeds
(common random numbers: the same initial particles and the same draws for every theta), which
makes the objective a deterministic, piecewise-smooth function of theta that a derivative-free
optimiser (Nelder-Mead) can minimise. Resampling still makes it discontinuous at small scales
(Malik & Pitt 2011 smooth it; not done here): with too few particles the optimiser stalls in a
pocket of the noise. The fit therefore re-evaluates the log-likelihood at the optimum with other
random numbers and reports the spread (``loglik_sd``).

Standard errors come from the observed information: the Hessian of the negative
log-likelihood at the optimum by central finite differences (in the optimiser's coordinates,
``log theta`` for positive parameters, mapped back by the delta method).

A fit never fails silently: ``success`` is False, with a message saying what went wrong and
what to do, when the optimiser reports a failure, the log-likelihood is not finite at or next
to the optimum, the optimiser stopped at its start although the start is no maximum, an
estimate sits on a bound, the Hessian is not positive definite (a parameter the records do not
determine), or the particle log-likelihood is too noisy at the optimum. Then a
:class:`FitWarning` is issued, or with ``strict=True`` a :class:`FitError` raised.

Usage::

    fit = fit_parameters(model, [sim1.y, sim2.y], {"sigma_y": 0.1, "q": 1e-3},
                         x0=m0, P0=P0, method="ekf")
    fit.params, fit.stderr, fit.success
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rulkit.estimation.base import gaussian_samples
from rulkit.estimation.ekf import ExtendedKalmanFilter
from rulkit.estimation.particle import ParticleFilter
from rulkit.estimation.ukf import UnscentedKalmanFilter
from rulkit.model import check_covariance, check_measurements, model_dt, plain

FloatArray = NDArray[np.float64]

__all__ = ["FitAttempt", "FitError", "FitWarning", "ParameterFit", "fit_parameters"]

#: Re-evaluations of a particle-filter objective at the optimum with fresh random numbers.
NOISE_REPEATS = 4
#: Default range of a log-scale parameter around its start (a factor of 1e10 either way).
LOG_RANGE = math.log(1e10)


class FitWarning(UserWarning):
    """A parameter fit did not succeed (its ``message`` says why and what to do)."""


class FitError(RuntimeError):
    """A parameter fit did not succeed and ``strict=True`` was asked: ``fit`` is the result."""

    def __init__(self, message: str, fit: ParameterFit) -> None:
        super().__init__(message)
        self.fit = fit


@dataclass(frozen=True)
class FitAttempt:
    """One optimisation of a (multi-start) fit: its ``start``, the ``params`` it reached, the
    log-likelihood there and the optimiser's ``success``/``message``."""

    start: dict[str, float]
    params: dict[str, float]
    loglik: float
    success: bool
    message: str


@dataclass(frozen=True)
class ParameterFit:
    """Result of :func:`fit_parameters`: ``params`` (name -> estimate), ``stderr`` (name ->
    standard error, NaN when the Hessian is not positive definite), ``cov`` the asymptotic
    covariance (in ``names`` order), ``loglik`` the maximised log-likelihood, ``loglik_sd``
    its spread over fresh random numbers (particle filter; 0 for the Kalman filters),
    ``model`` the model at the estimate, ``n_evaluations`` of the objective, ``success`` and
    ``message`` (module docstring: what failed and what to do), and the ``attempts`` of a
    multi-start fit (one per start)."""

    names: tuple[str, ...]
    params: dict[str, float]
    stderr: dict[str, float]
    cov: FloatArray
    loglik: float
    model: Any
    n_evaluations: int
    success: bool
    message: str
    loglik_sd: float = 0.0
    attempts: tuple[FitAttempt, ...] = ()


def _make_model(model: Any, values: Mapping[str, float]) -> Any:
    if isinstance(model, type) or (callable(model) and not hasattr(model, "step")):
        return model(**values)
    if dataclasses.is_dataclass(model) and not isinstance(model, type):
        return dataclasses.replace(model, **values)
    raise TypeError("model: expected a dataclass model (parameters replaced by "
                    "dataclasses.replace) or a callable make_model(**params) -> model")


def _records(records: Any, n_y: int) -> list[FloatArray]:
    """Each record as (T_r, n_y); a record without any measurement is refused."""
    if isinstance(records, np.ndarray) or (isinstance(records, Sequence) and records
                                           and np.isscalar(records[0])):
        records = [records]
    out = []
    for i, r in enumerate(records):
        try:
            y = check_measurements(r, n_y)
        except ValueError as err:
            raise ValueError(f"records[{i}]: {err}") from None
        if not np.isfinite(y).any(axis=1).any():
            raise ValueError(f"records[{i}]: no measurement (every row is NaN); a record needs "
                             "at least one measured row")
        out.append(y)
    if not out:
        raise ValueError("records: no measurement record given")
    return out


@dataclass(frozen=True)
class _Transform:
    """theta = exp(z) for log-scale parameters, z otherwise."""

    logs: NDArray[np.bool_]

    def __call__(self, z: FloatArray) -> FloatArray:
        return np.where(self.logs, np.exp(np.clip(z, -700, 700)), z)

    def inverse(self, theta: FloatArray) -> FloatArray:
        return np.where(self.logs, np.log(np.where(self.logs, theta, 1.0)), theta)

    def derivative(self, z: FloatArray) -> FloatArray:
        return np.where(self.logs, np.exp(z), 1.0)


@dataclass
class _Problem:
    """The validated fitting problem: names, transform, records, prior and filter settings."""

    model: Any
    names: tuple[str, ...]
    tr: _Transform
    recs: list[FloatArray]
    m0: FloatArray
    P0: FloatArray
    method: str
    n_particles: int
    dt: float | None
    t0: float
    failures: list[str] = dataclasses.field(default_factory=list)
    n_eval: int = 0

    def params(self, z: FloatArray) -> dict[str, float]:
        return dict(zip(self.names, self.tr(z).tolist(), strict=True))

    def objective(self, seed: int) -> Callable[[FloatArray], float]:
        """Negative total log-likelihood as a function of the optimiser's z; the particle
        filter's random numbers come from ``seed`` (common random numbers)."""
        if self.method == "pf":
            init = gaussian_samples(self.m0, self.P0, self.n_particles,
                                    np.random.default_rng([seed, 0]))

        def nll(z: FloatArray) -> float:
            self.n_eval += 1
            try:
                with np.errstate(all="ignore"), warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    mdl = _make_model(self.model, self.params(z))
                    total = (self._pf_loglik(mdl, init, seed) if self.method == "pf"
                             else self._kalman_loglik(mdl))
            except (ValueError, ArithmeticError, np.linalg.LinAlgError) as err:
                self._failed(z, f"{type(err).__name__}: {err}")
                return math.inf
            if not math.isfinite(total):
                self._failed(z, f"log-likelihood {total}")
                return math.inf
            return -total

        return nll

    def _failed(self, z: FloatArray, why: str) -> None:
        if len(self.failures) < 3:
            self.failures.append(f"at {plain(self.params(z))}: {why}")

    def _kalman_loglik(self, mdl: Any) -> float:
        """Records as units of one batch, in segments between record ends: a record that
        has ended leaves the batch, so no prediction runs past its last measurement."""
        cls = ExtendedKalmanFilter if self.method == "ekf" else UnscentedKalmanFilter
        h = model_dt(mdl, self.dt)
        lengths = np.array([y.shape[0] for y in self.recs])
        x = np.broadcast_to(self.m0, (len(self.recs), self.m0.size)).copy()
        P = np.broadcast_to(self.P0, (len(self.recs), *self.P0.shape)).copy()
        total, start = 0.0, 0
        for end in np.unique(lengths):
            active = np.flatnonzero(lengths >= end)
            ys = np.stack([self.recs[r][start:end] for r in active], axis=1)
            filt = cls.from_model(mdl, dt=self.dt, t0=self.t0 + start * h)
            res = filt.filter(ys, x[active], P[active])
            total += float(res.loglik.sum())
            x[active], P[active] = res.x[-1], res.P[-1]
            start = int(end)
        return total

    def _pf_loglik(self, mdl: Any, init: FloatArray, seed: int) -> float:
        total = 0.0
        pf = ParticleFilter.from_model(mdl, dt=self.dt, t0=self.t0)
        for r, y in enumerate(self.recs):
            res = pf.filter(y, init, np.random.default_rng([seed, r + 1]), quantiles=None)
            total += res.loglik
        return total


def _check_inputs(params: Mapping[str, float], positive: bool | Sequence[str], x0: ArrayLike,
                  P0: ArrayLike | None, method: str, n_particles: int
                  ) -> tuple[tuple[str, ...], NDArray[np.bool_], FloatArray, FloatArray,
                             FloatArray]:
    """Names, log-scale mask, start, prior mean and covariance, validated (errors name the
    argument and print plain numbers)."""
    names = tuple(params)
    if not names:
        raise ValueError("params: give at least one parameter name and starting value")
    if not isinstance(positive, bool):
        unknown = sorted(set(positive) - set(names))
        if unknown:
            raise ValueError(f"positive: {unknown} are not parameters being fitted {list(names)}")
    logs = np.array([positive is True or (not isinstance(positive, bool) and n in positive)
                     for n in names])
    start = _start_values(params, names, logs, "params")
    if method not in ("ekf", "ukf", "pf"):
        raise ValueError(f"method: expected 'ekf', 'ukf' or 'pf', got {method!r}")
    if P0 is None:
        raise ValueError("P0: the prior covariance of the initial state is required")
    m0 = np.atleast_1d(np.asarray(x0, dtype=np.float64))
    if m0.ndim != 1 or not np.all(np.isfinite(m0)):
        raise ValueError(f"x0: expected a finite prior mean (n_x,), got {plain(x0)}")
    P = check_covariance(P0, m0.size, "P0")
    if method == "pf" and (isinstance(n_particles, bool) or int(n_particles) != n_particles
                           or n_particles < 2):
        raise ValueError(f"n_particles: expected an integer >= 2, got {plain(n_particles)}")
    return names, logs, start, m0, P


def _start_values(values: Mapping[str, float], names: tuple[str, ...],
                  logs: NDArray[np.bool_], what: str) -> FloatArray:
    """Finite starting values (positive for log-scale parameters), in ``names`` order."""
    out = np.empty(len(names))
    for i, n in enumerate(names):
        try:
            v = float(values[n])
        except KeyError:
            raise ValueError(f"{what}: no value for {n!r}") from None
        except (TypeError, ValueError):
            raise ValueError(f"{what}: {n!r} must be a number, got {plain(values[n])}") from None
        if not math.isfinite(v):
            raise ValueError(f"{what}: {n!r} must be finite, got {v}")
        if logs[i] and not v > 0:
            raise ValueError(f"{what}: {n!r} is optimised on a log scale (positive=) and needs a "
                             f"starting value > 0, got {v}")
        out[i] = v
    return out


def _z_bounds(bounds: Mapping[str, tuple[float, float]] | None, names: tuple[str, ...],
              tr: _Transform, z0: FloatArray) -> list[tuple[float | None, float | None]]:
    """Bounds in the optimiser's coordinates: the given ones, else none (a box on every
    parameter makes L-BFGS-B take its first step all the way to the box; a log-scale estimate
    that runs away by more than a factor of 1e10 from its start is reported instead)."""
    given = dict(bounds or {})
    unknown = sorted(set(given) - set(names))
    if unknown:
        raise ValueError(f"bounds: {unknown} are not parameters being fitted {list(names)}")
    out: list[tuple[float | None, float | None]] = []
    for i, n in enumerate(names):
        if n not in given:
            out.append((None, None))
            continue
        lo, hi = (float(v) for v in given[n])
        if math.isnan(lo) or math.isnan(hi) or not lo < hi:
            raise ValueError(f"bounds: {n!r} needs lower < upper, got ({lo}, {hi})")
        theta0 = float(tr(z0)[i])
        if not lo <= theta0 <= hi:
            raise ValueError(f"bounds: the start of {n!r} ({theta0}) is outside ({lo}, {hi})")
        if tr.logs[i]:
            if hi <= 0:
                raise ValueError(f"bounds: {n!r} is positive (log scale): upper bound {hi} <= 0")
            out.append((math.log(lo) if lo > 0 else None, math.log(hi) if hi < math.inf else None))
        else:
            out.append((lo if lo > -math.inf else None, hi if hi < math.inf else None))
    return out


def fit_parameters(
    model: Any,
    records: Any,
    params: Mapping[str, float],
    *,
    x0: ArrayLike,
    P0: ArrayLike | None = None,
    method: Literal["ekf", "ukf", "pf"] = "ekf",
    positive: bool | Sequence[str] = True,
    n_particles: int = 1000,
    seed: int = 0,
    dt: float | None = None,
    t0: float = 0.0,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    starts: Sequence[Mapping[str, float]] = (),
    noise_tol: float = 1.0,
    strict: bool = False,
    options: Mapping[str, Any] | None = None,
) -> ParameterFit:
    """Maximum-likelihood estimate of ``params`` (module docstring).

    ``model``: a dataclass model (each trial is ``dataclasses.replace(model, **params)``) or a
    callable ``make_model(**params)``. ``records``: one measurement array (T, n_y) / (T,) or a
    list of them (different lengths allowed), all starting from the prior ``x0`` (mean (n_x,))
    with covariance ``P0`` at ``t0``. ``params``: names and starting values. ``positive``: the
    parameters optimised on a log scale (True: all; their starting values must be > 0).
    ``method``: ``"ekf"``/``"ukf"`` (L-BFGS-B) or ``"pf"`` (Nelder-Mead; ``n_particles`` drawn
    from ``N(x0, P0)`` with common random numbers from ``seed``). ``bounds``: name -> (lower,
    upper) in the parameters' units (default none; a log-scale estimate more than a factor of
    1e10 from its start is a failure, as is an estimate on a bound). ``starts``: more
    starting values (multi-start; each a mapping of some names to values, the others from
    ``params``): the attempt with the highest log-likelihood is returned, all are in
    ``attempts``. ``noise_tol``: the largest standard deviation (nats) of the particle
    log-likelihood at the optimum over fresh random numbers. ``strict``: raise
    :class:`FitError` instead of warning when the fit fails. ``options`` go to
    :func:`scipy.optimize.minimize`.

    Raises ``ValueError`` for invalid arguments, including starting values at which the
    log-likelihood is not finite for every start (the message gives the reason).
    """
    names, logs, start, m0, P = _check_inputs(params, positive, x0, P0, method, n_particles)
    tr = _Transform(logs)
    base = _make_model(model, dict(zip(names, start, strict=True)))
    prob = _Problem(model, names, tr, _records(records, base.n_y), m0, P, method,
                    int(n_particles), dt, float(t0))
    z_starts = [tr.inverse(start)] + [
        tr.inverse(_start_values({**params, **s}, names, logs, f"starts[{i}]"))
        for i, s in enumerate(starts)]
    zb = _z_bounds(bounds, names, tr, z_starts[0])
    nll = prob.objective(seed)
    runs = [_optimise(prob, nll, z, zb, options) for z in z_starts]
    tried = [r for r in runs if r is not None]
    if not tried:
        raise ValueError(f"params: the log-likelihood is not finite at the starting values "
                         f"({'; '.join(prob.failures)}); choose starting values where the "
                         "model runs on these records")
    best = min(tried, key=lambda r: r.fun)
    fit = _diagnose(prob, nll, best, z_starts[runs.index(best)], zb, seed, noise_tol)
    attempts = tuple(
        FitAttempt(prob.params(z), prob.params(r.x) if r else prob.params(z),
                   -float(r.fun) if r else -math.inf, bool(r and r.success),
                   str(r.message) if r else "log-likelihood not finite at this start")
        for z, r in zip(z_starts, runs, strict=True))
    fit = dataclasses.replace(fit, attempts=attempts)
    if not fit.success:
        if strict:
            raise FitError(fit.message, fit)
        warnings.warn(FitWarning(fit.message), stacklevel=2)
    return fit


def _optimise(prob: _Problem, nll: Callable[[FloatArray], float], z0: FloatArray,
              zb: list[tuple[float | None, float | None]], options: Mapping[str, Any] | None
              ) -> Any:
    """One optimisation from ``z0`` (None when the objective is not finite there).

    Where the log-likelihood is not finite (the model overflows, a filter fails) the optimiser
    sees a large finite value instead of ``inf``, so that a line search that steps into such a
    region backs off rather than stopping (an infinite value makes L-BFGS-B's interpolation
    NaN and it stops at its start)."""
    from scipy.optimize import minimize

    f_start = nll(z0)
    if not math.isfinite(f_start):
        return None
    wall = f_start + 1e6 * (1.0 + abs(f_start))

    def penalised(z: FloatArray) -> float:
        v = nll(z)
        return v if math.isfinite(v) else wall

    if prob.method == "pf":
        opts = {"xatol": 1e-4, "fatol": 1e-3, "maxiter": 400 * z0.size, **(options or {})}
        res = minimize(penalised, z0, method="Nelder-Mead", bounds=zb, options=opts)
    else:
        res = minimize(penalised, z0, method="L-BFGS-B", bounds=zb, options=dict(options or {}))
    if res.fun >= wall:  # never left the region where the log-likelihood is not finite
        res.success, res.message = False, "the log-likelihood is not finite at the result"
    return res


def _diagnose(prob: _Problem, nll: Callable[[FloatArray], float], res: Any, z0: FloatArray,
              zb: list[tuple[float | None, float | None]], seed: int, noise_tol: float
              ) -> ParameterFit:
    """The fit at the optimiser's result with every check of the module docstring."""
    z = np.asarray(res.x, dtype=np.float64)
    names, n_failed = prob.names, len(prob.failures)
    problems = [] if res.success else [f"the optimiser reports: {res.message}"]
    f0 = nll(z)
    H = _hessian(nll, z, 0.05 if prob.method == "pf" else 1e-4, f0)
    cov = np.full((len(names), len(names)), np.nan)
    if not (math.isfinite(f0) and np.all(np.isfinite(H))):
        problems.append("the log-likelihood is not finite at or next to the optimum ("
                        f"{'; '.join(prob.failures[n_failed:] or prob.failures)}): check the "
                        "model for overflow (e.g. an exponent that grows without bound)")
    elif np.all(np.linalg.eigvalsh(0.5 * (H + H.T)) > 0):
        J = np.diag(prob.tr.derivative(z))
        cov = J @ np.linalg.inv(H) @ J
        if not _moved(z, z0) and _newton_step(H, nll, z, f0) > 0.1:
            problems.append("the optimiser stopped at its start, which is not a maximum: try "
                            "other starting values (starts=...) or check the model")
    else:
        problems.append("the Hessian of the log-likelihood is not positive definite at the "
                        "estimate: a parameter is not determined by these records (flat or "
                        "not a maximum); fix it, add records or try other starting values")
    problems += _at_bounds(z, zb, prob)
    problems += [f"the estimate of {prob.names[i]!r} ran away from its start by more than a "
                 f"factor of 1e10 (to {float(prob.tr(z)[i]):.3g}): the records do not determine "
                 "it, or give bounds=" for i in np.flatnonzero(prob.tr.logs & (np.abs(z - z0)
                                                                           > LOG_RANGE))]
    sd = 0.0
    if prob.method == "pf" and math.isfinite(f0):
        sd = _loglik_spread(prob, z, seed)
        if not sd <= noise_tol:
            problems.append(f"the particle log-likelihood at the optimum varies with the random "
                            f"numbers (standard deviation {sd:.3g} nats over "
                            f"{NOISE_REPEATS} fresh seeds, tolerance {noise_tol:g}): the "
                            "optimiser may have stopped in a pocket of Monte Carlo noise; raise "
                            "n_particles or fit with method='ekf'/'ukf'")
    fitted = prob.params(z)
    se = np.sqrt(np.diag(cov))
    message = str(res.message) if not problems else "; ".join(problems)
    return ParameterFit(names=names, params=fitted,
                        stderr=dict(zip(names, se.tolist(), strict=True)), cov=cov,
                        loglik=-float(f0), model=_make_model(prob.model, fitted),
                        n_evaluations=prob.n_eval, success=not problems, message=message,
                        loglik_sd=sd)


def _moved(z: FloatArray, z0: FloatArray) -> bool:
    return bool(np.any(np.abs(z - z0) > 1e-6 * np.maximum(1.0, np.abs(z0))))


def _newton_step(H: FloatArray, nll: Callable[[FloatArray], float], z: FloatArray,
                 f0: float) -> float:
    """Length of the Newton step ``H^-1 g`` in standard errors (``g`` by central differences):
    small at a maximum, large at a start the optimiser never left."""
    h = 1e-4 * np.maximum(1.0, np.abs(z))
    g = np.array([(nll(z + e) - nll(z - e)) / (2 * hi) for e, hi in
                  zip(np.diag(h), h, strict=True)])
    step = np.linalg.solve(H, g)
    return float(np.sqrt(step @ H @ step))


def _at_bounds(z: FloatArray, zb: list[tuple[float | None, float | None]],
               prob: _Problem) -> list[str]:
    out = []
    for i, (lo, hi) in enumerate(zb):
        for b in (lo, hi):
            if b is not None and abs(z[i] - b) <= 1e-6 * max(1.0, abs(b)):
                value = math.exp(b) if prob.tr.logs[i] else b
                out.append(f"the estimate of {prob.names[i]!r} is at its bound {value:.6g}: "
                           "widen bounds=, or the records do not determine it")
    return out


def _loglik_spread(prob: _Problem, z: FloatArray, seed: int) -> float:
    """Standard deviation of the particle log-likelihood at ``z`` over fresh seeds."""
    vals = [-prob.objective(seed + 1_000_003 * (j + 1))(z) for j in range(NOISE_REPEATS)]
    return float(np.std(vals, ddof=1)) if all(map(math.isfinite, vals)) else math.inf


def _hessian(f: Callable[[FloatArray], float], z: FloatArray, step: float,
             f0: float) -> FloatArray:
    """Central finite-difference Hessian of ``f`` at ``z`` with steps ``step * max(1, |z|)``."""
    n = z.size
    h = step * np.maximum(1.0, np.abs(z))
    H = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            if i == j:
                e = np.zeros(n)
                e[i] = h[i]
                H[i, i] = (f(z + e) - 2 * f0 + f(z - e)) / h[i] ** 2
            else:
                ei, ej = np.zeros(n), np.zeros(n)
                ei[i], ej[j] = h[i], h[j]
                H[i, j] = H[j, i] = (f(z + ei + ej) - f(z + ei - ej) - f(z - ei + ej)
                                     + f(z - ei - ej)) / (4 * h[i] * h[j])
    return H
