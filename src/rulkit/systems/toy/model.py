"""A 2-state linear degradation model: the engine's end-to-end example and benchmark problem.

State ``x = [damage, rate]``; per step of length ``dt``::

    damage_{k+1} = damage_k + rate_k dt + w_d,     w_d ~ N(0, sigma_d^2 dt)
    rate_{k+1}   = rate_k + w_r,                   w_r ~ N(0, sigma_r^2 dt)
    y_k          = damage_k + v,                    v  ~ N(0, sigma_y^2)

Failure when ``damage >= 1`` (``threshold``). The process noise is that of a Brownian motion
(variance proportional to ``dt``), so refining ``dt`` does not change the continuous-time model.
The model is linear and Gaussian, which gives an exact Kalman filter as the oracle for the
particle filter (``F = [[1, dt], [0, 1]]``, ``H = [1, 0]``), and without process noise the
time to failure is ``(1 - damage) / rate`` in closed form.

It is the 2-state problem of the engine example and of the ProgPy benchmarks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np
from numpy.typing import NDArray

from rulkit.model import GaussianNoise, StateSpaceModel, as_batch

FloatArray = NDArray[np.float64]

__all__ = ["ToyDegradation"]


@nb.njit(cache=True)
def _advance(z, x, csd, csr, dt):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """In place: ``z[:, 0] = z0 csd + damage + rate dt``, ``z[:, 1] = z1 csr + rate`` (the
    module docstring's transition; each product and sum rounded separately, in this order)."""
    for i in range(z.shape[0]):
        rate = x[i, 1]
        d = z[i, 0] * csd
        d += x[i, 0]
        d += rate if dt == 1.0 else rate * dt
        z[i, 0] = d
        z[i, 1] = z[i, 1] * csr + rate
    return z


@nb.njit(cache=True)
def _gauss_loglik(x, y, sigma, log_norm):  # type: ignore[no-untyped-def]  # pragma: no cover
    """``-0.5 r r - log_norm`` with ``r = (y - x[:, 0]) / sigma``, rounded as numpy's
    ``((r * -0.5) * r) - log_norm``."""
    n = x.shape[0]
    out = np.empty(n)
    for i in range(n):
        r = (y - x[i, 0]) / sigma
        out[i] = r * -0.5 * r - log_norm
    return out


@dataclass(frozen=True)
class ToyDegradation(StateSpaceModel):
    """Linear damage accumulation with a slowly wandering damage rate (module docstring).

    Parameters
    ----------
    sigma_d : damage process-noise intensity [damage / sqrt(time)] (default 1e-3).
    sigma_r : rate process-noise intensity [damage / time / sqrt(time)] (default 1e-4).
    sigma_y : measurement noise standard deviation [damage] (default 0.02).
    dt : nominal step of :attr:`noise` and of :meth:`transition_matrix` (default 1.0).
    """

    sigma_d: float = 1e-3
    sigma_r: float = 1e-4
    sigma_y: float = 0.02
    dt: float = 1.0

    state_names = ("damage", "rate")
    input_names = ()
    output_names = ("damage_measured",)
    threshold = 1.0

    def __post_init__(self) -> None:
        for name in ("sigma_d", "sigma_r", "sigma_y"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name}: expected a finite value >= 0, got {v!r}")
        if not self.sigma_y > 0:
            raise ValueError("sigma_y: must be positive (the likelihood needs it)")
        if not (math.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"dt: expected a positive finite step, got {self.dt!r}")

    # ---------------------------------------------------------------- noise / linear form
    def process_cov(self, dt: float) -> FloatArray:
        """Process-noise covariance of one step of length ``dt``: diag(sigma_d^2, sigma_r^2) dt."""
        return np.diag([self.sigma_d**2, self.sigma_r**2]) * dt

    @property
    def noise(self) -> GaussianNoise:
        """Process noise per nominal step ``dt`` and measurement noise."""
        return GaussianNoise(Q=self.process_cov(self.dt), R=np.array([[self.sigma_y**2]]))

    def transition_matrix(self, dt: float | None = None) -> FloatArray:
        """``F = [[1, dt], [0, 1]]`` of the linear transition."""
        h = self.dt if dt is None else dt
        return np.array([[1.0, h], [0.0, 1.0]])

    @staticmethod
    def observation_matrix() -> FloatArray:
        """``H = [[1, 0]]``."""
        return np.array([[1.0, 0.0]])

    # ---------------------------------------------------------------- contract
    def step(
        self,
        x: FloatArray,
        u: FloatArray | None,
        t: float,
        dt: float,
        rng: np.random.Generator | None = None,
    ) -> FloatArray:
        """Advance a batch (N, 2) by ``dt``; add N(0, process_cov(dt)) noise when ``rng`` given.

        Hot path (called once per filter/propagation step): a float64 (N, 2) array is used
        as is, without the finiteness scan of :func:`as_batch`; NaN propagates to the caller,
        whose checks (log-weights, threshold indicator) report it with the step.
        """
        if isinstance(x, np.ndarray) and x.dtype == np.float64 and x.ndim == 2:
            if x.shape[1] != 2:
                raise ValueError(f"x: expected shape (N, 2) or (2,), got {x.shape}")
            xb = x
        else:
            xb = as_batch(x, 2)
        if rng is None:
            out = np.empty_like(xb)
            out[:, 0] = xb[:, 0] + xb[:, 1] * dt
            out[:, 1] = xb[:, 1]
            return out
        # One compiled pass over the standard normals (same draws, same floating-point
        # operations in the same order as ``z * (sd, sr) sqrt(dt) + x`` then
        # ``damage += rate dt``, each rounded as numpy rounds it; no fused multiply-add).
        out = rng.standard_normal(xb.shape)
        s = math.sqrt(dt)
        _advance(out, xb, self.sigma_d * s, self.sigma_r * s, dt)
        return out

    def output(self, x: FloatArray, u: FloatArray | None = None) -> FloatArray:
        """Noise-free measurement: the damage, shape (N, 1)."""
        return as_batch(x, 2)[:, :1].copy()

    def health(self, x: FloatArray) -> FloatArray:
        """The damage; failure when it reaches :attr:`threshold` (1.0)."""
        return np.asarray(x, dtype=np.float64)[:, 0]

    def log_likelihood(
        self, x: FloatArray, y: float | FloatArray, u: FloatArray | None = None
    ) -> FloatArray:
        """``log N(y; damage_i, sigma_y^2)`` per particle, shape (N,) (no input: ``u`` unused)."""
        if isinstance(y, np.ndarray) and y.dtype == np.float64 and y.size:
            yy = y.item(0)  # the first element as a Python float (no converted copy)
        else:
            yy = float(np.asarray(y, dtype=np.float64).reshape(-1)[0])
        xa = np.asarray(x, dtype=np.float64)
        if xa.ndim != 2 or xa.shape[1] < 1:
            raise ValueError(f"x: expected shape (N, 2), got {xa.shape}")
        # -0.5 r r - log(sigma_y sqrt(2 pi)) with r = (y - damage) / sigma_y, in one pass
        return _gauss_loglik(xa, yy, self.sigma_y,  # type: ignore[no-any-return]
                             math.log(self.sigma_y * math.sqrt(2.0 * math.pi)))

    def rul_noise_free(self, x: FloatArray) -> FloatArray:
        """Closed-form time to failure without process noise: ``(1 - damage) / rate``.

        0 for states already failed, ``inf`` where the rate is <= 0 and damage < 1.
        """
        xb = np.asarray(x, dtype=np.float64)
        d, r = xb[:, 0], xb[:, 1]
        out = np.full(d.shape, np.inf)
        failed = d >= self.threshold
        out[failed] = 0.0
        ok = ~failed & (r > 0)
        out[ok] = (self.threshold - d[ok]) / r[ok]
        return out

    # The contract's simulate (a Simulation, one unit without a batch axis) is inherited as
    # is; this batch-always tuple keeps the example's and the benchmarks' draws unchanged.
    def simulate_units(
        self, x0: FloatArray, n_steps: int, rng: np.random.Generator, dt: float | None = None
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Simulate one or more units: returns ``t (T+1,)``, states ``X (T+1, N, 2)`` and noisy
        measurements ``Y (T, N, 1)`` where ``Y[k]`` measures ``X[k + 1]`` (the particle-filter
        convention: a transition before every measurement)."""
        if n_steps < 1:
            raise ValueError(f"n_steps: expected >= 1, got {n_steps}")
        h = self.dt if dt is None else dt
        x = as_batch(x0, 2, "x0")
        xs = np.empty((n_steps + 1, *x.shape))
        xs[0] = x
        for k in range(n_steps):
            xs[k + 1] = self.step(xs[k], None, k * h, h, rng)
        ys = xs[1:, :, :1] + self.sigma_y * rng.standard_normal((n_steps, x.shape[0], 1))
        return np.arange(n_steps + 1, dtype=np.float64) * h, xs, np.asarray(ys, np.float64)
