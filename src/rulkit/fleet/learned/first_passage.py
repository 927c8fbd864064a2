"""The first measured crossing of the threshold over a unit's acquisition cadence.

docs/fleet-models.md section 2, eq. (5)-(6). A run-to-failure history ends at the first
acquisition whose *measured* HI reaches 1; the alarm keys on the same readings. Given the
latent path, readings are independent: reading j, at horizon j d after the last acquisition
(d the cadence), is >= 1 when z_j + e_j >= g(1), e_j ~ N(0, s^2), s^2 the measurement variance
at the threshold. Write y_J = (z_J - g(1)) / s for the level at the J-th future reading and
c = b d / s for the rise between readings in units of s (b the rate). With a straight path the
reading J - k sits k c below y_J, so no reading of the J is >= 1 exactly when

    y_J < Y*_J = min_{k = 0 .. J-1} (c k + eps_k),   eps_k ~ N(0, 1) i.i.d.,      (5a)

and the survival of the first passage is S(J) = P(y_J < Y*_J). y_J is eq. (5)'s Gaussian level
at the horizon (the posterior of level and rate, plus the random walk's variance); Y*_J depends
only on c and the span u = c (J - 1) of the readings. Y*_J is replaced by the Gaussian of its
mean mu*(c, u) and sd sigma*(c, u) (tabulated once by quadrature, :func:`ystar_table`), with c
taken at the rate the unit has if its level is at the threshold at that horizon,
b* = E[b | z_J = g(1)]. Then

    S(w) = Phi(-(m_z + m_b w - g(1) - s mu*) / sqrt(V(w) + s^2 sigma*^2)),               (5b)

V(w) eq. (5)'s variance: eq. (5) with the threshold lowered by s mu* (<= 0, the earlier of
several noisy readings) and the variance raised by s^2 sigma*^2. With s = 0 it is eq. (5) of
the latent level (a monotone path's first crossing is its marginal one); with readings far
apart (c large) it is eq. (5) of one measurement (mu* = 0, sigma* = 1). A quantile solves
N(w) - k D(w) = 0 (N, D (5b)'s numerator and sd, k = -Phi^-1(S)): Newton's steps per unit in
one compiled pass from eq. (6)'s closed-form root, the table's slope from its bilinear cells
(:func:`~rulkit.fleet.learned.filter_kernels.first_passage_quantiles`). The approximations (a
straight path between readings; the walk's variance at the horizon only; Y* Gaussian; c at b*;
the cadence d regular) are measured against a brute-force Monte Carlo of the event in
tests/fleet/learned/test_first_passage.py.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

C_MIN, C_MAX = 1e-3, 20.0
"""The rise between readings, in noise sds, that the table spans: above C_MAX one reading decides
(mu* = 0, sigma* = 1 to 1e-9); below C_MIN the readings are taken as C_MIN apart."""
U_MAX = 10.0
"""Readings more than U_MAX noise sds below the latest cannot be the first >= 1 (Phi(-10))."""
J_MAX = U_MAX / C_MIN + 1.0
"""Readings the table counts at most (more add nothing, by :data:`U_MAX`)."""
_LOG_C = np.linspace(math.log(C_MIN), math.log(C_MAX), 48)
_LOG_J = np.linspace(0.0, math.log(J_MAX), 60)
_Y = np.linspace(-12.0, 7.0, 381)
_EXACT = 64
"""Readings summed term by term in (5a); the rest (only where c < U_MAX / _EXACT) as the sum's
integral (midpoint rule: the terms vary on the scale of 1 / c readings)."""


def _moments(log_g: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Mean and sd of Y* from log P(Y* > y) on :data:`_Y` (last axis): the mass between
    neighbouring grid values at their midpoint (G = 1 below the grid, 0 above it)."""
    g = np.exp(log_g)
    mass = -np.diff(g, axis=-1, prepend=1.0, append=0.0)
    y = np.concatenate([[_Y[0] - 0.5 * (_Y[1] - _Y[0])], 0.5 * (_Y[1:] + _Y[:-1]),
                        [_Y[-1] + 0.5 * (_Y[1] - _Y[0])]])
    mean = mass @ y
    var = mass @ (y * y) - mean * mean - (_Y[1] - _Y[0]) ** 2 / 12.0  # Sheppard's correction
    return mean, np.sqrt(np.maximum(var, 1e-12))


def _log_survival(c: float, j: FloatArray, cont: FloatArray, fine: FloatArray
                  ) -> FloatArray:
    """log P(Y*_J > y) on :data:`_Y` for readings ``j`` (real, >= 1; rows) at rise ``c``:
    terms 0 .. _EXACT - 1 exactly (a real J interpolated between its integer neighbours),
    beyond by the integral ``cont`` (cumulative, on the grid ``fine`` of c k)."""
    from scipy.special import log_ndtr

    n = min(_EXACT, math.ceil(j.max()))
    terms = np.cumsum(log_ndtr(c * np.arange(n)[:, None] - _Y[None, :]), axis=0)
    lo = np.clip(np.floor(j).astype(np.int64), 1, n)
    hi = np.clip(lo + 1, 1, n)
    frac = np.clip(j - lo, 0.0, 1.0)[:, None]
    out = (1.0 - frac) * terms[lo - 1] + frac * terms[hi - 1]
    far = j > _EXACT
    if far.any():
        def at(v: FloatArray) -> FloatArray:
            k = np.clip(np.searchsorted(fine, v) - 1, 0, fine.size - 2)
            a = ((v - fine[k]) / (fine[k + 1] - fine[k]))[:, None]
            return (1.0 - a) * cont[:, k].T + a * cont[:, k + 1].T

        v_hi = c * (j[far] - 0.5)
        v_lo = np.full(v_hi.shape, c * (_EXACT - 0.5))
        out[far] = terms[_EXACT - 1] + (at(v_hi) - at(v_lo)) / c
    return out


