"""Condition indicators (CIs) to a health index (HI), seed 004 section 3
(docs/systems/embedded-rul.md section 1).

:class:`HealthIndexModel` maps n CIs to an HI: offset (:func:`empirical_offset`), whitening by
the Cholesky factor of the inverse covariance, the Nakagami critical value for a probability of
false alarm (:func:`nakagami_critical_value`) and the scaling HI = 0.5 ||Y|| / T.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

RAYLEIGH_UNIT_VARIANCE_BETA = 1.0 / math.sqrt(2.0 - math.pi / 2.0)
"""Rayleigh parameter of a unit-variance Rayleigh CI, 1/sqrt(2 - pi/2) = 1.5264 (seed eq 6)."""



# --------------------------------------------------------------------------------------------
# 1. Condition indicators -> health index
# --------------------------------------------------------------------------------------------


def nakagami_critical_value(n: int, pfa: float) -> float:
    """Critical value T of the norm of n IID unit-variance Rayleigh CIs at false-alarm ``pfa``.

    The squared norm of n IID Rayleigh(beta) variables is Gamma(n, 2 beta^2), so the norm is
    Nakagami with shape m = n and spread Omega = 2 n beta^2 = 2n / (2 - pi/2) (seed section 3,
    Bechhoefer & Bernhard 2007). T = Nakagami inverse CDF at 1 - PFA, computed as the inverse
    survival function (accurate for PFA = 1e-6). scipy's ``nakagami(nu, scale)`` has
    E[X^2] = scale^2, so scale = sqrt(Omega).
    """
    from scipy import stats

    if int(n) != n or n < 1:
        raise ValueError(f"n: expected a positive integer number of CIs, got {n!r}")
    if not 0.0 < pfa < 1.0:
        raise ValueError(f"pfa: expected a probability in (0, 1), got {pfa!r}")
    omega = 2.0 * n / (2.0 - math.pi / 2.0)
    return float(stats.nakagami.isf(pfa, n, scale=math.sqrt(omega)))


def empirical_offset(ci: np.ndarray, quantile: float = 0.05) -> FloatArray:
    """Offset per CI: the value at the ``quantile`` point of its empirical CDF (seed section 3.1).

    The seed sorts the N baseline values and takes the one at index round(0.05 N) (with N = 50
    acquisitions x number of aircraft); that value is shifted to 0 ("left shift" that makes
    RMS-biased bearing and gear CIs more Rayleigh-like).
    """
    x = _as_ci_matrix(ci, None, "ci")
    idx = min(round(quantile * x.shape[0]), x.shape[0] - 1)
    return np.sort(x, axis=0)[idx].copy()


def _as_ci_matrix(ci: np.ndarray, n: int | None, name: str) -> FloatArray:
    x = np.asarray(ci, dtype=np.float64)
    if x.ndim == 1 and n is not None:
        x = x[None, :] if x.shape[0] == n else x[:, None]
    if x.ndim != 2 or (n is not None and x.shape[1] != n):
        want = f"(N, {n})" if n is not None else "(N, n)"
        raise ValueError(f"{name}: expected shape {want}, got {np.shape(ci)}")
    if not np.all(np.isfinite(x)):
        row, col = np.argwhere(~np.isfinite(x))[0]
        raise ValueError(f"{name}: non-finite value at row {row}, column {col}")
    return x


@dataclass(frozen=True)
class HealthIndexModel:
    """A priori HI configuration of one component type (seed section 3.1).

    ``HI = || (CI - offset) @ scale ||`` with ``scale = L * 0.5 / T``, where L is the lower
    Cholesky factor of inv(Sigma) (``L L^T = Sigma^-1``). For row vectors x = CI - offset the
    whitened vector is ``Y = L^T x`` (``Y_rows = X @ L``), whose covariance is
    ``L^T Sigma L = I``; then HI = 0.5 ||Y|| / T, so HI = 0.5 exactly at the false-alarm
    critical value T, 0.75 is the warning and 1.0 the alarm level (docs/systems/embedded-rul.md §1).

    The seed stores ``S = L (0.5/T)^2``; squaring 0.5/T only makes sense for the squared norm,
    so we store ``S = L 0.5/T`` and take the plain norm (same HI).

    Why the norm is exactly Nakagami after whitening: if the healthy CIs are
    ``CI = offset + M R`` with R IID unit-variance Rayleigh and ``M M^T = Sigma``, then
    ``Q = L^T M`` satisfies ``Q Q^T = L^T Sigma L = I`` (orthogonal), and ``||Q R|| = ||R||``.
    """

    names: tuple[str, ...]
    offset: FloatArray
    mean: FloatArray
    cov: FloatArray
    whitening: FloatArray
    critical_value: float
    pfa: float
    whitened: bool = True

    @property
    def n(self) -> int:
        """Number of CIs."""
        return len(self.names)

    @property
    def scale(self) -> FloatArray:
        """Upper-level scale matrix S (n, n): HI = ||(CI - offset) @ S||."""
        return self.whitening * (0.5 / self.critical_value)

    @classmethod
    def fit(
        cls,
        baseline: np.ndarray,
        *,
        pfa: float = 1e-6,
        offset: Literal["cdf05", "none"] | np.ndarray = "cdf05",
        names: tuple[str, ...] | list[str] | None = None,
        whiten: bool = True,
    ) -> HealthIndexModel:
        """Fit from healthy baseline CIs ``baseline (N, n)``.

        ``offset``: ``"cdf05"`` (bearings and gears: the 5 % point of each CI's empirical CDF is
        shifted to 0, :func:`empirical_offset`), ``"none"`` (shafts: offset 0) or an explicit
        ``(n,)`` array. ``whiten=False`` replaces the Cholesky whitening by a per-CI division by
        the standard deviation (the correlation is ignored): only for demonstrating the
        inflated false-alarm rate of correlated CIs (seed section 3, docs/systems/embedded-rul.md
        §1). The design PFA is exact when ``CI - offset`` follows the healthy Rayleigh model; the
        cdf05 offset of a Rayleigh CI removes its own 5 % point too and so lowers the actual
        false-alarm rate below the design (conservative).
        """
        x = _as_ci_matrix(baseline, None, "baseline")
        n_obs, n = x.shape
        if n_obs < n + 1:
            raise ValueError(
                f"baseline: need more than {n} rows to estimate a covariance, got {n_obs}"
            )
        names_t = tuple(names) if names is not None else tuple(f"ci{i + 1}" for i in range(n))
        if len(names_t) != n:
            raise ValueError(f"names: expected {n} CI names, got {len(names_t)}")
        if isinstance(offset, str):
            if offset == "cdf05":
                off = empirical_offset(x, 0.05)
            elif offset == "none":
                off = np.zeros(n)
            else:
                raise ValueError(f"offset: expected 'cdf05', 'none' or an array, got {offset!r}")
        else:
            off = np.asarray(offset, dtype=np.float64).reshape(-1)
            if off.shape != (n,) or not np.all(np.isfinite(off)):
                raise ValueError(f"offset: expected {n} finite values, got {offset!r}")
        mean = x.mean(axis=0)
        cov = np.atleast_2d(np.cov(x, rowvar=False))
        if whiten:
            try:
                w = np.linalg.cholesky(np.linalg.inv(cov))
            except np.linalg.LinAlgError as err:
                raise ValueError(
                    "baseline: the CI covariance is singular or not positive definite; "
                    "drop linearly dependent CIs"
                ) from err
        else:
            sd = np.sqrt(np.diag(cov))
            if np.any(sd <= 0):
                raise ValueError(f"baseline: CI {names_t[int(np.argmin(sd))]!r} is constant")
            w = np.diag(1.0 / sd)
        return cls(
            names=names_t,
            offset=off,
            mean=mean,
            cov=cov,
            whitening=w,
            critical_value=nakagami_critical_value(n, pfa),
            pfa=float(pfa),
            whitened=bool(whiten),
        )

    def whiten(self, ci: np.ndarray) -> FloatArray:
        """Whitened CIs ``Y (N, n)`` (identity covariance on the baseline)."""
        x = _as_ci_matrix(ci, self.n, "ci")
        return (x - self.offset) @ self.whitening

    def health_index(self, ci: np.ndarray) -> FloatArray:
        """HI (N,) of CIs (N, n) (or one acquisition (n,)): ``0.5 ||Y|| / T``."""
        x = _as_ci_matrix(ci, self.n, "ci")
        y = (x - self.offset) @ self.scale
        return np.sqrt(np.einsum("ij,ij->i", y, y))

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict (arrays as lists)."""
        return {
            "names": list(self.names),
            "offset": self.offset.tolist(),
            "mean": self.mean.tolist(),
            "cov": self.cov.tolist(),
            "whitening": self.whitening.tolist(),
            "critical_value": self.critical_value,
            "pfa": self.pfa,
            "whitened": self.whitened,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> HealthIndexModel:
        """Inverse of :meth:`to_dict`."""
        return cls(
            names=tuple(d["names"]),
            offset=np.asarray(d["offset"], dtype=np.float64),
            mean=np.asarray(d["mean"], dtype=np.float64),
            cov=np.atleast_2d(np.asarray(d["cov"], dtype=np.float64)),
            whitening=np.atleast_2d(np.asarray(d["whitening"], dtype=np.float64)),
            critical_value=float(d["critical_value"]),
            pfa=float(d["pfa"]),
            whitened=bool(d.get("whitened", True)),
        )


__all__ = [
    "RAYLEIGH_UNIT_VARIANCE_BETA",
    "HealthIndexModel",
    "empirical_offset",
    "nakagami_critical_value",
]
