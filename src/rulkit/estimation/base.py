"""The estimator contract (docs/engine-api.md, "The estimator contract").

Every filter in rulkit turns a prior and measurements into posteriors of the same kind, a
:class:`Posterior`: the mean ``(n_x,)`` and covariance ``(n_x, n_x)`` of the state of one unit
at one time and, for a particle filter, the weighted samples behind them. Priors are
posteriors too (of the state one step before the first measurement). Every predictor, the
prognosis profile and the plots take a ``Posterior``; none asks which filter made it.

- A particle filter's posterior carries its particles *with* their weights: the weights
  travel with the samples, so a prediction can never drop them by accident.
- A Kalman-type posterior is Gaussian: ``samples`` is None; :meth:`Posterior.with_samples`
  draws from ``N(mean, cov)`` when samples are needed (Monte Carlo prediction, a particle
  filter started from a Gaussian prior).

The shared parts of every filter:

- :class:`FilterResult`, what every ``filter(...)`` returns: ``posterior(k)`` at step ``k``
  and ``moments()``, the means ``(T, n_x)`` and covariances ``(T, n_x, n_x)`` of all steps;
- :class:`Estimator`, the per-step API every filter has: ``state = f.initialise(prior, rng)``,
  then ``f.step(state, y)`` per measurement and ``state.posterior()`` at any time.

Usage::

    prior = Posterior(np.array([1.0, -20.0]), np.diag([0.1, 0.5]))
    state = estimator.initialise(prior if kalman else prior.with_samples(2000, rng), rng)
    for y in ys:
        estimator.step(state, y)
    rul = monte_carlo_rul(state.posterior(), model, horizon=100.0, rng=rng)
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rulkit.model import StateSpaceModel, as_batch, check_covariance, plain, psd_sqrt

FloatArray = NDArray[np.float64]

__all__ = [
    "Estimator",
    "EstimatorState",
    "FilterResult",
    "Posterior",
    "gaussian_samples",
    "refuse_model",
    "weighted_moments",
]


def weighted_moments(x: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Weighted mean ``sum_i w_i x_i`` (n_x,) and covariance ``sum_i w_i (x_i - m)(x_i - m)^T``
    (n_x, n_x) of samples ``x`` (N, n_x) with normalised weights ``w`` (N,).

    The plug-in moments of the weighted empirical measure (no small-sample correction),
    computed on one transposed copy: ``x - m`` on (N, n_x) with small ``n_x`` runs numpy's
    inner loop over ``n_x`` elements N times, on the (n_x, N) transpose over N.
    """
    xc = x.T.copy()  # (n_x, N), C-contiguous
    m = xc @ w
    xc -= m[:, None]
    return m, (xc * w) @ xc.T


def gaussian_samples(mean: ArrayLike, cov: ArrayLike, n_samples: int,
                     rng: np.random.Generator) -> FloatArray:
    """``n_samples`` draws of ``N(mean, cov)``, shape (n_samples, n) (a semi-definite ``cov``
    is sampled in its range, :func:`rulkit.model.psd_sqrt`)."""
    m = np.atleast_1d(np.asarray(mean, dtype=np.float64))
    c = check_covariance(cov, m.shape[0], "cov")
    n = int(n_samples)
    if n < 1:
        raise ValueError(f"n_samples: expected a positive number of samples, got {n_samples}")
    return m + rng.standard_normal((n, m.shape[0])) @ psd_sqrt(c).T