@functools.cache
def ystar_table() -> tuple[FloatArray, FloatArray]:
    """mu*(c, J) and sigma*(c, J) of (5a) on the grid log c (:data:`_LOG_C`) x log J
    (:data:`_LOG_J`), ``(len(_LOG_C), len(_LOG_J))`` each (about 0.1 s, once per process)."""
    from scipy.special import log_ndtr

    fine = np.linspace(0.0, U_MAX + 1.0, 1101)
    lf = log_ndtr(fine[None, :] - _Y[:, None])
    cont = np.concatenate([np.zeros((_Y.size, 1)),
                           np.cumsum(0.5 * (lf[:, 1:] + lf[:, :-1]) * np.diff(fine), 1)], 1)
    mu = np.empty((_LOG_C.size, _LOG_J.size))
    sd = np.empty_like(mu)
    for i, c in enumerate(np.exp(_LOG_C)):
        j = np.minimum(np.exp(_LOG_J), U_MAX / c + 1.0)
        mu[i], sd[i] = _moments(_log_survival(float(c), j, cont, fine))
    mu[:, 0], sd[:, 0] = 0.0, 1.0  # one reading: N(0, 1) exactly
    return mu, sd


def ystar_moments(c: FloatArray, j: FloatArray) -> tuple[FloatArray, FloatArray]:
    """mu*, sigma* of (5a) at rises ``c`` over ``j`` readings (bilinear in log c and log J;
    c above :data:`C_MAX`, or not finite, gives (0, 1): one reading decides)."""
    mu_t, sd_t = ystar_table()
    lc = np.log(np.clip(np.nan_to_num(c, nan=C_MAX, posinf=C_MAX, neginf=C_MIN), C_MIN,
                        C_MAX))
    fi = (lc - _LOG_C[0]) / (_LOG_C[1] - _LOG_C[0])
    lj = np.log(np.clip(np.nan_to_num(j, nan=1.0), 1.0, J_MAX))
    fj = lj / (_LOG_J[1] - _LOG_J[0])
    i0 = np.minimum(fi.astype(np.int64), _LOG_C.size - 2)
    j0 = np.minimum(fj.astype(np.int64), _LOG_J.size - 2)
    a, b = fi - i0, fj - j0

    def bilinear(t: FloatArray) -> FloatArray:
        return ((1 - a) * ((1 - b) * t[i0, j0] + b * t[i0, j0 + 1])
                + a * ((1 - b) * t[i0 + 1, j0] + b * t[i0 + 1, j0 + 1]))

    return bilinear(mu_t), bilinear(sd_t)


def kernel_table() -> tuple[FloatArray, FloatArray, float, float, float]:
    """The table as the compiled kernels read it: (mu*, sigma*, log c of the first row, the
    step of log c, the step of log J)."""
    mu, sd = ystar_table()
    return (mu, sd, float(_LOG_C[0]), float(_LOG_C[1] - _LOG_C[0]),
            float(_LOG_J[1] - _LOG_J[0]))


def rise(rate: FloatArray, delta: FloatArray, s: float) -> FloatArray:
    """c = b d / s, the rise between readings in noise sds (+inf where the cadence is: one
    reading; a rate <= 0 rises by :data:`C_MIN`)."""
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        c = np.maximum(rate, 0.0) * delta / s
    return np.where(np.isinf(delta), np.inf, c)


def level_terms(m: FloatArray, p: FloatArray, q: float, zs: float, s: float,
                delta: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(5b)'s numerator and sd at scaled horizons ``w (B,)``: S(w) = Phi(-num / sd).

    ``m (B, 2)``, ``p (B, 3)`` the posterior of (level, rate), ``q`` the walk's variance,
    ``zs`` g(1), ``s`` the measurement sd at the threshold (0: the latent level's eq. (5)),
    ``delta (B,)`` the cadence in scaled time (inf: one reading, eq. (5) of one measurement).
    """
    a = m[:, 0] - zs + m[:, 1] * w
    v = p[:, 0] + 2.0 * w * p[:, 1] + w * w * p[:, 2] + q * w
    if s == 0.0:
        return a, np.sqrt(np.maximum(v, 1e-300))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        rate = m[:, 1] - (p[:, 1] + w * p[:, 2]) * a / np.maximum(v, 1e-300)
        mu, sig = ystar_moments(rise(rate, delta, s), np.maximum(w / delta, 1.0))
    return a - s * mu, np.sqrt(np.maximum(v + s * s * sig * sig, 1e-300))


__all__ = ["C_MAX", "C_MIN", "J_MAX", "U_MAX", "kernel_table", "level_terms", "rise",
           "ystar_moments", "ystar_table"]
