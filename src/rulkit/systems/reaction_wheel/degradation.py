"""Step 2 of the reaction-wheel study: tracking the lubricant-loss parameters
(docs/systems/reaction-wheel.md §4, Table 6).

Three trackers of ``theta = [b, beta0]`` (random walks) from the window losses
``y_k = beta0 S_k(b) dt + noise`` with ``S_k(b) = sum_{j in window k} exp(-b / T^_j)``:

* one-step PF (seed 001 eq. 30): particles over ``(b, beta0)``;
* two-step PF (seed 001 eqs 32-34): PF1 over ``b`` from ``z_k = y_k / y_{k-1} = S_k(b)/S_{k-1}(b)``
  (free of beta0; exact window sums, not eq. 31's single temperature), then PF2 over ``beta0``
  from ``y_k`` with ``b^_k`` from PF1;
* Rao-Blackwellised PF (ours): particles over ``b``; given ``b`` the model is linear-Gaussian in
  ``beta0`` (``y_k = H_k(b) beta0 + v_k``, ``H_k = S_k(b) dt``, random-walk ``beta0``), so each
  particle carries an exact scalar Kalman filter ``(m, P)`` for ``beta0`` and is weighted by the
  Kalman predictive likelihood ``N(y_k; H m, H^2 P + sigma_y^2)``.

The window sums use :class:`rulkit.systems.reaction_wheel.lubrication.WindowQuadrature` (n Gauss
nodes per window
instead of 4,800 exponentials per particle). ``T^`` over three months comes from the error-process
shortcut (docs/systems/reaction-wheel.md §4): true path + an error process whose statistics are
measured on step-1 runs (:func:`measure_temperature_errors`), validated against the real step-1
estimator on a shorter horizon
(:func:`validate_shortcut`).

Batched over units: every array has a leading unit axis U (runs x scenarios x T^ sources) and a
particle axis N, so the 32,400-window loop runs once per tracker for all 20 runs. Each unit has its
own random generators, so a unit's numbers do not depend on how units are batched or spread over
workers. The per-unit normalisation, ESS and systematic resampling are the batched particle core
:mod:`rulkit.estimation.batched` (numpy rows in the numpy path, the numba row functions inside
the compiled kernels); a single-run
path through the engine's :class:`~rulkit.estimation.particle.ParticleFilter` is
:func:`rbpf_engine` (tested to agree with the batched RBPF).
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from rulkit.estimation.batched import (
    ess_row,
    ess_rows,
    normalise_row,
    normalise_rows,
    systematic_row,
    systematic_rows,
)
from rulkit.systems.reaction_wheel.lubrication import (
    DAY_S,
    PATHS,
    SAMPLE_DT,
    SCENARIOS,
    WINDOW_S,
    EstimateErrorProcess,
    LubricationSetup,
    WindowQuadrature,
    simulate_measurements,
    synthetic_estimate_quadrature,
    true_window_increments,
)

FloatArray = NDArray[np.float64]
Progress = Callable[[str, int, int], None]

#: Paper values, seed 001 Table 6 (RMSPE %, b / beta; scenario 1 | scenario 2).
PAPER_TABLE6: dict[str, tuple[float, float, float, float]] = {
    "APF + two-step PF": (3.947, 2.051, 1.920, 2.709),
    "PF + two-step PF": (5.081, 3.586, 3.726, 4.707),
    "APF + one-step PF": (136.999, 23.896, 66.172, 24.303),
}

#: Step-1 estimators whose error statistics feed the shortcut, and their Table 5 labels.
#: "APF" and "PF" are the seed's; "RBPF" (ours, beyond the seeds) is the Rao-Blackwellised PF
#: of :mod:`rulkit.systems.reaction_wheel.rbpf`, design :data:`RBPF_STEP1_DESIGN`. A source's
#: index here keys its random streams, so adding a source leaves the others' numbers unchanged.
SOURCES = ("APF", "PF", "RBPF")


@dataclass(frozen=True)
class DegradationConfig:
    """Every setting of step 2 the seeds leave open [R]; each is varied in the sensitivity study.

    ``q_b`` random-walk std of b per window (deg C); ``q_beta0_rel`` that of beta0 per window as a
    fraction of the healthy beta0; priors uniform on ``b_prior`` and on ``beta0_prior_rel`` x
    healthy beta0 (the RBPF uses a Gaussian with the same mean and std); ``noise_rel`` the std of
    the window measurement noise as a fraction of the healthy window loss at the mean temperature;
    ``ess_threshold`` resampling when ESS < threshold x N (systematic); ``n_nodes`` Gauss nodes per
    window; ``horizon_days`` tracking horizon; ``hold_samples`` sample-and-hold length of the
    synthetic T^ error.
    """

    n_particles: int = 150
    q_b: float = 0.2
    q_beta0_rel: float = 0.002
    b_prior: tuple[float, float] = (10.0, 80.0)
    beta0_prior_rel: tuple[float, float] = (0.5, 2.0)
    noise_rel: float = 0.01
    ess_threshold: float = 0.5
    n_nodes: int = 4
    horizon_days: float = 90.0
    hold_samples: int = 40

    @property
    def n_windows(self) -> int:
        return round(self.horizon_days * DAY_S / WINDOW_S)


# ---------------------------------------------------------------------------------------------
# Random streams: one generator per (purpose, scenario, source, run)
# ---------------------------------------------------------------------------------------------

_STREAMS = {"measurement": 0, "estimate": 1, "one_step": 2, "pf1": 3, "pf2": 4, "rbpf": 5,
            "forecast": 6}


def unit_rng(seed: int, stream: str, scenario_id: int, source: int, run: int
             ) -> np.random.Generator:
    """Generator for one unit and purpose, independent of batching (SeedSequence spawn keys)."""
    ss = np.random.SeedSequence(seed, spawn_key=(_STREAMS[stream], scenario_id, source, run))
    return np.random.default_rng(ss)


# ---------------------------------------------------------------------------------------------
# Batched particle-filter pieces
# ---------------------------------------------------------------------------------------------


def _progress(progress: Progress | None, label: str, done: int, W: int) -> None:
    if progress is not None:
        progress(label, done, W)


CHUNK = 256  # windows of noise drawn at once per unit (fixed: streams do not depend on splits)


class _Noise:
    """Noise pre-drawn per unit in blocks of :data:`CHUNK` windows, each from its own generator.

    Block ``j`` holds ``eps`` (U, CHUNK, N, dims) standard normals and ``unif`` (U, CHUNK)
    resampling uniforms for windows ``j*CHUNK ..``; blocks are drawn in order, so a unit's
    numbers depend only on its generator.
    """

    def __init__(self, rngs: list[np.random.Generator], n_particles: int, dims: int) -> None:
        self.rngs, self.n, self.dims = rngs, n_particles, dims
        self.blk = -1
        self.eps = np.empty((len(rngs), CHUNK, n_particles, dims))
        self.unif = np.empty((len(rngs), CHUNK))

    def block(self, blk: int) -> tuple[FloatArray, FloatArray]:
        while self.blk < blk:
            self.blk += 1
            for r, g in enumerate(self.rngs):
                self.eps[r] = g.standard_normal((CHUNK, self.n, self.dims))
                self.unif[r] = g.random(CHUNK)
        return self.eps, self.unif


def _segments(W: int, snapshots: Sequence[int]) -> list[tuple[int, int]]:
    cuts = set(range(0, W, CHUNK)) | {int(s) + 1 for s in snapshots if 0 <= s < W} | {W}
    c = sorted(x for x in cuts if 0 <= x <= W)
    return list(itertools.pairwise(c))


@dataclass
class TrackOutput:
    """Per-window posterior summaries of one tracker over U units and W windows.

    ``b_mean``, ``b_std``, ``beta0_mean``, ``beta0_std``: (U, W), after the update of window k.
    ``snapshots[k]`` holds the posterior at the end of window k (after any resampling) as
    ``(particles (U, N, 2) of [b, beta0], weights (U, N))``; for the RBPF beta0 is drawn once per
    particle from its Kalman posterior. ``n_resampled`` counts resampling events over all units.
    """

    b_mean: FloatArray
    b_std: FloatArray
    beta0_mean: FloatArray
    beta0_std: FloatArray
    snapshots: dict[int, tuple[FloatArray, FloatArray]] = field(default_factory=dict)
    n_resampled: int = 0
    seconds: float = 0.0


def _alloc(U: int, W: int) -> TrackOutput:
    return TrackOutput(np.zeros((U, W)), np.zeros((U, W)), np.zeros((U, W)), np.zeros((U, W)))


def _wmean_std(x: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray]:
    m = (w * x).sum(axis=1)
    v = (w * (x - m[:, None]) ** 2).sum(axis=1)
    return m, np.sqrt(np.maximum(v, 0.0))


def _np_normalise(logw: FloatArray) -> tuple[FloatArray, FloatArray]:
    """numpy path: normalise ``logw`` (U, N) in place; return weights and ESS per unit."""
    lwn, w, ls = normalise_rows(logw, weights_from_log=True)
    bad = ~(ls > -np.inf)
    if bad.any():
        raise FloatingPointError(f"degenerate weights in unit {int(np.flatnonzero(bad)[0])}")
    logw[:] = lwn
    return w, ess_rows(w)


def _np_resample(logw: FloatArray, ess: FloatArray, states: list[FloatArray], u: FloatArray,
                 thr: float) -> FloatArray:
    """numpy path: systematic resampling (in place) of the units whose ESS < thr N."""
    N = logw.shape[1]
    do = ess < thr * N
    if do.any():
        rows = np.flatnonzero(do)
        idx = systematic_rows(np.exp(logw[rows]), u[rows])
        for st in states:
            st[rows] = np.take_along_axis(st[rows], idx, axis=1)
        logw[rows] = -np.log(N)
    return do


# ---------------------------------------------------------------------------------------------
# Compiled kernels (same algebra and draws as the numpy path, tested equal)
# ---------------------------------------------------------------------------------------------


@numba.njit(cache=True)
def _k_logsum(bb, c, s, nodes, weights, lcount):  # pragma: no cover - compiled
    acc = 0.0
    for j in range(nodes.shape[0]):
        acc += weights[j] * np.exp(-(bb * s) * nodes[j])
    return lcount - bb * c + np.log(acc)


@numba.njit(cache=True)
def _k_normalise(r, logw, w):  # pragma: no cover - compiled
    """Normalise row r of logw in place, weights into ``w``; returns the ESS, or -1 when the
    row is degenerate (all -inf or NaN: the caller raises, naming the unit)."""
    if not normalise_row(logw[r], w, True) > -np.inf:
        return -1.0
    return ess_row(w)


@numba.njit(cache=True)
def _k_resample(r, logw, w, u, s0, s1, s2, nstate, c, idx, tmp):  # pragma: no cover
    """Systematic resampling of row r (as ``resampling.systematic`` with uniform ``u``)."""
    N = logw.shape[1]
    systematic_row(w, u, idx, c)
    for q in range(nstate):
        st = s0 if q == 0 else (s1 if q == 1 else s2)
        for p in range(N):
            tmp[p] = st[r, idx[p]]
        for p in range(N):
            st[r, p] = tmp[p]
    lw0 = -np.log(N)
    for p in range(N):
        logw[r, p] = lw0


@numba.njit(cache=True)
def _k_est(x, r, w):  # pragma: no cover - compiled
    N = w.shape[0]
    m = 0.0
    for p in range(N):
        m += w[p] * x[r, p]
    v = 0.0
    for p in range(N):
        d = x[r, p] - m
        v += w[p] * d * d
    return m, np.sqrt(max(v, 0.0))


@numba.njit(cache=True)
def _k_one_step(k0, k1, koff, y, qc, qs, qn, qw, lcount, dt, sigma_y, q_b, q_beta, thr,
                b, beta, logw, eps, unif, bm, bsd, em, esd, nres):  # pragma: no cover
    U, N = b.shape
    for r in range(U):
        w, c, tmp = np.empty(N), np.empty(N), np.empty(N)
        idx = np.empty(N, np.int64)
        for k in range(k0, k1):
            i = k - koff
            for p in range(N):
                bb = b[r, p] + q_b * eps[r, i, p, 0]
                b[r, p] = bb
                be = abs(beta[r, p] + q_beta * eps[r, i, p, 1])
                beta[r, p] = be
                mu = be * np.exp(_k_logsum(bb, qc[r, k], qs[r, k], qn[r, k], qw[r, k], lcount)) * dt
                z = (y[r, k] - mu) / sigma_y
                logw[r, p] -= 0.5 * z * z
            ess = _k_normalise(r, logw, w)
            if ess < 0:
                nres[r] = -1
                break
            bm[r, k], bsd[r, k] = _k_est(b, r, w)
            em[r, k], esd[r, k] = _k_est(beta, r, w)
            if ess < thr * N:
                _k_resample(r, logw, w, unif[r, i], b, beta, beta, 2, c, idx, tmp)
                nres[r] += 1


@numba.njit(cache=True)
def _k_pf1(k0, k1, koff, dlny, sd, ok, qc, qs, qn, qw, lcount, q_b, thr, b, logw, eps, unif,
           bm, bsd, nres):  # pragma: no cover
    U, N = b.shape
    for r in range(U):
        w, c, tmp = np.empty(N), np.empty(N), np.empty(N)
        idx = np.empty(N, np.int64)
        for k in range(k0, k1):
            i = k - koff
            for p in range(N):
                bb = b[r, p] + q_b * eps[r, i, p, 0]
                b[r, p] = bb
                if ok[r, k]:
                    pred = (_k_logsum(bb, qc[r, k], qs[r, k], qn[r, k], qw[r, k], lcount)
                            - _k_logsum(bb, qc[r, k - 1], qs[r, k - 1], qn[r, k - 1],
                                        qw[r, k - 1], lcount))
                    z = (dlny[r, k] - pred) / sd[r, k]
                    logw[r, p] -= 0.5 * z * z
            ess = _k_normalise(r, logw, w)
            if ess < 0:
                nres[r] = -1
                break
            bm[r, k], bsd[r, k] = _k_est(b, r, w)
            if ess < thr * N:
                _k_resample(r, logw, w, unif[r, i], b, b, b, 1, c, idx, tmp)
                nres[r] += 1


@numba.njit(cache=True)
def _k_pf2(k0, k1, koff, y, H, sigma_y, q_beta, thr, beta, logw, eps, unif, em, esd, nres
           ):  # pragma: no cover
    U, N = beta.shape
    for r in range(U):
        w, c, tmp = np.empty(N), np.empty(N), np.empty(N)
        idx = np.empty(N, np.int64)
        for k in range(k0, k1):
            i = k - koff
            for p in range(N):
                be = abs(beta[r, p] + q_beta * eps[r, i, p, 0])
                beta[r, p] = be
                z = (y[r, k] - be * H[r, k]) / sigma_y
                logw[r, p] -= 0.5 * z * z
            ess = _k_normalise(r, logw, w)
            if ess < 0:
                nres[r] = -1
                break
            em[r, k], esd[r, k] = _k_est(beta, r, w)
            if ess < thr * N:
                _k_resample(r, logw, w, unif[r, i], beta, beta, beta, 1, c, idx, tmp)
                nres[r] += 1


@numba.njit(cache=True)
def _k_rbpf(k0, k1, koff, y, qc, qs, qn, qw, lcount, dt, R, q_b, q2, thr, b, m, P, logw, eps,
            unif, bm, bsd, em, esd, nres):  # pragma: no cover
    U, N = b.shape
    for r in range(U):
        w, c, tmp = np.empty(N), np.empty(N), np.empty(N)
        idx = np.empty(N, np.int64)
        for k in range(k0, k1):
            i = k - koff
            for p in range(N):
                bb = b[r, p] + q_b * eps[r, i, p, 0]
                b[r, p] = bb
                Pp = P[r, p] + q2
                H = np.exp(_k_logsum(bb, qc[r, k], qs[r, k], qn[r, k], qw[r, k], lcount)) * dt
                s = H * H * Pp + R
                nu = y[r, k] - H * m[r, p]
                logw[r, p] -= 0.5 * (np.log(s) + nu * nu / s)
                K = Pp * H / s
                m[r, p] += K * nu
                P[r, p] = (1.0 - K * H) * Pp
            ess = _k_normalise(r, logw, w)
            if ess < 0:
                nres[r] = -1
                break
            bm[r, k], bsd[r, k] = _k_est(b, r, w)
            mm = 0.0
            for p in range(N):
                mm += w[p] * m[r, p]
            v = 0.0
            for p in range(N):
                d = m[r, p] - mm
                v += w[p] * (P[r, p] + d * d)
            em[r, k], esd[r, k] = mm, np.sqrt(max(v, 0.0))
            if ess < thr * N:
                _k_resample(r, logw, w, unif[r, i], b, m, P, 3, c, idx, tmp)
                nres[r] += 1


def _check_degenerate(nres: NDArray[np.int64], label: str) -> None:
    bad = np.flatnonzero(nres < 0)
    if bad.size:
        raise FloatingPointError(f"{label}: degenerate weights in unit {int(bad[0])}")


def _quad_arrays(quad: WindowQuadrature) -> tuple[FloatArray, ...]:
    return (np.ascontiguousarray(quad.center), np.ascontiguousarray(quad.scale),
            np.ascontiguousarray(quad.nodes), np.ascontiguousarray(quad.weights))


def _log_sums_np(b: FloatArray, qa: tuple[FloatArray, ...], k: int, lcount: float) -> FloatArray:
    """numpy twin of ``_k_logsum`` for all units/particles at window k (b (U, N))."""
    c, s, x, w = (a[:, k] for a in qa)
    inner = (w[:, None, :] * np.exp(-(b * s[:, None])[..., None] * x[:, None, :])).sum(axis=-1)
    return lcount - b * c[:, None] + np.log(inner)


def _check_backend(backend: str) -> None:
    if backend not in ("numba", "numpy"):
        raise ValueError(f"backend: expected 'numba' or 'numpy', got {backend!r}")


def _check_inputs(y: FloatArray, quad: WindowQuadrature, n_rngs: int) -> tuple[int, int]:
    if y.ndim != 2:
        raise ValueError(f"y: expected shape (U, W), got {y.shape}")
    U, W = y.shape
    if quad.center.shape != (U, W):
        raise ValueError(f"quad: expected arrays of shape ({U}, {W}), got {quad.center.shape}")
    if n_rngs != U:
        raise ValueError(f"rngs: expected {U} generators (one per unit), got {n_rngs}")
    if not np.all(np.isfinite(y)):
        raise ValueError("y: non-finite window measurements")
    return U, W


def one_step_pf(y: FloatArray, quad: WindowQuadrature, sigma_y: float, settings: DegradationConfig,
                rngs: list[np.random.Generator], *, beta_ref: float,
                snapshot_windows: Sequence[int] = (), progress: Progress | None = None,
                backend: str = "numba") -> TrackOutput:
    """One-step PF over ``[b, beta0]`` (seed 001 eq. 30), batched over units; ``y`` (U, W).

    ``y_k ~ N(beta0 S_k(b) dt, sigma_y^2)``; random walks on b and beta0 (beta0 reflected at 0).
    """
    _check_backend(backend)
    t0 = time.perf_counter()
    U, W = _check_inputs(y, quad, len(rngs))
    N = settings.n_particles
    lo, hi = settings.b_prior
    plo, phi = settings.beta0_prior_rel
    b = np.stack([g.uniform(lo, hi, N) for g in rngs])
    beta = np.stack([g.uniform(plo, phi, N) for g in rngs]) * beta_ref
    logw = np.full((U, N), -np.log(N))
    out = _alloc(U, W)
    nres = np.zeros(U, np.int64)
    qb, qbeta, thr = settings.q_b, settings.q_beta0_rel * beta_ref, settings.ess_threshold
    noise = _Noise(rngs, N, 2)
    qa = _quad_arrays(quad)
    lcount = float(np.log(quad.count))
    for a, e in _segments(W, snapshot_windows):
        koff = (a // CHUNK) * CHUNK
        eps, unif = noise.block(a // CHUNK)
        if backend == "numba":
            _k_one_step(a, e, koff, y, *qa, lcount, SAMPLE_DT, sigma_y, qb, qbeta, thr, b, beta,
                        logw, eps, unif, out.b_mean, out.b_std, out.beta0_mean, out.beta0_std,
                        nres)
            _check_degenerate(nres, "one-step PF")
        else:
            for k in range(a, e):
                ek = eps[:, k - koff]
                b += qb * ek[..., 0]
                beta[:] = np.abs(beta + qbeta * ek[..., 1])
                mu = beta * np.exp(_log_sums_np(b, qa, k, lcount)) * SAMPLE_DT
                z = (y[:, k:k + 1] - mu) / sigma_y
                logw -= 0.5 * z * z
                w, ess = _np_normalise(logw)
                out.b_mean[:, k], out.b_std[:, k] = _wmean_std(b, w)
                out.beta0_mean[:, k], out.beta0_std[:, k] = _wmean_std(beta, w)
                nres += _np_resample(logw, ess, [b, beta], unif[:, k - koff], thr)
        if e - 1 in snapshot_windows:
            out.snapshots[e - 1] = (np.stack([b, beta], axis=-1), np.exp(logw))
        _progress(progress, "one-step PF", e, W)
    out.n_resampled, out.seconds = int(nres.sum()), time.perf_counter() - t0
    return out


def two_step_pf(y: FloatArray, quad: WindowQuadrature, sigma_y: float, settings: DegradationConfig,
                rngs_b: list[np.random.Generator], rngs_beta: list[np.random.Generator], *,
                beta_ref: float, snapshot_windows: Sequence[int] = (),
                progress: Progress | None = None, backend: str = "numba") -> TrackOutput:
    """Two-step PF (seed 001 eqs 32-34), batched over units.

    PF1 over ``b``: ``ln z_k = ln y_k - ln y_{k-1} ~ N(ln S_k(b) - ln S_{k-1}(b), s_k^2)`` with the
    delta-method variance ``s_k^2 = (sigma_y/y_k)^2 + (sigma_y/y_{k-1})^2`` [R] (consecutive ratios
    share a measurement; like the seeds we treat them as independent); a pair with a non-positive
    ``y`` is skipped. PF2 over ``beta0``: ``y_k ~ N(beta0 S_k(b^_k) dt, sigma_y^2)`` with ``b^_k``
    PF1's posterior mean. Snapshots pair PF1's b with PF2's beta0 particles, both resampled to
    equal weights and shuffled (the product of the two marginal posteriors).
    """
    _check_backend(backend)
    t0 = time.perf_counter()
    U, W = _check_inputs(y, quad, len(rngs_b))
    N = settings.n_particles
    thr = settings.ess_threshold
    qa = _quad_arrays(quad)
    lcount = float(np.log(quad.count))
    out = _alloc(U, W)
    nres = np.zeros(U, np.int64)
    # PF1 on b from ratios of consecutive window losses
    lo, hi = settings.b_prior
    b = np.stack([g.uniform(lo, hi, N) for g in rngs_b])
    logw = np.full((U, N), -np.log(N))
    ok = np.zeros((U, W), dtype=np.bool_)
    ok[:, 1:] = (y[:, 1:] > 0) & (y[:, :-1] > 0)
    ysafe = np.where(y > 0, y, 1.0)
    dlny = np.zeros((U, W))
    dlny[:, 1:] = np.where(ok[:, 1:], np.log(ysafe[:, 1:]) - np.log(ysafe[:, :-1]), 0.0)
    sd = np.ones((U, W))
    sd[:, 1:] = np.where(ok[:, 1:], np.sqrt((sigma_y / ysafe[:, 1:]) ** 2
                                            + (sigma_y / ysafe[:, :-1]) ** 2), 1.0)
    noise = _Noise(rngs_b, N, 1)
    snaps_b: dict[int, tuple[FloatArray, FloatArray]] = {}
    for a, e in _segments(W, snapshot_windows):
        koff = (a // CHUNK) * CHUNK
        eps, unif = noise.block(a // CHUNK)
        if backend == "numba":
            _k_pf1(a, e, koff, dlny, sd, ok, *qa, lcount, settings.q_b, thr, b, logw, eps, unif,
                   out.b_mean, out.b_std, nres)
            _check_degenerate(nres, "two-step PF1")
        else:
            for k in range(a, e):
                b += settings.q_b * eps[:, k - koff, :, 0]
                if k >= 1:
                    pred = _log_sums_np(b, qa, k, lcount) - _log_sums_np(b, qa, k - 1, lcount)
                    z = (dlny[:, k:k + 1] - pred) / sd[:, k:k + 1]
                    logw -= np.where(ok[:, k:k + 1], 0.5 * z * z, 0.0)
                w, ess = _np_normalise(logw)
                out.b_mean[:, k], out.b_std[:, k] = _wmean_std(b, w)
                nres += _np_resample(logw, ess, [b], unif[:, k - koff], thr)
        if e - 1 in snapshot_windows:
            snaps_b[e - 1] = (b.copy(), np.exp(logw))
        _progress(progress, "two-step PF1 (b)", e, W)
    # PF2 on beta0 with b^ from PF1
    c, s_, x, wq = qa
    bh = out.b_mean
    inner = (wq * np.exp(-(bh * s_)[..., None] * x)).sum(axis=-1)
    H = np.exp(lcount - bh * c + np.log(inner)) * SAMPLE_DT
    plo, phi = settings.beta0_prior_rel
    beta = np.stack([g.uniform(plo, phi, N) for g in rngs_beta]) * beta_ref
    logw = np.full((U, N), -np.log(N))
    qbeta = settings.q_beta0_rel * beta_ref
    noise = _Noise(rngs_beta, N, 1)
    for a, e in _segments(W, snapshot_windows):
        koff = (a // CHUNK) * CHUNK
        eps, unif = noise.block(a // CHUNK)
        if backend == "numba":
            _k_pf2(a, e, koff, y, H, sigma_y, qbeta, thr, beta, logw, eps, unif,
                   out.beta0_mean, out.beta0_std, nres)
            _check_degenerate(nres, "two-step PF2")
        else:
            for k in range(a, e):
                beta[:] = np.abs(beta + qbeta * eps[:, k - koff, :, 0])
                z = (y[:, k:k + 1] - beta * H[:, k:k + 1]) / sigma_y
                logw -= 0.5 * z * z
                w, ess = _np_normalise(logw)
                out.beta0_mean[:, k], out.beta0_std[:, k] = _wmean_std(beta, w)
                nres += _np_resample(logw, ess, [beta], unif[:, k - koff], thr)
        if e - 1 in snapshot_windows:
            bp, bw = snaps_b[e - 1]
            ib = systematic_rows(bw, np.array([g.random() for g in rngs_b]))
            ie = systematic_rows(np.exp(logw), np.array([g.random() for g in rngs_beta]))
            perm = np.stack([g.permutation(N) for g in rngs_b])
            bs = np.take_along_axis(np.take_along_axis(bp, ib, axis=1), perm, axis=1)
            out.snapshots[e - 1] = (
                np.stack([bs, np.take_along_axis(beta, ie, axis=1)], axis=-1),
                np.full((U, N), 1.0 / N))
        _progress(progress, "two-step PF2 (beta0)", e, W)
    out.n_resampled, out.seconds = int(nres.sum()), time.perf_counter() - t0
    return out


def rbpf(y: FloatArray, quad: WindowQuadrature, sigma_y: float, settings: DegradationConfig,
         rngs: list[np.random.Generator], *, beta_ref: float,
         snapshot_windows: Sequence[int] = (), progress: Progress | None = None,
         backend: str = "numba") -> TrackOutput:
    """Rao-Blackwellised PF: particles over ``b``, an exact scalar Kalman filter for ``beta0``.

    Per window: ``b += q_b eps``; ``P += q_beta0^2``; ``H = S_k(b) dt``; ``s = H^2 P + sigma_y^2``;
    weight by ``N(y_k; H m, s)`` (the Kalman predictive density); ``K = P H / s``,
    ``m += K (y_k - H m)``, ``P = (1 - K H) P``. With b known this is exactly the Kalman filter of
    the linear-Gaussian beta0 model (tested against ``rulkit.estimation.kalman``). The beta0
    posterior is the mixture ``sum_i w_i N(m_i, P_i)``; its prior a Gaussian with the mean and
    std of the uniform prior of the other trackers.
    """
    _check_backend(backend)
    t0 = time.perf_counter()
    U, W = _check_inputs(y, quad, len(rngs))
    N = settings.n_particles
    lo, hi = settings.b_prior
    b = np.stack([g.uniform(lo, hi, N) for g in rngs])
    plo, phi = settings.beta0_prior_rel
    m = np.full((U, N), 0.5 * (plo + phi) * beta_ref)
    P = np.full((U, N), ((phi - plo) * beta_ref) ** 2 / 12.0)
    logw = np.full((U, N), -np.log(N))
    q2 = (settings.q_beta0_rel * beta_ref) ** 2
    R = sigma_y**2
    thr = settings.ess_threshold
    out = _alloc(U, W)
    nres = np.zeros(U, np.int64)
    qa = _quad_arrays(quad)
    lcount = float(np.log(quad.count))
    noise = _Noise(rngs, N, 1)
    for a, e in _segments(W, snapshot_windows):
        koff = (a // CHUNK) * CHUNK
        eps, unif = noise.block(a // CHUNK)
        if backend == "numba":
            _k_rbpf(a, e, koff, y, *qa, lcount, SAMPLE_DT, R, settings.q_b, q2, thr, b, m, P,
                    logw, eps, unif, out.b_mean, out.b_std, out.beta0_mean, out.beta0_std, nres)
            _check_degenerate(nres, "RB-PF")
        else:
            for k in range(a, e):
                b += settings.q_b * eps[:, k - koff, :, 0]
                P += q2
                H = np.exp(_log_sums_np(b, qa, k, lcount)) * SAMPLE_DT
                s = H * H * P + R
                nu = y[:, k:k + 1] - H * m
                logw -= 0.5 * (np.log(s) + nu * nu / s)
                K = P * H / s
                m += K * nu
                P[:] = (1.0 - K * H) * P
                w, ess = _np_normalise(logw)
                out.b_mean[:, k], out.b_std[:, k] = _wmean_std(b, w)
                mm = (w * m).sum(axis=1)
                out.beta0_mean[:, k] = mm
                out.beta0_std[:, k] = np.sqrt(np.maximum(
                    (w * (P + (m - mm[:, None]) ** 2)).sum(axis=1), 0.0))
                nres += _np_resample(logw, ess, [b, m, P], unif[:, k - koff], thr)
        if e - 1 in snapshot_windows:
            draw = m + np.sqrt(P) * np.stack([g.standard_normal(N) for g in rngs])
            out.snapshots[e - 1] = (np.stack([b, np.abs(draw)], axis=-1), np.exp(logw))
        _progress(progress, "Rao-Blackwellised PF", e, W)
    out.n_resampled, out.seconds = int(nres.sum()), time.perf_counter() - t0
    return out


def rbpf_engine(y: FloatArray, quad: WindowQuadrature, sigma_y: float, settings: DegradationConfig,
                rng: np.random.Generator, *, beta_ref: float) -> tuple[FloatArray, FloatArray]:
    """The same RBPF for a single run through the engine's ``ParticleFilter`` (per-step API).

    ``quad`` without a run axis (W,). State columns ``[b, m, P]``; the engine propagates and
    weights (log-likelihood = Kalman predictive density), the Kalman update of ``(m, P)`` is
    applied to the weighted particles before the engine resamples. Returns ``(b_mean, beta0_mean)``
    per window. Slow (one engine step per window); used to check the batched path.
    """
    from rulkit.estimation.particle import ParticleFilter

    N = settings.n_particles
    q2 = (settings.q_beta0_rel * beta_ref) ** 2
    R = sigma_y**2

    def transition(x: FloatArray, k: int, g: np.random.Generator) -> FloatArray:
        x = x.copy()
        x[:, 0] += settings.q_b * g.standard_normal(x.shape[0])
        x[:, 2] += q2
        return x

    def loglik(x: FloatArray, yk: Any, k: int) -> FloatArray:
        H = quad.sums(x[:, 0], k) * SAMPLE_DT
        s = H * H * x[:, 2] + R
        nu = float(yk) - H * x[:, 1]
        return -0.5 * (np.log(2 * np.pi * s) + nu * nu / s)

    pf = ParticleFilter(transition, loglik, resampler="systematic",
                        ess_threshold=settings.ess_threshold)
    lo, hi = settings.b_prior
    plo, phi = settings.beta0_prior_rel
    x0 = np.column_stack([rng.uniform(lo, hi, N), np.full(N, 0.5 * (plo + phi) * beta_ref),
                          np.full(N, ((phi - plo) * beta_ref) ** 2 / 12.0)])
    state = pf.initialise(x0, rng)
    W = y.shape[0]
    b_mean, beta_mean = np.empty(W), np.empty(W)
    for k in range(W):
        state = pf.update(state, float(y[k]))  # engine: propagate + weight (no resampling)
        x = state.particles
        H = quad.sums(x[:, 0], k) * SAMPLE_DT  # Kalman update of (m, P) per particle
        s = H * H * x[:, 2] + R
        K = x[:, 2] * H / s
        x[:, 1] += K * (y[k] - H * x[:, 1])
        x[:, 2] *= 1.0 - K * H
        b_mean[k] = state.weights @ x[:, 0]
        beta_mean[k] = state.weights @ x[:, 1]
        state = pf.resample_if_needed(state)
    return b_mean, beta_mean


# ---------------------------------------------------------------------------------------------
# The Table 6 experiment
# ---------------------------------------------------------------------------------------------

#: Trackers run on the T^ of each step-1 estimator; the seed's three rows plus our RBPF.
METHODS: dict[str, tuple[str, ...]] = {"APF": ("two_step", "one_step", "rbpf"),
                                       "PF": ("two_step", "rbpf"),
                                       "RBPF": ("two_step", "rbpf")}
ROW_LABELS: dict[tuple[str, str], str] = {
    ("APF", "two_step"): "APF + two-step PF",
    ("PF", "two_step"): "PF + two-step PF",
    ("APF", "one_step"): "APF + one-step PF",
    ("APF", "rbpf"): "APF + RB-PF (ours)",
    ("PF", "rbpf"): "PF + RB-PF (ours)",
    ("RBPF", "two_step"): "RBPF + two-step PF (ours)",
    ("RBPF", "rbpf"): "RBPF + RB-PF (ours)",
}


@dataclass(frozen=True)
class CaseTask:
    """One scenario x one T^ source x a set of runs: the unit of work given to the runner."""

    scenario_id: int
    source: str
    runs: tuple[int, ...]
    seed: int
    settings: DegradationConfig
    error: EstimateErrorProcess
    snapshot_windows: tuple[int, ...] = ()
    methods: tuple[str, ...] | None = None
    keep_traces: bool = True
    backend: str = "numba"


@dataclass
class CaseResult:
    """Per-run RMSPE (%) of b and beta0 per method, snapshots for step 3, traces of run 0."""

    scenario_id: int
    source: str
    runs: tuple[int, ...]
    rmspe_b: dict[str, FloatArray]
    rmspe_beta0: dict[str, FloatArray]
    snapshots: dict[str, dict[int, tuple[FloatArray, FloatArray]]]
    X_at: dict[int, FloatArray]
    traces: dict[str, tuple[FloatArray, FloatArray, FloatArray, FloatArray]]
    seconds: dict[str, float]


_TRUTH_CACHE: dict[tuple[Any, ...], FloatArray] = {}


def truth_increments(scenario_id: int, n_windows: int) -> FloatArray:
    """Noise-free window losses on the scenario's path (direct 0.05 s sum; cached per process)."""
    key = (scenario_id, n_windows, PATHS[scenario_id])
    if key not in _TRUTH_CACHE:
        _TRUTH_CACHE[key] = true_window_increments(PATHS[scenario_id], SCENARIOS[scenario_id],
                                                   n_windows)
    return _TRUTH_CACHE[key]


