"""Fused numba kernels for the reaction-wheel step-1 particle filters (spec rw-lubrication.md
section 3; seed 000 eqs 13-17 and 27, seed 001 eq. 28).

The whole time loop is compiled: per step the temperature random walk, one RK4 step of the
Ithaco wheel (spec section 1) per particle, the Gaussian likelihood, the weight update of the
chosen variant, the estimates, the ESS and systematic resampling. Random numbers come from the
``numpy.random.Generator`` passed in (numba draws from the same bit generator, in the same
order as the numpy reference path
:func:`rulkit.systems.reaction_wheel.temperature.run_step1_numpy`, so both
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

import numba as nb
import numpy as np

from rulkit.systems.reaction_wheel.wheel import IthacoParams

# variants and designs (integer codes used by the kernel)
VARIANTS = {"pf": 0, "adaptive": 1, "apf_eq28": 2, "apf_tempered": 3}
DESIGNS = {"F1": 0, "F2": 1}


def pack_params(p: IthacoParams) -> np.ndarray:
    """Pack :class:`IthacoParams` into the kernel's float64 parameter vector."""
    if p.B != 0.0 or p.C != 0.0:
        raise ValueError("the step-1 kernels model no ripple (B = C = 0, spec section 1)")
    return np.array(
        [p.G_d, p.w_d, p.K_t, p.K_e, p.K_s, p.w_s, p.tau_c, p.J, p.R_in, p.K_f, p.theta_a,
         p.w_a, p.V_bus, p.R_B, p.P_q, 0.0 if p.friction_law == "spec" else 1.0],
        dtype=np.float64,
    )


_FM = {"nsz", "arcp", "contract", "reassoc"}  # no nnan/ninf: NaN and -inf are handled


@nb.njit(cache=True, inline="always", fastmath=_FM)
def _deriv(I, w, V, b, tn, C):  # type: ignore[no-untyped-def]
    """Wheel derivatives for one particle: the algebra of ``wheel_derivatives`` written
    branch-free (comparisons as 0/1 factors, spec section 1: Heavisides are exact steps) so the
    particle loop vectorises. ``C`` is the tuple from :func:`_consts` (inverses precomputed)."""
    G_d, w_d, K_t, K_e, K_s, w_s, tau_c, inv_J, R_in, K_f, V_bus, R_B, P_q, inv_Vbus = C
    aI = abs(I)
    aw = abs(w)
    sw = (1.0 if w > 0.0 else 0.0) - (1.0 if w < 0.0 else 0.0)
    I_bus = (R_B * I * I + 0.04 * aI * V_bus + P_q + K_e * w * I) * inv_Vbus
    V_h = K_f * (V_bus - 6.0 - (1.0 + R_in * I_bus) * (1.0 if I_bus > 0.0 else 0.0) - K_e * aw)
    f3 = min(V_h, 0.0)
    f5 = sw * K_s * (aw - w_s) * (1.0 if aw >= w_s else 0.0)
    dI = w_d * (G_d * (V + f3 - f5) - I)
    dw = (K_t * I - b * w - tau_c * sw + tn) * inv_J
    return dI, dw


@nb.njit(cache=True)
def _consts(P):  # type: ignore[no-untyped-def]
    return (P[0], P[1], P[2], P[3], P[4], P[5], P[6], 1.0 / P[7], P[8], P[9], P[12], P[13],
            P[14], 1.0 / P[12])


@nb.njit(cache=True, inline="always", fastmath=_FM)
def _rk4(I, w, V, b, tn0, tn1, tn2, dt, C):  # type: ignore[no-untyped-def]
    """Classical RK4 step; tn0/tn1/tn2: torque noise at t, t + dt/2, t + dt."""
    k1I, k1w = _deriv(I, w, V, b, tn0, C)
    k2I, k2w = _deriv(I + 0.5 * dt * k1I, w + 0.5 * dt * k1w, V, b, tn1, C)
    k3I, k3w = _deriv(I + 0.5 * dt * k2I, w + 0.5 * dt * k2w, V, b, tn1, C)
    k4I, k4w = _deriv(I + dt * k3I, w + dt * k3w, V, b, tn2, C)
    return (I + dt / 6.0 * (k1I + 2.0 * k2I + 2.0 * k3I + k4I),
            w + dt / 6.0 * (k1w + 2.0 * k2w + 2.0 * k3w + k4w))


