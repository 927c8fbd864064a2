"""The augmented EKF of seed section 4.2 compiled for long records: the contact quality alpha and
the wear rate m of the friction drive from its measured speeds and current
(docs/systems/friction-drive.md §4, docs/systems/friction-drive.md §9).

One step k (sample k-1 to sample k, the current of sample k-1 held over the step, (FD-1)-(FD-4)):

- mean: ``n_sub`` classical RK4 sub-steps over the sampling step ``t_s``;
- covariance: ``P <- Phi P Phi^T + Q_d`` with ``Phi = expm(F t_s)`` and ``Q_d`` by Van Loan
  from one 8 x 8 exponential, ``F`` the analytic Jacobian of seed eq. 19 taken at the prior mean
  (``jacobian_at = "start"``) or after half an RK4 step (``"midpoint"``, second order in t_s);
- update with ``y = [w1, w2]`` (Joseph form); a missing channel (NaN) is left out of the
  update, a sample with both missing is a prediction only;
- gate: when the normalised innovation squared of the sample exceeds ``gate`` the sample is not
  used for alpha and m: the speeds are reset to the measurement (variance R, no correlation with
  alpha and m) and alpha, m keep their prediction. A spike in a speed, or a glitch in the current
  that makes the prediction wrong, then touches two samples of the speeds and none of alpha, m.

The same filter (without the gate) is the engine's
:class:`rulkit.estimation.ekf.ExtendedKalmanFilter` as the reproduction builds it
(:func:`rulkit.systems.friction_drive.reproduce.make_ekf`); the tests hold the two to the same
numbers. The kernel needs no BLAS: it gives the same bits on every OpenBLAS kernel.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np
from numpy.typing import NDArray

from rulkit.model import FloatArray
from rulkit.systems.friction_drive.drive import FrictionDriveParams, _rk4_scalar

__all__ = ["STATUS", "DriveTrack", "EKFSettings", "expm_taylor", "track"]

#: Status of each sample in :attr:`DriveTrack.status`.
STATUS = {0: "updated", 1: "gated", 2: "missing", 3: "one channel", 4: "prior"}
UPDATED, GATED, MISSING, ONE_CHANNEL, PRIOR = 0, 1, 2, 3, 4


class EKFSettings(NamedTuple):
    """The kernel's scalar settings (a typed bundle): sampling step ``dt`` (s), RK4 sub-steps
    ``n_sub``, the Jacobian-only (4,4) entry ``f44``, the NIS ``gate`` (0: off) and
    ``midpoint`` (Jacobian after half a step)."""

    dt: float
    n_sub: int
    f44: float
    gate: float
    midpoint: bool


@numba.njit(cache=True)
def _matmul(A, B):  # pragma: no cover - compiled
    """A @ B for C-contiguous 2-D arrays (one compiled specialisation: no BLAS)."""
    n, k = A.shape
    m = B.shape[1]
    C = np.zeros((n, m))
    for i in range(n):
        for p in range(k):
            a = A[i, p]
            for j in range(m):
                C[i, j] += a * B[p, j]
    return C


@numba.njit(cache=True)
def _transpose(A):  # pragma: no cover - compiled
    n, m = A.shape
    T = np.empty((m, n))
    for i in range(n):
        for j in range(m):
            T[j, i] = A[i, j]
    return T


@numba.njit(cache=True)
def _expm_kernel(M):  # pragma: no cover - compiled
    n = M.shape[0]
    norm = 0.0
    for j in range(n):
        col = 0.0
        for i in range(n):
            col += abs(M[i, j])
        norm = max(norm, col)
    s = 0
    while norm > 0.5:
        norm *= 0.5
        s += 1
    A = M * (0.5**s)
    # Horner form of the Taylor polynomial of order 16: E = I + A (I + A/2 (I + ... (I + A/16)))
    E = np.eye(n)
    for j in range(16, 0, -1):
        E = _matmul(A, E) / j
        for i in range(n):
            E[i, i] += 1.0
    for _ in range(s):
        E = _matmul(E, E)
    return E


def expm_taylor(M: FloatArray) -> FloatArray:
    """Matrix exponential of a square ``M`` by scaling and squaring with a Taylor polynomial of
    order 16 (the scaled matrix has 1-norm <= 0.5: truncation below 1e-19 relative); the
    kernel's exponential, tested against :func:`scipy.linalg.expm`."""
    M = np.ascontiguousarray(np.asarray(M, dtype=np.float64))
    if M.ndim != 2 or M.shape[0] != M.shape[1] or not np.all(np.isfinite(M)):
        raise ValueError(f"M: expected a finite square matrix, got shape {M.shape}")
    return _expm_kernel(M)