def truth_parameters(scenario_id: int, n_windows: int) -> tuple[FloatArray, FloatArray]:
    """Piecewise-constant truth per window, taken at the window's end (159 min -> window 39)."""
    t_end = (np.arange(n_windows) + 1.0) * WINDOW_S
    b, beta0 = SCENARIOS[scenario_id].parameters(t_end)
    return np.asarray(b, dtype=np.float64), np.asarray(beta0, dtype=np.float64)


def measurements(task: CaseTask) -> tuple[FloatArray, float]:
    """Measured window losses (R, W) of the task's runs and their noise std.

    Keyed by (scenario, run) only: every T^ source sees the same measured lubricant losses.
    """
    st = task.settings
    setup = LubricationSetup(task.scenario_id, st.horizon_days, st.noise_rel,
                             PATHS[task.scenario_id])
    y_true = truth_increments(task.scenario_id, st.n_windows)
    rngs = [unit_rng(task.seed, "measurement", task.scenario_id, 0, r) for r in task.runs]
    return simulate_measurements(y_true, setup.sigma_y, rngs), setup.sigma_y


def run_case(task: CaseTask, rng: np.random.Generator | None = None) -> CaseResult:
    """Run the step-2 trackers of one task (``rng`` unused: streams come from :func:`unit_rng`).

    Streams are keyed by (seed, purpose, scenario, source, run), so results do not depend on
    how runs are grouped into tasks or which worker runs them.
    """
    st = task.settings
    sid, src = task.scenario_id, task.source
    si = SOURCES.index(src)
    W = st.n_windows
    t0 = time.perf_counter()
    y, sigma_y = measurements(task)
    est_rngs = [unit_rng(task.seed, "estimate", sid, si, r) for r in task.runs]
    quad = synthetic_estimate_quadrature(PATHS[sid], replace(task.error,
                                         hold_samples=st.hold_samples), W, est_rngs,
                                         n_nodes=st.n_nodes)
    seconds = {"data": time.perf_counter() - t0}
    beta_ref = SCENARIOS[sid].beta0_healthy
    b_true, beta_true = truth_parameters(sid, W)
    methods = task.methods or METHODS[src]
    rm_b: dict[str, FloatArray] = {}
    rm_beta: dict[str, FloatArray] = {}
    snaps: dict[str, dict[int, tuple[FloatArray, FloatArray]]] = {}
    traces: dict[str, tuple[FloatArray, FloatArray, FloatArray, FloatArray]] = {}

    def rr(stream: str) -> list[np.random.Generator]:
        return [unit_rng(task.seed, stream, sid, si, r) for r in task.runs]

    kw = dict(beta_ref=beta_ref, snapshot_windows=task.snapshot_windows, backend=task.backend)
    from rulkit.metrics import rmspe

    for meth in methods:
        if meth == "one_step":
            out = one_step_pf(y, quad, sigma_y, st, rr("one_step"), **kw)
        elif meth == "two_step":
            out = two_step_pf(y, quad, sigma_y, st, rr("pf1"), rr("pf2"), **kw)
        elif meth == "rbpf":
            out = rbpf(y, quad, sigma_y, st, rr("rbpf"), **kw)
        else:
            raise ValueError(f"method: expected one_step, two_step or rbpf, got {meth!r}")
        rm_b[meth] = np.asarray(rmspe(out.b_mean, np.broadcast_to(b_true, out.b_mean.shape),
                                      axis=1))
        rm_beta[meth] = np.asarray(rmspe(out.beta0_mean,
                                         np.broadcast_to(beta_true, out.beta0_mean.shape), axis=1))
        snaps[meth] = out.snapshots
        seconds[meth] = out.seconds
        if task.keep_traces:
            traces[meth] = (out.b_mean[0].copy(), out.b_std[0].copy(),
                            out.beta0_mean[0].copy(), out.beta0_std[0].copy())
    X = np.cumsum(y, axis=1)
    X_at = {k: X[:, k].copy() for k in task.snapshot_windows}
    return CaseResult(sid, src, task.runs, rm_b, rm_beta, snaps, X_at, traces, seconds)


