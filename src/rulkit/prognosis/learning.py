"""Parameter learning: maximum likelihood of model parameters from measurement records.

``fit_parameters`` maximises ``sum_r log p(y^r_{1:T_r} | theta)`` over one or many records
(run-to-failure or censored: each is a measurement sequence; a record that stops before failure
simply has fewer measurements), where each record's log-likelihood is the filter's
prediction-error decomposition ``sum_k log p(y_k | y_{1:k-1}, theta)``: exact for a linear-
Gaussian model with the Kalman filter, a first/second-order approximation with the EKF/UKF,
and an unbiased (in ``exp``) Monte Carlo estimate with the particle filter.

With the particle filter the estimate is random; every evaluation reuses the same seeds
(common random numbers: the same initial particles and the same draws for every theta), which
makes the objective a deterministic, piecewise-smooth function of theta that a derivative-free
optimiser (Nelder-Mead) can minimise. Resampling still makes it discontinuous at small scales
(Malik & Pitt 2011 smooth it; not done here), so its finite-difference standard errors are
rougher than the Kalman ones: check them with more particles.

Standard errors come from the observed information: the Hessian of the negative
log-likelihood at the optimum by central finite differences (in the optimiser's coordinates,
``log theta`` for positive parameters, mapped back by the delta method).

Usage::

    fit = fit_parameters(model, [sim1.y, sim2.y], {"sigma_y": 0.1, "q": 1e-3},
                         x0=m0, P0=P0, method="ekf")
    fit.params, fit.stderr
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rulkit.estimation.base import gaussian_samples
from rulkit.estimation.ekf import ExtendedKalmanFilter
from rulkit.estimation.particle import ParticleFilter
from rulkit.estimation.ukf import UnscentedKalmanFilter
from rulkit.model import check_measurements

FloatArray = NDArray[np.float64]

__all__ = ["ParameterFit", "fit_parameters"]


@dataclass(frozen=True)
class ParameterFit:
    """Result of :func:`fit_parameters`: ``params`` (name -> estimate), ``stderr`` (name ->
    standard error, NaN when the Hessian is not positive definite), ``cov`` the asymptotic
    covariance (in ``names`` order), ``loglik`` the maximised log-likelihood, ``model`` the
    model at the estimate, ``n_evaluations`` and the optimiser's ``success``/``message``."""

    names: tuple[str, ...]
    params: dict[str, float]
    stderr: dict[str, float]
    cov: FloatArray
    loglik: float
    model: Any
    n_evaluations: int
    success: bool
    message: str


def _make_model(model: Any, values: Mapping[str, float]) -> Any:
    if isinstance(model, type) or (callable(model) and not hasattr(model, "step")):
        return model(**values)
    if dataclasses.is_dataclass(model) and not isinstance(model, type):
        return dataclasses.replace(model, **values)
    raise TypeError("model: expected a dataclass model (parameters replaced by "
                    "dataclasses.replace) or a callable make_model(**params) -> model")


