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

The window sums use :class:`rulkit.systems.reaction_wheel.degradation.quadrature.WindowQuadrature`
(n Gauss
nodes per window
instead of 4,800 exponentials per particle). ``T^`` over three months comes from the error-process
shortcut (docs/systems/reaction-wheel.md §4); it and the Table 6 study are in
:mod:`rulkit.systems.reaction_wheel.degradation.study`.

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
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
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
from rulkit.systems.reaction_wheel.degradation.quadrature import WindowQuadrature
from rulkit.systems.reaction_wheel.lubrication import DAY_S, SAMPLE_DT, WINDOW_S

FloatArray = NDArray[np.float64]


Progress = Callable[[str, int, int], None]


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
        """Number of 2-hour windows in ``horizon_days``."""
        return round(self.horizon_days * DAY_S / WINDOW_S)

    def beta0_gaussian_prior(self, beta_ref: float) -> tuple[float, float]:
        """Mean and variance of the uniform beta0 prior (``beta0_prior_rel`` x ``beta_ref``): the
        Gaussian prior of the RBPF's Kalman filters."""
        plo, phi = self.beta0_prior_rel
        return 0.5 * (plo + phi) * beta_ref, ((phi - plo) * beta_ref) ** 2 / 12.0


_STREAMS = {"measurement": 0, "estimate": 1, "one_step": 2, "pf1": 3, "pf2": 4, "rbpf": 5,
            "forecast": 6}


def unit_rng(seed: int, stream: str, scenario_id: int, source: int, run: int
             ) -> np.random.Generator:
    """Generator for one unit and purpose, independent of batching (SeedSequence spawn keys)."""
    ss = np.random.SeedSequence(seed, spawn_key=(_STREAMS[stream], scenario_id, source, run))
    return np.random.default_rng(ss)


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
    return w, np.asarray(ess_rows(w), dtype=np.float64)  # (U, N) with U >= 1: an array


def _np_resample(logw: FloatArray, ess: FloatArray, states: list[FloatArray], u: FloatArray,
                 thr: float) -> NDArray[np.bool_]:
    """numpy path: systematic resampling (in place) of the units whose ESS < thr N; returns
    which units were resampled."""
    N = logw.shape[1]
    do = ess < thr * N
    if do.any():
        rows = np.flatnonzero(do)
        idx = systematic_rows(np.exp(logw[rows]), u[rows])
        for st in states:
            st[rows] = np.take_along_axis(st[rows], idx, axis=1)
        logw[rows] = -np.log(N)
    return do


@numba.njit(cache=True)
def _k_logsum(bb, c, s, nodes, weights, lcount):  # pragma: no cover - compiled
    acc = 0.0
    for j in range(nodes.shape[0]):
        acc += weights[j] * np.exp(-(bb * s) * nodes[j])
    return lcount - bb * c + np.log(acc)


@numba.njit(cache=True)
def _k_scratch(N):  # pragma: no cover - compiled
    """One unit's work arrays: weights ``w``, cumulative weights ``c``, a copy buffer ``tmp``
    and the resampled indices ``idx``, each (N,)."""
    return np.empty(N), np.empty(N), np.empty(N), np.empty(N, np.int64)


@numba.njit(cache=True)
def _k_normalise(r, logw, w, nres):  # pragma: no cover - compiled
    """Normalise row r of logw in place, weights into ``w``; returns the ESS, or -1 (and
    ``nres[r] = -1``) when the row is degenerate (all -inf or NaN: the caller stops the unit and
    :func:`_check_degenerate` raises, naming it)."""
    if not normalise_row(logw[r], w, True) > -np.inf:
        nres[r] = -1
        return -1.0
    return ess_row(w)