@dataclass
class Table6Result:
    """Table 6 (ours beside the paper's) and the case results behind it."""

    table: Any  # pandas.DataFrame
    cases: list[CaseResult]
    settings: DegradationConfig
    errors: dict[str, EstimateErrorProcess]
    n_runs: int
    seed: int
    seconds: float

    def case(self, scenario_id: int, source: str) -> CaseResult:
        for c in self.cases:
            if c.scenario_id == scenario_id and c.source == source:
                return c
        raise KeyError((scenario_id, source))


def run_table6(n_runs: int, seed: int, settings: DegradationConfig,
               errors: dict[str, EstimateErrorProcess], *, workers: int = 1,
               scheduler: str | None = None, snapshot_windows: Sequence[int] = (),
               progress: Any = None, backend: str = "numba",
               scenarios: Sequence[int] = (1, 2)) -> Table6Result:
    """Table 6: mean over ``n_runs`` runs of the per-run RMSPE of b and beta0
    (docs/systems/reaction-wheel.md §6).

    Tasks are (scenario, T^ source) pairs sent to :func:`rulkit.runner.run_independent`
    (serial, ``workers`` processes, or a Dask ``scheduler``); results are identical either way.
    The T^ sources are those of :data:`SOURCES` present in ``errors`` (rows of absent sources
    are left out); a source's numbers do not depend on which other sources run.
    """
    import pandas as pd

    from rulkit.runner import run_independent

    if n_runs < 1:
        raise ValueError(f"n_runs: expected >= 1, got {n_runs}")
    unknown = sorted(set(errors) - set(SOURCES))
    if unknown:
        raise ValueError(f"errors: unknown T^ source(s) {unknown}; expected some of {SOURCES}")
    sources = [s for s in SOURCES if s in errors]
    if not sources:
        raise ValueError(f"errors: expected error processes for some of {SOURCES}, got none")
    t0 = time.perf_counter()
    tasks = [CaseTask(sid, src, tuple(range(n_runs)), seed, settings, errors[src],
                      tuple(sorted(snapshot_windows)), backend=backend)
             for sid in scenarios for src in sources]
    cases = run_independent(run_case, tasks, seed=seed, workers=workers, scheduler=scheduler,
                            progress=progress, description="step 2 (Table 6)")
    rows = []
    for (src, meth), label in ROW_LABELS.items():
        if src not in sources:
            continue
        row: dict[str, Any] = {"method": label}
        for sid in scenarios:
            c = next(c for c in cases if c.scenario_id == sid and c.source == src)
            if meth not in c.rmspe_b:
                continue
            paper = PAPER_TABLE6.get(label)
            for j, (name, vals) in enumerate((("b", c.rmspe_b[meth]),
                                              ("beta", c.rmspe_beta0[meth]))):
                row[f"S{sid} {name} ours"] = float(np.mean(vals))
                row[f"S{sid} {name} sd"] = float(np.std(vals))
                row[f"S{sid} {name} paper"] = (paper[2 * (sid - 1) + j] if paper else np.nan)
        rows.append(row)
    table = pd.DataFrame(rows)
    table["runs"] = n_runs
    table["seed"] = seed
    return Table6Result(table, cases, settings, dict(errors), n_runs, seed,
                        time.perf_counter() - t0)