@nb.njit(cache=True, fastmath=_FM)
def _predict_loglik(I, W, T, ll, N, design, yprev_w, yprev_I, yw, yI, Vk, tn0, tn1, tn2, dt,
                    b0, b1, a11, a12, a22, log_norm, C):  # type: ignore[no-untyped-def]
    """RK4 per particle with b_v = b0 + b1 T and the Gaussian log-likelihood (hot loop)."""
    for i in range(N):
        b = b0 + b1 * T[i]
        if design == 0:
            Ii, Wi = _rk4(yprev_I, yprev_w, Vk, b, tn0, tn1, tn2, dt, C)
        else:
            Ii, Wi = _rk4(I[i], W[i], Vk, b, tn0, tn1, tn2, dt, C)
        I[i] = Ii
        W[i] = Wi
        e0 = yw - Wi
        e1 = yI - Ii
        ll[i] = -0.5 * (a11 * e0 * e0 + 2.0 * a12 * e0 * e1 + a22 * e1 * e1) - log_norm


@nb.njit(cache=True)
def _weighted_quantile(x, w, q, order, cw):  # type: ignore[no-untyped-def]
    """Inverse weighted CDF: smallest sorted x with cumulative weight >= q."""
    n = x.size
    order[:] = np.argsort(x, kind="mergesort")
    acc = 0.0
    for j in range(n):
        acc += w[order[j]]
        cw[j] = acc
    qq = q * cw[n - 1]
    for j in range(n):
        if cw[j] >= qq:
            return x[order[j]]
    return x[order[n - 1]]


@nb.njit(cache=True)
def _normalise(lw, wn):  # type: ignore[no-untyped-def]
    """Log-sum-exp normalisation in place: wn = exp(lw - max) / sum; lw -= log-sum.

    Returns the log of the sum of the unnormalised weights (the log-likelihood increment when
    lw held normalised log-weights plus log-likelihoods), or -inf when all weights are zero.
    """
    n = lw.size
    mx = -np.inf
    for i in range(n):
        if lw[i] > mx:
            mx = lw[i]
    if not mx > -np.inf:  # all -inf or NaN
        return -np.inf
    s = 0.0
    for i in range(n):
        e = math.exp(lw[i] - mx)
        wn[i] = e
        s += e
    ls = mx + math.log(s)
    for i in range(n):
        wn[i] /= s
        lw[i] -= ls
    return ls


@nb.njit(cache=True)
def _ess(wn):  # type: ignore[no-untyped-def]
    s = 0.0
    for i in range(wn.size):
        s += wn[i] * wn[i]
    return 1.0 / s


@nb.njit(cache=True)
def _systematic(wn, u, idx, cw):  # type: ignore[no-untyped-def]
    """Systematic resampling as rulkit.estimation.resampling.systematic: positions
    (j + u) / N scaled by the last cumulative weight, located with side='right'."""
    n = wn.size
    acc = 0.0
    for i in range(n):
        acc += wn[i]
        cw[i] = acc
    last_nz = n - 1
    while last_nz > 0 and wn[last_nz] == 0.0:
        last_nz -= 1
    i = 0
    for j in range(n):
        pos = (j + u) / n * cw[n - 1]
        while i < n and cw[i] <= pos:
            i += 1
        idx[j] = i if i < n else last_nz


