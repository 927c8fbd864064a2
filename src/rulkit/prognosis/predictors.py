"""RUL predictors from a state estimate: Monte Carlo and the unscented transform.

Both turn a :class:`~rulkit.estimation.base.Posterior` of the state at a prediction time (any
filter's: ``result.posterior(k)``, ``state.posterior()``) into a :class:`RULDistribution` by
running the model forward to its failure threshold (docs/engine-api.md, "Prediction"):

* :func:`monte_carlo_rul` propagates samples of the posterior *with process noise* by
  :func:`propagate_to_threshold`: a particle filter's particles with their weights, or
  ``n_samples`` draws of the Gaussian ``N(mean, cov)`` of a Kalman-type posterior.
* :func:`unscented_rul` propagates the ``2 n + 1`` sigma points of ``N(mean, cov)`` *without*
  process noise (Julier & Uhlmann 1997, the unscented transform; the predictor ProgPy calls
  ``UnscentedTransformPredictor``). The time of event is a nonlinear function of the initial
  state, and the weighted sigma-point times give its mean and variance to second order. It
  ignores the process noise between the prediction time and the failure (so its spread is the
  state uncertainty's share only) and its quantiles come from 2n + 1 points: use it where the
  state uncertainty dominates and speed matters; Monte Carlo otherwise.

Usage::

    dist = monte_carlo_rul(pf_result.posterior(), model, horizon=200.0, rng=rng)
    dist = unscented_rul(kf_result.posterior(), model, horizon=200.0)
"""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rulkit.estimation.base import Posterior
from rulkit.model import check_covariance, plain, psd_sqrt
from rulkit.prognosis.rul import AfterCrossing, RULDistribution, propagate_to_threshold

FloatArray = NDArray[np.float64]

__all__ = ["monte_carlo_rul", "sigma_points", "unscented_rul"]


def sigma_points(mean: ArrayLike, cov: ArrayLike, kappa: float | None = None
                 ) -> tuple[FloatArray, FloatArray]:
    """Sigma points (2n + 1, n) and their non-negative weights (2n + 1,) of ``N(mean, cov)``.

    ``X_0 = m``, ``X_{+-i} = m +- sqrt(n + kappa) L_i`` (``L L^T = cov``, columns ``L_i``),
    weights ``kappa / (n + kappa)`` and ``1 / (2 (n + kappa))`` (Julier & Uhlmann 1997, with
    ``alpha = 1``, ``beta = 0``: the same weights give the mean and the covariance, and they
    are never negative, so the points form a proper weighted sample). ``kappa`` defaults to
    ``max(3 - n, 0)`` (matches the fourth moment of a Gaussian for n <= 3); it must be >= 0.
    The weighted mean and covariance of the points are ``mean`` and ``cov`` exactly.
    """
    m = np.atleast_1d(np.asarray(mean, dtype=np.float64))
    n = m.shape[0]
    if m.ndim != 1 or not np.all(np.isfinite(m)):
        raise ValueError(f"mean: expected a finite state (n,), got {plain(mean)}")
    P = check_covariance(cov, n, "cov")
    k = max(3.0 - n, 0.0) if kappa is None else float(kappa)
    if not (math.isfinite(k) and k >= 0):
        raise ValueError(f"kappa: expected a finite value >= 0 (non-negative weights), got "
                         f"{plain(kappa)}")
    L = psd_sqrt(P)  # L L^T = P (also for a singular P)
    d = math.sqrt(n + k) * L.T  # rows: scaled columns of L
    pts = np.concatenate([m[None], m + d, m - d])
    wts = np.full(2 * n + 1, 0.5 / (n + k))
    wts[0] = k / (n + k)
    return pts, wts


def monte_carlo_rul(
    posterior: Posterior | ArrayLike,
    model: Any = None,
    *,
    horizon: float,
    rng: np.random.Generator,
    n_samples: int = 1000,
    t0: float = 0.0,
    dt: float | None = None,
    u: Any = None,
    after_crossing: AfterCrossing = "drop",
    **kwargs: Any,
) -> RULDistribution:
    """Monte Carlo RUL from a :class:`Posterior`: its weighted samples (a particle filter's),
    or ``n_samples`` draws of ``N(mean, cov)`` (a Kalman-type posterior); an (N, n) array is
    taken as equally likely states. Propagation with process noise by
    :func:`propagate_to_threshold` (``model=``; ``step=``/``indicator=``/``threshold=`` in
    ``kwargs`` override the model's). Crossed samples leave the batch (``"drop"``: a model
    steps rows independently) unless ``after_crossing`` says otherwise."""
    x0 = posterior.with_samples(n_samples, rng) if isinstance(posterior, Posterior) else posterior
    return propagate_to_threshold(x0, model=model, horizon=horizon, rng=rng, t0=t0, dt=dt, u=u,
                                  after_crossing=after_crossing, **kwargs)


def unscented_rul(
    posterior: Posterior,
    model: Any = None,
    *,
    horizon: float,
    kappa: float | None = None,
    t0: float = 0.0,
    dt: float | None = None,
    u: Any = None,
    direction: Literal["up", "down"] = "up",
    **kwargs: Any,
) -> RULDistribution:
    """Unscented-transform RUL of the Gaussian ``N(mean, cov)`` of a :class:`Posterior`
    (module docstring): the 2n + 1 sigma points of :func:`sigma_points` run noise-free
    (``rng=None`` reaches the step) to the threshold; their times with the sigma-point weights
    form the returned distribution, whose ``mean`` and ``std`` are the unscented estimates of
    the RUL's mean and standard deviation. A sigma point that does not fail within ``horizon``
    is censored there (the mean is then a restricted mean, as everywhere in rulkit)."""
    if not isinstance(posterior, Posterior):
        raise TypeError(f"posterior: expected a Posterior (mean, cov), got "
                        f"{type(posterior).__name__}; build one with Posterior(mean, cov)")
    pts, wts = sigma_points(posterior.mean, posterior.cov, kappa)
    return propagate_to_threshold(Posterior.from_samples(pts, wts), model=model,
                                  horizon=horizon, rng=None,  # type: ignore[arg-type]
                                  t0=t0, dt=dt, u=u, direction=direction,
                                  after_crossing="drop", **kwargs)