# ---------------------------------------------------------------------------------------------
# Error statistics of the real step-1 estimator, and validation of the shortcut
# ---------------------------------------------------------------------------------------------

#: Step-1 variants behind the T^ sources: names of
#: rulkit.systems.reaction_wheel.temperature.TemperatureConfig
#: variants, and for "RBPF" the design name in rulkit.systems.reaction_wheel.rbpf.RBPF_DESIGNS.
RBPF_STEP1_DESIGN = "RBJ"
STEP1_VARIANTS = {"APF": "apf_eq28", "PF": "adaptive", "RBPF": f"rbpf {RBPF_STEP1_DESIGN}"}


def estimate_temperature_for_source(source: str, y: FloatArray, V: FloatArray,
                                    rng: np.random.Generator, *,
                      n_particles: int, sigma: tuple[float, float], dt: float = SAMPLE_DT
                      ) -> FloatArray:
    """T^ (K,) of the real step-1 estimator behind ``source`` on telemetry ``y`` (K, 2), ``V``.

    "APF", "PF": ``rulkit.systems.reaction_wheel.temperature.filter_temperature`` (variant
    :data:`STEP1_VARIANTS`,
    F2 design, its default settings); "RBPF": ``rulkit.systems.reaction_wheel.rbpf.run_rbpf``
    with design :data:`RBPF_STEP1_DESIGN` (its settings, ``n_particles`` particles).
    """
    if source == "RBPF":
        from rulkit.systems.reaction_wheel.rbpf import RBPF_DESIGNS, run_rbpf

        rcfg = replace(RBPF_DESIGNS[RBPF_STEP1_DESIGN], n_particles=n_particles)
        return run_rbpf(y, V, rng, rcfg, sigma=sigma, dt=dt, quantiles=False).T_mean
    if source not in STEP1_VARIANTS:
        raise ValueError(f"source: expected one of {SOURCES}, got {source!r}")
    from rulkit.systems.reaction_wheel.temperature import TemperatureConfig, filter_temperature

    cfg = TemperatureConfig(variant=STEP1_VARIANTS[source], n_particles=n_particles)
    return filter_temperature(y, V, rng, cfg, sigma=sigma, dt=dt, quantiles=False).T_mean


