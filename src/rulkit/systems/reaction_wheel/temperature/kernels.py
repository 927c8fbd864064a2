"""Fused numba kernels for the reaction-wheel step-1 particle filters
(docs/systems/reaction-wheel.md §3; seed 000 eqs 13-17 and 27, seed 001 eq. 28).

The whole time loop is compiled: per step the temperature random walk, one RK4 step of the
Ithaco wheel (docs/systems/reaction-wheel.md §1) per particle, the Gaussian likelihood, the weight
update of the chosen variant, the estimates, the ESS and systematic resampling. Random numbers come
from the
``numpy.random.Generator`` passed in (numba draws from the same bit generator, in the same
order as the numpy reference path
:func:`rulkit.systems.reaction_wheel.temperature.particle.filter_temperature_numpy`, so both
give the same numbers; tested).

Draw order (both paths): T0 = lo + (hi - lo) U (N uniforms); for F2 the initial [I, w] as
(N, 2) standard normals, row-major; per step k: N normals for the T random walk, then N for I
(if q_I > 0), then N for w (if q_w > 0); one uniform per systematic resampling; N normals per
adaptive spread.

Parameter vector ``P`` (float64): G_d, w_d, K_t, K_e, K_s, w_s, tau_c, J, R_in, K_f, theta_a,
w_a, V_bus, R_B, P_q, friction law (0 spec, 1 seed literal); see :func:`pack_params`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from rulkit.estimation.batched import (
    ess_row,
    normalise_row,
    systematic_row,
    weighted_quantile_pair_row,
)
from rulkit.systems.reaction_wheel.wheel_kernels import (
    rk4,
    viscous_law,
    wheel_constants,
)

# variants and designs (integer codes used by the kernel)
VARIANTS = {"pf": 0, "adaptive": 1, "apf_eq28": 2, "apf_tempered": 3, "apf": 4}


DESIGNS = {"F1": 0, "F2": 1}


@nb.njit(cache=True)
def _predict_loglik(I, W, T, ll, N, design, yprev_w, yprev_I, yw, yI, Vk, tn0, tn1, tn2, dt,
                    b0, b1, a11, a12, a22, log_norm, C):  # type: ignore[no-untyped-def]
    """RK4 per particle with b_v = b0 + b1 T and the Gaussian log-likelihood (hot loop)."""
    for i in range(N):
        b = b0 + b1 * T[i]
        if design == 0:
            Ii, Wi = rk4(yprev_I, yprev_w, Vk, b, tn0, tn1, tn2, dt, C)
        else:
            Ii, Wi = rk4(I[i], W[i], Vk, b, tn0, tn1, tn2, dt, C)
        I[i] = Ii
        W[i] = Wi
        e0 = yw - Wi
        e1 = yI - Ii
        ll[i] = -0.5 * (a11 * e0 * e0 + 2.0 * a12 * e0 * e1 + a22 * e1 * e1) - log_norm


@nb.njit(cache=True)
def _point_loglik(I, W, T, ll1, N, design, yprev_w, yprev_I, yw, yI, Vk, tn0, tn1, tn2, dt,
                  b0, b1, a11, a12, a22, log_norm, C):  # type: ignore[no-untyped-def]
    """The auxiliary PF's first-stage log-likelihoods log p(y_k | mu_k^i), ``mu`` the point
    prediction of particle i (its T held, [I, w] by one RK4 step; the state is not changed)."""
    for i in range(N):
        b = b0 + b1 * T[i]
        if design == 0:
            Ii, Wi = rk4(yprev_I, yprev_w, Vk, b, tn0, tn1, tn2, dt, C)
        else:
            Ii, Wi = rk4(I[i], W[i], Vk, b, tn0, tn1, tn2, dt, C)
        e0 = yw - Wi
        e1 = yI - Ii
        v = -0.5 * (a11 * e0 * e0 + 2.0 * a12 * e0 * e1 + a22 * e1 * e1) - log_norm
        ll1[i] = v if v == v else -np.inf


class KernelInputs(NamedTuple):
    """Arrays of one filter run: ``y`` (K, 2) = [w, I_m], ``V`` (K,) commanded voltage,
    ``S_inv`` (2, 2) inverse likelihood covariance of [w, I], ``init_sd`` (2,) = [sd_I, sd_w]
    of the F2 initial cloud around y_0, ``P`` the parameter vector of :func:`pack_params`."""

    y: np.ndarray
    V: np.ndarray
    S_inv: np.ndarray
    init_sd: np.ndarray
    P: np.ndarray


class KernelSettings(NamedTuple):
    """Scalar settings of :func:`pf_kernel` (types fixed: numba compiles one signature).

    ``design`` 0 F1 / 1 F2; ``variant`` 0 PF, 1 adaptive, 2 APF eq. 28, 3 APF tempering;
    ``log_norm`` = log(2 pi sqrt det S); ``log_p_eff`` the adaptive threshold (log);
    ``temper_log_gmax`` = log gamma_max; ``gate_d2``: a sample whose *best* particle has a
    squared Mahalanobis prediction error above this is not trusted (inf: no gate);
    ``reanchor_after``: after that many untrusted samples in a row the F2 particles' [I, w]
    are redrawn around the measurement (recovery from a corrupted input) and, with
    ``rollback`` > 0, T and the weights go back to their values ``rollback`` samples before the
    first untrusted one (undoing the updates by predictions the bad input had already
    biased)."""

    t0: float
    dt: float
    design: int
    variant: int
    n: int
    T_lo: float
    T_hi: float
    q_T: float
    q_I: float
    q_w: float
    log_norm: float
    ess_frac: float
    adapt_window: int
    log_p_eff: float
    adapt_spread: float
    apf_c0: float
    apf_c1: float
    temper_target: float
    temper_log_gmax: float
    want_quantiles: bool
    q_lo: float
    q_hi: float
    gate_d2: float
    reanchor_after: int
    rollback: int


@nb.njit(cache=True)
def _mean_std(T, wn):  # type: ignore[no-untyped-def]
    m = 0.0
    for i in range(T.size):
        m += wn[i] * T[i]
    v = 0.0
    for i in range(T.size):
        v += wn[i] * (T[i] - m) ** 2
    return m, math.sqrt(v)


@nb.njit(cache=True)
def _temper_gamma(lw, ll, s, T2, cw):  # type: ignore[no-untyped-def]
    """Largest gamma in [1, gmax] with ESS(lw + gamma ll) >= target N (bisection in log);
    ``cw`` holds the weights of the plain update on entry."""
    N = lw.size
    if not ess_row(cw) > s.temper_target * N:
        return 1.0
    lo = 0.0
    hi = s.temper_log_gmax
    for i in range(N):
        T2[i] = lw[i] + math.exp(hi) * ll[i]
    normalise_row(T2, cw)
    if ess_row(cw) >= s.temper_target * N:
        return math.exp(hi)
    for _it in range(30):
        mid = 0.5 * (lo + hi)
        gm = math.exp(mid)
        for i in range(N):
            T2[i] = lw[i] + gm * ll[i]
        normalise_row(T2, cw)
        if ess_row(cw) >= s.temper_target * N:
            lo = mid
        else:
            hi = mid
    return math.exp(lo)


@nb.njit(cache=True)
def _weight_update(lw, wn, ll, Vk, s, T2, cw):  # type: ignore[no-untyped-def]
    """Weight update of the chosen variant, normalised in place. Returns (log-sum of the new
    unnormalised weights, data log-likelihood log sum_i exp(lw_i + ll_i), clipped count,
    gamma)."""
    N = lw.size
    ls_data = 0.0
    ncl = 0
    g = 1.0
    if s.variant >= 2:
        for i in range(N):
            T2[i] = lw[i] + ll[i]
        ls_data = normalise_row(T2, cw)
    if s.variant == 2:  # APF, seed 001 eq. 28 with clipping
        c = s.apf_c0 / (s.apf_c0 - Vk)
        tot = 0.0
        for i in range(N):
            beta = 1.0 / N - wn[i] * math.exp(ll[i])
            sb = 1.0 if beta > 0.0 else (-1.0 if beta < 0.0 else 0.0)
            wt = 1.0 - math.exp(c * (beta - s.apf_c1 * sb))
            if wt < 0.0:
                wt = 0.0
                ncl += 1
            T2[i] = wt
            tot += wt
        if tot > 0.0:
            for i in range(N):
                lw[i] = math.log(T2[i]) if T2[i] > 0.0 else -np.inf
        else:
            for i in range(N):
                lw[i] += ll[i]
    elif s.variant == 3:
        g = _temper_gamma(lw, ll, s, T2, cw)
        for i in range(N):
            lw[i] += g * ll[i]
    else:
        for i in range(N):
            lw[i] += ll[i]
    ls = normalise_row(lw, wn)
    if s.variant < 2:
        ls_data = ls
    return ls, ls_data, ncl, g


@nb.njit(cache=True)
def _resample(T, I, W, idx, wn, u, design, T2, I2, W2, cw):  # type: ignore[no-untyped-def]
    """Systematic resampling of the cloud in place (ancestors into ``idx``)."""
    N = T.size
    systematic_row(wn, u, idx, cw)
    for j in range(N):
        T2[j] = T[idx[j]]
    for j in range(N):
        T[j] = T2[j]
    if design == 1:
        for j in range(N):
            I2[j] = I[idx[j]]
            W2[j] = W[idx[j]]
        for j in range(N):
            I[j] = I2[j]
            W[j] = W2[j]


@nb.njit(cache=True)
def _interval(T, wn, s, ibuf, fbuf):  # type: ignore[no-untyped-def]
    """Weighted (q_lo, q_hi) quantiles of T by one histogram pass (O(N), no sort)."""
    return weighted_quantile_pair_row(T, wn, s.q_lo, s.q_hi, ibuf, fbuf)


class PFState(NamedTuple):
    """The cloud between two calls of :func:`pf_steps` (a record filtered in chunks): the
    particles ``T``, ``I``, ``W``, log-weights ``lw`` and weights ``wn`` (N,), the rollback
    ring ``ring_T``, ``ring_lw`` (R, N) and ``sc`` = [adaptive window sum, window count,
    untrusted samples in a row]."""

    T: np.ndarray
    I: np.ndarray
    W: np.ndarray
    lw: np.ndarray
    wn: np.ndarray
    ring_T: np.ndarray
    ring_lw: np.ndarray
    sc: np.ndarray


@nb.njit(cache=True)
def _ring_size(s):  # type: ignore[no-untyped-def]
    gated = -0.5 * s.gate_d2 - s.log_norm > -np.inf
    return s.rollback + s.reanchor_after + 2 if gated and s.rollback > 0 else 1


@nb.njit(cache=True)
def pf_start(y0, init_sd, s, rng):  # type: ignore[no-untyped-def]
    """The prior cloud from the first sample ``y0`` = [w, I_m]: T ~ U(T_lo, T_hi); for F2
    [I, w] = y0 + init_sd * normal. Returns (:class:`PFState`, row-0 estimates (mean, sd,
    q_lo, q_hi))."""
    N = s.n
    R = _ring_size(s)
    st = PFState(np.empty(N), np.empty(N), np.empty(N), np.empty(N), np.empty(N),
                 np.empty((R, N)), np.empty((R, N)), np.zeros(3))
    T, I, W, lw, wn = st.T, st.I, st.W, st.lw, st.wn
    for i in range(N):
        T[i] = s.T_lo + (s.T_hi - s.T_lo) * rng.random()
    if s.design == 1:
        for i in range(N):
            I[i] = y0[1] + init_sd[0] * rng.standard_normal()
            W[i] = y0[0] + init_sd[1] * rng.standard_normal()
    else:
        I[:] = 0.0
        W[:] = 0.0
    for i in range(N):
        lw[i] = -math.log(N)
        wn[i] = 1.0 / N
    m, sd = _mean_std(T, wn)
    qlo = np.nan
    qhi = np.nan
    if s.want_quantiles:
        qlo, qhi = _interval(T, wn, s, np.empty(N, dtype=np.int64), np.empty(3 * N))
    return st, m, sd, qlo, qhi


@nb.njit(cache=True)
def pf_kernel(inp, s, rng):  # type: ignore[no-untyped-def]
    """Run one temperature particle filter over ``inp.y`` (K, 2) = [w, I_m]:
    :func:`pf_start` on ``y[0]`` then :func:`pf_steps` over the record. Row 0 is the prior.
    Returns what :func:`pf_steps` returns."""
    st, m, sd, qlo, qhi = pf_start(inp.y[0], inp.init_sd, s, rng)
    out = pf_steps(inp, s, rng, st, 0)
    out[0][0] = m
    out[1][0] = sd
    out[2][0] = qlo
    out[3][0] = qhi
    out[4][0] = s.n
    return out


@nb.njit(cache=True)
def _untrusted(T, I, W, lw, wn, ring_T, ring_lw, k, n_bad, yw, yI, init_sd, s, rng
               ):  # type: ignore[no-untyped-def]
    """A sample no particle explains: keep the weights; after ``reanchor_after`` in a row
    redraw the F2 [I, w] around the measurement and roll T and the weights back. Returns
    (n_bad, action)."""
    n_bad += 1
    act = 4
    R = ring_T.shape[0]
    if s.design == 1 and n_bad >= s.reanchor_after:
        for i in range(T.size):
            I[i] = yI + init_sd[0] * rng.standard_normal()
            W[i] = yw + init_sd[1] * rng.standard_normal()
        back = k - n_bad - s.rollback  # the cloud after step back, if still kept
        if R > 1 and back >= 0:
            T[:] = ring_T[back % R]
            lw[:] = ring_lw[back % R]
            normalise_row(lw, wn)
        n_bad = 0
        act = 5
    return n_bad, act


@nb.njit(cache=True)
def _renew(T, I, W, lw, wn, m, ess, spread, s, rng, idx, T2, I2, W2, cw
           ):  # type: ignore[no-untyped-def]
    """After the update: the adaptive spread around the estimate ``m`` (``spread``), or
    ESS-triggered systematic resampling (not for the auxiliary PF, which resampled in its
    first stage). Returns the action (0, 1 or 2)."""
    N = T.size
    logN = math.log(N)
    if spread:
        for i in range(N):
            T[i] = m + s.adapt_spread * rng.standard_normal()
            lw[i] = -logN
            wn[i] = 1.0 / N
        return 2
    if s.variant != 4 and ess < s.ess_frac * N:
        _resample(T, I, W, idx, wn, rng.random(), s.design, T2, I2, W2, cw)
        for i in range(N):
            lw[i] = -logN
            wn[i] = 1.0 / N
        return 1
    return 0


@nb.njit(cache=True)
def _apf_first_stage(T, I, W, lw, wn, ll1, u, s, idx, T2, I2, W2, cw
                     ):  # type: ignore[no-untyped-def]
    """The auxiliary PF's first stage (Pitt and Shephard 1999): resample the ancestors by
    w_{k-1} p(y_k | mu_k), keep each survivor's ``ll1`` for its second-stage weight
    p(y_k | x_k) / p(y_k | mu_k), set equal weights. Returns log sum_i w_i p(y_k | mu_k^i),
    the first factor of the data likelihood."""
    N = T.size
    for i in range(N):
        T2[i] = lw[i] + ll1[i]
    ls = normalise_row(T2, cw)
    fw = np.empty(N)
    fw[:] = cw
    _resample(T, I, W, idx, fw, u, s.design, T2, I2, W2, cw)
    for j in range(N):
        T2[j] = ll1[idx[j]]
    logN = math.log(N)
    for i in range(N):
        ll1[i] = T2[i]
        lw[i] = -logN
        wn[i] = 1.0 / N
    return ls


@nb.njit(cache=True)
def _outputs(K):  # type: ignore[no-untyped-def]
    """The per-sample outputs of :func:`pf_steps`, unfilled."""
    return (np.full(K, np.nan), np.full(K, np.nan), np.full(K, np.nan), np.full(K, np.nan),
            np.full(K, np.nan), np.zeros(K, dtype=np.int8), np.zeros(K, dtype=np.int64),
            np.ones(K), np.zeros(K), np.zeros(K, dtype=np.int8))


@nb.njit(cache=True)
def _record(outs, kk, T, wn, s, ibuf, fbuf):  # type: ignore[no-untyped-def]
    """Write the estimates of row ``kk`` (mean, sd, interval, ESS); returns (mean, ESS)."""
    m, sd = _mean_std(T, wn)
    outs[0][kk] = m
    outs[1][kk] = sd
    if s.want_quantiles:
        outs[2][kk], outs[3][kk] = _interval(T, wn, s, ibuf, fbuf)
    ess = ess_row(wn)
    outs[4][kk] = ess
    return m, ess


@nb.njit(cache=True)
def _propagate(T, I, W, ll, I2, W2, s, rng, yprev_w, yprev_I, yw, yI, Vk, tn0, tn1, tn2, b0, b1,
               S_inv, C):  # type: ignore[no-untyped-def]
    """The prediction of one step: T random walk, then RK4 per particle with its own T (plus
    the F2 process noise of [I, w]), and the log-likelihood of the sample; returns the largest
    log-likelihood (NaN predictions count as zero likelihood)."""
    N = T.size
    a11, a12, a22 = S_inv[0, 0], S_inv[0, 1], S_inv[1, 1]
    for i in range(N):
        T[i] += s.q_T * rng.standard_normal()
    if s.design == 1 and s.q_I > 0.0:
        for i in range(N):
            I2[i] = s.q_I * rng.standard_normal()
    if s.design == 1 and s.q_w > 0.0:
        for i in range(N):
            W2[i] = s.q_w * rng.standard_normal()
    _predict_loglik(I, W, T, ll, N, s.design, yprev_w, yprev_I, yw, yI, Vk,
                    tn0, tn1, tn2, s.dt, b0, b1, a11, a12, a22, s.log_norm, C)
    if s.design == 1 and (s.q_I > 0.0 or s.q_w > 0.0):
        for i in range(N):
            if s.q_I > 0.0:
                I[i] += I2[i]
            if s.q_w > 0.0:
                W[i] += W2[i]
            e0 = yw - W[i]
            e1 = yI - I[i]
            ll[i] = -0.5 * (a11 * e0 * e0 + 2.0 * a12 * e0 * e1 + a22 * e1 * e1) - s.log_norm
    llmax = -np.inf
    for i in range(N):
        if ll[i] != ll[i]:  # NaN prediction (diverged particle): zero likelihood
            ll[i] = -np.inf
        if ll[i] > llmax:
            llmax = ll[i]
    return llmax


@nb.njit(cache=True)
def pf_steps(inp, s, rng, st, k0):  # type: ignore[no-untyped-def]
    """Advance the cloud ``st`` (a :class:`PFState`, updated in place) over ``inp.y`` (K, 2) =
    [w, I_m]: row 0 is the sample the cloud is at (global index ``k0``), rows 1..K-1 the new
    ones (global ``k0 + 1 ..``). A record filtered in chunks that overlap by one row gives
    the numbers of one call over the whole record.

    ``inp`` a :class:`KernelInputs`, ``s`` a :class:`KernelSettings`. ``V[k-1]`` is held over
    the step ending at t_k = t0 + k dt (and sets the APF gain c = c0 / (c0 - V)). Design F1:
    each particle predicts y_k by one RK4 step from the measured y_{k-1}; F2: particles carry
    [I, w], initialised at y_0 + init_sd * normal. Likelihood log p = -d^2/2 - log_norm.
    The auxiliary PF (variant 4) first resamples by the point predictions' likelihoods (one
    uniform, drawn before the step's normals), then weights by p(y | x) / p(y | mu).

    Returns (T_mean, T_std, T_qlo, T_qhi, ess, action, n_clipped, gamma, loglik, untrusted),
    each (K,), row 0 not filled (NaN / 0). ``action``: 0 none, 1 ESS resampling, 2 adaptive
    spread, 3 all weights zero (reset to equal weights), 4 untrusted sample (gated: weights
    kept), 5 untrusted and the F2 [I, w] redrawn around the measurement, 6 auxiliary PF
    first-stage resampling. ``untrusted`` (int8) is 1 for a gated sample.
    """
    y, V, S_inv, init_sd, P = inp
    K = y.shape[0]
    N = s.n
    T, I, W, lw, wn, ring_T, ring_lw, sc = st
    ll, ll1, T2, I2, W2, cw = (np.empty(N), np.empty(N), np.empty(N), np.empty(N),
                               np.empty(N), np.empty(N))
    idx, ibuf, fbuf = np.empty(N, dtype=np.int64), np.empty(N, dtype=np.int64), np.empty(3 * N)
    outs = _outputs(K)
    out_act, out_clip, out_gamma, out_ll, out_flag = outs[5:]
    a11, a12, a22 = S_inv[0, 0], S_inv[0, 1], S_inv[1, 1]
    logN = math.log(N)
    C = wheel_constants(P)
    b0, b1 = viscous_law(P)
    tn_amp = P[7] * P[10] * P[11] * P[11]
    w_a = P[11]
    ll_gate = -0.5 * s.gate_d2 - s.log_norm
    R = ring_T.shape[0]
    win_sum, win_cnt, n_bad = sc[0], int(sc[1]), int(sc[2])

    for kk in range(1, K):
        k = k0 + kk  # the global sample index
        if R > 1:  # the cloud after step k - 1, for a rollback
            ring_T[(k - 1) % R] = T
            ring_lw[(k - 1) % R] = lw
        t = s.t0 + (k - 1) * s.dt
        Vk = V[kk - 1]
        tn0 = tn_amp * math.sin(w_a * t)
        tn1 = tn_amp * math.sin(w_a * (t + 0.5 * s.dt))
        tn2 = tn_amp * math.sin(w_a * (t + s.dt))
        yw = y[kk, 0]
        yI = y[kk, 1]
        ls_first = 0.0
        first = False
        if s.variant == 4:  # auxiliary PF: resample by the point predictions first
            _point_loglik(I, W, T, ll1, N, s.design, y[kk - 1, 0], y[kk - 1, 1], yw, yI, Vk,
                          tn0, tn1, tn2, s.dt, b0, b1, a11, a12, a22, s.log_norm, C)
            if ll1.max() >= ll_gate:
                ls_first = _apf_first_stage(T, I, W, lw, wn, ll1, rng.random(), s, idx, T2,
                                            I2, W2, cw)
                first = True
        llmax = _propagate(T, I, W, ll, I2, W2, s, rng, y[kk - 1, 0], y[kk - 1, 1], yw, yI,
                           Vk, tn0, tn1, tn2, b0, b1, S_inv, C)
        if llmax < ll_gate or (s.variant == 4 and not first):
            # --- untrusted sample: no particle explains it; keep the weights
            out_flag[kk] = 1
            n_bad, out_act[kk] = _untrusted(T, I, W, lw, wn, ring_T, ring_lw, k, n_bad, yw, yI,
                                            init_sd, s, rng)
            _record(outs, kk, T, wn, s, ibuf, fbuf)
            continue
        n_bad = 0
        if first:  # second-stage weight p(y | x) / p(y | mu) of the auxiliary PF
            for i in range(N):
                ll[i] -= ll1[i]
        # --- weight update; ls_data = log sum_i exp(lw_i + ll_i), the data log-likelihood
        ls, ls_data, out_clip[kk], out_gamma[kk] = _weight_update(lw, wn, ll, Vk, s, T2, cw)
        act = 6 if first else 0
        if not ls > -np.inf:  # every weight zero: documented reset to equal weights
            for i in range(N):
                lw[i] = -logN
                wn[i] = 1.0 / N
            act = 3
        out_ll[kk] = ls_data + ls_first
        # --- estimates
        m, ess = _record(outs, kk, T, wn, s, ibuf, fbuf)
        # --- resampling / adaptive spread
        spread = False
        if s.variant == 1:
            win_sum += math.exp(llmax)
            win_cnt += 1
            if win_cnt >= s.adapt_window and math.log(win_sum / win_cnt) < s.log_p_eff:
                spread = True
                win_sum = 0.0
                win_cnt = 0
        renewed = _renew(T, I, W, lw, wn, m, ess, spread, s, rng, idx, T2, I2, W2, cw)
        out_act[kk] = renewed if renewed else act
    sc[0] = win_sum
    sc[1] = win_cnt
    sc[2] = n_bad
    return outs