@numba.njit(cache=True)
def _jacobian(x, pr, f44):  # pragma: no cover - compiled
    """Seed eq. 19 at x = [w1, w2, alpha, m] (as :func:`.drive.jacobian`)."""
    r1, r2, B1, B2, J1, J2 = pr[0], pr[1], pr[2], pr[3], pr[4], pr[5]
    w1, w2, a, m = x[0], x[1], x[2], x[3]
    s = r1 * w1 - r2 * w2
    F = np.zeros((4, 4))
    F[0, 0] = -(a * r1**2 + B1) / J1
    F[0, 1] = a * r1 * r2 / J1
    F[0, 2] = (r1 * r2 * w2 - r1**2 * w1) / J1
    F[1, 0] = a * r1 * r2 / J2
    F[1, 1] = -(a * r2**2 + B2) / J2
    F[1, 2] = (r1 * r2 * w1 - r2**2 * w2) / J2
    F[2, 0] = -2.0 * a * m * r1 * s
    F[2, 1] = 2.0 * a * m * r2 * s
    F[2, 2] = -m * s * s
    F[2, 3] = -a * s * s
    F[3, 3] = f44
    return F


@numba.njit(cache=True)
def _rk4(x, cur, h, n, pr):  # pragma: no cover - compiled
    w1, w2, a, m = x[0], x[1], x[2], x[3]
    for _ in range(n):
        w1, w2, a = _rk4_scalar(w1, w2, a, m, cur, h, pr)
    out = np.empty(4)
    out[0], out[1], out[2], out[3] = w1, w2, a, m
    return out


@numba.njit(cache=True)
def _predict(x, P, cur, pr, qc, st):  # pragma: no cover - compiled
    """Mean by RK4 sub-steps, covariance by Van Loan with F at the start or the midpoint."""
    dt = st.dt
    xj = _rk4(x, cur, 0.5 * dt, 1, pr) if st.midpoint else x
    F = _jacobian(xj, pr, st.f44)
    M = np.zeros((8, 8))
    for i in range(4):
        for j in range(4):
            M[i, j] = -F[i, j] * dt
            M[4 + i, 4 + j] = F[j, i] * dt
        M[i, 4 + i] = qc[i] * dt
    E = _expm_kernel(M)
    Phi = _transpose(E[4:, 4:].copy())
    Qd = _matmul(Phi, E[:4, 4:].copy())
    Pn = _matmul(_matmul(Phi, P), _transpose(Phi)) + Qd
    return _rk4(x, cur, dt / st.n_sub, st.n_sub, pr), 0.5 * (Pn + Pn.T)


@numba.njit(cache=True)
def _update(x, P, y, R, gate):  # pragma: no cover - compiled
    """Joseph-form update on the finite channels of y; returns x, P, nu (2,), S (2, 2), nis,
    status (module docstring: missing, one channel, gated)."""
    idx = np.empty(2, np.int64)
    k = 0
    for j in range(2):
        if np.isfinite(y[j]):
            idx[k] = j
            k += 1
    nu = np.full(2, np.nan)
    S = np.full((2, 2), np.nan)
    if k == 0:
        return x, P, nu, S, np.nan, MISSING
    Sk = np.empty((k, k))
    for a in range(k):
        nu[idx[a]] = y[idx[a]] - x[idx[a]]
        for b in range(k):
            Sk[a, b] = P[idx[a], idx[b]] + R[idx[a], idx[b]]
    if k == 2:
        det = Sk[0, 0] * Sk[1, 1] - Sk[0, 1] * Sk[1, 0]
        Si = np.array([[Sk[1, 1], -Sk[0, 1]], [-Sk[1, 0], Sk[0, 0]]]) / det
    else:
        Si = np.array([[1.0 / Sk[0, 0]]])
    nis = 0.0
    for a in range(k):
        for b in range(k):
            nis += nu[idx[a]] * Si[a, b] * nu[idx[b]]
            S[idx[a], idx[b]] = Sk[a, b]
    if gate > 0.0 and nis > gate:
        xg = x.copy()
        Pg = P.copy()
        for a in range(k):
            j = idx[a]
            xg[j] = y[j]
            Pg[j, :] = 0.0
            Pg[:, j] = 0.0
            Pg[j, j] = R[j, j]
        return xg, Pg, nu, S, nis, GATED
    K = np.zeros((4, k))
    for i in range(4):
        for b in range(k):
            acc = 0.0
            for a in range(k):
                acc += P[i, idx[a]] * Si[a, b]
            K[i, b] = acc
    xn = x.copy()
    IKH = np.eye(4)
    for i in range(4):
        for a in range(k):
            xn[i] += K[i, a] * nu[idx[a]]
            IKH[i, idx[a]] -= K[i, a]
    Rk = np.empty((k, k))
    for a in range(k):
        for b in range(k):
            Rk[a, b] = R[idx[a], idx[b]]
    Pn = _matmul(_matmul(IKH, P), _transpose(IKH)) + _matmul(_matmul(K, Rk), _transpose(K))
    return xn, 0.5 * (Pn + Pn.T), nu, S, nis, UPDATED if k == 2 else ONE_CHANNEL


