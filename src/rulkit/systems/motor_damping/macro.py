"""Macro EKF across cycles and the RUL in cycles (seed 002 eqs. 4-7, section 3.2 and 4.3).

State ``x_n = [c_n, a_n]`` (damping trend value and slope per cycle). Between observed cycles
``n_{i-1} -> n_i`` (gap ``D``) the model is the integrated random walk

    F = [[1, D], [0, 1]],  Q = q_a [[D^3/3, D^2/2], [D^2/2, D]]

(the Van Loan discretisation of ``dc/dn = a, da/dn = white noise of density q_a``; ``q_a = 0`` is
the seed's linear law eq. 4, F is eq. 7). Measurement ``z_n = c_n + v_n``, ``H = [1, 0]``, with
``var(v_n) = r_n + s^2``: the micro EKF's variance of that cycle plus the cycle-to-cycle
scatter of the damping, estimated from the residuals of a straight-line fit
(docs/systems/motor-damping.md §6).

After each cycle n the filter is re-run on cycles 1..n with the scatter estimated from those
cycles only (no look-ahead), all runs of a Monte Carlo study together as a batch of units.

RUL (cycles after cycle n until the damping crosses ``c_fail``):

* ``"covariance"`` - from the EKF covariance: the predicted damping ``c(n+m) ~ N(mu(m), v(m))``,
  ``mu = c + a m``, ``v = P_cc + 2 m P_ca + m^2 P_aa + q_a m^3 / 3 (+ s^2)``. The q-quantile of
  the crossing time solves ``mu(m) - z_q sqrt(v(m)) = c_fail`` (the seed's predictive bands
  crossing the threshold, Figs. 13-15). For ``q_a = 0`` and the trend truth this is exact
  (``T <= m  <=>  c + a m >= c_fail`` for a > 0), otherwise a marginal approximation.
* ``"monte-carlo"`` - samples of ``[c, a]`` from ``N(x, P)`` propagated with the model's process
  noise by :func:`rulkit.prognosis.rul.propagate_to_threshold` (censored at the horizon).

Quadratic (constant-acceleration) option, ``MacroSettings(model="quadratic")``: state
``x_n = [c_n, a_n, j_n]`` (damping, slope per cycle, change of the slope per cycle), i.e. the
trend ``c(n + m) = c + a m + j m^2 / 2``, with

    F = [[1, D, D^2/2], [0, 1, D], [0, 0, 1]],
    Q = q [[D^5/20, D^4/8, D^3/6], [D^4/8, D^3/3, D^2/2], [D^3/6, D^2/2, D]]

(Van Loan discretisation of ``d^3 c/dn^3 = white noise of density q``; ``q = 0``: an exact
quadratic law; ``q`` is ``MacroSettings.q_a`` for this model). It generalises the seed's
linear law (eq. 4) by one order; with a zero curvature prior (``j_prior_sd -> 0``) it is the
linear filter. The scatter is then estimated from the residuals of a quadratic fit (dof n - 3).
Predicted damping ``mu = h(m)^T x``, ``v = h^T P h + q m^5 / 20 (+ s^2)`` with
``h = [1, m, m^2/2]``; the RUL quantiles and Monte Carlo use the same machinery as the linear
law. :func:`quadratic_crossing` is the analytic first crossing of the trend with ``c_fail``.

Truth (``truth=``): ``"trend"`` - the cycle at which the damping trend crosses ``c_fail``
(real-valued); ``"first-crossing"`` - the first cycle whose (noisy) damping is ``>= c_fail``
(integer). For the latter the predictive distributions include the future scatter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.stats import norm

FloatArray = NDArray[np.float64]

MACRO_MODELS = ("linear", "quadratic")

__all__ = [
    "MacroSettings",
    "MacroTrack",
    "estimate_scatter_var",
    "macro_filter",
    "macro_track",
    "predicted_damping",
    "quadratic_crossing",
    "rul_covariance_quantiles",
    "rul_monte_carlo",
]


@dataclass(frozen=True)
class MacroSettings:
    """Tuning of the macro EKF.

    ``q_a``: spectral density of the slope's random walk per cycle (0: seed's linear law).
    ``q_a_grid``: when given, ``q_a`` is chosen after every cycle and for every unit by maximum
    marginal likelihood (sum of the innovations' log-likelihoods of cycles 1..n) over these
    values (type-II maximum likelihood; no look-ahead).
    ``c_prior_sd``, ``a_prior_sd``: zero-mean prior at cycle 0 (diffuse: 1e-3 is ~7x c_fail,
    1e-5 per cycle ~5x the synthetic slope). Scatter variance at cycle n:
    ``s^2 = max((nu0 s0^2 + RSS_n) / (nu0 + n - 2) - mean(r), 0)`` with a weak prior
    ``s0 = scatter_prior_sd`` worth ``nu0 = scatter_prior_dof`` residuals (default 0: the pure
    residual estimate; ``s0`` is then only used while n <= 2); ``scatter_sd`` fixes ``s``.
    ``include_scatter=False`` uses the micro variance alone (the failure mode of
    docs/systems/motor-damping.md §6).
    ``model``: ``"linear"`` (the seed's law, state [c, a]) or ``"quadratic"`` (state [c, a, j],
    module docstring); ``j_prior_sd``: zero-mean prior sd of the curvature j (change of the
    slope per cycle) at cycle 0, used by the quadratic model only (default 1e-7 per cycle^2:
    the slope may change by ~1e-5 per 100 cycles, 5x the synthetic slope, in line with
    ``a_prior_sd``). For the quadratic model ``q_a`` / ``q_a_grid`` are the density of the
    curvature's random walk.
    """

    q_a: float = 0.0
    q_a_grid: tuple[float, ...] | None = None
    c_prior_sd: float = 1.0e-3
    a_prior_sd: float = 1.0e-5
    scatter_prior_sd: float = 5.0e-6
    scatter_prior_dof: float = 0.0
    scatter_sd: float | None = None
    include_scatter: bool = True
    model: str = "linear"
    j_prior_sd: float = 1.0e-7

    def __post_init__(self) -> None:
        if self.model not in MACRO_MODELS:
            raise ValueError(
                f"model: expected one of {', '.join(MACRO_MODELS)}, got {self.model!r}"
            )
        if not self.j_prior_sd >= 0:
            raise ValueError(f"j_prior_sd: expected >= 0, got {self.j_prior_sd}")
        if not self.q_a >= 0:
            raise ValueError(f"q_a: expected >= 0, got {self.q_a}")
        if self.q_a_grid is not None and (
            len(self.q_a_grid) == 0 or not all(q >= 0 for q in self.q_a_grid)
        ):
            raise ValueError(f"q_a_grid: expected non-negative values, got {self.q_a_grid}")
        for name in ("c_prior_sd", "a_prior_sd"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: expected > 0, got {getattr(self, name)}")
        if self.scatter_sd is not None and not self.scatter_sd >= 0:
            raise ValueError(f"scatter_sd: expected >= 0, got {self.scatter_sd}")

    @property
    def dim(self) -> int:
        """Size of the macro state: 2 (linear) or 3 (quadratic)."""
        return 2 if self.model == "linear" else 3

    def prior_cov(self) -> FloatArray:
        """Prior covariance of the state at cycle 0 (zero mean)."""
        sds = [self.c_prior_sd, self.a_prior_sd]
        if self.model == "quadratic":
            sds.append(self.j_prior_sd)
        return np.diag(np.square(sds))


def _transition(gap: float, q_a: float, dim: int = 2) -> tuple[FloatArray, FloatArray]:
    """F and Q for a gap of ``gap`` cycles (module docstring); ``dim`` 2 (linear) or 3
    (quadratic)."""
    D = gap
    if dim == 2:
        F = np.array([[1.0, D], [0.0, 1.0]])
        Q = q_a * np.array([[D**3 / 3.0, D**2 / 2.0], [D**2 / 2.0, D]])
        return F, Q
    F = np.array([[1.0, D, D * D / 2.0], [0.0, 1.0, D], [0.0, 0.0, 1.0]])
    Q = q_a * np.array([
        [D**5 / 20.0, D**4 / 8.0, D**3 / 6.0],
        [D**4 / 8.0, D**3 / 3.0, D**2 / 2.0],
        [D**3 / 6.0, D**2 / 2.0, D],
    ])
    return F, Q


def estimate_scatter_var(
    cycles: np.ndarray, z: np.ndarray, r: np.ndarray, settings: MacroSettings
) -> FloatArray:
    """Cycle-to-cycle scatter variance ``s^2`` per unit from cycles (n,), estimates ``z`` (B, n)
    and their micro variances ``r`` (B, n) (residuals of a straight line, or of a quadratic for
    ``model="quadratic"``; see :class:`MacroSettings`)."""
    z = np.atleast_2d(z)
    b, n = z.shape
    if not settings.include_scatter:
        return np.zeros(b)
    if settings.scatter_sd is not None:
        return np.full(b, settings.scatter_sd**2)
    x = np.asarray(cycles, dtype=np.float64)
    nu0 = settings.scatter_prior_dof
    s0 = settings.scatter_prior_sd
    if settings.model == "quadratic" and n >= 3:
        xc = x - x.mean()
        X = np.column_stack([np.ones(n), xc, xc * xc])
        beta, *_ = np.linalg.lstsq(X, z.T, rcond=None)
        rss = np.sum((z.T - X @ beta) ** 2, axis=0)
        dof = n - 3
    elif settings.model == "quadratic":
        rss = np.zeros(b)
        dof = 0
    elif n >= 2:
        xm = x.mean()
        zm = z.mean(axis=1, keepdims=True)
        sxx = np.sum((x - xm) ** 2)
        beta = ((x - xm) * (z - zm)).sum(axis=1, keepdims=True) / sxx if sxx > 0 else 0.0
        rss = np.sum((z - zm - beta * (x - xm)) ** 2, axis=1)
        dof = n - 2
    else:
        rss = np.zeros(b)
        dof = 0
    if nu0 + dof <= 0:
        return np.full(b, s0**2)
    total = (nu0 * s0**2 + rss) / (nu0 + dof)
    return np.maximum(total - np.mean(np.atleast_2d(r), axis=1), 0.0)


def _check_cycles(cycles: np.ndarray, z: FloatArray, r: FloatArray) -> FloatArray:
    """Cycles (n,) finite, >= 0 and strictly increasing; ``z``/``r`` (B, n) finite, r >= 0.

    The prior sits at cycle 0 and every gap must be positive: an unsorted or repeated cycle
    would silently skip a prediction (wrong slope and covariance), so it is refused.
    """
    cyc = np.asarray(cycles, dtype=np.float64)
    if cyc.ndim != 1 or cyc.size == 0 or cyc.shape[0] != z.shape[1] or r.shape != z.shape:
        raise ValueError(
            f"cycles (n,), z and meas_var (B, n): got {cyc.shape}, {z.shape} and {r.shape}"
        )
    if not np.isfinite(cyc).all() or cyc[0] < 0 or np.any(np.diff(cyc) <= 0):
        raise ValueError(
            f"cycles: expected finite cycle numbers >= 0 in strictly increasing order, got "
            f"{cyc.tolist()}"
        )
    for name, a in (("z", z), ("meas_var", r)):
        if not np.isfinite(a).all():
            b, i = np.argwhere(~np.isfinite(a))[0]
            raise ValueError(f"{name}: non-finite value at unit {b}, cycle {cyc[i]:g}")
    if np.any(r < 0):
        b, i = np.argwhere(r < 0)[0]
        raise ValueError(f"meas_var: negative variance {r[b, i]!r} at unit {b}, cycle {cyc[i]:g}")
    return cyc


def macro_filter(
    cycles: np.ndarray,
    z: np.ndarray,
    meas_var: np.ndarray,
    settings: MacroSettings,
    q_a: float | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Filter the damping estimates ``z`` (B, n) of cycles (n,) with measurement variances
    ``meas_var`` (B, n); returns the final ``x`` (B, 2), ``P`` (B, 2, 2) (seed eqs. 5-7) and the
    log marginal likelihood (B,), using the engine's :func:`kf_predict` / :func:`kf_update`
    (``x`` (B, 3), ``P`` (B, 3, 3) for ``settings.model == "quadratic"``).
    ``q_a`` overrides ``settings.q_a``. Cycles must be strictly increasing and >= 0, ``z`` and
    ``meas_var`` finite (``ValueError`` otherwise)."""
    from rulkit.estimation.kalman import kf_predict, kf_update

    z = np.atleast_2d(np.asarray(z, dtype=np.float64))
    rv = np.atleast_2d(np.asarray(meas_var, dtype=np.float64))
    b, n = z.shape
    cyc = _check_cycles(cycles, z, rv)
    d = settings.dim
    x = np.zeros((b, d))
    P = np.broadcast_to(settings.prior_cov(), (b, d, d))
    H = np.eye(1, d)
    qa = settings.q_a if q_a is None else float(q_a)
    loglik = np.zeros(b)
    prev = 0.0
    for i in range(n):
        gap = cyc[i] - prev
        if gap > 0:
            F, Q = _transition(gap, qa, d)
            x, P = kf_predict(x, P, F, Q)
        prev = cyc[i]
        x, P, inn = kf_update(x, P, z[:, i : i + 1], H, rv[:, i, None, None])
        loglik += inn.loglik
    return x, P, loglik


@dataclass(frozen=True)
class MacroTrack:
    """Macro posterior after every cycle: ``cycles`` (n,), ``x`` (n, B, d), ``P`` (n, B, d, d)
    (d = 2 linear, 3 quadratic),
    ``scatter_var`` (n, B) (the ``s^2`` used at that cycle), ``q_a`` (n, B) (the slope noise
    used at that cycle)."""

    cycles: FloatArray
    x: FloatArray
    P: FloatArray
    scatter_var: FloatArray
    q_a: FloatArray


def macro_track(
    cycles: np.ndarray, z: np.ndarray, r: np.ndarray, settings: MacroSettings
) -> MacroTrack:
    """The macro posterior after each cycle n, from cycles 1..n only (scatter, and ``q_a`` when
    ``settings.q_a_grid`` is given, estimated from cycles 1..n: no look-ahead).

    Vectorised: every (prefix n, unit, q_a candidate) is one unit of a single batched filter
    over all cycles; a prefix's measurements after its cycle n are NaN (skipped by
    :func:`kf_update`) and its posterior is read right after cycle n's update. Equivalent to
    re-running :func:`macro_filter` on every prefix (tested).
    """
    from rulkit.estimation.kalman import kf_predict, kf_update

    z = np.atleast_2d(np.asarray(z, dtype=np.float64))
    r = np.atleast_2d(np.asarray(r, dtype=np.float64))
    cyc = _check_cycles(cycles, z, r)
    b, n = z.shape
    grid = np.asarray((settings.q_a,) if settings.q_a_grid is None else settings.q_a_grid)
    g = grid.size
    s2 = np.empty((n, b))
    for k in range(n):
        s2[k] = estimate_scatter_var(cyc[: k + 1], z[:, : k + 1], r[:, : k + 1], settings)
    # units ordered (g, k, b)
    u = g * n * b
    qa_u = np.repeat(grid, n * b)
    d = settings.dim
    x = np.zeros((u, d))
    P = np.broadcast_to(settings.prior_cov(), (u, d, d))
    H = np.eye(1, d)
    loglik = np.zeros(u)
    xs = np.empty((g, n, b, d))
    Ps = np.empty((g, n, b, d, d))
    lls = np.empty((g, n, b))
    kk = np.arange(n)
    prev = 0.0
    for i in range(n):
        gap = cyc[i] - prev
        if gap > 0:
            F, _ = _transition(gap, 0.0, d)
            Qu = qa_u[:, None, None] * _transition(gap, 1.0, d)[1]
            x, P = kf_predict(x, P, F, Qu)
        prev = cyc[i]
        y = np.where(kk[:, None] >= i, z[None, :, i], np.nan)  # (n, b): prefix k sees cycle i<=k
        y = np.broadcast_to(y, (g, n, b)).reshape(u, 1)
        rv = np.broadcast_to(r[None, None, :, i] + s2[None], (g, n, b)).reshape(u, 1, 1)
        x, P, inn = kf_update(x, P, y, H, rv)
        loglik += inn.loglik
        xs[:, i] = x.reshape(g, n, b, d)[:, i]
        Ps[:, i] = P.reshape(g, n, b, d, d)[:, i]
        lls[:, i] = loglik.reshape(g, n, b)[:, i]
    best = np.argmax(lls, axis=0)  # (n, b): first maximum, i.e. the smallest q_a on ties
    x_best = np.take_along_axis(xs, best[None, :, :, None], axis=0)[0]
    P_best = np.take_along_axis(Ps, best[None, :, :, None, None], axis=0)[0]
    return MacroTrack(cycles=cyc, x=x_best, P=P_best, scatter_var=s2, q_a=grid[best])


def predicted_damping(
    x: FloatArray,
    P: FloatArray,
    m: np.ndarray,
    q_a: np.ndarray | float,
    extra_var: np.ndarray | float = 0.0,
) -> tuple[FloatArray, FloatArray]:
    """Mean and variance of the damping ``m`` cycles ahead: (B, M) each (module docstring);
    ``q_a`` and ``extra_var`` scalars or (B,). The model follows from ``x``: (B, 2) linear,
    (B, 3) quadratic."""
    m = np.asarray(m, dtype=np.float64)
    q_a = np.asarray(q_a, dtype=np.float64).reshape(-1, 1)
    if x.shape[1] == 3:
        h = np.stack([np.ones_like(m), m, 0.5 * m * m])  # (3, M)
        mu = x @ h
        v = (
            np.einsum("im,bij,jm->bm", h, P, h)
            + q_a * m**5 / 20.0
            + np.asarray(extra_var, dtype=np.float64).reshape(-1, 1)
        )
        return mu, v
    mu = x[:, 0, None] + x[:, 1, None] * m
    v = (
        P[:, 0, 0, None]
        + 2.0 * m * P[:, 0, 1, None]
        + m * m * P[:, 1, 1, None]
        + q_a * m**3 / 3.0
        + np.asarray(extra_var, dtype=np.float64).reshape(-1, 1)
    )
    return mu, v


def rul_covariance_quantiles(
    x: FloatArray,
    P: FloatArray,
    c_fail: float,
    levels: np.ndarray,
    *,
    q_a: np.ndarray | float = 0.0,
    extra_var: np.ndarray | float = 0.0,
    horizon: float = 300.0,
    step: float = 0.1,
) -> FloatArray:
    """RUL quantiles (B, L) from the EKF covariance (module docstring): for each level q the
    first ``m`` on a grid (spacing ``step``, linear interpolation inside a cell) with
    ``mu(m) - z_q sqrt(v(m)) >= c_fail``; ``inf`` when not reached within ``horizon``."""
    x = np.atleast_2d(x)
    d = x.shape[1]
    P = np.asarray(P).reshape(-1, d, d)
    grid = np.arange(0.0, horizon + 0.5 * step, step)
    mu, v = predicted_damping(x, P, grid, q_a, extra_var)
    sd = np.sqrt(np.maximum(v, 0.0))
    zq = norm.ppf(np.asarray(levels, dtype=np.float64))
    g = mu[:, None, :] - zq[None, :, None] * sd[:, None, :] - c_fail  # (B, L, M)
    above = g >= 0
    first = np.argmax(above, axis=2)
    found = above.any(axis=2)
    j1 = np.maximum(first, 1)
    g1 = np.take_along_axis(g, j1[..., None], axis=2)[..., 0]
    g0 = np.take_along_axis(g, (j1 - 1)[..., None], axis=2)[..., 0]
    frac = np.where(g1 > g0, -g0 / np.where(g1 > g0, g1 - g0, 1.0), 1.0)
    m_cross = grid[j1 - 1] + step * np.clip(frac, 0.0, 1.0)
    m_cross = np.where(first == 0, 0.0, m_cross)
    return np.where(found, m_cross, np.inf)


def rul_monte_carlo(
    x: FloatArray,
    P: FloatArray,
    c_fail: float,
    rng: np.random.Generator,
    *,
    n_samples: int = 400,
    q_a: np.ndarray | float = 0.0,
    scatter_var: np.ndarray | None = None,
    horizon: float = 300.0,
    t0: float = 0.0,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Monte Carlo RUL samples (B, S) and censored flags (B, S) for B units at once.

    ``[c, a]`` (``[c, a, j]`` for the quadratic model, ``x`` (B, 3)) drawn from ``N(x_b, P_b)``,
    propagated one cycle at a time with ``F``, ``Q`` (module docstring) by
    :func:`propagate_to_threshold`. Without ``scatter_var`` the indicator
    is the trend ``c`` (trend truth; crossing interpolated within the cycle); with it, each
    future cycle's damping is ``c + N(0, s_b^2)`` and the RUL is the first whole cycle whose
    damping reaches ``c_fail`` (first-crossing truth).
    """
    from rulkit.prognosis.rul import propagate_to_threshold

    x = np.atleast_2d(x)
    d = x.shape[1]
    P = np.asarray(P).reshape(-1, d, d)
    b = x.shape[0]
    s = int(n_samples)
    # Cholesky with a relative jitter (P is PSD but may be near-singular in c)
    scale = np.sqrt(np.maximum(np.diagonal(P, axis1=1, axis2=2), 1e-300))
    corr = P / (scale[:, :, None] * scale[:, None, :])
    corr = corr + 1e-12 * np.eye(d)
    L = np.linalg.cholesky(corr) * scale[:, :, None]
    eps = rng.standard_normal((b, s, d))
    draws = x[:, None, :] + np.einsum("bij,bsj->bsi", L, eps)
    first = scatter_var is not None
    n_col = d + 1 if first else d
    x0 = np.empty((b * s, n_col))
    x0[:, :d] = draws.reshape(b * s, d)
    s_sd = None
    if first:
        s_sd = np.repeat(np.sqrt(np.asarray(scatter_var, dtype=np.float64)), s)
        x0[:, d] = x0[:, 0]  # the current cycle's damping is not "future": no crossing at t0

    qa = np.repeat(np.broadcast_to(np.asarray(q_a, dtype=np.float64), (b,)), s)
    noisy = bool(np.any(qa > 0))
    if d == 3:
        # exact triple-integrated-random-walk noise over one cycle: q * chol(Q(1) / q)
        L3 = np.linalg.cholesky(_transition(1.0, 1.0, 3)[1])

        def step3(xk: FloatArray, u: object, t: float, dt: float, rng_: np.random.Generator
                  ) -> FloatArray:
            out = np.empty_like(xk)
            out[:, 0] = xk[:, 0] + xk[:, 1] * dt + 0.5 * xk[:, 2] * dt * dt
            out[:, 1] = xk[:, 1] + xk[:, 2] * dt
            out[:, 2] = xk[:, 2]
            if noisy:
                Lq = L3 if dt == 1.0 else np.linalg.cholesky(_transition(dt, 1.0, 3)[1])
                e = rng_.standard_normal((xk.shape[0], 3)) @ Lq.T
                out[:, :3] += np.sqrt(qa)[:, None] * e
            if s_sd is not None:
                out[:, 3] = out[:, 0] + s_sd * rng_.standard_normal(xk.shape[0])
            return out

    def step(xk: FloatArray, u: object, t: float, dt: float, rng_: np.random.Generator
             ) -> FloatArray:
        out = np.empty_like(xk)
        out[:, 0] = xk[:, 0] + xk[:, 1] * dt
        out[:, 1] = xk[:, 1]
        if noisy:
            # exact integrated-random-walk noise over dt: Q = q_a [[dt^3/3, dt^2/2], [., dt]]
            e1 = rng_.standard_normal(xk.shape[0])
            e2 = rng_.standard_normal(xk.shape[0])
            sa = np.sqrt(qa * dt)
            out[:, 1] += sa * e1
            out[:, 0] += sa * dt * (0.5 * e1 + np.sqrt(1.0 / 12.0) * e2)
        if s_sd is not None:
            out[:, 2] = out[:, 0] + s_sd * rng_.standard_normal(xk.shape[0])
        return out

    col = d if first else 0
    dist = propagate_to_threshold(
        x0, step if d == 2 else step3, lambda xk: xk[:, col], c_fail, t0=t0, dt=1.0,
        horizon=horizon, rng=rng,
    )
    samples = np.asarray(dist.samples).reshape(b, s).copy()
    censored = np.asarray(dist.censored).reshape(b, s).copy()
    if first:
        samples = np.where(censored, samples, np.ceil(samples - 1e-9))
    return samples, censored


def quadratic_crossing(
    c: np.ndarray | float, a: np.ndarray | float, j: np.ndarray | float, c_fail: float
) -> FloatArray:
    """First ``m >= 0`` with ``c + a m + j m^2 / 2 >= c_fail`` (the quadratic trend's crossing;
    ``j = 0`` is the seed's linear law ``(c_fail - c) / a``); 0 when ``c >= c_fail`` already,
    ``inf`` when the trend never reaches ``c_fail`` (``a <= 0`` and ``j <= 0``, or ``j < 0``
    with a maximum below ``c_fail``). Elementwise over broadcast arrays.

    Root in the cancellation-free form ``m = 2 d / (a + sqrt(a^2 + 2 j d))``, ``d = c_fail - c``,
    which is the smallest non-negative root whenever the denominator is positive.
    """
    c, a, j = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (c, a, j)))
    dlt = c_fail - c
    disc = a * a + 2.0 * j * dlt
    root = np.sqrt(np.maximum(disc, 0.0))
    den = a + root
    ok = (disc >= 0) & (den > 0)
    m = np.where(ok, 2.0 * dlt / np.where(ok, den, 1.0), np.inf)
    return np.where(dlt <= 0, 0.0, m)
