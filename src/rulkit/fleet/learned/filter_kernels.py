"""Compiled kernels of the learned fleet models (numba, cached on disk).

docs/fleet-models.md eq. (2)-(3) and (7)-(9). Module-level functions so that numba's cache finds
them again in the next process (functions built inside a function and calling each other are
recompiled every time). Imported lazily by :mod:`rulkit.fleet.learned.degradation` and
:mod:`rulkit.fleet.learned.growth_filter`, so that importing those does not load numba.

* ``kf_*``: the exact Kalman filter of eq. (2) on the transformed HI z = g(hi) with Gaussian
  noise on that scale; its prediction-error likelihood (eq. (3)) and, for the optimiser, the
  likelihood with its central-difference gradient over the 7 parameters in one call;
* ``growth_*``: the iterated extended Kalman filter of eq. (8) measuring the HI itself
  (additive noise, multiplicative noise on the log scale, or both, eq. (7)), over an onset grid
  (eq. (9));
* ``first_passage_quantiles``: the RUL quantiles of the first measured crossing (eq. (5b)),
  Newton's steps per unit from eq. (6)'s closed-form root.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from rulkit.fleet.learned.growth_filter import (
    HI_HI,
    HI_LO,
    IEKF_ITERATIONS,
    IEKF_TOL,
    GrowthParams,
)

FloatArray = NDArray[np.float64]


# ------------------------------------------------------------------- Gaussian, transformed HI
@numba.njit(cache=True)
def kf_nll(mu, cov, q, r, x, z, start):  # pragma: no cover - compiled
    """-log p(z) of every unit (eq. (3)); ``start`` row offsets per unit."""
    total = 0.0
    for u in range(start.shape[0] - 1):
        mz, mb = mu[0], mu[1]
        pzz, pzb, pbb = cov[0], cov[1], cov[2]
        xp = 0.0
        for k in range(start[u], start[u + 1]):
            dx = x[k] - xp
            xp = x[k]
            mz = mz + mb * dx
            pzz = pzz + 2.0 * dx * pzb + dx * dx * pbb + q * abs(dx)
            pzb = pzb + dx * pbb
            s = pzz + r
            inn = z[k] - mz
            total += 0.5 * (math.log(2.0 * math.pi * s) + inn * inn / s)
            kz, kb = pzz / s, pzb / s
            mz, mb = mz + kz * inn, mb + kb * inn
            pbb = pbb - kb * pzb
            pzb = pzb - kz * pzb
            pzz = pzz - kz * pzz
    return total


@numba.njit(cache=True)
def kf_replay(x, z, start, mu, cov, q, r, m_out, p_out):  # pragma: no cover - compiled
    """The posterior after every row (eq. (2)) into ``m_out (R, 2)``, ``p_out (R, 3)``."""
    for u in range(start.shape[0] - 1):
        mz, mb = mu[0], mu[1]
        pzz, pzb, pbb = cov[0], cov[1], cov[2]
        xp = 0.0
        for k in range(start[u], start[u + 1]):
            dx = x[k] - xp
            xp = x[k]
            mz = mz + mb * dx
            pzz = pzz + 2.0 * dx * pzb + dx * dx * pbb + q * abs(dx)
            pzb = pzb + dx * pbb
            s = pzz + r
            inn = z[k] - mz
            kz, kb = pzz / s, pzb / s
            mz, mb = mz + kz * inn, mb + kb * inn
            pbb = pbb - kb * pzb
            pzb = pzb - kz * pzb
            pzz = pzz - kz * pzz
            m_out[k, 0], m_out[k, 1] = mz, mb
            p_out[k, 0], p_out[k, 1], p_out[k, 2] = pzz, pzb, pbb
    return 0


@numba.njit(cache=True)
def _kf_nll_theta(t, x, z, start):  # pragma: no cover - compiled
    l11, l22 = math.exp(t[2]), math.exp(t[4])
    mu = np.array([t[0], t[1]])
    cov = np.array([l11 * l11, l11 * t[3], t[3] * t[3] + l22 * l22])
    v = kf_nll(mu, cov, math.exp(t[6]), math.exp(t[5]), x, z, start)
    return v if math.isfinite(v) else 1e300


@numba.njit(cache=True)
def kf_nll_grad(th, steps, x, z, start):  # pragma: no cover - compiled
    """(nll, central-difference gradient) at th = (m_a, m_b, log l11, l21, log l22,
    log sigma_e^2, log sigma_w^2)."""
    f0 = _kf_nll_theta(th, x, z, start)
    g = np.zeros(th.size)
    tt = th.copy()
    for i in range(th.size):
        tt[i] = th[i] + steps[i]
        fp = _kf_nll_theta(tt, x, z, start)
        tt[i] = th[i] - steps[i]
        fm = _kf_nll_theta(tt, x, z, start)
        tt[i] = th[i]
        g[i] = (fp - fm) / (2.0 * steps[i])
    return f0, g


# ------------------------------------------------------------------- HI measured (eq. (7)-(9))
@numba.njit(cache=True)
def boxcox(h, lam):  # pragma: no cover - compiled
    """g(h) = (h^lam - 1) / lam (ln h at lam = 0)."""
    if abs(lam) < 1e-12:
        return math.log(h)
    return (h**lam - 1.0) / lam


@numba.njit(cache=True)
def boxcox_inverse(z, lam):  # pragma: no cover - compiled
    """(hi, dhi/dz) at z clipped to g([HI_LO, HI_HI])."""
    zc = min(max(z, boxcox(HI_LO, lam)), boxcox(HI_HI, lam))
    if abs(lam) < 1e-12:
        h = math.exp(zc)
        return h, h
    base = 1.0 + lam * zc
    h = base ** (1.0 / lam)
    return h, h / base  # dh/dz = h^(1 - lam) = h / (1 + lam z)


@numba.njit(cache=True)
def assimilate(st, dx, y, lam, rz, rhi, q):  # pragma: no cover - compiled
    """Predict over dx, update with y (eq. (8)); st = [mz, mb, pzz, pzb, pbb] in place;
    returns the log predictive density of y."""
    mz = st[0] + st[1] * dx
    pzz = st[2] + 2.0 * dx * st[3] + dx * dx * st[4] + q * dx
    pzb = st[3] + dx * st[4]
    pbb = st[4]
    zlo, zhi = boxcox(HI_LO, lam), boxcox(HI_HI, lam)
    zi = min(max(mz, zlo), zhi)
    for _ in range(IEKF_ITERATIONS):
        h, hh = boxcox_inverse(zi, lam)
        s = hh * hh * pzz + h * h * rz + rhi
        nu = y - h - hh * (mz - zi)
        zn = min(max(mz + pzz * hh * nu / s, zlo), zhi)
        done = abs(zn - zi) <= IEKF_TOL * (1.0 + abs(zi))
        zi = zn
        if done:
            break
    h, hh = boxcox_inverse(zi, lam)
    s = hh * hh * pzz + h * h * rz + rhi
    nu = y - h - hh * (mz - zi)
    kz, kb = pzz * hh / s, pzb * hh / s
    st[0] = mz + kz * nu
    st[1] = st[1] + kb * nu
    st[2] = pzz - kz * hh * pzz
    st[3] = pzb - kz * hh * pzb
    st[4] = pbb - kb * hh * pzb
    return -0.5 * (math.log(2.0 * math.pi * s) + nu * nu / s)


@numba.njit(cache=True)
def growth_unpack(theta, grid):  # pragma: no cover - compiled
    """(prior [m_a, m_b, S_aa, S_ab, S_bb], log pi_k, r_z, r_hi, q) from theta."""
    l11, l22 = math.exp(theta[2]), math.exp(theta[4])
    l21 = theta[3]
    prior = np.array([theta[0], theta[1], l11 * l11, l11 * l21, l21 * l21 + l22 * l22])
    k = grid.shape[0]
    logpi = np.zeros(k)
    if k > 1:
        sd = math.exp(theta[9])
        for j in range(k):
            d = (grid[j] - theta[8]) / sd
            logpi[j] = -0.5 * d * d
        logpi -= _logsumexp(logpi)
    return prior, logpi, math.exp(theta[5]), math.exp(theta[6]), math.exp(theta[7])


@numba.njit(cache=True)
def _logsumexp(v):  # pragma: no cover - compiled
    mx = v.max()
    tot = 0.0
    for j in range(v.shape[0]):
        tot += math.exp(v[j] - mx)
    return mx + math.log(tot)


@numba.njit(cache=True)
def growth_nll(theta, x, y, start, lam, grid):  # pragma: no cover - compiled
    """-log p(hi) of every unit: the onset mixture of IEKF likelihoods (eq. (7)-(9))."""
    prior, logpi, rz, rhi, q = growth_unpack(theta, grid)
    k = grid.shape[0]
    ll = np.empty(k)
    st = np.empty(5)
    total = 0.0
    for u in range(start.shape[0] - 1):
        flat = math.nan  # every onset at or after the last age: the same (flat) filter
        for j in range(k):
            if grid[j] >= x[start[u + 1] - 1] and math.isfinite(flat):
                ll[j] = logpi[j] + flat
                continue
            st[:] = prior
            xe_prev = 0.0
            acc = 0.0
            for i in range(start[u], start[u + 1]):
                xe = max(x[i] - grid[j], 0.0)
                acc += assimilate(st, xe - xe_prev, y[i], lam, rz, rhi, q)
                xe_prev = xe
            if grid[j] >= x[start[u + 1] - 1]:
                flat = acc
            ll[j] = logpi[j] + acc
        total -= _logsumexp(ll)
    return total if math.isfinite(total) else 1e300


@numba.njit(cache=True)
def growth_nll_grad(theta, free, steps, x, y, start, lam, grid):  # pragma: no cover
    """(nll, central-difference gradient over the ``free`` entries of theta)."""
    f0 = growth_nll(theta, x, y, start, lam, grid)
    g = np.zeros(free.shape[0])
    th = theta.copy()
    for i in range(free.shape[0]):
        j = free[i]
        th[j] = theta[j] + steps[i]
        fp = growth_nll(th, x, y, start, lam, grid)
        th[j] = theta[j] - steps[i]
        fm = growth_nll(th, x, y, start, lam, grid)
        th[j] = theta[j]
        g[i] = (fp - fm) / (2.0 * steps[i])
    return f0, g


@numba.njit(cache=True)
def _assimilate_grid(st, lw, x_prev, x, y, lam, rz, rhi, q, grid):  # pragma: no cover
    """One acquisition for every onset value: st (K, 5), lw (K,) in place (normalised)."""
    for j in range(grid.shape[0]):
        xe0 = max(x_prev - grid[j], 0.0)
        xe = max(x - grid[j], 0.0)
        lw[j] += assimilate(st[j], xe - xe0, y, lam, rz, rhi, q)
    lw -= _logsumexp(lw)


@numba.njit(cache=True)
def growth_replay(theta, x, y, start, lam, grid, m_out, p_out, lw_out):  # pragma: no cover
    """State after every row: m_out (R, K, 2), p_out (R, K, 3), lw_out (R, K) normalised
    posterior log-weights of the onset grid."""
    prior, logpi, rz, rhi, q = growth_unpack(theta, grid)
    k = grid.shape[0]
    st = np.empty((k, 5))
    lw = np.empty(k)
    for u in range(start.shape[0] - 1):
        for j in range(k):
            st[j, :] = prior
            lw[j] = logpi[j]
        x_prev = 0.0
        for i in range(start[u], start[u + 1]):
            _assimilate_grid(st, lw, x_prev, x[i], y[i], lam, rz, rhi, q, grid)
            x_prev = x[i]
            for j in range(k):
                m_out[i, j, 0], m_out[i, j, 1] = st[j, 0], st[j, 1]
                p_out[i, j, 0], p_out[i, j, 1], p_out[i, j, 2] = st[j, 2], st[j, 3], st[j, 4]
                lw_out[i, j] = lw[j]
    return 0


@numba.njit(cache=True)
def growth_step_units(m, p, lw, x_prev, x, y, lam, rz, rhi, q, grid):  # pragma: no cover
    """One acquisition per unit (NaN y or x: none), in place: m (B, K, 2), p (B, K, 3),
    lw (B, K); x_prev the scaled age of each unit's last acquisition (0 before one)."""
    k = grid.shape[0]
    st = np.empty((k, 5))
    for u in range(m.shape[0]):
        if not (math.isfinite(x[u]) and math.isfinite(y[u])):
            continue
        for j in range(k):
            st[j, 0], st[j, 1] = m[u, j, 0], m[u, j, 1]
            st[j, 2], st[j, 3], st[j, 4] = p[u, j, 0], p[u, j, 1], p[u, j, 2]
        _assimilate_grid(st, lw[u], x_prev[u], x[u], y[u], lam, rz, rhi, q, grid)
        for j in range(k):
            m[u, j, 0], m[u, j, 1] = st[j, 0], st[j, 1]
            p[u, j, 0], p[u, j, 1], p[u, j, 2] = st[j, 2], st[j, 3], st[j, 4]
    return 0