@numba.njit(cache=True)
def _k_resample(ess, thr, r, logw, w, u, s0, s1, s2, nstate, c, idx, tmp, nres
                ):  # pragma: no cover - compiled
    """When ``ess < thr N``: systematic resampling of row r (as ``resampling.systematic`` with
    uniform ``u``) of the first ``nstate`` of the states ``s0, s1, s2``, counted in ``nres[r]``."""
    N = logw.shape[1]
    if not ess < thr * N:
        return
    nres[r] += 1
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
        w, c, tmp, idx = _k_scratch(N)
        for k in range(k0, k1):
            i = k - koff
            for p in range(N):
                bb = b[r, p] + q_b * eps[r, i, p, 0]
                b[r, p] = bb
                be = abs(beta[r, p] + q_beta * eps[r, i, p, 1])
                beta[r, p] = be
                mu = be * np.exp(_k_logsum(bb, qc[r, k], qs[r, k], qn[r, k], qw[r, k],
                                            lcount[r, k])) * dt
                z = (y[r, k] - mu) / sigma_y
                logw[r, p] -= 0.5 * z * z
            ess = _k_normalise(r, logw, w, nres)
            if ess < 0:
                break
            bm[r, k], bsd[r, k] = _k_est(b, r, w)
            em[r, k], esd[r, k] = _k_est(beta, r, w)
            _k_resample(ess, thr, r, logw, w, unif[r, i], b, beta, beta, 2, c, idx, tmp, nres)


@numba.njit(cache=True)
def _k_pf1(k0, k1, koff, dlny, sd, ok, qc, qs, qn, qw, lcount, q_b, thr, b, logw, eps, unif,
           bm, bsd, nres):  # pragma: no cover
    U, N = b.shape
    for r in range(U):
        w, c, tmp, idx = _k_scratch(N)
        for k in range(k0, k1):
            i = k - koff
            for p in range(N):
                bb = b[r, p] + q_b * eps[r, i, p, 0]
                b[r, p] = bb
                if ok[r, k]:
                    pred = (_k_logsum(bb, qc[r, k], qs[r, k], qn[r, k], qw[r, k], lcount[r, k])
                            - _k_logsum(bb, qc[r, k - 1], qs[r, k - 1], qn[r, k - 1],
                                        qw[r, k - 1], lcount[r, k - 1]))
                    z = (dlny[r, k] - pred) / sd[r, k]
                    logw[r, p] -= 0.5 * z * z
            ess = _k_normalise(r, logw, w, nres)
            if ess < 0:
                break
            bm[r, k], bsd[r, k] = _k_est(b, r, w)
            _k_resample(ess, thr, r, logw, w, unif[r, i], b, b, b, 1, c, idx, tmp, nres)


@numba.njit(cache=True)
def _k_pf2(k0, k1, koff, y, H, sigma_y, q_beta, thr, beta, logw, eps, unif, em, esd, nres
           ):  # pragma: no cover
    U, N = beta.shape
    for r in range(U):
        w, c, tmp, idx = _k_scratch(N)
        for k in range(k0, k1):
            i = k - koff
            for p in range(N):
                be = abs(beta[r, p] + q_beta * eps[r, i, p, 0])
                beta[r, p] = be
                z = (y[r, k] - be * H[r, k]) / sigma_y
                logw[r, p] -= 0.5 * z * z
            ess = _k_normalise(r, logw, w, nres)
            if ess < 0:
                break
            em[r, k], esd[r, k] = _k_est(beta, r, w)
            _k_resample(ess, thr, r, logw, w, unif[r, i], beta, beta, beta, 1, c, idx, tmp, nres)


