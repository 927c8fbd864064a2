"""RUL predictors from a state estimate: Monte Carlo and the unscented transform.

Both turn an estimate of the state at a prediction time into a :class:`RULDistribution` by
running the model forward to its failure threshold (docs/engine-api.md, "Prediction"):

* :func:`monte_carlo_rul` draws samples of the estimate (the particles of a particle filter
  with their weights, or ``n_samples`` draws of a Gaussian ``N(mean, cov)`` from a Kalman
  filter) and propagates them *with process noise* by :func:`propagate_to_threshold`.
* :func:`unscented_rul` propagates the ``2 n + 1`` sigma points of ``N(mean, cov)`` *without*
  process noise (Julier & Uhlmann 1997, the unscented transform; the predictor ProgPy calls
  ``UnscentedTransformPredictor``). The time of event is a nonlinear function of the initial
  state, and the weighted sigma-point times give its mean and variance to second order. It
  ignores the process noise between the prediction time and the failure (so its spread is the
  state uncertainty's share only) and its quantiles come from 2n + 1 points: use it where the
  state uncertainty dominates and speed matters; Monte Carlo otherwise.

Usage::

    dist = monte_carlo_rul(pf_result, model, horizon=200.0, rng=rng)      # weighted particles
    dist = unscented_rul(kf.x[-1, 0], kf.P[-1, 0], model, horizon=200.0)   # Gaussian estimate
"""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rulkit.prognosis.rul import AfterCrossing, RULDistribution, propagate_to_threshold

FloatArray = NDArray[np.float64]

__all__ = ["gaussian_samples", "monte_carlo_rul", "sigma_points", "unscented_rul"]


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
    P = np.atleast_2d(np.asarray(cov, dtype=np.float64))
    if m.ndim != 1 or P.shape != (n, n):
        raise ValueError(f"mean (n,) and cov (n, n): got shapes {np.shape(mean)}, {np.shape(cov)}")
    if not (np.all(np.isfinite(m)) and np.all(np.isfinite(P))):
        raise ValueError("mean, cov: non-finite values")
    k = max(3.0 - n, 0.0) if kappa is None else float(kappa)
    if not (math.isfinite(k) and k >= 0):
        raise ValueError(f"kappa: expected a finite value >= 0 (non-negative weights), got "
                         f"{kappa!r}")
    w, V = np.linalg.eigh(0.5 * (P + P.T))
    if w[0] < -1e-10 * max(1.0, abs(w[-1])):
        raise ValueError(f"cov: not positive semi-definite (smallest eigenvalue {w[0]:.3g})")
    L = V * np.sqrt(np.clip(w, 0.0, None))  # L L^T = P (also for a singular P)
    d = math.sqrt(n + k) * L.T  # rows: scaled columns of L
    pts = np.concatenate([m[None], m + d, m - d])
    wts = np.full(2 * n + 1, 0.5 / (n + k))
    wts[0] = k / (n + k)
    return pts, wts


def gaussian_samples(mean: ArrayLike, cov: ArrayLike, n_samples: int,
                     rng: np.random.Generator) -> FloatArray:
    """``n_samples`` draws of ``N(mean, cov)`` (n_samples, n) (semi-definite ``cov`` allowed)."""
    m = np.atleast_1d(np.asarray(mean, dtype=np.float64))
    P = np.atleast_2d(np.asarray(cov, dtype=np.float64))
    w, V = np.linalg.eigh(0.5 * (P + P.T))
    L = V * np.sqrt(np.clip(w, 0.0, None))
    return m + rng.standard_normal((int(n_samples), m.shape[0])) @ L.T


def monte_carlo_rul(
    estimate: Any,
    model: Any = None,
    *,
    horizon: float,
    rng: np.random.Generator,
    cov: ArrayLike | None = None,
    n_samples: int = 1000,
    t0: float = 0.0,
    dt: float | None = None,
    u: Any = None,
    after_crossing: AfterCrossing = "drop",
    **kwargs: Any,
) -> RULDistribution:
    """Monte Carlo RUL from an estimate: weighted particles (an object with ``particles`` and
    ``weights``, e.g. a ``ParticleFilterResult``), an (N, n) sample array, or a Gaussian mean
    (n,) with ``cov`` (n, n), of which ``n_samples`` are drawn. Propagation with process noise
    by :func:`propagate_to_threshold` (``model=``, ``step=``/``indicator=``/``threshold=`` in
    ``kwargs`` override the model's). Crossed samples leave the batch (``"drop"``: a model
    steps rows independently) unless ``after_crossing`` says otherwise."""
    x0: Any = estimate
    if cov is not None:
        x0 = gaussian_samples(estimate, cov, n_samples, rng)
    return propagate_to_threshold(x0, model=model, horizon=horizon, rng=rng, t0=t0, dt=dt, u=u,
                                  after_crossing=after_crossing, **kwargs)


def unscented_rul(
    mean: ArrayLike,
    cov: ArrayLike,
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
    """Unscented-transform RUL of ``N(mean, cov)`` (module docstring): the 2n + 1 sigma points
    of :func:`sigma_points` run noise-free (``rng=None`` reaches the step) to the threshold;
    their times with the sigma-point weights form the returned distribution, whose ``mean``
    and ``std`` are the unscented estimates of the RUL's mean and standard deviation. A sigma
    point that does not fail within ``horizon`` is censored there (the mean is then a
    restricted mean, as everywhere in rulkit)."""
    pts, wts = sigma_points(mean, cov, kappa)
    return propagate_to_threshold(pts, model=model, horizon=horizon, rng=None,  # type: ignore[arg-type]
                                  t0=t0, dt=dt, u=u, direction=direction, weights=wts,
                                  after_crossing="drop", **kwargs)