# ------------------------------------------------------------------- numpy-facing wrappers
def negative_log_likelihood(theta: FloatArray, x: FloatArray, y: FloatArray,
                            start: NDArray[np.int64], lam: float, grid: FloatArray) -> float:
    """-log p(hi of all units) under eq. (7)-(9) (the prediction-error decomposition)."""
    return float(growth_nll(np.asarray(theta, dtype=np.float64), x, y, start, lam,
                                  np.asarray(grid, dtype=np.float64)))


def replay(theta: FloatArray, x: FloatArray, y: FloatArray, start: NDArray[np.int64],
           lam: float, grid: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Each row's posterior: means (R, K, 2), covariances (R, K, 3), log-weights (R, K)."""
    n, k = x.size, grid.size
    m, p, lw = np.empty((n, k, 2)), np.empty((n, k, 3)), np.empty((n, k))
    growth_replay(np.asarray(theta, dtype=np.float64), x, y, start, lam,
                        np.asarray(grid, dtype=np.float64), m, p, lw)
    return m, p, lw


def step_units(m: FloatArray, p: FloatArray, lw: FloatArray, x_prev: FloatArray, x: FloatArray,
               y: FloatArray, lam: float, params: GrowthParams, grid: FloatArray) -> None:
    """One acquisition per unit, in place (NaN = none for that unit); see :func:`replay`."""
    growth_step_units(m, p, lw, x_prev, x, y, lam, params.r_log, params.r_hi, params.q,
                            np.asarray(grid, dtype=np.float64))


# ------------------------------------------------------------------- RUL quantiles (bisection)
@numba.njit(cache=True)
def log_ndtr(x):  # pragma: no cover - compiled
    """log Phi(x), accurate in the lower tail (asymptotic series below x = -30)."""
    if x > -30.0:
        return math.log(0.5 * math.erfc(-x / math.sqrt(2.0)))
    x2 = x * x
    return -0.5 * x2 - math.log(-x) - 0.5 * math.log(2.0 * math.pi) + math.log1p(
        -1.0 / x2 + 3.0 / (x2 * x2))


@numba.njit(cache=True)
def _mixture_log_surv(lw, m, p, x0, w, grid, q, r):  # pragma: no cover - compiled
    """log sum_k w_k S_k(e_k(w)) for one unit (eq. (10)); components with a weight below
    1e-16 of the largest are left out (a relative error below 1e-15)."""
    k = grid.shape[0]
    acc = np.full(k, -np.inf)
    top = lw.max()
    for j in range(k):
        if lw[j] < top - 37.0:
            continue
        e = max(x0 + w - grid[j], 0.0) - max(x0 - grid[j], 0.0)
        num = m[j, 0] + m[j, 1] * e
        var = p[j, 0] + r + 2.0 * e * p[j, 1] + e * e * p[j, 2] + q * e
        acc[j] = lw[j] + log_ndtr(-num / math.sqrt(max(var, 1e-300)))
    return _logsumexp(acc)


@numba.njit(cache=True)
def onset_quantiles(lw, m, p, x0, grid, q, r, levels, iterations, out):  # pragma: no cover
    """Quantiles of eq. (10) per unit into ``out (L, B)``, in scaled age: bisection on
    u in (0, 1), w = W u / (1 - u), W = max(x0, 1); +inf beyond the failing mass."""
    for b in range(lw.shape[0]):
        ls0 = _mixture_log_surv(lw[b], m[b], p[b], x0[b], 0.0, grid, q, r)
        inf_acc = np.empty(grid.shape[0])
        for j in range(grid.shape[0]):
            inf_acc[j] = lw[b, j] + log_ndtr(-m[b, j, 1] / math.sqrt(p[b, j, 2]))
        ls_inf = _logsumexp(inf_acc)
        scale = max(x0[b], 1.0)
        for i in range(levels.shape[0]):
            target = ls0 + math.log1p(-levels[i])
            if target <= ls_inf:
                out[i, b] = np.inf
                continue
            lo, hi = 0.0, 1.0
            for _ in range(iterations):
                u = 0.5 * (lo + hi)
                if _mixture_log_surv(lw[b], m[b], p[b], x0[b], scale * u / (1.0 - u), grid,
                                     q, r) > target:
                    lo = u
                else:
                    hi = u
            u = 0.5 * (lo + hi)
            out[i, b] = scale * u / (1.0 - u)
    return 0


@numba.njit(cache=True)
def lognormal_mixture_quantiles(w, lr, bw, levels, iterations, out):  # pragma: no cover
    """Quantiles of sum_j w_j LogNormal(lr_j, bw^2) per unit into ``out (L, B)``: bisection
    on log r between the smallest and largest centre -+ 6 bw; weights below 1e-12 of the
    largest are left out (an error below 1e-10 in the CDF)."""
    keep = np.empty(w.shape[1], dtype=np.int64)
    for b in range(w.shape[0]):
        lo0, hi0 = np.inf, -np.inf
        top = w[b].max()
        nk = 0
        for j in range(w.shape[1]):
            if w[b, j] > 1e-12 * top:
                lo0 = min(lo0, lr[b, j])
                hi0 = max(hi0, lr[b, j])
                keep[nk] = j
                nk += 1
        for i in range(levels.shape[0]):
            lo, hi = lo0 - 6.0 * bw, hi0 + 6.0 * bw
            for _ in range(iterations):
                mid = 0.5 * (lo + hi)
                f = 0.0
                for jj in range(nk):
                    j = keep[jj]
                    f += w[b, j] * 0.5 * math.erfc(-(mid - lr[b, j]) / (bw * math.sqrt(2.0)))
                if f < levels[i]:
                    lo = mid
                else:
                    hi = mid
            out[i, b] = math.exp(0.5 * (lo + hi))
    return 0


# ------------------------------------------------------------------- first measured crossing
@numba.njit(cache=True)
def _ystar(c, j, th, mu_t, sd_t, lc0, dlc, dlj, dth):  # pragma: no cover - compiled
    """(mu*, sigma*) of eq. (5a) from the tables ``mu_t``, ``sd_t`` over log c (first row
    ``lc0``, step ``dlc``), log n (step ``dlj``) and theta (step ``dth``), trilinear as
    :func:`rulkit.fleet.learned.first_passage.ystar_moments`, and their slopes per step of
    log c and of theta (0 where c is clamped to the table's edge; n is fixed between
    readings)."""
    nc, nj, nt = mu_t.shape
    lc = (math.log(c) - lc0) / dlc if c > 0.0 else 0.0
    on_c = 0.0 < lc < nc - 1.0
    lc = min(max(lc, 0.0), nc - 1.0)
    lj = min(math.log(max(j, 1.0)) / dlj, nj - 1.0)
    lt = min(max(th / dth, 0.0), nt - 1.0)
    i0 = min(int(lc), nc - 2)
    j0 = min(int(lj), nj - 2)
    t0 = min(int(lt), nt - 2)
    a, b, e = lc - i0, lj - j0, lt - t0
    mu = sd = mu_c = sd_c = mu_t_ = sd_t_ = 0.0
    for di in range(2):
        wi = a if di else 1.0 - a
        si = 1.0 if di else -1.0
        for dj in range(2):
            wj = b if dj else 1.0 - b
            for dt in range(2):
                wt = e if dt else 1.0 - e
                st = 1.0 if dt else -1.0
                m = mu_t[i0 + di, j0 + dj, t0 + dt]
                v = sd_t[i0 + di, j0 + dj, t0 + dt]
                mu += wi * wj * wt * m
                sd += wi * wj * wt * v
                mu_c += si * wj * wt * m
                sd_c += si * wj * wt * v
                mu_t_ += wi * wj * st * m
                sd_t_ += wi * wj * st * v
    if not on_c:
        mu_c, sd_c = 0.0, 0.0
    return mu, sd, mu_c, sd_c, mu_t_, sd_t_


@numba.njit(cache=True)
def growth_scale(h, kind, shape, lo, hi):  # pragma: no cover - compiled
    """(g(h), g'(h)) of a growth scale: ``kind`` 0 linear, 1 ln(h - shape), 2 Box-Cox of
    ``shape``; h (h - shape for kind 1) clipped to [lo, hi] (g' = 0 where clipped), as
    :func:`rulkit.fleet.learned.degradation.transform` and
    :func:`rulkit.fleet.learned.growth_filter.boxcox` clip."""
    if kind == 0:
        return h, 1.0
    x = h - shape if kind == 1 else h
    inside = lo <= x <= hi
    x = min(max(x, lo), hi)
    if kind == 1 or abs(shape) < 1e-12:
        return math.log(x), (1.0 / x if inside else 0.0)
    return (x**shape - 1.0) / shape, (x ** (shape - 1.0) if inside else 0.0)


@numba.njit(cache=True)
def _fp_terms(st, q, s, delta, w, mu_t, sd_t, lc0, dlc, dlj, dth):  # pragma: no cover
    """(5b)'s numerator N and sd D at horizon ``w`` for one unit (S(w) = Phi(-N / D)) and
    their derivatives in w (the table's through its trilinear slopes). ``st`` (m_z - g(1),
    m_b, P_zz, P_zb, P_bb, h_0, g(1), and the growth scale's kind, shape, lower and upper
    clip, :func:`growth_scale`) with h_0 the last reading; ``delta`` inf: one reading at the
    horizon; ``s`` 0: the latent level. Before the first reading (w < delta) the
    interpolation between the last reading and the next on the HI scale,
    (1 - theta) h_0 + theta h_1 < 1, i.e. the next reading below
    H = 1 + (1 - theta) (1 - h_0) / theta: N = m_z + m_b d - g(H), D = (V(d) + s^2)^(1/2)."""
    mz, mb, pzz, pzb, pbb = st[0], st[1], st[2], st[3], st[4]
    if s > 0.0 and delta < np.inf and w < delta:
        d1 = math.sqrt(max(pzz + 2.0 * delta * pzb + delta * delta * pbb + q * delta, 0.0)
                       + s * s)
        th = w / delta
        if th <= 1e-100:  # H beyond every HI: S = 1 (and no 1 / theta^2 overflow)
            return -1e300, d1, 0.0, 0.0
        gap = 1.0 - st[5]
        big = 1.0 + (1.0 - th) * gap / th
        g, dg = growth_scale(big, int(st[7]), st[8], st[9], st[10])
        dbig = -gap / (th * th * delta)
        return mz + mb * delta + st[6] - g, d1, -dg * dbig, 0.0
    a = mz + mb * w
    g = pzb + w * pbb
    v = max(pzz + 2.0 * w * pzb + w * w * pbb + q * w, 1e-300)
    dv = 2.0 * g + q
    if s == 0.0:
        d = math.sqrt(v)
        return a, d, mb, dv / (2.0 * d)
    mu, sd, dmu, dsd = 0.0, 1.0, 0.0, 0.0
    if delta < np.inf:
        iv = 1.0 / v
        rate = mb - g * a * iv
        drate = (g * a * dv * iv - pbb * a - g * mb) * iv
        if rate <= 0.0:
            rate, drate = 0.0, 0.0
        x = w / delta
        n = math.floor(x)
        mu, sd, mu_c, sd_c, mu_th, sd_th = _ystar(rate * delta / s, n, x - n, mu_t, sd_t,
                                                  lc0, dlc, dlj, dth)
        dlog_c = drate / (rate * dlc) if rate > 0.0 else 0.0  # in table steps per unit w
        dth_w = 1.0 / (delta * dth)
        dmu = mu_c * dlog_c + mu_th * dth_w
        dsd = sd_c * dlog_c + sd_th * dth_w
    d = math.sqrt(v + s * s * sd * sd)
    return a - s * mu, d, mb - s * dmu, (dv + 2.0 * s * s * sd * dsd) / (2.0 * d)


@numba.njit(cache=True)
def _fp_log_surv(st, q, s, delta, w, mu_t, sd_t, lc0, dlc, dlj, dth):  # pragma: no cover
    """log S(w) of eq. (5b) for one unit (:func:`_fp_terms`)."""
    n, d, _, _ = _fp_terms(st, q, s, delta, w, mu_t, sd_t, lc0, dlc, dlj, dth)
    return log_ndtr(-n / d)


@numba.njit(cache=True)
def _ndtri_log(lp):  # pragma: no cover - compiled
    """x <= 0 with log Phi(x) = ``lp`` <= log 1/2: Acklam's rational approximation (relative
    error 1.2e-9), from log p alone in the lower tail, then one Halley step on
    :func:`log_ndtr` (cubic: to rounding). scipy's ndtri is not callable from cached code."""
    if lp >= -0.6931471805599453:
        return 0.0
    if lp < -3.719339771724596:  # p < 0.02425
        t = math.sqrt(-2.0 * lp)
        x = ((((((-7.784894002430293e-03 * t - 3.223964580411365e-01) * t
                 - 2.400758277161838e+00) * t - 2.549732539343734e+00) * t
               + 4.374664141464968e+00) * t + 2.938163982698783e+00)
             / ((((7.784695709041462e-03 * t + 3.224671290700398e-01) * t
                  + 2.445134137142996e+00) * t + 3.754408661907416e+00) * t + 1.0))
    else:
        h = math.exp(lp) - 0.5
        r = h * h
        x = ((((((-3.969683028665376e+01 * r + 2.209460984245205e+02) * r
                 - 2.759285104469687e+02) * r + 1.383577518672690e+02) * r
               - 3.066479806614716e+01) * r + 2.506628277459239e+00) * h
             / (((((-5.447609879822406e+01 * r + 1.615858368580409e+02) * r
                   - 1.556989798598866e+02) * r + 6.680131188771972e+01) * r
                 - 1.328068155288572e+01) * r + 1.0))
    lx = log_ndtr(x)
    f = lx - lp
    r = math.exp(-0.5 * x * x - 0.9189385332046728 - lx)  # phi / Phi, log Phi's slope
    return x - f / r / (1.0 + 0.5 * f * (x + r) / r)


@numba.njit(cache=True)
def _margin_quantile(target):  # pragma: no cover - compiled
    """k = -Phi^-1(exp(target)): log S(w) = target exactly where N(w) / D(w) = k (eq. (6));
    precise near S = 1 through 1 - S = -expm1(target)."""
    if target > -0.6931471805599453:
        return _ndtri_log(math.log(-math.expm1(target)))
    return -_ndtri_log(target)


@numba.njit(cache=True)
def _quadratic_root(st, q, s2, k, w_lo):  # pragma: no cover - compiled
    """Eq. (6) of one measurement (the variance raised by ``s2``, s^2): the smallest root
    w >= ``w_lo`` of (A + m_b w)^2 = k^2 (P_zz + s2 + w (2 P_zb + q) + w^2 P_bb) with A + m_b w
    of k's sign (squaring lost it), A = m_z - g(1); -1 if none."""
    a_, b_ = st[0], st[1]
    k2 = k * k
    a2 = b_ * b_ - k2 * st[4]
    a1 = 2.0 * a_ * b_ - k2 * (2.0 * st[3] + q)
    a0 = a_ * a_ - k2 * (st[2] + s2)
    best = -1.0
    if abs(a2) <= 1e-14 * (abs(a1) + abs(a0) + 1e-300):
        r1, r2 = (-a0 / a1 if a1 != 0.0 else -1.0), -1.0
    else:
        sq = math.sqrt(max(a1 * a1 - 4.0 * a2 * a0, 0.0))
        qq = -0.5 * (a1 + math.copysign(sq, a1))
        r1, r2 = qq / a2, (a0 / qq if qq != 0.0 else -1.0)
    for r in (r1, r2):
        num = a_ + b_ * r
        if r >= w_lo and r < np.inf and (best < 0.0 or r < best) and (
                num * k >= 0.0 or abs(num) <= 1e-7 * (abs(a_) + abs(b_ * r))):
            best = r
    return best


@numba.njit(cache=True)
def _fp_root(st, q, s, delta, k, mu_t, sd_t, lc0, dlc, dlj, dth,
             iterations):  # pragma: no cover - compiled
    """The horizon w > 0 where S of eq. (5b) falls to Phi(-k), known to lie there:
    G(w) = N(w) - k D(w) = 0 (G < 0 before the root), by Newton's steps from one
    measurement's eq. (6) root (mu* = 0, sigma* = 1; so a level's root does not depend on the
    other levels asked), safeguarded by the bracket (a step leaving it is a halving, or a
    doubling while the bracket is open: G has kinks at the readings and at the table's cell
    edges, the bracket holds across them), until a step is below 1e-13 w or, below 1e-6 w,
    the error left after it, |G''| h^2 / (2 |G'|) with G'' from the last two slopes, is below
    1e-14 w (tested against bisection to 1e-9), at most ``iterations`` steps."""
    lo, hi = 0.0, np.inf
    w = _quadratic_root(st, q, s * s, k, 0.0)
    if not (lo < w < hi):
        w = 1.0
    w_prev, dg_prev = np.nan, np.nan
    for _ in range(iterations):
        n, d, dn, dd = _fp_terms(st, q, s, delta, w, mu_t, sd_t, lc0, dlc, dlj, dth)
        g, dg = n - k * d, dn - k * dd
        if g < 0.0:
            lo = w
        elif g > 0.0:
            hi = w
        if g == 0.0:
            w_new = w
        elif dg != 0.0:
            w_new = w - g / dg
        else:  # a flat stretch (g's bound clipped): no step, a halving below
            w_new = np.nan
        h = abs(w_new - w)
        # Newton's error after the step: |G''| h^2 / (2 |G'|), G'' from the last two slopes
        if lo <= w_new <= hi and (h <= 1e-13 * w_new or (
                h <= 1e-6 * w_new and abs(dg - dg_prev) * h * h
                <= 2e-14 * abs(dg) * abs(w - w_prev) * w_new)):
            w = w_new
            break
        w_prev, dg_prev = w, dg
        if not (lo < w_new < hi):
            w_new = 0.5 * (lo + hi) if hi < np.inf else 2.0 * w + 1.0
        w = w_new
    return w


@numba.njit(cache=True)
def first_passage_quantiles(m, p, h0, growth, delta, q, zs, s, levels, mu_t, sd_t, lc0, dlc,
                            dlj, dth, iterations, out):  # pragma: no cover - compiled
    """Quantiles of eq. (5b) per unit into ``out (L, B)``, in scaled age (see
    :func:`rulkit.fleet.learned.degradation.rul_quantiles`): +inf beyond the failing mass.
    ``h0 (B,)`` each unit's last reading (the first step's interpolation from it,
    :func:`_fp_terms`), ``growth`` the growth scale's (kind, shape, lower, upper clip) of
    :func:`growth_scale`."""
    inf = np.inf
    k_fp = np.empty(levels.shape[0])  # the first passage's k per level (its reference is 0)
    for i in range(levels.shape[0]):
        k_fp[i] = _margin_quantile(math.log1p(-levels[i])) if 0.0 < levels[i] < 1.0 else 0.0
    st = np.empty(11)
    st[6], st[7], st[8], st[9], st[10] = zs, growth[0], growth[1], growth[2], growth[3]
    for b in range(m.shape[0]):
        d = delta[b]
        st[0], st[1], st[2], st[3], st[4] = m[b, 0] - zs, m[b, 1], p[b, 0], p[b, 1], p[b, 2]
        st[5] = h0[b]
        fp = s > 0.0 and d < inf
        ref = 0.0 if fp else _fp_log_surv(st, q, s, inf, 0.0, mu_t, sd_t, lc0, dlc, dlj, dth)
        ls_inf = log_ndtr(-st[1] / math.sqrt(st[4]))
        for i in range(levels.shape[0]):
            lev = levels[i]
            target = ref + math.log1p(-lev)
            if target <= ls_inf:
                out[i, b] = inf
                continue
            if target >= 0.0 or lev <= 0.0 or (fp and st[5] >= 1.0):  # or already read >= 1
                out[i, b] = 0.0
                continue
            k = k_fp[i] if fp else _margin_quantile(target)
            out[i, b] = _fp_root(st, q, s, d, k, mu_t, sd_t, lc0, dlc, dlj, dth, iterations)
    return 0