@numba.njit(cache=True)
def _k_rbpf(k0, k1, koff, y, qc, qs, qn, qw, lcount, dt, R, q_b, q2, thr, b, m, P, logw, eps,
            unif, bm, bsd, em, esd, nres):  # pragma: no cover
    U, N = b.shape
    for r in range(U):
        w, c, tmp, idx = _k_scratch(N)
        for k in range(k0, k1):
            i = k - koff
            for p in range(N):
                bb = b[r, p] + q_b * eps[r, i, p, 0]
                b[r, p] = bb
                Pp = P[r, p] + q2
                H = np.exp(_k_logsum(bb, qc[r, k], qs[r, k], qn[r, k], qw[r, k],
                                       lcount[r, k])) * dt
                s = H * H * Pp + R
                nu = y[r, k] - H * m[r, p]
                logw[r, p] -= 0.5 * (np.log(s) + nu * nu / s)
                K = Pp * H / s
                m[r, p] += K * nu
                P[r, p] = (1.0 - K * H) * Pp
            ess = _k_normalise(r, logw, w, nres)
            if ess < 0:
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
            _k_resample(ess, thr, r, logw, w, unif[r, i], b, m, P, 3, c, idx, tmp, nres)


def _check_degenerate(nres: NDArray[np.int64], label: str) -> None:
    bad = np.flatnonzero(nres < 0)
    if bad.size:
        raise FloatingPointError(f"{label}: degenerate weights in unit {int(bad[0])}")


def _quad_arrays(quad: WindowQuadrature) -> tuple[FloatArray, ...]:
    return (np.ascontiguousarray(quad.center), np.ascontiguousarray(quad.scale),
            np.ascontiguousarray(quad.nodes), np.ascontiguousarray(quad.weights))


def _log_sums_np(b: FloatArray, qa: tuple[FloatArray, ...], k: int, lcount: FloatArray
                 ) -> FloatArray:
    """numpy twin of ``_k_logsum`` for all units/particles at window k (b (U, N)); ``lcount``
    (U, W) the log sample counts."""
    c, s, x, w = (a[:, k] for a in qa)
    inner = (w[:, None, :] * np.exp(-(b * s[:, None])[..., None] * x[:, None, :])).sum(axis=-1)
    return lcount[:, k:k + 1] - b * c[:, None] + np.log(inner)


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


@dataclass
class _Pass:
    """What a tracker's run over U units and W windows works with: the quadrature arrays
    ``qa``, the log sample counts ``lcount`` (U, W), the output, the resampling counts ``nres``
    (U,) and the start time of the run."""

    U: int
    W: int
    qa: tuple[FloatArray, ...]
    lcount: FloatArray
    out: TrackOutput
    nres: NDArray[np.int64]
    t0: float

    @classmethod
    def start(cls, y: FloatArray, quad: WindowQuadrature, n_rngs: int, backend: str) -> _Pass:
        """Check the inputs and allocate the outputs (no random draws)."""
        _check_backend(backend)
        t0 = time.perf_counter()
        U, W = _check_inputs(y, quad, n_rngs)
        lcount = np.ascontiguousarray(np.broadcast_to(quad.log_counts(), (U, W)))
        return cls(U, W, _quad_arrays(quad), lcount, _alloc(U, W), np.zeros(U, np.int64), t0)

    def finish(self) -> TrackOutput:
        """The output with the resampling count and the run's wall time."""
        self.out.n_resampled = int(self.nres.sum())
        self.out.seconds = time.perf_counter() - self.t0
        return self.out