def _step1_name(source: str) -> str:
    return STEP1_VARIANTS[source] + ("" if source == "RBPF" else ", F2")


def measure_temperature_errors(source: str, n_runs: int, seed: int, *, n_particles: int = 200,
                         noise: str = "low", burn_in_s: float = 100.0,
                         hold_samples: int = 40, on: str = "path",
                         hours: float = 2.0) -> EstimateErrorProcess:
    """Fit the T^ error process to real step-1 runs (docs/systems/reaction-wheel.md §4).

    Runs the real step-1 estimator of ``source`` (:func:`estimate_temperature_for_source`:
    the seed PFs' variant :data:`STEP1_VARIANTS` [source], F2 design, or the RBJ RBPF) on
    ``n_runs`` simulated wheel runs and fits :func:`fit_error_process` to ``T^ - T`` after
    ``burn_in_s`` [R].
    ``on="path"`` [R, default]: the wheel at constant 2 V along the scenario-1 step-2 path for
    ``hours`` (the conditions of step 2); ``on="table3"``: the 500 s Table 3 validation path of
    step 1 (a temperature step and a voltage step: transients that the months-long path lacks).
    """
    from rulkit.systems.reaction_wheel.lubrication import fit_error_process
    from rulkit.systems.reaction_wheel.wheel import NOISE_LEVELS, ReactionWheel, simulate_table3

    errs = []
    si = SOURCES.index(source)
    if on == "path":
        t, V, T, x = _wheel_on_path_cached(1, hours)
        model = ReactionWheel(noise=noise)
    elif on != "table3":
        raise ValueError(f"on: expected 'path' or 'table3', got {on!r}")
    for r in range(n_runs):
        g = unit_rng(seed, "estimate", 0 if on == "table3" else 10, si, 1000 + r)
        if on == "table3":
            run = simulate_table3(g, noise)
            t, V, T, y = run.t, run.V, run.T, run.y
        else:
            y = model.output(x) + model.noise.sample_measurement(t.size, g)
        est = estimate_temperature_for_source(source, y, V, g, n_particles=n_particles,
                                sigma=NOISE_LEVELS[noise])[-t.size:]
        keep = t >= burn_in_s
        errs.append(est[keep] - T[keep])
    where = (f"Table 3 path after {burn_in_s:g} s" if on == "table3" else
             f"scenario-1 step-2 path, wheel at 2 V, {hours:g} h after {burn_in_s:g} s")
    return fit_error_process(np.stack(errs), hold_samples=hold_samples,
                             source=f"measured: {n_runs} step-1 runs ({_step1_name(source)}, "
                                    f"N={n_particles}, {noise} noise, {where})")


