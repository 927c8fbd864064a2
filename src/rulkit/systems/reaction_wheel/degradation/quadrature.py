"""Window sums of step 2 by Gauss quadrature (docs/systems/reaction-wheel.md §4, (RW-19)):

    S_k(b) = sum_{j in window k} exp(-b / T^_j)

evaluated for many particles at once by a Gauss rule on each window's empirical distribution of
``u = 1/T^`` (:func:`window_quadrature`), n nodes per window instead of 4,800 exponentials per
particle; :func:`path_quadrature` builds the same rule on a deterministic future path (step 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from rulkit.systems.reaction_wheel.lubrication import (
    SAMPLE_DT,
    FloatArray,
    TemperaturePath,
    check_temperature,
)


@dataclass(frozen=True)
class WindowQuadrature:
    """Gauss rule per window for the empirical distribution of ``u = 1/T^`` in that window.

    ``u_j = center + scale * x_j``; ``nodes`` (..., W, n) hold the standardised nodes ``x_i`` and
    ``weights`` (..., W, n) the Gauss weights (summing to 1); ``count`` is the number of samples
    per window, one number or one per window (a user's windows differ in length). Then
    ``S_k(b) ~= count_k * exp(-b c_k) * sum_i w_ki exp(-b s_k x_ki)``, exact for
    any ``b`` when ``exp(-b s x)`` is a polynomial of degree <= 2n - 1 in x.
    """

    center: FloatArray
    scale: FloatArray
    nodes: FloatArray
    weights: FloatArray
    count: float | FloatArray

    @property
    def n_windows(self) -> int:
        """Number of windows W."""
        return int(self.center.shape[-1])

    @property
    def n_nodes(self) -> int:
        """Gauss nodes per window n."""
        return int(self.nodes.shape[-1])

    def log_sums(self, b: FloatArray, k: int | slice) -> FloatArray:
        """``ln S_k(b)`` for particles ``b``; ``b`` shape (..., N) matching the leading axes.

        With a leading run axis (R, W): ``b`` (R, N) -> (R, N). Without (W,): ``b`` (N,) -> (N,).
        Costs N * n exponentials per window instead of N * 4800.
        """
        c = self.center[..., k][..., None]
        s = self.scale[..., k][..., None]
        x = self.nodes[..., k, :][..., None, :]
        w = self.weights[..., k, :][..., None, :]
        b = np.asarray(b, dtype=np.float64)
        inner = (w * np.exp(-(b * s)[..., None] * x)).sum(axis=-1)
        return self.log_counts()[..., k][..., None] - b * c + np.log(inner)

    def log_counts(self) -> FloatArray:
        """``ln count`` per window, shape of ``center`` (a scalar ``count`` broadcast)."""
        return np.broadcast_to(np.log(np.asarray(self.count, dtype=np.float64)),
                               self.center.shape)

    def sums(self, b: FloatArray, k: int | slice) -> FloatArray:
        """``S_k(b)`` for particles ``b`` (see :meth:`log_sums`)."""
        return np.exp(self.log_sums(b, k))


def window_quadrature(u: FloatArray, n_nodes: int = 5, *, count: float | FloatArray | None = None,
                      backend: str = "numba") -> WindowQuadrature:
    """Gauss quadrature of the empirical distribution of ``u`` per window (last axis: samples).

    ``u`` has shape (..., W, m): m equally weighted values per window (m = 4800 for a 0.05 s
    estimate, fewer for a sample-and-hold path whose values repeat). ``count`` is the number of
    0.05 s samples the window stands for (default m). The rule is built by the discretised
    Stieltjes procedure on the standardised values ``x = (u - mean)/std`` (Gautschi 2004,
    "Orthogonal Polynomials", section 2.2.3; stable, unlike Hankel moment matrices), then the
    Golub-Welsch eigen-decomposition of the Jacobi matrix. A window with fewer than ``n_nodes``
    distinct values (e.g. a constant T) gets zero-weight spare nodes, so the rule stays exact.
    ``backend="numba"``: compiled per-window kernel; ``"numpy"``: vectorised reference path
    (same numbers to round-off, tested).
    """
    u = np.asarray(u, dtype=np.float64)
    if u.ndim < 2:
        raise ValueError(f"u: expected shape (..., W, m), got {u.shape}")
    if not np.all(np.isfinite(u)):
        raise ValueError("u: non-finite values (a temperature of 0 C or NaN in T^?)")
    if not 1 <= n_nodes <= 12:
        raise ValueError(f"n_nodes: expected 1..12, got {n_nodes}")
    m = u.shape[-1]
    lead = u.shape[:-1]
    if backend == "numba":
        flat = np.ascontiguousarray(u.reshape(-1, m))
        center, scale, alpha, beta = _stieltjes_kernel(flat, n_nodes)
        center, scale = center.reshape(lead), scale.reshape(lead)
        alpha, beta = alpha.reshape(*lead, n_nodes), beta.reshape(*lead, n_nodes)
    elif backend == "numpy":
        center, scale, alpha, beta = _stieltjes_numpy(u, n_nodes)
    else:
        raise ValueError(f"backend: expected 'numba' or 'numpy', got {backend!r}")
    J = np.zeros((*lead, n_nodes, n_nodes))
    idx = np.arange(n_nodes)
    J[..., idx, idx] = alpha
    off = np.sqrt(beta[..., 1:])
    J[..., idx[:-1], idx[1:]] = off
    J[..., idx[1:], idx[:-1]] = off
    nodes, vecs = np.linalg.eigh(J)
    weights = vecs[..., 0, :] ** 2
    weights /= weights.sum(axis=-1, keepdims=True)
    return WindowQuadrature(center=center, scale=scale, nodes=nodes, weights=weights,
                            count=float(m) if count is None else count)


_TINY_REL = 1e-14  # a window whose std is below this x |mean| is treated as constant


_NORM_FLOOR = 1e-24  # relative drop of the Stieltjes norm that ends the recurrence


def _stieltjes_numpy(u: FloatArray, n_nodes: int
                     ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Vectorised reference: recurrence coefficients of the standardised empirical measure."""
    center = u.mean(axis=-1)
    scale = np.sqrt(((u - center[..., None]) ** 2).mean(axis=-1))
    const = scale <= _TINY_REL * np.abs(center) + 1e-300
    safe = np.where(const, 1.0, scale)
    x = (u - center[..., None]) / safe[..., None]
    x[const] = 0.0
    lead = u.shape[:-1]
    alpha = np.zeros((*lead, n_nodes))
    beta = np.zeros((*lead, n_nodes))  # beta[..., k] couples p_{k-1} and p_k (k >= 1)
    p_prev = np.zeros_like(x)
    p = np.ones_like(x)
    norm = np.ones(lead)  # (1/m) sum p_k^2 of the monic polynomials
    for k in range(n_nodes):
        alive = norm > 0.0
        xp2 = (x * p * p).mean(axis=-1)
        alpha[..., k] = np.where(alive, xp2 / np.where(alive, norm, 1.0), 0.0)
        if k + 1 == n_nodes:
            break
        p_next = (x - alpha[..., k][..., None]) * p - beta[..., k][..., None] * p_prev
        norm_next = (p_next * p_next).mean(axis=-1)
        ok = alive & (norm_next > _NORM_FLOOR * norm)
        beta[..., k + 1] = np.where(ok, norm_next / np.where(alive, norm, 1.0), 0.0)
        p_next[~ok] = 0.0
        p_prev, p = p, p_next
        norm = np.where(ok, norm_next, 0.0)
    return center, np.where(const, 0.0, scale), alpha, beta


@numba.njit(cache=True, fastmath=True)
def _stieltjes_kernel(u: FloatArray, n_nodes: int
                      ) -> tuple[FloatArray, ...]:  # pragma: no cover - compiled
    """Compiled twin of :func:`_stieltjes_numpy` for ``u`` (M, m): one window per row."""
    M, m = u.shape
    center = np.empty(M)
    scale = np.empty(M)
    alpha = np.zeros((M, n_nodes))
    beta = np.zeros((M, n_nodes))
    x = np.empty(m)
    p = np.empty(m)
    pp = np.empty(m)
    for r in range(M):
        c = 0.0
        for j in range(m):
            c += u[r, j]
        c /= m
        v = 0.0
        for j in range(m):
            d = u[r, j] - c
            v += d * d
        sd = np.sqrt(v / m)
        center[r] = c
        if sd <= _TINY_REL * abs(c) + 1e-300:
            scale[r] = 0.0
            continue  # constant window: one node at x = 0 (alpha = beta = 0)
        scale[r] = sd
        for j in range(m):
            x[j] = (u[r, j] - c) / sd
            p[j] = 1.0
            pp[j] = 0.0
        norm = 1.0
        for k in range(n_nodes):
            xp2 = 0.0
            for j in range(m):
                xp2 += x[j] * p[j] * p[j]
            a = xp2 / m / norm
            alpha[r, k] = a
            if k + 1 == n_nodes:
                break
            bk = beta[r, k]
            nn = 0.0
            for j in range(m):
                pn = (x[j] - a) * p[j] - bk * pp[j]
                pp[j] = p[j]
                p[j] = pn
                nn += pn * pn
            nn /= m
            if not nn > _NORM_FLOOR * norm:
                break
            beta[r, k + 1] = nn / norm
            norm = nn
    return center, scale, alpha, beta


def direct_log_sums(u: FloatArray, b: FloatArray, *, multiplicity: float = 1.0) -> FloatArray:
    """Reference ``ln sum_j exp(-b u_j)`` by the direct sum (log-sum-exp), ``u`` (W, m), ``b`` (N,).

    Returns (W, N). ``multiplicity`` multiplies each term (sample-and-hold values standing for
    several 0.05 s samples). Costs N * m exponentials per window: the baseline of the benchmark.
    """
    u = np.asarray(u, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a = -b[None, :, None] * u[:, None, :]
    amax = a.max(axis=-1)
    return amax + np.log(np.exp(a - amax[..., None]).sum(axis=-1)) + np.log(multiplicity)


def path_quadrature(path: TemperaturePath, t0: float, n_windows: int, window_s: float, *,
                    points_per_window: int = 720, n_nodes: int = 5) -> WindowQuadrature:
    """Quadrature of ``1/T`` for a deterministic path over windows of ``window_s`` from ``t0``.

    Used by the step-3 forecast (windows of an hour): ``count`` is the number of 0.05 s samples
    per window, the distribution of ``u`` is taken at ``points_per_window`` midpoints.
    """
    dt_pt = window_s / points_per_window
    t = np.asarray(t0 + (np.arange(n_windows)[:, None] * points_per_window
                         + np.arange(points_per_window) + 0.5) * dt_pt, dtype=np.float64)
    T = path(t)
    check_temperature(T, "temperature path")
    return window_quadrature(1.0 / T, n_nodes, count=window_s / SAMPLE_DT)
