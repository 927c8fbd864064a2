"""The model contract shared by every physical system (architecture.md, "Layout").

A model is a vectorised discrete-time (or discretised continuous-time) state-space model over a
batch of states ``x`` of shape ``(N, n_x)``: N particles, N Monte Carlo samples or N fleet units.
One noise description per model, used by the simulator and by every filter.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def as_batch(x: np.ndarray, n_x: int, name: str = "x") -> FloatArray:
    """Return ``x`` as a float64 ``(N, n_x)`` array, accepting a single state of shape ``(n_x,)``.

    Raises ``ValueError`` naming ``name`` and the expected shape when the shape is wrong or
    the array holds NaN or infinite values.
    """
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != n_x:
        raise ValueError(f"{name}: expected shape (N, {n_x}) or ({n_x},), got {np.shape(x)}")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{name}: non-finite value at row {bad[0]}, column {bad[1]}")
    return arr


def check_covariance(cov: np.ndarray, n: int, name: str) -> FloatArray:
    """Validate a covariance matrix: shape (n, n), finite, symmetric, positive semi-definite."""
    c = np.atleast_2d(np.asarray(cov, dtype=np.float64))
    if c.shape != (n, n):
        raise ValueError(f"{name}: expected shape ({n}, {n}), got {np.shape(cov)}")
    if not np.all(np.isfinite(c)):
        raise ValueError(f"{name}: contains NaN or infinite entries")
    if not np.allclose(c, c.T, rtol=1e-10, atol=1e-14 * max(1.0, np.abs(c).max())):
        raise ValueError(f"{name}: not symmetric")
    eig = np.linalg.eigvalsh(c)
    if eig.min() < -1e-12 * max(1.0, abs(eig.max())):
        raise ValueError(
            f"{name}: not positive semi-definite (smallest eigenvalue {eig.min():.3g})"
        )
    return c


@dataclass(frozen=True)
class GaussianNoise:
    """Additive zero-mean Gaussian process and measurement noise of a model.

    ``Q`` is the process-noise covariance per step of length ``dt`` (n_x, n_x); ``R`` the
    measurement-noise covariance (n_y, n_y). Validated on construction.
    """

    Q: FloatArray
    R: FloatArray
    _chol_Q: FloatArray = field(init=False, repr=False)
    _chol_R: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        for name in ("Q", "R"):
            shape = np.shape(getattr(self, name))
            if len(shape) > 2 or (len(shape) == 2 and shape[0] != shape[1]) or len(shape) == 1:
                raise ValueError(f"{name}: expected a square (n, n) matrix or a scalar, got "
                                 f"shape {shape}")
        Q = check_covariance(self.Q, np.atleast_2d(self.Q).shape[0], "Q")
        R = check_covariance(self.R, np.atleast_2d(self.R).shape[0], "R")
        object.__setattr__(self, "Q", Q)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "_chol_Q", _psd_sqrt(Q))
        object.__setattr__(self, "_chol_R", _psd_sqrt(R))

    def sample_process(self, n: int, rng: np.random.Generator) -> FloatArray:
        """Draw ``n`` process-noise vectors, shape (n, n_x)."""
        return rng.standard_normal((n, self.Q.shape[0])) @ self._chol_Q.T

    def sample_measurement(self, n: int, rng: np.random.Generator) -> FloatArray:
        """Draw ``n`` measurement-noise vectors, shape (n, n_y)."""
        return rng.standard_normal((n, self.R.shape[0])) @ self._chol_R.T


def _psd_sqrt(c: FloatArray) -> FloatArray:
    """A square root L with L L^T = c, valid for semi-definite c (eigen-decomposition).

    Eigenvalues below ``n eps max|lambda|`` are round-off of a zero eigenvalue and are set to 0,
    so a singular c is sampled in its range only (no noise of relative size sqrt(eps) in the
    directions c says are noise-free).
    """
    w, v = np.linalg.eigh(c)
    tol = c.shape[0] * np.finfo(np.float64).eps * max(float(np.abs(w).max(initial=0.0)), 0.0)
    return v * np.sqrt(np.where(w > tol, w, 0.0))


class StateSpaceModel(ABC):
    """Vectorised state-space model: ``x_{k+1} = step(x_k, u_k, t_k, dt, rng)``, ``y = output(x)``.

    Subclasses set ``state_names``, ``input_names`` and ``output_names`` and implement
    :meth:`step` (which adds process noise when ``rng`` is given and is deterministic when
    ``rng`` is None) and :meth:`output` (noise-free). :attr:`noise` is the single noise
    description used by the simulator and every filter. A failure event is given by
    :meth:`health` (a scalar per state) crossing :attr:`threshold` upward.
    """

    state_names: tuple[str, ...] = ()
    input_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()
    threshold: float = np.inf

    @property
    def n_x(self) -> int:
        return len(self.state_names)

    @property
    def n_y(self) -> int:
        return len(self.output_names)

    @property
    @abstractmethod
    def noise(self) -> GaussianNoise:
        """Process and measurement noise of the model."""

    @abstractmethod
    def step(
        self,
        x: FloatArray,
        u: FloatArray | None,
        t: float,
        dt: float,
        rng: np.random.Generator | None = None,
    ) -> FloatArray:
        """Advance a batch of states (N, n_x) by ``dt``; add process noise when ``rng`` is given."""

    @abstractmethod
    def output(self, x: FloatArray, u: FloatArray | None = None) -> FloatArray:
        """Noise-free measurement of a batch of states, shape (N, n_y)."""

    def health(self, x: FloatArray) -> FloatArray:
        """Scalar degradation indicator per state, shape (N,); failure when >= ``threshold``."""
        raise NotImplementedError(f"{type(self).__name__} defines no failure event")