@dataclass(frozen=True, eq=False)
class Posterior:
    """The state estimate of one unit at one time.

    ``mean`` (n_x,) and ``cov`` (n_x, n_x) always; ``samples`` (N, n_x) with normalised
    ``weights`` (N,) when the estimate is a weighted sample (a particle filter's), else None.
    Validated on construction (finite, shapes, ``cov`` symmetric positive semi-definite;
    weights non-negative, not all zero: stored divided by their sum); arrays are stored
    read-only. Build one from samples with :meth:`from_samples`.
    """

    mean: FloatArray
    cov: FloatArray
    samples: FloatArray | None = None
    weights: FloatArray | None = None

    def __post_init__(self) -> None:
        m = np.atleast_1d(np.asarray(self.mean, dtype=np.float64))
        if m.ndim != 1 or m.size == 0 or not np.all(np.isfinite(m)):
            raise ValueError(f"mean: expected a finite 1-D state (n_x,), got {plain(self.mean)}")
        c = check_covariance(self.cov, m.size, "cov")
        s = w = None
        if self.samples is not None:
            s = as_batch(self.samples, m.size, "samples", single=False)
            w = _normalised(self.weights, s.shape[0])
        elif self.weights is not None:
            raise ValueError("weights: given without samples")
        for name, arr in (("mean", m), ("cov", c), ("samples", s), ("weights", w)):
            if arr is not None:
                arr = np.array(arr, dtype=np.float64)
                arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @classmethod
    def from_samples(cls, samples: ArrayLike, weights: ArrayLike | None = None) -> Posterior:
        """The posterior of weighted samples (N, n_x) (equal weights when None): their
        weighted mean and covariance (:func:`weighted_moments`) with the samples and weights."""
        s = as_batch(samples, None, "samples", single=False)
        w = _normalised(weights, s.shape[0])
        m, c = weighted_moments(s, w)
        return cls(m, 0.5 * (c + c.T), s, w)

    @property
    def n_x(self) -> int:
        """Number of state components."""
        return int(self.mean.shape[0])

    @property
    def std(self) -> FloatArray:
        """Standard deviations ``sqrt(diag(cov))`` (n_x,)."""
        return np.sqrt(np.diag(self.cov))

    def with_samples(self, n_samples: int, rng: np.random.Generator) -> Posterior:
        """This posterior with samples: itself when it has them, else ``n_samples`` equally
        weighted draws of ``N(mean, cov)`` (:func:`gaussian_samples`)."""
        if self.samples is not None:
            return self
        return Posterior.from_samples(gaussian_samples(self.mean, self.cov, n_samples, rng))


def _normalised(weights: ArrayLike | None, n: int) -> FloatArray:
    """Weights (n,) divided by their sum (equal weights when None; kept as they are when they
    sum to 1 within 1e-12); refused when not finite, negative or all zero, naming the first
    bad index."""
    if weights is None:
        return np.full(n, 1.0 / n)
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (n,):
        raise ValueError(f"weights: expected shape ({n},) like the samples, got {w.shape}")
    bad = np.flatnonzero(~np.isfinite(w) | (w < 0))
    if bad.size:
        raise ValueError(f"weights: expected finite non-negative weights, got {w[bad[0]]} at "
                         f"index {bad[0]}")
    total = float(w.sum())
    if not total > 0:
        raise ValueError("weights: all zero; at least one weight must be positive")
    # weights normalised already (to round-off) are kept bit for bit, as RULDistribution does
    return w if abs(total - 1.0) <= 1e-12 else w / total


class FilterResult(ABC):
    """What every filter's ``filter(...)`` returns (a particle filter's or a Kalman-type
    filter's result): the posterior at every step, of one unit (``unit``) of a batch."""

    @property
    @abstractmethod
    def n_steps(self) -> int:
        """Number of assimilated measurements ``T``."""

    @abstractmethod
    def posterior(self, k: int | None = None, unit: int = 0) -> Posterior:
        """The posterior after measurement ``k`` (None: after the last one)."""

    @abstractmethod
    def moments(self, unit: int = 0) -> tuple[FloatArray, FloatArray]:
        """Posterior means (T, n_x) and covariances (T, n_x, n_x) after every measurement."""


class EstimatorState(ABC):
    """The running state of a filter's per-step API: ``k`` is the last assimilated step
    (-1 after ``initialise``)."""

    k: int

    @abstractmethod
    def posterior(self, unit: int = 0) -> Posterior:
        """The posterior after step ``k`` (the prior after ``initialise``)."""


class Estimator(ABC):
    """The per-step API every filter has: ``initialise(prior, rng)``, then ``step(state, y)``
    once per measurement (step ``k`` predicts and assimilates ``ys[k]``, as in ``filter``)."""

    @abstractmethod
    def initialise(self, prior: Any, rng: np.random.Generator | None = None) -> EstimatorState:
        """Start from ``prior`` (a :class:`Posterior`, or the filter's own prior arrays)."""

    @abstractmethod
    def step(self, state: Any, y: Any) -> EstimatorState:
        """Assimilate one measurement; mutates and returns ``state``."""


def refuse_model(obj: Any, cls_name: str) -> None:
    """A model (or its bound ``step``) where a low-level function is expected is a
    ``TypeError`` naming ``from_model`` (docs/engine-api.md, "The calling convention")."""
    owner = getattr(obj, "__self__", None)
    bound_step = isinstance(owner, StateSpaceModel) and getattr(obj, "__name__", "") == "step"
    if isinstance(obj, StateSpaceModel) or bound_step:
        raise TypeError(f"{cls_name}(...) takes the low-level functions; for a model use "
                        f"{cls_name}.from_model(model, ...) (docs/engine-api.md, 'from_model')")