def _records(records: Any, n_y: int) -> list[FloatArray]:
    if isinstance(records, np.ndarray) or (isinstance(records, Sequence) and records
                                           and np.isscalar(records[0])):
        records = [records]
    out = []
    for i, r in enumerate(records):
        try:
            out.append(check_measurements(r, n_y))
        except ValueError as err:
            raise ValueError(f"records[{i}]: {err}") from None
    if not out:
        raise ValueError("records: no measurement record given")
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
    options: Mapping[str, Any] | None = None,
) -> ParameterFit:
    """Maximum-likelihood estimate of ``params`` (module docstring).

    ``model``: a dataclass model (each trial is ``dataclasses.replace(model, **params)``) or a
    callable ``make_model(**params)``. ``records``: one measurement array (T, n_y) / (T,) or a
    list of them (different lengths allowed), all starting from the prior ``x0`` (mean (n_x,))
    with covariance ``P0`` at ``t0``. ``params``: names and starting values. ``positive``: the
    parameters optimised on a log scale (True: all; their starting values must be > 0).
    ``method``: ``"ekf"``/``"ukf"`` (L-BFGS-B) or ``"pf"`` (Nelder-Mead; ``n_particles`` drawn
    from ``N(x0, P0)`` with common random numbers from ``seed``). ``options`` go to
    :func:`scipy.optimize.minimize`.
    """
    from scipy.optimize import minimize

    names = tuple(params)
    if not names:
        raise ValueError("params: give at least one parameter name and starting value")
    logs = np.array([positive is True or (not isinstance(positive, bool) and n in positive)
                     for n in names])
    start = np.array([float(params[n]) for n in names])
    bad = np.flatnonzero(logs & ~(start > 0))
    if bad.size:
        raise ValueError(f"params: {names[bad[0]]!r} is optimised on a log scale (positive=) "
                         f"and needs a starting value > 0, got {start[bad[0]]!r}")
    if method not in ("ekf", "ukf", "pf"):
        raise ValueError(f"method: expected 'ekf', 'ukf' or 'pf', got {method!r}")
    if P0 is None:
        raise ValueError("P0: the prior covariance of the initial state is required")
    m0 = np.asarray(x0, dtype=np.float64)
    base = _make_model(model, dict(zip(names, start, strict=True)))
    recs = _records(records, base.n_y)
    to_theta = _Transform(logs)
    nll = _objective(model, names, to_theta, recs, m0, np.asarray(P0, dtype=np.float64),
                     method, n_particles, seed, dt, t0)
    z0 = to_theta.inverse(start)
    if method == "pf":
        opts = {"xatol": 1e-4, "fatol": 1e-3, "maxiter": 400 * len(names), **(options or {})}
        res = minimize(nll, z0, method="Nelder-Mead", options=opts)
    else:
        res = minimize(nll, z0, method="L-BFGS-B", options=dict(options or {}))
    theta = to_theta(res.x)
    step = 0.05 if method == "pf" else 1e-4
    H = _hessian(nll, res.x, step)
    cov = np.full((len(names), len(names)), np.nan)
    try:
        if np.all(np.linalg.eigvalsh(H) > 0):
            J = np.diag(to_theta.derivative(res.x))
            cov = J @ np.linalg.inv(H) @ J
    except np.linalg.LinAlgError:
        pass
    se = np.sqrt(np.diag(cov))
    fitted = dict(zip(names, theta.tolist(), strict=True))
    return ParameterFit(names=names, params=fitted,
                        stderr=dict(zip(names, se.tolist(), strict=True)), cov=cov,
                        loglik=-float(res.fun), model=_make_model(model, fitted),
                        n_evaluations=int(res.nfev), success=bool(res.success),
                        message=str(res.message))


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


def _objective(model: Any, names: tuple[str, ...], tr: _Transform, recs: list[FloatArray],
               m0: FloatArray, P0: FloatArray, method: str, n_particles: int, seed: int,
               dt: float | None, t0: float) -> Callable[[FloatArray], float]:
    """Negative total log-likelihood of the records as a function of the optimiser's z."""
    if method == "pf":
        init = gaussian_samples(m0, P0, n_particles, np.random.default_rng([seed, 0]))
    else:  # the Kalman filters are batched over units: one run for all records, the shorter
        # ones padded with NaN (a missing measurement: no update, log-likelihood increment 0)
        t_max = max(y.shape[0] for y in recs)
        stacked = np.full((t_max, len(recs), recs[0].shape[1]), np.nan)
        for r, y in enumerate(recs):
            stacked[: y.shape[0], r] = y
        mb = np.broadcast_to(m0, (len(recs), m0.shape[0])).copy()

    def nll(z: FloatArray) -> float:
        try:
            mdl = _make_model(model, dict(zip(names, tr(z).tolist(), strict=True)))
            total = 0.0
            if method != "pf":
                cls = ExtendedKalmanFilter if method == "ekf" else UnscentedKalmanFilter
                total = float(cls.from_model(mdl, dt=dt, t0=t0).filter(stacked, mb, P0)
                              .loglik.sum())
            for r, y in enumerate(recs if method == "pf" else ()):
                pf = ParticleFilter.from_model(mdl, dt=dt, t0=t0)
                res = pf.filter(y, init, np.random.default_rng([seed, r + 1]), quantiles=None)
                total += res.loglik
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            return math.inf  # parameters outside the model's domain
        return -total if math.isfinite(total) else math.inf

    return nll


def _hessian(f: Callable[[FloatArray], float], z: FloatArray, step: float) -> FloatArray:
    """Central finite-difference Hessian of ``f`` at ``z`` with steps ``step * max(1, |z|)``."""
    n = z.size
    h = step * np.maximum(1.0, np.abs(z))
    H = np.empty((n, n))
    f0 = f(z)
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
