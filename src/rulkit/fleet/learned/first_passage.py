"""The first measured crossing of the threshold over a unit's acquisition cadence.

docs/fleet-models.md section 2, eq. (5)-(6). A run-to-failure history ends at the first
acquisition whose *measured* HI reaches 1, and its failure time (``rulkit evaluate``'s truth)
is that reading's crossing interpolated from the reading before; the alarm keys on the same
readings. Given the latent path, readings are independent: reading j, at j d after the last
acquisition (d the cadence), is z_j + e_j, e_j ~ N(0, s^2), s^2 the measurement variance at the
threshold. Write x(r) = (z(r) - g(1)) / s for the level at horizon r in units of s and
c = b d / s for the rise between readings (b the rate). Let r lie between readings n and n + 1,
theta = r / d - n in [0, 1). The interpolated crossing comes after r exactly when readings
1 .. n are < 1 and the interpolated value at r is < 1; on a straight path the interpolated
level is x(r) and reading n - k sits c (theta + k) below it, so the crossing comes after r
exactly when

    x(r) < Y* = min((1 - theta) eps_0 + theta eps', min_{k = 0 .. n-1} c (theta + k) + eps_k)
                                                                                     (5a)

with eps_k, eps' i.i.d. N(0, 1) (eps_0 the noise of reading n, in both terms). With n = 0
(before the first reading) only the interpolation between the last reading h_0 (known) and
the next is left, on the HI scale as the truth's: S(r) = P((1 - theta) h_0 + theta h_1 < 1),
the next reading below H = 1 + (1 - theta) (1 - h_0) / theta, one Gaussian on the growth
scale. For
n >= 1, x(r) is eq. (5)'s Gaussian level at the horizon (the posterior of level and rate, plus
the random walk's variance) and Y* depends only on (c, n, theta). Y* is replaced by the
Gaussian of its mean mu*(c, n, theta) and sd sigma*(c, n, theta) (tabulated once by quadrature,
:func:`ystar_table`: the horizon's pair term is a bivariate normal orthant, the readings'
terms a product), with c taken at the rate the unit has if its level is at the threshold at
that horizon, b* = E[b | z(r) = g(1)]. Then

    S(w) = Phi(-(m_z + m_b w - g(1) - s mu*) / sqrt(V(w) + s^2 sigma*^2)),               (5b)

V(w) eq. (5)'s variance. With s = 0 it is eq. (5) of the latent level (a monotone path's first
crossing is its marginal one); at theta = 0 it is the event of a reading at the horizon and n - 1
before it; with readings far apart (c large) one interpolated value, mu* = 0 and
sigma* = ((1 - theta)^2 + theta^2)^(1/2). A quantile solves N(w) - k D(w) = 0 (N, D (5b)'s
numerator and sd, k = -Phi^-1(S)): Newton's steps per unit in one compiled pass from eq. (6)'s
closed-form root, the table's slope from its trilinear cells
(:func:`~rulkit.fleet.learned.filter_kernels.first_passage_quantiles`). The approximations (a
straight path between readings; the walk's variance at the horizon only; Y* Gaussian; c at b*;
the cadence d regular; for n >= 1 the interpolation on the model's growth scale) are measured
against a brute-force Monte Carlo of the event in tests/fleet/learned/test_first_passage.py.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

C_MIN, C_MAX = 1e-3, 20.0
"""The rise between readings, in noise sds, that the table spans: above C_MAX it is read at
C_MAX (the readings before the pair at the horizon matter only where c theta is below a few
sds, where the table's theta steps are coarse; the level's own spread dominates there); below
C_MIN the readings are taken as C_MIN apart."""
U_MAX = 10.0
"""Readings more than U_MAX noise sds below the horizon cannot be the first >= 1 (Phi(-10))."""
J_MAX = U_MAX / C_MIN + 1.0
"""Readings the table counts at most (more add nothing, by :data:`U_MAX`)."""
_LOG_C = np.linspace(math.log(C_MIN), math.log(C_MAX), 48)
_LOG_J = np.linspace(0.0, math.log(J_MAX), 60)
_THETA = np.linspace(0.0, 1.0, 9)
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


def _pair_log_survival(c: float, theta: float) -> FloatArray:
    """log P((1 - theta) eps_0 + theta eps' > y, c theta + eps_0 > y) on :data:`_Y`: the
    horizon's interpolated value and reading n, a bivariate normal orthant (Owen's T)."""
    from scipy.special import log_ndtr, ndtr, owens_t

    if theta <= 0.0:
        return np.asarray(log_ndtr(-_Y))
    if theta >= 1.0:
        return np.asarray(log_ndtr(-_Y) + log_ndtr(c - _Y))
    sa = math.hypot(1.0 - theta, theta)
    rho = (1.0 - theta) / sa
    r = math.sqrt(1.0 - rho * rho)
    h, k = -_Y / sa, c * theta - _Y
    h = np.where(np.abs(h) < 1e-10, 1e-10, h)
    k = np.where(np.abs(k) < 1e-10, 1e-10, k)
    p = (0.5 * ndtr(h) + 0.5 * ndtr(k) - owens_t(h, (k - rho * h) / (h * r))
         - owens_t(k, (h - rho * k) / (k * r)) - np.where(h * k < 0.0, 0.5, 0.0))
    return np.log(np.clip(p, 1e-300, 1.0))


def _readings_log_survival(c: float, theta: float, j: FloatArray, cont: FloatArray,
                           fine: FloatArray) -> FloatArray:
    """log prod_{k=1}^{J-1} P(c (theta + k) + eps_k > y) on :data:`_Y` for readings ``j``
    (real, >= 1; rows): terms 1 .. _EXACT - 1 exactly (a real J interpolated between its
    integer neighbours), beyond by the integral ``cont`` (cumulative, on the grid ``fine`` of
    c k, its rows the values of y: shifted by c theta by linear interpolation)."""
    from scipy.special import log_ndtr

    n = min(_EXACT, math.ceil(j.max()))
    k = np.arange(n)
    terms = np.where(k[:, None] > 0, log_ndtr(c * (k[:, None] + theta) - _Y[None, :]), 0.0)
    terms = np.cumsum(terms, axis=0)
    lo = np.clip(np.floor(j).astype(np.int64), 1, n)
    hi = np.clip(lo + 1, 1, n)
    frac = np.clip(j - lo, 0.0, 1.0)[:, None]
    out = (1.0 - frac) * terms[lo - 1] + frac * terms[hi - 1]
    far = j > _EXACT
    if far.any():
        step = _Y[1] - _Y[0]
        shift = c * theta / step  # cont at y - c theta: rows interpolated
        i = math.floor(shift)
        f = shift - i
        rows = np.arange(_Y.size)
        r0 = np.clip(rows - i, 0, _Y.size - 1)
        r1 = np.clip(rows - i - 1, 0, _Y.size - 1)

        def col(m: NDArray[np.int64]) -> FloatArray:
            return ((1.0 - f) * cont[r0[:, None], m[None, :]]
                    + f * cont[r1[:, None], m[None, :]])

        def at(v: FloatArray) -> FloatArray:
            m = np.clip(np.searchsorted(fine, v) - 1, 0, fine.size - 2)
            a = ((v - fine[m]) / (fine[m + 1] - fine[m]))[:, None]
            return (1.0 - a) * col(m).T + a * col(m + 1).T

        v_hi = c * (j[far] - 0.5)
        v_lo = np.full(v_hi.shape, c * (_EXACT - 0.5))
        out[far] = terms[_EXACT - 1] + (at(v_hi) - at(v_lo)) / c
    return out


def _log_survival_table() -> FloatArray:
    """log P(Y* > y) of (5a), ``(len(_LOG_C), len(_LOG_J), len(_THETA), len(_Y))``."""
    from scipy.special import log_ndtr

    fine = np.linspace(0.0, U_MAX + 1.0, 1101)
    lf = log_ndtr(fine[None, :] - _Y[:, None])
    cont = np.concatenate([np.zeros((_Y.size, 1)),
                           np.cumsum(0.5 * (lf[:, 1:] + lf[:, :-1]) * np.diff(fine), 1)], 1)
    out = np.empty((_LOG_C.size, _LOG_J.size, _THETA.size, _Y.size))
    for i, c in enumerate(np.exp(_LOG_C)):
        j = np.minimum(np.exp(_LOG_J), U_MAX / c + 1.0)
        for t, theta in enumerate(_THETA):
            out[i, :, t] = (_pair_log_survival(float(c), float(theta))[None, :]
                            + _readings_log_survival(float(c), float(theta), j, cont, fine))
    return out


@functools.cache
def ystar_table(phase: str = "known") -> tuple[FloatArray, FloatArray]:
    """mu*(c, n, theta) and sigma*(c, n, theta) of (5a) on the grid log c (:data:`_LOG_C`) x
    log n (:data:`_LOG_J`) x theta (:data:`_THETA`), ``(48, 60, 9)`` each (once per process).

    ``phase="averaged"``: Y* of a horizon whose phase between readings is unknown (theta
    uniform on [0, 1): the mixture of the theta slices' laws), the same in every theta slice.
    """
    if phase not in ("known", "averaged"):
        raise ValueError(f"phase: expected 'known' or 'averaged', got {phase!r}")
    log_g = _log_survival_table()
    if phase == "averaged":
        wt = np.full(_THETA.size, 1.0 / (_THETA.size - 1))
        wt[[0, -1]] *= 0.5  # trapezoid over theta in [0, 1]
        g = np.tensordot(np.exp(log_g), wt, axes=([2], [0]))
        log_g = np.broadcast_to(np.log(np.maximum(g, 1e-300))[:, :, None, :], log_g.shape)
    mu, sd = _moments(log_g)
    if phase == "known":
        mu[:, 0, 0], sd[:, 0, 0] = 0.0, 1.0  # one reading at the horizon: N(0, 1) exactly
    return np.ascontiguousarray(mu), np.ascontiguousarray(sd)


def ystar_moments(c: FloatArray, j: FloatArray, theta: FloatArray
                  ) -> tuple[FloatArray, FloatArray]:
    """mu*, sigma* of (5a) at rises ``c`` with ``j`` readings up to the horizon (n >= 1) and
    the horizon at ``theta`` between reading n and the next (trilinear in log c, log n and
    theta; c above :data:`C_MAX`, or not finite, is read at C_MAX)."""
    mu_t, sd_t = ystar_table()
    lc = np.log(np.clip(np.nan_to_num(c, nan=C_MAX, posinf=C_MAX, neginf=C_MIN), C_MIN,
                        C_MAX))
    fi = (lc - _LOG_C[0]) / (_LOG_C[1] - _LOG_C[0])
    lj = np.log(np.clip(np.nan_to_num(j, nan=1.0), 1.0, J_MAX))
    fj = lj / (_LOG_J[1] - _LOG_J[0])
    ft = np.clip(np.nan_to_num(theta), 0.0, 1.0) / (_THETA[1] - _THETA[0])
    i0 = np.minimum(fi.astype(np.int64), _LOG_C.size - 2)
    j0 = np.minimum(fj.astype(np.int64), _LOG_J.size - 2)
    t0 = np.minimum(ft.astype(np.int64), _THETA.size - 2)
    a, b, e = fi - i0, fj - j0, ft - t0

    def trilinear(t: FloatArray) -> FloatArray:
        out = np.zeros(np.shape(a))
        for di, wi in ((0, 1 - a), (1, a)):
            for dj, wj in ((0, 1 - b), (1, b)):
                for dt, wt in ((0, 1 - e), (1, e)):
                    out = out + wi * wj * wt * t[i0 + di, j0 + dj, t0 + dt]
        return out

    return trilinear(mu_t), trilinear(sd_t)


def kernel_table(phase: str = "known"
                 ) -> tuple[FloatArray, FloatArray, float, float, float, float]:
    """The table as the compiled kernels read it: (mu*, sigma*, log c of the first row, the
    step of log c, the step of log n, the step of theta)."""
    mu, sd = ystar_table(phase)
    return (mu, sd, float(_LOG_C[0]), float(_LOG_C[1] - _LOG_C[0]),
            float(_LOG_J[1] - _LOG_J[0]), float(_THETA[1] - _THETA[0]))


def rise(rate: FloatArray, delta: FloatArray, s: float) -> FloatArray:
    """c = b d / s, the rise between readings in noise sds (+inf where the cadence is: one
    reading; a rate <= 0 rises by :data:`C_MIN`)."""
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        c = np.maximum(rate, 0.0) * delta / s
    return np.where(np.isinf(delta), np.inf, c)


def _level(m: FloatArray, p: FloatArray, q: float, zs: float, w: FloatArray
           ) -> tuple[FloatArray, FloatArray]:
    """Eq. (5)'s mean above g(1) and variance of the level at scaled horizons ``w``."""
    a = m[:, 0] - zs + m[:, 1] * w
    v = p[:, 0] + 2.0 * w * p[:, 1] + w * w * p[:, 2] + q * w
    return a, v


def level_terms(m: FloatArray, p: FloatArray, q: float, zs: float, s: float,
                delta: FloatArray, w: FloatArray, h0: FloatArray | None = None,
                g: Callable[[FloatArray], FloatArray] | None = None
                ) -> tuple[FloatArray, FloatArray]:
    """(5b)'s numerator and sd at scaled horizons ``w (B,)``: S(w) = Phi(-num / sd).

    ``m (B, 2)``, ``p (B, 3)`` the posterior of (level, rate), ``q`` the walk's variance,
    ``zs`` g(1), ``s`` the measurement sd at the threshold (0: the latent level's eq. (5)),
    ``delta (B,)`` the cadence in scaled time (inf: one reading at the horizon, eq. (5) of one
    measurement), ``h0 (B,)`` the last reading and ``g`` the growth scale (needed where
    ``delta`` is finite: before the next reading the crossing is interpolated between the
    last reading and the next on the HI scale, (1 - theta) h_0 + theta h_1 < 1, so the next
    reading is below H = 1 + (1 - theta) (1 - h_0) / theta, one Gaussian on the growth scale).
    """
    a, v = _level(m, p, q, zs, w)
    if s == 0.0:
        return a, np.sqrt(np.maximum(v, 1e-300))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        x = w / delta
        n = np.floor(x)
        rate = m[:, 1] - (p[:, 1] + w * p[:, 2]) * a / np.maximum(v, 1e-300)
        mu, sig = ystar_moments(rise(rate, delta, s), np.maximum(n, 1.0), x - n)
        one = ~np.isfinite(delta)
        mu, sig = np.where(one, 0.0, mu), np.where(one, 1.0, sig)
        num, sd = a - s * mu, np.sqrt(np.maximum(v + s * s * sig * sig, 1e-300))
        first = np.isfinite(delta) & (n < 1.0)
        if first.any():
            if h0 is None or g is None:
                raise ValueError("level_terms: h0 and g are needed with a finite cadence")
            a1, v1 = _level(m, p, q, zs, np.where(first, delta, 0.0))
            big = np.where(x > 0.0, 1.0 + (1.0 - x) * (1.0 - h0) / x, np.inf)
            num = np.where(first, np.where(x > 0.0, a1 + zs - g(big), -1e300), num)
            sd = np.where(first, np.sqrt(np.maximum(v1, 0.0) + s * s), sd)
    return num, sd


__all__ = ["C_MAX", "C_MIN", "J_MAX", "U_MAX", "kernel_table", "level_terms", "rise",
           "ystar_moments", "ystar_table"]
