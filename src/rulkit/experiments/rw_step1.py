"""Step 1 of the reaction-wheel lubrication prognostics: estimate the lubricant temperature
T_lub from wheel speed and motor current (spec rw-lubrication.md section 3; seed 001 section
3.1, eqs 13-17 and 28; seed 000 section 3.2 and eq. 27), and the Table 5 experiment (spec
section 6).

Estimators (all with the temperature random walk T_k = T_{k-1} + q_T xi_k):

- ``variant="pf"``: SIR with ESS-triggered systematic resampling (seed eqs 13-17).
- ``variant="adaptive"``: PF + adaptive resampling (seed 001 section 3.1.1) [R]: the mean, since
  the last adaptive trigger, of the largest unnormalised likelihood max_i p(y_k | x_k^i) is
  compared with p_eff = p_peak e^-adapt_log_drop after >= adapt_window steps; below it the
  particles are spread around the estimate (N(T^, adapt_spread^2)) with equal weights and the
  window restarts; otherwise ordinary ESS resampling. p_peak is the peak of the likelihood
  density in use (1 / (2 pi sigma_w sigma_I) for F2; the inflated covariance for F1).
- ``variant="apf_eq28"``: APF, seed 001 eq. 28 as printed: w~ = 1 - exp(c (beta - 0.6 sign beta)),
  c = 10 / (10 - V_comm), beta = 1/N - w_prev p(y|x), p the (unnormalised-across-particles)
  Gaussian pdf; negative w~ clipped to 0 (counted per step in ``n_clipped``); if all clip, the
  plain update w_prev p; then normalised.
- ``variant="apf_tempered"``: the intent of eq. 28 in a well-defined form: w ~ w_prev p^gamma
  with the largest gamma in [1, temper_gamma_max] keeping ESS >= temper_target N.

Prediction designs (spec section 3): ``"F1"`` each particle predicts y_k by one RK4 step from
the measured y_{k-1} with its own T; the likelihood covariance is inflated to
S = R + Phi R Phi^T for the noise in that start (Phi the Jacobian of the RK4 step, by central
differences at the 1 V / 23 C steady state). ``"F2"`` particles carry their own [I, w].

Two implementations give the same numbers (tested): the fused numba kernel
(:mod:`rulkit.experiments.rw_step1_kernels`, default) and a vectorised numpy reference path
built on the engine (:func:`run_step1_numpy`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from rulkit.experiments import rw_step1_kernels as kern
from rulkit.models.reaction_wheel import (
    NOISE_LEVELS,
    IthacoParams,
    ReactionWheel,
    rk4_wheel_step,
)

FloatArray = np.ndarray
Design = Literal["F1", "F2"]
Variant = Literal["pf", "adaptive", "apf_eq28", "apf_tempered"]

#: Seed 001 Table 5 (RMSPE of T, %), keyed by (method, noise) -> values for N = 50..350.
PAPER_TABLE5: dict[tuple[str, str], tuple[float, ...]] = {
    ("adaptive", "low"): (2.359, 2.216, 2.012, 1.983, 2.015, 1.935, 1.919),
    ("apf_eq28", "low"): (2.554, 2.471, 2.292, 2.340, 2.378, 2.436, 2.305),
    ("adaptive", "high"): (3.596, 3.118, 2.745, 2.742, 2.735, 2.707, 2.748),
    ("apf_eq28", "high"): (3.048, 2.691, 2.697, 2.605, 2.589, 2.496, 2.480),
}
TABLE5_N: tuple[int, ...] = (50, 100, 150, 200, 250, 300, 350)


@dataclass(frozen=True)
class Step1Config:
    """Settings of a step-1 estimator. Every value the seeds leave open is [R] (spec section 3).

    q_T: random-walk step of T per sample (C); T_prior: uniform prior bounds (C); q_I, q_w:
    process noise of the F2 particles' [I, w] per step (0: the wheel is deterministic given T);
    ess_threshold: resample when ESS < ess_threshold N (N_th = N/2).
    """

    design: Design = "F2"
    variant: Variant = "adaptive"
    n_particles: int = 200
    q_T: float = 0.02
    T_prior: tuple[float, float] = (15.0, 45.0)
    q_I: float = 0.0
    q_w: float = 0.0
    ess_threshold: float = 0.5
    adapt_window: int = 20
    adapt_log_drop: float = 4.0
    adapt_spread: float = 3.0
    apf_c0: float = 10.0
    apf_c1: float = 0.6
    temper_target: float = 0.5
    temper_gamma_max: float = 1e4
    quantiles: tuple[float, float] = (0.025, 0.975)

    def __post_init__(self) -> None:
        if self.design not in kern.DESIGNS:
            raise ValueError(f"design: expected one of {sorted(kern.DESIGNS)}, got {self.design!r}")
        if self.variant not in kern.VARIANTS:
            raise ValueError(
                f"variant: expected one of {sorted(kern.VARIANTS)}, got {self.variant!r}"
            )
        if int(self.n_particles) < 2:
            raise ValueError(f"n_particles: need at least 2, got {self.n_particles}")
        lo, hi = self.T_prior
        if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
            raise ValueError(f"T_prior: expected finite (lo, hi) with lo < hi, got {self.T_prior}")
        for name in ("q_T", "q_I", "q_w", "adapt_spread"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name}: must be >= 0, got {getattr(self, name)}")
        if not 0 < self.ess_threshold <= 1:
            raise ValueError(f"ess_threshold: expected 0 < value <= 1, got {self.ess_threshold}")
        if not 0 < self.temper_target <= 1 or self.temper_gamma_max < 1:
            raise ValueError("temper_target must be in (0, 1] and temper_gamma_max >= 1")
        q0, q1 = self.quantiles
        if not 0 < q0 < q1 < 1:
            raise ValueError(f"quantiles: expected 0 < lo < hi < 1, got {self.quantiles}")


@dataclass(frozen=True)
class Step1Result:
    """Per-sample output of a step-1 filter (all arrays (K,); row 0 is the prior).

    ``action``: 0 none, 1 ESS resampling, 2 adaptive spread, 3 all weights zero (reset).
    ``n_clipped``: APF eq. 28 weights clipped at 0 per step. ``gamma``: tempering exponent.
    """

    t: FloatArray
    T_mean: FloatArray
    T_std: FloatArray
    T_lo: FloatArray
    T_hi: FloatArray
    ess: FloatArray
    action: FloatArray
    n_clipped: FloatArray
    gamma: FloatArray
    loglik: FloatArray
    config: Step1Config = field(repr=False)


# --------------------------------------------------------------------------------------------
# likelihood covariance


def _rk4_jacobian(sigma: tuple[float, float], params: IthacoParams, dt: float) -> np.ndarray:
    """Jacobian (in output order [w, I]) of one RK4 step w.r.t. its start, by central
    differences at the 1 V, 23 C steady state (near-constant: the wheel is almost linear)."""
    model = ReactionWheel(params, noise=sigma)
    x0 = model.steady_state(1.0, 23.0)
    J = np.empty((2, 2))
    for j, h in ((0, 1e-4), (1, 1e-3)):  # state order [I, w]
        e = np.zeros(2)
        e[j] = h
        xp = rk4_wheel_step((x0 + e)[None], 1.0, 23.0, 0.0, dt, params)[0]
        xm = rk4_wheel_step((x0 - e)[None], 1.0, 23.0, 0.0, dt, params)[0]
        J[:, j] = (xp - xm) / (2 * h)
    P = np.array([[0, 1], [1, 0]])  # [I, w] <-> [w, I]
    return P @ J @ P


def likelihood_covariance(
    design: Design, sigma: tuple[float, float], params: IthacoParams | None = None,
    dt: float = 0.05,
) -> np.ndarray:
    """Covariance S of the [w, I] prediction error used in the likelihood (spec section 3).

    F2: the measurement noise R = diag(sigma_w^2, sigma_I^2). F1: R + Phi R Phi^T, adding the
    measurement noise carried by the measured start y_{k-1} through one RK4 step.
    """
    sw, sI = sigma
    R = np.diag([sw**2, sI**2])
    if design == "F2":
        return R
    Phi = _rk4_jacobian(sigma, params or IthacoParams(), dt)
    return R + Phi @ R @ Phi.T


def _prepare(
    y: FloatArray, V: FloatArray, cfg: Step1Config, sigma: tuple[float, float],
    params: IthacoParams, dt: float,
) -> dict[str, Any]:
    y = np.ascontiguousarray(y, dtype=np.float64)
    V = np.ascontiguousarray(V, dtype=np.float64)
    if y.ndim != 2 or y.shape[1] != 2 or y.shape[0] < 2:
        raise ValueError(f"y: expected shape (K >= 2, 2) holding [w, I_m], got {y.shape}")
    if V.shape != (y.shape[0],):
        raise ValueError(f"V: expected shape ({y.shape[0]},), got {V.shape}")
    if not (np.all(np.isfinite(y)) and np.all(np.isfinite(V))):
        raise ValueError("y and V must be finite (validate telemetry with rulkit.data.telemetry)")
    if not dt > 0:
        raise ValueError(f"dt: must be positive, got {dt}")
    S = likelihood_covariance(cfg.design, sigma, params, dt)
    S_inv = np.linalg.inv(S)
    log_norm = math.log(2 * math.pi) + 0.5 * math.log(np.linalg.det(S))
    return {
        "y": y, "V": V, "S_inv": S_inv, "log_norm": log_norm,
        "log_p_eff": -log_norm - cfg.adapt_log_drop,
        "init_sd": np.array([sigma[1], sigma[0]]),
    }


def run_step1(
    y: FloatArray,
    V: FloatArray,
    rng: np.random.Generator,
    config: Step1Config | None = None,
    *,
    sigma: tuple[float, float] = NOISE_LEVELS["low"],
    dt: float = 0.05,
    t0: float = 0.0,
    params: IthacoParams | None = None,
    backend: Literal["numba", "numpy"] = "numba",
    quantiles: bool = True,
) -> Step1Result:
    """Run a step-1 temperature estimator over ``y`` (K, 2) = [w (rad/s), I_m (A)] with
    commanded voltage ``V`` (K,) sampled every ``dt`` s (spec section 3).

    ``sigma = (sigma_w, sigma_I)`` is the measurement-noise level assumed by the filter.
    ``backend="numba"`` runs the fused kernel, ``"numpy"`` the vectorised reference path
    (same numbers for the same ``rng`` state). ``quantiles=False`` skips the per-step weighted
    quantiles (T_lo/T_hi are then NaN), which costs a sort per step.
    """
    cfg = config or Step1Config()
    p = params or IthacoParams()
    d = _prepare(y, V, cfg, sigma, p, dt)
    if backend == "numpy":
        return run_step1_numpy(d, cfg, rng, p, dt, t0, quantiles)
    if backend != "numba":
        raise ValueError(f"backend: expected 'numba' or 'numpy', got {backend!r}")
    out = kern.pf_kernel(
        d["y"], d["V"], float(t0), float(dt), kern.DESIGNS[cfg.design], kern.VARIANTS[cfg.variant],
        int(cfg.n_particles), float(cfg.T_prior[0]), float(cfg.T_prior[1]), float(cfg.q_T),
        float(cfg.q_I), float(cfg.q_w), d["init_sd"], d["S_inv"], float(d["log_norm"]),
        float(cfg.ess_threshold), int(cfg.adapt_window), float(d["log_p_eff"]),
        float(cfg.adapt_spread), float(cfg.apf_c0), float(cfg.apf_c1), float(cfg.temper_target),
        math.log(cfg.temper_gamma_max), bool(quantiles), float(cfg.quantiles[0]),
        float(cfg.quantiles[1]), kern.pack_params(p), rng,
    )
    t = t0 + dt * np.arange(d["y"].shape[0])
    return Step1Result(t, *out, config=cfg)


# --------------------------------------------------------------------------------------------
# numpy reference path: the engine's ParticleFilter (per-step API) with plug-ins; same random
# draws and algebra as the fused kernel


def run_step1_numpy(
    d: dict[str, Any], cfg: Step1Config, rng: np.random.Generator, p: IthacoParams, dt: float,
    t0: float, quantiles: bool,
) -> Step1Result:
    """Vectorised numpy reference of :func:`rulkit.experiments.rw_step1_kernels.pf_kernel`.

    Built on :class:`rulkit.estimation.particle.ParticleFilter`: ``transition`` (T random walk,
    F2 RK4 via :func:`rulkit.integrate.rk4_step`), ``log_likelihood``, ``weight_update`` for
    the APF variants, ``resample`` (engine systematic) for the ESS rule; the adaptive spread is
    applied between steps. Particles are [T] (F1) or [T, I, w] (F2).
    """
    from rulkit.estimation.particle import ParticleFilter, weighted_quantile

    y, V = d["y"], d["V"]
    S_inv, log_norm = d["S_inv"], d["log_norm"]
    K, N = y.shape[0], int(cfg.n_particles)
    lo, hi = cfg.T_prior
    f2 = cfg.design == "F2"
    pred: dict[str, FloatArray] = {}

    # The engine counts assimilated measurements from 0; ours are y[1:], so engine step j is
    # our sample k = j + 1 (y[0] only initialises).
    def transition(x: FloatArray, j: int, g: np.random.Generator) -> FloatArray:
        k = j + 1
        T = x[:, 0] + cfg.q_T * g.standard_normal(N)
        if not f2:
            return T[:, None]
        nI = cfg.q_I * g.standard_normal(N) if cfg.q_I > 0 else 0.0
        nw = cfg.q_w * g.standard_normal(N) if cfg.q_w > 0 else 0.0
        X = rk4_wheel_step(x[:, 1:], V[k - 1], T, t0 + (k - 1) * dt, dt, p)
        return np.stack([T, X[:, 0] + nI, X[:, 1] + nw], axis=1)

    def log_likelihood(x: FloatArray, yk: FloatArray, j: int) -> FloatArray:
        k = j + 1
        if f2:
            I, w = x[:, 1], x[:, 2]
        else:
            start = np.broadcast_to(np.array([y[k - 1, 1], y[k - 1, 0]]), (N, 2))
            X = rk4_wheel_step(start, V[k - 1], x[:, 0], t0 + (k - 1) * dt, dt, p)
            I, w = X[:, 0], X[:, 1]
        e0 = yk[0] - w
        e1 = yk[1] - I
        ll = -0.5 * (S_inv[0, 0] * e0 * e0 + 2.0 * S_inv[0, 1] * e0 * e1
                     + S_inv[1, 1] * e1 * e1) - log_norm
        ll = np.where(np.isnan(ll), -np.inf, ll)
        pred["llmax"] = ll.max()
        pred["ll"] = ll
        return ll

    def apf_eq28(logw: FloatArray, ll: FloatArray, state: Any) -> FloatArray:
        """Seed 001 eq. 28 with clipping of negative weights (spec section 3)."""
        c = cfg.apf_c0 / (cfg.apf_c0 - V[state.k])  # V[k-1], k = state.k + 1
        beta = 1.0 / N - state.weights * np.exp(ll)
        wt = 1.0 - np.exp(c * (beta - cfg.apf_c1 * np.sign(beta)))
        state.info["n_clipped"] = int(np.count_nonzero(wt < 0))
        wt = np.maximum(wt, 0.0)
        if not wt.sum() > 0:
            return logw + ll
        with np.errstate(divide="ignore"):
            return np.log(wt)

    def tempered(logw: FloatArray, ll: FloatArray, state: Any) -> FloatArray:
        g = _temper_gamma_np(logw, ll, cfg, N)
        state.info["gamma"] = g
        return logw + g * ll

    wu = {"apf_eq28": apf_eq28, "apf_tempered": tempered}.get(cfg.variant)
    pf = ParticleFilter(transition, log_likelihood, resampler="systematic",
                        ess_threshold=cfg.ess_threshold, weight_update=wu, recovery="reset")
    T0 = lo + (hi - lo) * rng.random(N)
    if f2:
        Z = rng.standard_normal((N, 2))
        x0 = np.stack([T0, y[0, 1] + d["init_sd"][0] * Z[:, 0],
                       y[0, 0] + d["init_sd"][1] * Z[:, 1]], axis=1)
    else:
        x0 = T0[:, None]
    state = pf.initialise(x0, rng)
    out = {k: np.full(K, np.nan) for k in ("mean", "std", "qlo", "qhi", "ess")}
    act = np.zeros(K, dtype=np.int8)
    clip = np.zeros(K, dtype=np.int64)
    gam = np.ones(K)
    lls = np.zeros(K)

    def record(k: int) -> float:
        T, w = state.particles[:, 0], state.weights
        m = float(np.sum(w * T))
        out["mean"][k] = m
        out["std"][k] = math.sqrt(float(np.sum(w * (T - m) ** 2)))
        if quantiles:
            out["qlo"][k], out["qhi"][k] = weighted_quantile(T, w, np.array(cfg.quantiles))
        out["ess"][k] = state.ess
        return m

    record(0)
    win_sum, win_cnt = 0.0, 0
    for k in range(1, K):
        state.info.clear()
        lw_prev = state.logw
        pf.update(state, y[k])
        clip[k] = state.info.get("n_clipped", 0)
        gam[k] = state.info.get("gamma", 1.0)
        a = 3 if state.reset else 0
        lls[k] = _logsumexp_np(lw_prev + pred["ll"])
        m = record(k)
        spread = False
        if cfg.variant == "adaptive":
            win_sum += math.exp(pred["llmax"])
            win_cnt += 1
            spread = win_cnt >= cfg.adapt_window and math.log(win_sum / win_cnt) < d["log_p_eff"]
        if spread:
            x = state.particles.copy()
            x[:, 0] = m + cfg.adapt_spread * rng.standard_normal(N)
            state.particles = x
            state.logw = np.full(N, -math.log(N))
            state.weights = np.full(N, 1.0 / N)
            state.ess = float(N)
            win_sum, win_cnt, a = 0.0, 0, 2
        elif state.ess < cfg.ess_threshold * N:
            pf.resample(state)
            a = 1
        act[k] = a
    tt = t0 + dt * np.arange(K)
    return Step1Result(tt, out["mean"], out["std"], out["qlo"], out["qhi"], out["ess"], act,
                       clip, gam, lls, config=cfg)


def _logsumexp_np(a: FloatArray) -> float:
    m = a.max()
    if not m > -np.inf:
        return -np.inf
    return float(m + math.log(np.exp(a - m).sum()))


def _normalise_np(lw: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    mx = lw.max()
    if not mx > -np.inf:
        return lw, np.full(lw.size, 1.0 / lw.size), -np.inf
    e = np.exp(lw - mx)
    s = e.sum()
    ls = float(mx + math.log(s))
    return lw - ls, e / s, ls


def _temper_gamma_np(lw: FloatArray, ll: FloatArray, cfg: Step1Config, N: int) -> float:
    """Largest gamma in [1, gamma_max] with ESS(lw + gamma ll) >= target N (bisection in
    log gamma, 30 halvings), 1 when the plain update is already below the target."""
    def ess(g: float) -> float:
        _, w, _ = _normalise_np(lw + g * ll)
        return 1.0 / float(np.sum(w * w))

    target = cfg.temper_target * N
    if not ess(1.0) > target:
        return 1.0
    lo, hi = 0.0, math.log(cfg.temper_gamma_max)
    if ess(math.exp(hi)) >= target:
        return math.exp(hi)
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if ess(math.exp(mid)) >= target:
            lo = mid
        else:
            hi = mid
    return math.exp(lo)