_WHEEL_CACHE: dict[tuple[int, float], tuple[FloatArray, ...]] = {}


def _wheel_on_path_cached(scenario_id: int, hours: float) -> tuple[FloatArray, ...]:
    key = (scenario_id, float(hours))
    if key not in _WHEEL_CACHE:
        _WHEEL_CACHE[key] = simulate_wheel_on_path(PATHS[scenario_id], hours)
    return _WHEEL_CACHE[key]


@dataclass
class ShortcutValidation:
    """Step-2 results with the real step-1 T^ versus the synthetic T^ over a short horizon."""

    hours: float
    n_runs: int
    window_error_std_real: float  # std over windows of the window-mean error of T^ (C)
    window_error_std_synth: float
    rmspe_b_real: dict[str, FloatArray]
    rmspe_b_synth: dict[str, FloatArray]
    fitted_on_path: EstimateErrorProcess
    seconds: float


def simulate_wheel_on_path(path: Any, hours: float, v_comm: float = 2.0, dt: float = SAMPLE_DT
                           ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Noise-free wheel run along a step-2 temperature path at constant ``v_comm`` [R].

    Starts at the steady state of the initial temperature; returns ``(t, V, T, x)``. A Python
    loop of RK4 steps of ``rulkit.systems.reaction_wheel.wheel`` (slow: ~72,000 steps per hour).
    """
    from rulkit.systems.reaction_wheel.wheel import ReactionWheel, rk4_wheel_step

    model = ReactionWheel()
    n = round(hours * 3600.0 / dt)
    t = np.arange(n) * dt
    T = np.asarray(path(t))
    V = np.full(n, v_comm)
    x = np.empty((n, model.n_x))
    x[0] = model.steady_state(v_comm, float(T[0]))
    p = model.params
    for k in range(n - 1):
        x[k + 1] = rk4_wheel_step(x[k:k + 1], V[k], T[k], t[k], dt, p)[0]
    return t, V, T, x


def validate_shortcut(error_table3: EstimateErrorProcess, source: str, *, hours: float = 3.0,
                      n_runs: int = 3, seed: int = 0, settings: DegradationConfig | None = None,
                      n_particles_step1: int = 200) -> ShortcutValidation:
    """Compare step 2 on the real step-1 T^ with step 2 on the synthetic T^
    (docs/systems/reaction-wheel.md §4).

    Scenario 1 path over ``hours``; the wheel at constant 2 V [R]; low noise; noise seeds
    different from those the error statistics were fitted on. For each run the real
    estimator's T^ (0.05 s) gives a 4800-sample quadrature per window; the synthetic T^ uses
    ``error_table3`` (the error process used for Table 6, whatever runs it was fitted on).
    Reports the window-mean error std of both and the b RMSPE of the two-step PF and the RB-PF
    on each; also fits the error process to the real errors of these runs (``fitted_on_path``).
    """
    from rulkit.systems.reaction_wheel.lubrication import (
        WINDOW_SAMPLES,
        fit_error_process,
        window_quadrature,
    )
    from rulkit.systems.reaction_wheel.wheel import ReactionWheel

    t0 = time.perf_counter()
    st = replace(settings or DegradationConfig(), horizon_days=hours / 24.0)
    W = st.n_windows
    sid, si = 1, SOURCES.index(source)
    path = PATHS[sid]
    t, V, T, x = _wheel_on_path_cached(sid, W * WINDOW_S / 3600.0 + 1e-9)
    model = ReactionWheel(noise="low")
    T_hat = np.empty((n_runs, W * WINDOW_SAMPLES))
    for r in range(n_runs):
        g = unit_rng(seed, "estimate", 9, si, r)
        y1 = model.output(x) + model.noise.sample_measurement(t.size, g)
        T_hat[r] = estimate_temperature_for_source(source, y1, V, g, n_particles=n_particles_step1,
                                     sigma=(model.sigma_w, model.sigma_I))[-W * WINDOW_SAMPLES:]
    T_true = T[-W * WINDOW_SAMPLES:]
    err = T_hat - T_true
    fitted = fit_error_process(err[:, 2000:], hold_samples=st.hold_samples,
                               source=f"real step-1 ({_step1_name(source)}) on the step-2 path")
    q_real = window_quadrature(1.0 / np.clip(T_hat, 5.0, None).reshape(n_runs, W, WINDOW_SAMPLES),
                               st.n_nodes)
    rngs = [unit_rng(seed, "estimate", 8, si, r) for r in range(n_runs)]
    q_syn = synthetic_estimate_quadrature(path, replace(error_table3,
                                          hold_samples=st.hold_samples), W, rngs,
                                          n_nodes=st.n_nodes)
    task = CaseTask(sid, source, tuple(range(n_runs)), seed, st, error_table3)
    y, sigma_y = measurements(task)
    b_true, _ = truth_parameters(sid, W)
    beta_ref = SCENARIOS[sid].beta0_healthy
    from rulkit.metrics import rmspe

    out_real: dict[str, FloatArray] = {}
    out_syn: dict[str, FloatArray] = {}
    for name, q, dest in (("real", q_real, out_real), ("synthetic", q_syn, out_syn)):
        for meth in ("two_step", "rbpf"):
            rr = [unit_rng(seed, "pf1" if meth == "two_step" else "rbpf", 7, si, r)
                  for r in range(n_runs)]
            if meth == "two_step":
                rr2 = [unit_rng(seed, "pf2", 7, si, r) for r in range(n_runs)]
                o = two_step_pf(y, q, sigma_y, st, rr, rr2, beta_ref=beta_ref)
            else:
                o = rbpf(y, q, sigma_y, st, rr, beta_ref=beta_ref)
            dest[meth] = np.asarray(rmspe(o.b_mean, np.broadcast_to(b_true, o.b_mean.shape),
                                          axis=1))
        del name
    win_err_real = float(err.reshape(n_runs, W, WINDOW_SAMPLES).mean(axis=2).std())
    d = 1.0 / q_syn.center - np.asarray(path((np.arange(W) + 0.5) * WINDOW_S))
    return ShortcutValidation(hours, n_runs, win_err_real, float(d.std()), out_real, out_syn,
                              fitted, time.perf_counter() - t0)


# ---------------------------------------------------------------------------------------------
# Sensitivity of Table 6 to the unstated settings
# ---------------------------------------------------------------------------------------------

#: Variations of the sensitivity study: (label, field, values). Fields of DegradationConfig, of the
#: error process ("error.std_c", "error.tau_s" as multiples) or of the path ("path.orbit").
SENSITIVITY: tuple[tuple[str, str, tuple[float, ...]], ...] = (
    ("measurement noise (fraction of window loss)", "noise_rel", (0.003, 0.01, 0.03)),
    ("random-walk step of b per window (C)", "q_b", (0.05, 0.2, 0.5)),
    ("random-walk step of beta0 per window (x healthy beta0)", "q_beta0_rel",
     (0.0005, 0.002, 0.01)),
    ("particles", "n_particles", (75, 150, 300)),
    ("T^ error std (x measured)", "error.std_scale", (0.0, 0.5, 1.0, 2.0)),
    ("T^ error correlation time (x measured)", "error.tau_scale", (0.25, 1.0, 4.0)),
)


def sensitivity_study(base: DegradationConfig, error: EstimateErrorProcess, *, n_runs: int = 5,
                      horizon_days: float = 10.0, seed: int = 0, source: str = "APF",
                      methods: tuple[str, ...] = ("two_step", "rbpf", "one_step"),
                      progress: Progress | None = None) -> Any:
    """Mean RMSPE of b and beta0 (scenario 1) when one unstated setting varies
    (docs/systems/reaction-wheel.md §4).

    Shorter horizon and fewer runs than Table 6 (stated in the output). Returns a DataFrame.
    """
    import pandas as pd

    rows = []
    total = sum(len(v) for _, _, v in SENSITIVITY)
    done = 0
    for label, fld, values in SENSITIVITY:
        for v in values:
            st = replace(base, horizon_days=horizon_days)
            err = error
            if fld == "error.std_scale":
                err = replace(error, std_c=error.std_c * v)
            elif fld == "error.tau_scale":
                err = replace(error, tau_s=error.tau_s * v)
            else:
                st = replace(st, **{fld: type(getattr(base, fld))(v)})
            task = CaseTask(1, source, tuple(range(n_runs)), seed, st, err, (), methods,
                            keep_traces=False)
            res = run_case(task)
            for meth in methods:
                rows.append({"setting": label, "value": v, "method": meth,
                             "rmspe_b": float(res.rmspe_b[meth].mean()),
                             "rmspe_beta0": float(res.rmspe_beta0[meth].mean()),
                             "runs": n_runs, "horizon_days": horizon_days})
            done += 1
            if progress is not None:
                progress("sensitivity", done, total)
    return pd.DataFrame(rows)


def settings_dict(settings: DegradationConfig) -> dict[str, Any]:
    """The settings as a plain dict (for report.md)."""
    return asdict(settings)
