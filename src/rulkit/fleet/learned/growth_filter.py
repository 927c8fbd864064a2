"""The filter of growth laws measured with additive noise, multiplicative noise, or both.

docs/fleet-models.md section 6. The unit's hidden state is the Gaussian (level z, rate b) of
eq. (1) on the Box-Cox growth scale z = g(hi) = (hi^lam - 1) / lam (lam = 1 - m/2, g = ln hi at
m = 2, so g(1) = 0 is the failure level), but the measurement is the HI itself (eq. (7)):

    hi_k = g^-1(z(x_k)) exp(e1) + e2,   e1 ~ N(0, r_log), e2 ~ N(0, r_hi),

``r_log`` the multiplicative noise (on the log scale, whatever the shape), ``r_hi`` the
additive HI noise; either may be zero. One acquisition is one iterated extended Kalman update
(eq. (8)): Gauss-Newton steps on z to the posterior mode, then the Kalman update linearised
there, with H = dhi/dz = hi^(1 - lam) and the measurement variance R = r_hi + hi^2 r_log (the
multiplicative noise to first order). Its prediction errors give the marginal
likelihood of the HI (no Jacobian needed: the density is of hi itself, so it compares with the
transformed models' likelihoods of eq. (4)); tested against a brute-force quadrature of the
exact likelihood.

An onset (eq. (9)) replaces the age x by max(x - s, 0): the HI is flat at the unit's level until
s, then grows. s takes values on a fixed grid with fleet probabilities pi_k (a normal density
on the grid, mean and sd learned); a unit's likelihood is the mixture over the grid of the
filters run with each s_k, and its posterior is the mixture of those filters' Gaussians with
weights pi_k L_k (normalised).

The compiled kernels (:mod:`rulkit.fleet.learned.filter_kernels`) are the single
implementation of the step: replay, online update and likelihood all call its ``assimilate``.
Parameters travel as one vector (:data:`THETA`); a variance parameter at -inf is a fixed zero
(an additive-only or walk-free model). This module holds what needs no compiler.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

THETA = ("m_a", "m_b", "log_l11", "l21", "log_l22", "log_r_log", "log_r_hi", "log_q", "mu_s",
         "log_sd_s")
"""Parameter vector: prior mean (level at age 0, rate), log-Cholesky of the prior covariance,
log variances of the multiplicative (log-scale) noise, the additive HI noise and the random walk
(per unit of scaled age), the onset prior's mean and log sd (scaled age; unused without
onset)."""
HI_LO, HI_HI = 1e-6, 1e3
"""The HI range the inverse transform is evaluated in (z is clipped to g of this range)."""
IEKF_ITERATIONS = 8
IEKF_TOL = 1e-9
"""The iterations of eq. (8) stop after IEKF_ITERATIONS steps, or when a step moves z by at most
IEKF_TOL (1 + |z|)."""


def boxcox(hi: FloatArray, lam: float) -> FloatArray:
    """g(hi) (eq. (7)) on ``[HI_LO, HI_HI]`` (clipped)."""
    h = np.clip(np.asarray(hi, dtype=np.float64), HI_LO, HI_HI)
    if abs(lam) < 1e-12:
        return np.log(h)
    return (h**lam - 1.0) / lam


@dataclass(frozen=True)
class GrowthParams:
    """Unpacked parameters of eq. (7)-(9) in scaled age (see :data:`THETA`)."""

    mean: tuple[float, float]
    cov: tuple[float, float, float]
    r_log: float
    r_hi: float
    q: float
    onset_mean: float
    onset_sd: float

    @classmethod
    def from_theta(cls, th: FloatArray) -> GrowthParams:
        """From the parameter vector (:data:`THETA`)."""
        l11, l21, l22 = math.exp(th[2]), float(th[3]), math.exp(th[4])
        return cls(mean=(float(th[0]), float(th[1])),
                   cov=(l11 * l11, l11 * l21, l21 * l21 + l22 * l22),
                   r_log=math.exp(th[5]), r_hi=math.exp(th[6]), q=math.exp(th[7]),
                   onset_mean=float(th[8]), onset_sd=math.exp(th[9]))

    def theta(self) -> FloatArray:
        """The parameter vector (:data:`THETA`); zero variances as -inf."""
        saa, sab, sbb = self.cov
        l11 = math.sqrt(saa)
        l21 = sab / l11
        l22 = math.sqrt(max(sbb - l21 * l21, 1e-300))
        lg = lambda v: math.log(v) if v > 0 else -math.inf  # noqa: E731
        return np.array([self.mean[0], self.mean[1], math.log(l11), l21, math.log(l22),
                         lg(self.r_log), lg(self.r_hi), lg(self.q), self.onset_mean,
                         lg(self.onset_sd) if self.onset_sd > 0 else 0.0])


def boxcox_inverse(z: FloatArray, lam: float) -> FloatArray:
    """hi = g^-1(z), z clipped to g([HI_LO, HI_HI])."""
    zc = np.clip(np.asarray(z, dtype=np.float64), boxcox(np.array(HI_LO), lam),
                 boxcox(np.array(HI_HI), lam))
    if abs(lam) < 1e-12:
        return np.exp(zc)
    return np.asarray((1.0 + lam * zc) ** (1.0 / lam))


def growth_hi_quantiles(m: FloatArray, p: FloatArray, walk_sd: float, time_scale: float,
                        lam: float, horizons: FloatArray, levels: tuple[float, ...]
                        ) -> tuple[FloatArray, ...]:
    """Quantiles of the (latent) HI ``horizons (B, K)`` after the last acquisition of B units
    with Gaussian (level, rate) posteriors ``m (B, 2)``, ``p (B, 3)``: the growth-scale level
    is Gaussian with mean m_z + m_b w and variance P_zz + 2 w P_zb + w^2 P_bb + sigma_w^2 w,
    w = r / tau (eq. (5)), mapped back through g^-1 (monotone, so quantiles map)."""
    from scipy.special import ndtri

    w = np.asarray(horizons, dtype=np.float64) / time_scale
    mean = m[:, :1] + m[:, 1:] * w
    var = p[:, :1] + 2.0 * w * p[:, 1:2] + w * w * p[:, 2:] + walk_sd**2 * w
    sd = np.sqrt(np.maximum(var, 0.0))
    return tuple(boxcox_inverse(mean + float(ndtri(q)) * sd, lam) for q in levels)


def onset_prior(grid: FloatArray, mean: float, sd: float) -> FloatArray:
    """log pi_k of the onset grid (eq. (9)): a normal density on the grid, normalised."""
    if grid.size == 1:
        return np.zeros(1)
    lp = -0.5 * ((grid - mean) / sd) ** 2
    return lp - (lp.max() + math.log(np.exp(lp - lp.max()).sum()))


__all__ = ["HI_HI", "HI_LO", "IEKF_ITERATIONS", "IEKF_TOL", "THETA", "GrowthParams", "boxcox",
           "boxcox_inverse", "growth_hi_quantiles", "onset_prior"]