@numba.njit(cache=True)
def _track_kernel(ys, currents, x0, P0, pr, qc, R, st):  # pragma: no cover - compiled
    T = ys.shape[0]
    xs = np.empty((T, 4))
    Pd = np.empty((T, 4))
    nus = np.full((T, 2), np.nan)
    Ss = np.full((T, 2, 2), np.nan)
    nis = np.full(T, np.nan)
    status = np.empty(T, np.int8)
    x = x0.copy()
    P = P0.copy()
    xs[0] = x
    for i in range(4):
        Pd[0, i] = P[i, i]
    status[0] = PRIOR
    for k in range(1, T):
        x, P = _predict(x, P, currents[k - 1], pr, qc, st)
        x, P, nu, S, q, flag = _update(x, P, ys[k], R, st.gate)
        xs[k] = x
        for i in range(4):
            Pd[k, i] = P[i, i]
        nus[k] = nu
        Ss[k] = S
        nis[k] = q
        status[k] = flag
    return xs, Pd, nus, Ss, nis, status, P


@dataclass(frozen=True)
class DriveTrack:
    """The filter over a record of T samples: ``x`` (T, 4) posterior means
    ``[w1, w2, alpha, m]`` (row 0: the prior), ``sd`` (T, 4) their standard deviations, ``nu``
    (T, 2) innovations and ``S`` (T, 2, 2) their covariances (NaN where a channel was missing),
    ``nis`` (T,), ``status`` (T,) codes of :data:`STATUS`, ``P`` (4, 4) the last covariance."""

    x: FloatArray
    sd: FloatArray
    nu: FloatArray
    S: FloatArray
    nis: FloatArray
    status: NDArray[np.int8]
    P: FloatArray

    def count(self, status: int) -> int:
        """Number of samples with the given status code."""
        return int(np.count_nonzero(self.status == status))


def track(
    ys: FloatArray,
    currents: FloatArray,
    x0: FloatArray,
    P0: FloatArray,
    settings: EKFSettings,
    params: FrictionDriveParams,
    q_rates: FloatArray,
    R: FloatArray,
) -> DriveTrack:
    """Run the compiled augmented EKF (module docstring) over ``ys`` (T, 2) measured speeds
    (NaN: missing), ``currents`` (T,) (sample k's current held until sample k+1), from the
    prior ``x0`` (4,), ``P0`` (4, 4) at sample 0, with process-noise rates ``q_rates`` (4,)
    per second on (w1, w2, alpha, m) and measurement covariance ``R`` (2, 2)."""
    ys = np.ascontiguousarray(np.asarray(ys, dtype=np.float64))
    cur = np.ascontiguousarray(np.asarray(currents, dtype=np.float64))
    if ys.ndim != 2 or ys.shape[1] != 2 or cur.shape != (ys.shape[0],):
        raise ValueError(f"ys, currents: expected (T, 2) and (T,), got {ys.shape}, {cur.shape}")
    if not np.all(np.isfinite(cur)) or np.isinf(ys).any():
        raise ValueError("currents must be finite and speeds finite or NaN (missing)")
    if not (np.isfinite(settings.dt) and settings.dt > 0 and settings.n_sub >= 1):
        raise ValueError(f"settings: expected dt > 0 and n_sub >= 1, got {settings}")
    st = EKFSettings(float(settings.dt), int(settings.n_sub), float(settings.f44),
                     float(settings.gate), bool(settings.midpoint))
    xs, Pd, nu, S, nis, status, P = _track_kernel(
        ys, cur, np.asarray(x0, np.float64).copy(), np.asarray(P0, np.float64).copy(),
        params.as_array(), np.asarray(q_rates, np.float64), np.asarray(R, np.float64), st)
    return DriveTrack(x=xs, sd=np.sqrt(np.maximum(Pd, 0.0)), nu=nu, S=S, nis=nis,
                      status=status, P=P)