def _blocks(noise: _Noise, W: int, snapshots: Sequence[int]
            ) -> Iterator[tuple[int, int, int, FloatArray, FloatArray]]:
    """The segments ``[a, e)`` of the run with the window offset ``koff`` of their noise block
    and that block's ``eps``, ``unif`` (drawn when the segment is reached)."""
    for a, e in _segments(W, snapshots):
        eps, unif = noise.block(a // CHUNK)
        yield a, e, (a // CHUNK) * CHUNK, eps, unif


def _uniform_rows(rngs: list[np.random.Generator], bounds: tuple[float, float], n: int
                  ) -> FloatArray:
    """(U, n) uniforms on ``bounds``, row r from ``rngs[r]``."""
    lo, hi = bounds
    return np.stack([g.uniform(lo, hi, n) for g in rngs])


def one_step_pf(y: FloatArray, quad: WindowQuadrature, sigma_y: float, settings: DegradationConfig,
                rngs: list[np.random.Generator], *, beta_ref: float,
                snapshot_windows: Sequence[int] = (), progress: Progress | None = None,
                backend: str = "numba") -> TrackOutput:
    """One-step PF over ``[b, beta0]`` (seed 001 eq. 30), batched over units; ``y`` (U, W).

    ``y_k ~ N(beta0 S_k(b) dt, sigma_y^2)``; random walks on b and beta0 (beta0 reflected at 0).
    """
    run = _Pass.start(y, quad, len(rngs), backend)
    U, W, qa, lcount, out, nres = run.U, run.W, run.qa, run.lcount, run.out, run.nres
    N = settings.n_particles
    b = _uniform_rows(rngs, settings.b_prior, N)
    beta = _uniform_rows(rngs, settings.beta0_prior_rel, N) * beta_ref
    logw = np.full((U, N), -np.log(N))
    qb, qbeta, thr = settings.q_b, settings.q_beta0_rel * beta_ref, settings.ess_threshold
    for a, e, koff, eps, unif in _blocks(_Noise(rngs, N, 2), W, snapshot_windows):
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
    return run.finish()


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
    run = _Pass.start(y, quad, len(rngs_b), backend)
    U, W, qa, lcount, out, nres = run.U, run.W, run.qa, run.lcount, run.out, run.nres
    N = settings.n_particles
    thr = settings.ess_threshold
    # PF1 on b from ratios of consecutive window losses
    b = _uniform_rows(rngs_b, settings.b_prior, N)
    logw = np.full((U, N), -np.log(N))
    ok = np.zeros((U, W), dtype=np.bool_)
    ok[:, 1:] = (y[:, 1:] > 0) & (y[:, :-1] > 0)
    ysafe = np.where(y > 0, y, 1.0)
    dlny = np.zeros((U, W))
    dlny[:, 1:] = np.where(ok[:, 1:], np.log(ysafe[:, 1:]) - np.log(ysafe[:, :-1]), 0.0)
    sd = np.ones((U, W))
    sd[:, 1:] = np.where(ok[:, 1:], np.sqrt((sigma_y / ysafe[:, 1:]) ** 2
                                            + (sigma_y / ysafe[:, :-1]) ** 2), 1.0)
    snaps_b: dict[int, tuple[FloatArray, FloatArray]] = {}
    for a, e, koff, eps, unif in _blocks(_Noise(rngs_b, N, 1), W, snapshot_windows):
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
    beta = _uniform_rows(rngs_beta, settings.beta0_prior_rel, N) * beta_ref
    logw = np.full((U, N), -np.log(N))
    qbeta = settings.q_beta0_rel * beta_ref
    for a, e, koff, eps, unif in _blocks(_Noise(rngs_beta, N, 1), W, snapshot_windows):
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
    return run.finish()


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
    run = _Pass.start(y, quad, len(rngs), backend)
    U, W, qa, lcount, out, nres = run.U, run.W, run.qa, run.lcount, run.out, run.nres
    N = settings.n_particles
    b = _uniform_rows(rngs, settings.b_prior, N)
    m0, P0 = settings.beta0_gaussian_prior(beta_ref)
    m, P = np.full((U, N), m0), np.full((U, N), P0)
    logw = np.full((U, N), -np.log(N))
    q2 = (settings.q_beta0_rel * beta_ref) ** 2
    R = sigma_y**2
    thr = settings.ess_threshold
    for a, e, koff, eps, unif in _blocks(_Noise(rngs, N, 1), W, snapshot_windows):
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
    return run.finish()


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
    m0, P0 = settings.beta0_gaussian_prior(beta_ref)
    x0 = np.column_stack([rng.uniform(lo, hi, N), np.full(N, m0), np.full(N, P0)])
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