@nb.njit(cache=True)
def pf_kernel(  # type: ignore[no-untyped-def]
    y, V, t0, dt, design, variant, N, T_lo, T_hi, q_T, q_I, q_w, init_sd, S_inv, log_norm,
    ess_frac, adapt_window, log_p_eff, adapt_spread, apf_c0, apf_c1, temper_target,
    temper_log_gmax, want_quantiles, q_lo, q_hi, P, rng,
):
    """Run one step-1 particle filter over measurements ``y`` (K, 2) = [w, I_m].

    ``V`` (K,) commanded voltage; V[k-1] is held over the step ending at t_k = t0 + k dt (and
    sets the APF gain c = c0 / (c0 - V)). ``design`` 0 = F1 (each particle predicts y_k by one
    RK4 step from the measured y_{k-1}), 1 = F2 (particles carry [I, w], initialised at
    y_0 + init_sd * normal). ``variant`` 0 PF, 1 PF + adaptive resampling, 2 APF eq. 28 with
    clipping, 3 APF by likelihood tempering. ``S_inv`` (2, 2) inverse likelihood covariance of
    [w, I]; ``log_norm`` = log(2 pi sqrt det S), so log p = -d^2/2 - log_norm.

    Returns (T_mean, T_std, T_qlo, T_qhi, ess, action, n_clipped, gamma, loglik), each (K,).
    Row 0 is the prior. ``action``: 0 none, 1 ESS resampling, 2 adaptive spread, 3 all
    weights zero (reset to equal weights, flagged).
    """
    K = y.shape[0]
    T = np.empty(N)
    I = np.empty(N)
    W = np.empty(N)
    lw = np.empty(N)
    ll = np.empty(N)
    wn = np.empty(N)
    T2 = np.empty(N)
    I2 = np.empty(N)
    W2 = np.empty(N)
    cw = np.empty(N)
    idx = np.empty(N, dtype=np.int64)
    order = np.empty(N, dtype=np.int64)
    out_mean = np.full(K, np.nan)
    out_std = np.full(K, np.nan)
    out_qlo = np.full(K, np.nan)
    out_qhi = np.full(K, np.nan)
    out_ess = np.full(K, np.nan)
    out_act = np.zeros(K, dtype=np.int8)
    out_clip = np.zeros(K, dtype=np.int64)
    out_gamma = np.ones(K)
    out_ll = np.zeros(K)
    a11 = S_inv[0, 0]
    a12 = S_inv[0, 1]
    a22 = S_inv[1, 1]
    logN = math.log(N)
    C = _consts(P)
    if P[15] > 0.5:  # seed literal viscous law b = 0.0049 - 0.0002 (T + 30)
        b0, b1 = 0.0049 - 0.0002 * 30.0, -0.0002
    else:  # spec: b = 1e-3 (0.049 - 0.0002 (T + 30))
        b0, b1 = 1e-3 * (0.049 - 0.0002 * 30.0), -1e-3 * 0.0002
    tn_amp = P[7] * P[10] * P[11] * P[11]
    w_a = P[11]

    for i in range(N):
        T[i] = T_lo + (T_hi - T_lo) * rng.random()
    if design == 1:
        for i in range(N):
            I[i] = y[0, 1] + init_sd[0] * rng.standard_normal()
            W[i] = y[0, 0] + init_sd[1] * rng.standard_normal()
    for i in range(N):
        lw[i] = -logN
        wn[i] = 1.0 / N
    # prior row
    m = 0.0
    for i in range(N):
        m += wn[i] * T[i]
    v = 0.0
    for i in range(N):
        v += wn[i] * (T[i] - m) ** 2
    out_mean[0] = m
    out_std[0] = math.sqrt(v)
    out_ess[0] = N
    if want_quantiles:
        out_qlo[0] = _weighted_quantile(T, wn, q_lo, order, cw)
        out_qhi[0] = _weighted_quantile(T, wn, q_hi, order, cw)
    win_sum = 0.0
    win_cnt = 0

    for k in range(1, K):
        t = t0 + (k - 1) * dt
        Vk = V[k - 1]
        tn0 = tn_amp * math.sin(w_a * t)
        tn1 = tn_amp * math.sin(w_a * (t + 0.5 * dt))
        tn2 = tn_amp * math.sin(w_a * (t + dt))
        yw = y[k, 0]
        yI = y[k, 1]
        # --- prediction: T random walk, then RK4 per particle with its own T
        for i in range(N):
            T[i] += q_T * rng.standard_normal()
        if design == 1 and q_I > 0.0:
            for i in range(N):
                I2[i] = q_I * rng.standard_normal()
        if design == 1 and q_w > 0.0:
            for i in range(N):
                W2[i] = q_w * rng.standard_normal()
        _predict_loglik(I, W, T, ll, N, design, y[k - 1, 0], y[k - 1, 1], yw, yI, Vk, tn0, tn1,
                        tn2, dt, b0, b1, a11, a12, a22, log_norm, C)
        if design == 1 and (q_I > 0.0 or q_w > 0.0):
            for i in range(N):
                if q_I > 0.0:
                    I[i] += I2[i]
                if q_w > 0.0:
                    W[i] += W2[i]
                e0 = yw - W[i]
                e1 = yI - I[i]
                ll[i] = -0.5 * (a11 * e0 * e0 + 2.0 * a12 * e0 * e1 + a22 * e1 * e1) - log_norm
        llmax = -np.inf
        for i in range(N):
            if ll[i] != ll[i]:  # NaN prediction (diverged particle): zero likelihood
                ll[i] = -np.inf
            if ll[i] > llmax:
                llmax = ll[i]
        # --- weight update; ls_data = log sum_i exp(lw_i + ll_i), the data log-likelihood
        ls_data = 0.0
        if variant >= 2:
            for i in range(N):
                T2[i] = lw[i] + ll[i]
            ls_data = _normalise(T2, cw)
        if variant == 2:
            c = apf_c0 / (apf_c0 - Vk)
            ncl = 0
            tot = 0.0
            for i in range(N):
                beta = 1.0 / N - wn[i] * math.exp(ll[i])
                sb = 1.0 if beta > 0.0 else (-1.0 if beta < 0.0 else 0.0)
                wt = 1.0 - math.exp(c * (beta - apf_c1 * sb))
                if wt < 0.0:
                    wt = 0.0
                    ncl += 1
                T2[i] = wt
                tot += wt
            out_clip[k] = ncl
            if tot > 0.0:
                for i in range(N):
                    lw[i] = math.log(T2[i]) if T2[i] > 0.0 else -np.inf
            else:
                for i in range(N):
                    lw[i] += ll[i]
            ls = _normalise(lw, wn)
        elif variant == 3:
            # largest gamma in [1, gmax] with ESS(lw + gamma ll) >= target N (bisection in log)
            g = 1.0
            if _ess(cw) > temper_target * N:
                lo = 0.0
                hi = temper_log_gmax
                for i in range(N):
                    T2[i] = lw[i] + math.exp(hi) * ll[i]
                _normalise(T2, cw)
                if _ess(cw) >= temper_target * N:
                    lo = hi
                else:
                    for _it in range(30):
                        mid = 0.5 * (lo + hi)
                        gm = math.exp(mid)
                        for i in range(N):
                            T2[i] = lw[i] + gm * ll[i]
                        _normalise(T2, cw)
                        if _ess(cw) >= temper_target * N:
                            lo = mid
                        else:
                            hi = mid
                g = math.exp(lo)
            out_gamma[k] = g
            for i in range(N):
                lw[i] += g * ll[i]
            ls = _normalise(lw, wn)
        else:
            for i in range(N):
                lw[i] += ll[i]
            ls = _normalise(lw, wn)
        if variant < 2:
            ls_data = ls
        act = 0
        if not ls > -np.inf:  # every weight zero: documented reset to equal weights
            for i in range(N):
                lw[i] = -logN
                wn[i] = 1.0 / N
            act = 3
        out_ll[k] = ls_data
        # --- estimates
        m = 0.0
        for i in range(N):
            m += wn[i] * T[i]
        v = 0.0
        for i in range(N):
            v += wn[i] * (T[i] - m) ** 2
        out_mean[k] = m
        out_std[k] = math.sqrt(v)
        if want_quantiles:
            out_qlo[k] = _weighted_quantile(T, wn, q_lo, order, cw)
            out_qhi[k] = _weighted_quantile(T, wn, q_hi, order, cw)
        ess = _ess(wn)
        out_ess[k] = ess
        # --- resampling / adaptive spread
        spread = False
        if variant == 1:
            win_sum += math.exp(llmax)
            win_cnt += 1
            if win_cnt >= adapt_window and math.log(win_sum / win_cnt) < log_p_eff:
                spread = True
        if spread:
            for i in range(N):
                T[i] = m + adapt_spread * rng.standard_normal()
                lw[i] = -logN
                wn[i] = 1.0 / N
            win_sum = 0.0
            win_cnt = 0
            act = 2
        elif ess < ess_frac * N:
            u = rng.random()
            _systematic(wn, u, idx, cw)
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
            for i in range(N):
                lw[i] = -logN
                wn[i] = 1.0 / N
            act = 1
        out_act[k] = act
    return (out_mean, out_std, out_qlo, out_qhi, out_ess, out_act, out_clip, out_gamma, out_ll)
