"""Step 1 of the reaction-wheel lubrication prognostics: estimate the lubricant temperature
T_lub from wheel speed and motor current (docs/systems/reaction-wheel.md §3; seed 001 section
3.1, eqs 13-17 and 28; seed 000 section 3.2 and eq. 27). The Table 5 experiment and its
figures (docs/systems/reaction-wheel.md §6) are in
:mod:`rulkit.systems.reaction_wheel.temperature.study`.

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
- ``variant="apf"``: the auxiliary particle filter of Pitt and Shephard (1999), which eq. 28
  names but does not implement: first-stage weights w_{k-1} p(y_k | mu_k^i) from each
  particle's point prediction mu (its T held, [I, w] one RK4 step ahead) choose the ancestors,
  which are then propagated and weighted by p(y_k | x_k) / p(y_k | mu_k^ancestor). Why eq. 28
  as printed fails: :func:`apf_eq28_weights` and docs/systems/reaction-wheel.md §3.2.

Prediction designs (docs/systems/reaction-wheel.md §3): ``"F1"`` each particle predicts y_k by one
RK4 step from the measured y_{k-1} with its own T; the likelihood covariance is inflated to
S = R + Phi R Phi^T for the noise in that start (Phi the Jacobian of the RK4 step, by central
differences at the 1 V / 23 C steady state). ``"F2"`` particles carry their own [I, w].

Two implementations give the same numbers (tested): the fused numba kernel
(:mod:`rulkit.systems.reaction_wheel.temperature.kernels`, default) and a vectorised numpy
reference path
built on the engine (:func:`filter_temperature_numpy`).

Beyond the seeds: the Rao-Blackwellised PF over T with a Kalman filter on [I, w] per particle
(:mod:`rulkit.systems.reaction_wheel.temperature.rbpf`), as Table 5 designs "RB", "RB05", "RBJ"
(``run_table5(designs=...)``) and ``estimate_temperature(method="rbpf")``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from rulkit.estimation.batched import ess_rows, normalise_rows, weighted_quantile_rows
from rulkit.systems.reaction_wheel.temperature import kernels as kern
from rulkit.systems.reaction_wheel.wheel import (
    NOISE_LEVELS,
    IthacoParams,
    ReactionWheel,
    check_measurements,
    rk4_wheel_step,
)
from rulkit.systems.reaction_wheel.wheel_kernels import pack_params

FloatArray = np.ndarray


Design = Literal["F1", "F2"]


Variant = Literal["pf", "adaptive", "apf_eq28", "apf_tempered", "apf"]


#: Outlier gate of :func:`estimate_temperature`'s particle filters (squared Mahalanobis
#: prediction error of the best particle, 2 degrees of freedom: exceeded by chance with
#: probability e^-12.5 ~ 4e-6 per sample for a particle on the truth). Beyond the seeds; the
#: paper's filters (Table 5) run without it.
DEFAULT_GATE_D2 = 25.0


@dataclass(frozen=True)
class TemperatureConfig:
    """Settings of a step-1 estimator. Every value the seeds leave open is [R]
    (docs/systems/reaction-wheel.md §3).

    q_T: random-walk step of T per sample (C); T_prior: uniform prior bounds (C); q_I, q_w:
    process noise of the F2 particles' [I, w] per step (0: the wheel is deterministic given T);
    ess_threshold: resample when ESS < ess_threshold N (N_th = N/2). gate_d2: outlier gate
    (beyond the seeds): a sample whose best particle has squared Mahalanobis prediction error
    d^2 > gate_d2 is not trusted (weights kept, flagged); after ``reanchor_after`` untrusted
    samples in a row the F2 particles' [I, w] are redrawn around the measurement and T and the
    weights return to their values ``rollback`` samples before the first untrusted one
    (recovery from a corrupted command sample). inf (the default here, the paper's filters)
    disables it; :func:`estimate_temperature` uses :data:`DEFAULT_GATE_D2`.
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
    gate_d2: float = math.inf
    reanchor_after: int = 1
    rollback: int = 8

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
        if not self.gate_d2 > 0 or int(self.reanchor_after) < 1 or int(self.rollback) < 0:
            raise ValueError("gate_d2 must be > 0 (inf: no gate), reanchor_after >= 1 and "
                             "rollback >= 0")
        q0, q1 = self.quantiles
        if not 0 < q0 < q1 < 1:
            raise ValueError(f"quantiles: expected 0 < lo < hi < 1, got {self.quantiles}")


@dataclass(frozen=True)
class TemperatureResult:
    """Per-sample output of a step-1 filter (all arrays (K,); row 0 is the prior).

    ``action``: 0 none, 1 ESS resampling, 2 adaptive spread, 3 all weights zero (reset),
    4 untrusted sample (weights kept), 5 untrusted and the F2 [I, w] redrawn around the
    measurement. ``n_clipped``: APF eq. 28 weights clipped at 0 per step. ``gamma``: tempering
    exponent. ``untrusted``: 1 where the outlier gate refused the sample (``gate_d2``).
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
    untrusted: FloatArray
    config: TemperatureConfig = field(repr=False)


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
    """Covariance S of the [w, I] prediction error used in the likelihood
    (docs/systems/reaction-wheel.md §3).

    F2: the measurement noise R = diag(sigma_w^2, sigma_I^2). F1: R + Phi R Phi^T, adding the
    measurement noise carried by the measured start y_{k-1} through one RK4 step.
    """
    sw, sI = sigma
    R = np.diag([sw**2, sI**2])
    if design == "F2":
        return R
    Phi = _rk4_jacobian(sigma, params or IthacoParams(), dt)
    return R + Phi @ R @ Phi.T


def temperature_outputs(K: int) -> dict[str, FloatArray]:
    """The per-sample summaries a numpy reference path fills, NaN until written: ``"mean"``,
    ``"std"``, ``"lo"``, ``"hi"`` (see :func:`summarise_temperature`) and ``"ess"``, each (K,)."""
    return {c: np.full(K, np.nan) for c in ("mean", "std", "lo", "hi", "ess")}


def summarise_temperature(out: dict[str, FloatArray], k: int, T: FloatArray, w: FloatArray,
                          levels: tuple[float, float] | None) -> float:
    """Write sample ``k``'s summary of the particles' temperatures ``T`` (N,) with normalised
    weights ``w`` into ``out`` (from :func:`temperature_outputs`): the weighted mean and std
    and, when ``levels`` is given, the weighted quantiles at those levels as ``"lo"``, ``"hi"``.
    Returns the mean. The numpy reference paths' twin of the kernels' per-sample outputs."""
    m = float(np.sum(w * T))
    out["mean"][k] = m
    out["std"][k] = math.sqrt(max(float(np.sum(w * (T - m) ** 2)), 0.0))
    if levels is not None:
        out["lo"][k], out["hi"][k] = weighted_quantile_rows(T, w, np.array(levels))
    return m


def _prepare(
    y: FloatArray, V: FloatArray, cfg: TemperatureConfig, sigma: tuple[float, float],
    params: IthacoParams, dt: float,
) -> dict[str, Any]:
    y, V, _, _ = check_measurements(y, V, sigma, dt)
    S = likelihood_covariance(cfg.design, sigma, params, dt)
    S_inv = np.linalg.inv(S)
    log_norm = math.log(2 * math.pi) + 0.5 * math.log(np.linalg.det(S))
    return {
        "y": y, "V": V, "S_inv": S_inv, "log_norm": log_norm,
        "log_p_eff": -log_norm - cfg.adapt_log_drop,
        "init_sd": np.array([sigma[1], sigma[0]]),
    }


def filter_temperature(
    y: FloatArray,
    V: FloatArray,
    rng: np.random.Generator,
    config: TemperatureConfig | None = None,
    *,
    sigma: tuple[float, float] = NOISE_LEVELS["low"],
    dt: float = 0.05,
    t0: float = 0.0,
    params: IthacoParams | None = None,
    backend: Literal["numba", "numpy"] = "numba",
    quantiles: bool = True,
) -> TemperatureResult:
    """Run a step-1 temperature estimator over ``y`` (K, 2) = [w (rad/s), I_m (A)] with
    commanded voltage ``V`` (K,) sampled every ``dt`` s (docs/systems/reaction-wheel.md §3).

    ``sigma = (sigma_w, sigma_I)`` is the measurement-noise level assumed by the filter.
    ``backend="numba"`` runs the fused kernel, ``"numpy"`` the vectorised reference path
    (same numbers for the same ``rng`` state). ``quantiles=False`` skips the per-step weighted
    quantiles (T_lo/T_hi are then NaN), which costs a sort per step.
    """
    cfg = config or TemperatureConfig()
    p = params or IthacoParams()
    d = _prepare(y, V, cfg, sigma, p, dt)
    if backend == "numpy" and cfg.variant == "apf":
        if math.isfinite(cfg.gate_d2):
            raise ValueError("backend 'numpy' (the reference path) has no outlier gate: "
                             "use gate_d2=inf")
        return apf_numpy(d, cfg, rng, p, dt, t0, quantiles)
    if backend == "numpy":
        if math.isfinite(cfg.gate_d2):
            raise ValueError("backend 'numpy' (the reference path) has no outlier gate: "
                             "use gate_d2=inf")
        return filter_temperature_numpy(d, cfg, rng, p, dt, t0, quantiles)
    if backend != "numba":
        raise ValueError(f"backend: expected 'numba' or 'numpy', got {backend!r}")
    inp = kern.KernelInputs(d["y"], d["V"], d["S_inv"], d["init_sd"], pack_params(p))
    settings = kernel_settings(cfg, d, t0, dt, quantiles)
    out = kern.pf_kernel(inp, settings, rng)
    t = t0 + dt * np.arange(d["y"].shape[0])
    T_mean, T_std, T_lo, T_hi, ess, action, n_clipped, gamma, loglik, untrusted = out
    return TemperatureResult(t, T_mean, T_std, T_lo, T_hi, ess, action, n_clipped, gamma, loglik,
                             untrusted, config=cfg)


def kernel_settings(cfg: TemperatureConfig, d: dict[str, Any], t0: float, dt: float,
                    quantiles: bool = True) -> kern.KernelSettings:
    """The fused kernel's scalar settings for ``cfg`` (``d`` from :func:`_prepare`)."""
    return kern.KernelSettings(
        t0=float(t0), dt=float(dt), design=kern.DESIGNS[cfg.design],
        variant=kern.VARIANTS[cfg.variant], n=int(cfg.n_particles), T_lo=float(cfg.T_prior[0]),
        T_hi=float(cfg.T_prior[1]), q_T=float(cfg.q_T), q_I=float(cfg.q_I), q_w=float(cfg.q_w),
        log_norm=float(d["log_norm"]), ess_frac=float(cfg.ess_threshold),
        adapt_window=int(cfg.adapt_window), log_p_eff=float(d["log_p_eff"]),
        adapt_spread=float(cfg.adapt_spread), apf_c0=float(cfg.apf_c0),
        apf_c1=float(cfg.apf_c1), temper_target=float(cfg.temper_target),
        temper_log_gmax=math.log(cfg.temper_gamma_max), want_quantiles=bool(quantiles),
        q_lo=float(cfg.quantiles[0]), q_hi=float(cfg.quantiles[1]),
        gate_d2=float(cfg.gate_d2), reanchor_after=int(cfg.reanchor_after),
        rollback=int(cfg.rollback),
    )


def _numpy_particle_filter(d: dict[str, Any], cfg: TemperatureConfig, p: IthacoParams,
                           dt: float, t0: float, pred: dict[str, FloatArray]) -> Any:
    """The engine's :class:`~rulkit.estimation.particle.ParticleFilter` of
    :func:`filter_temperature_numpy`: its transition, likelihood (which leaves the last
    log-likelihoods and their maximum in ``pred``) and the APF variants' weight update."""
    from rulkit.estimation.particle import ParticleFilter

    y, V = d["y"], d["V"]
    S_inv, log_norm = d["S_inv"], d["log_norm"]
    N = int(cfg.n_particles)
    f2 = cfg.design == "F2"

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
        """Seed 001 eq. 28 with clipping of negative weights (docs/systems/reaction-wheel.md §3)."""
        # V[k-1] with k = state.k + 1
        wt, state.info["n_clipped"] = apf_eq28_weights(state.weights, np.exp(ll), V[state.k],
                                                       cfg.apf_c0, cfg.apf_c1)
        if not wt.sum() > 0:
            return logw + ll
        with np.errstate(divide="ignore"):
            return np.log(wt)

    def tempered(logw: FloatArray, ll: FloatArray, state: Any) -> FloatArray:
        g = _temper_gamma_np(logw, ll, cfg, N)
        state.info["gamma"] = g
        return logw + g * ll

    wu = {"apf_eq28": apf_eq28, "apf_tempered": tempered}.get(cfg.variant)
    return ParticleFilter(transition, log_likelihood, resampler="systematic",
                        ess_threshold=cfg.ess_threshold, weight_update=wu, recovery="reset")


def _initial_particles(d: dict[str, Any], cfg: TemperatureConfig, rng: np.random.Generator
                       ) -> FloatArray:
    """The particles before the first sample: T uniform over the prior, and for F2 the
    current and speed around the first measurement."""
    y, N = d["y"], int(cfg.n_particles)
    lo, hi = cfg.T_prior
    T0 = lo + (hi - lo) * rng.random(N)
    if cfg.design == "F2":
        Z = rng.standard_normal((N, 2))
        x0 = np.stack([T0, y[0, 1] + d["init_sd"][0] * Z[:, 0],
                       y[0, 0] + d["init_sd"][1] * Z[:, 1]], axis=1)
    else:
        x0 = T0[:, None]
    return x0


def filter_temperature_numpy(
    d: dict[str, Any], cfg: TemperatureConfig, rng: np.random.Generator, p: IthacoParams, dt: float,
    t0: float, quantiles: bool,
) -> TemperatureResult:
    """Vectorised numpy reference of
    :func:`rulkit.systems.reaction_wheel.temperature.kernels.pf_kernel`.

    Built on :class:`rulkit.estimation.particle.ParticleFilter`: ``transition`` (T random walk,
    F2 RK4 via :func:`rulkit.integrate.rk4_step`), ``log_likelihood``, ``weight_update`` for
    the APF variants, ``resample`` (engine systematic) for the ESS rule; the adaptive spread is
    applied between steps. Particles are [T] (F1) or [T, I, w] (F2).
    """
    y = d["y"]
    K, N = y.shape[0], int(cfg.n_particles)
    pred: dict[str, FloatArray] = {}
    pf = _numpy_particle_filter(d, cfg, p, dt, t0, pred)
    state = pf.initialise(_initial_particles(d, cfg, rng), rng)
    out = temperature_outputs(K)
    levels = cfg.quantiles if quantiles else None
    act = np.zeros(K, dtype=np.int8)
    clip = np.zeros(K, dtype=np.int64)
    gam = np.ones(K)
    lls = np.zeros(K)

    def record(k: int) -> float:
        out["ess"][k] = state.ess
        return summarise_temperature(out, k, state.particles[:, 0], state.weights, levels)

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
    return TemperatureResult(tt, out["mean"], out["std"], out["lo"], out["hi"], out["ess"], act,
                       clip, gam, lls, np.zeros(K, dtype=np.int8), config=cfg)


def apf_numpy(
    d: dict[str, Any], cfg: TemperatureConfig, rng: np.random.Generator, p: IthacoParams,
    dt: float, t0: float, quantiles: bool,
) -> TemperatureResult:
    """Vectorised numpy reference of the auxiliary particle filter (variant "apf") of
    :func:`rulkit.systems.reaction_wheel.temperature.kernels.pf_steps`, without the outlier
    gate; the same draws in the same order (per step: one uniform for the first-stage
    systematic resampling, then the N normals of the T random walk)."""
    from rulkit.estimation.batched import systematic_rows

    y, V, S_inv, log_norm = d["y"], d["V"], d["S_inv"], d["log_norm"]
    K, N = y.shape[0], int(cfg.n_particles)
    lo, hi = cfg.T_prior
    f2 = cfg.design == "F2"
    T = lo + (hi - lo) * rng.random(N)
    Iw = np.zeros((N, 2))  # [I, w] per particle (F2)
    if f2:
        Z = rng.standard_normal((N, 2))
        Iw = np.column_stack([y[0, 1] + d["init_sd"][0] * Z[:, 0],
                              y[0, 0] + d["init_sd"][1] * Z[:, 1]])
    lw = np.full(N, -math.log(N))

    def loglik(X: FloatArray, k: int) -> FloatArray:
        e0, e1 = y[k, 0] - X[:, 1], y[k, 1] - X[:, 0]
        ll = -0.5 * (S_inv[0, 0] * e0 * e0 + 2.0 * S_inv[0, 1] * e0 * e1
                     + S_inv[1, 1] * e1 * e1) - log_norm
        return np.where(np.isnan(ll), -np.inf, ll)

    out = temperature_outputs(K)
    lls = np.zeros(K)

    def record(k: int) -> None:
        _, w, _ = normalise_rows(lw)
        summarise_temperature(out, k, T, w, cfg.quantiles if quantiles else None)
        out["ess"][k] = float(ess_rows(w))

    record(0)
    for k in range(1, K):
        tk = t0 + (k - 1) * dt
        start = Iw if f2 else np.broadcast_to(np.array([y[k - 1, 1], y[k - 1, 0]]), (N, 2))
        ll1 = loglik(rk4_wheel_step(start, V[k - 1], T, tk, dt, p), k)
        _, fw, ls_first = normalise_rows(lw + ll1)
        a = systematic_rows(fw, rng.random())
        T, Iw, ll1 = T[a] + cfg.q_T * rng.standard_normal(N), Iw[a], ll1[a]
        start = Iw if f2 else np.broadcast_to(np.array([y[k - 1, 1], y[k - 1, 0]]), (N, 2))
        X = rk4_wheel_step(start, V[k - 1], T, tk, dt, p)
        if f2:
            Iw = X
        lw, _, ls = normalise_rows(np.full(N, -math.log(N)) + loglik(X, k) - ll1)
        lls[k] = float(ls_first) + float(ls)
        record(k)
    act = np.full(K, 6, dtype=np.int8)
    act[0] = 0
    return TemperatureResult(t0 + dt * np.arange(K), out["mean"], out["std"], out["lo"],
                             out["hi"], out["ess"], act, np.zeros(K, dtype=np.int64), np.ones(K),
                             lls, np.zeros(K, dtype=np.int8), config=cfg)


def apf_eq28_weights(
    w_prev: FloatArray, p: FloatArray, V_comm: float, c0: float = 10.0, c1: float = 0.6
) -> tuple[FloatArray, int]:
    """Seed 001 eq. 28 as printed, made usable (docs/systems/reaction-wheel.md §3): returns the
    clipped, unnormalised weights ``max(0, 1 - exp(c (beta - c1 sign beta)))`` with ``c = c0 / (c0 -
    V_comm)``, ``beta = 1/N - w_prev p`` (``p`` the likelihood pdf values), and the number of
    clipped (negative) weights. The printed rule maps weights into (1 - e^{c(1/N - c1)}, 1):
    it compresses rather than amplifies, and is negative for -c1 < beta < 0."""
    n = w_prev.size
    c = c0 / (c0 - V_comm)
    beta = 1.0 / n - w_prev * p
    wt = 1.0 - np.exp(c * (beta - c1 * np.sign(beta)))
    clipped = int(np.count_nonzero(wt < 0))
    return np.maximum(wt, 0.0), clipped


def _logsumexp_np(a: FloatArray) -> float:
    ls = float(normalise_rows(a)[2])
    return ls if ls > -np.inf else -np.inf


def _normalise_np(lw: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    lwn, w, ls = normalise_rows(lw)
    if not ls > -np.inf:
        return lw, np.full(lw.size, 1.0 / lw.size), -np.inf
    return lwn, w, float(ls)


def _temper_gamma_np(lw: FloatArray, ll: FloatArray, cfg: TemperatureConfig, N: int) -> float:
    """Largest gamma in [1, gamma_max] with ESS(lw + gamma ll) >= target N (bisection in
    log gamma, 30 halvings), 1 when the plain update is already below the target."""
    def ess(g: float) -> float:
        return float(ess_rows(_normalise_np(lw + g * ll)[1]))

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
