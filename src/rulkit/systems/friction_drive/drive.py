"""Roller-on-tire friction drive with contact-quality deterioration (seed 003,
docs/systems/friction-drive.md).

Augmented state ``x = [w1, w2, alpha, m]`` (seed section 4.2), input ``u = I`` (motor current),
output ``y = [w1, w2]``:

    dw1/dt = ((-alpha r1^2 - B1) w1 + alpha r1 r2 w2 + Km I) / J1          seed eq. (1), (3), (4)
    dw2/dt = (alpha r2 r1 w1 + (-alpha r2^2 - B2) w2) / J2
    dalpha/dt = -m p(x) alpha,   p(x) = (r1 w1 - r2 w2)^2                   seed eq. (7), (10)
    dm/dt = 0                                                              seed eq. (11)

Normalised deterioration ``D = 1 - alpha / alpha0`` (seed eq. 8); failure when ``D >= D_f``
(docs/systems/friction-drive.md §2: D = 1 is never reached, default ``D_f = 0.99``).

Besides the vectorised right-hand side and its analytic Jacobian (seed eq. 19) this module holds
the physics used by the fast long-horizon RUL propagation (docs/systems/friction-drive.md §7): the
quasi-steady slip at constant current, the closed-form time for alpha to fall between two levels on
the quasi-steady manifold, its inverse, and a fixed-step RK4 integrator of the full model over a
batch (numpy reference path and a numba kernel that gives the same numbers).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np

from rulkit.model import FloatArray, GaussianNoise, StateSpaceModel, as_batch

STATE_NAMES = ("w1", "w2", "alpha", "m")


@dataclass(frozen=True)
class FrictionDriveParams:
    """Physical parameters of the roller-on-tire actuator (seed Table 1) and the failure level.

    ``alpha0`` is the known initial contact quality used in D = 1 - alpha/alpha0 (seed eq. 8);
    ``failure_level`` is D_f (docs/systems/friction-drive.md §2, default 0.99).
    """

    r1: float = 0.0315
    r2: float = 0.35
    B1: float = 6.36e-3
    B2: float = 1.76e-3
    J1: float = 3.47e-4
    J2: float = 0.2
    Km: float = 0.0477465
    alpha0: float = 10.0
    failure_level: float = 0.99

    def __post_init__(self) -> None:
        for name in ("r1", "r2", "B1", "B2", "J1", "J2", "Km", "alpha0"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"FrictionDriveParams.{name}: expected finite > 0, got {v}")
        if not (0.0 < self.failure_level < 1.0):
            raise ValueError(
                f"FrictionDriveParams.failure_level: expected 0 < D_f < 1, got {self.failure_level}"
            )

    @property
    def c(self) -> float:
        """c = r1^2/B1 + r2^2/B2, the slip-reduction coefficient of the quasi-steady slip."""
        return self.r1**2 / self.B1 + self.r2**2 / self.B2

    def gain(self, current: float | FloatArray) -> float | FloatArray:
        """G = r1 Km I / B1: the slip at alpha = 0 under constant current I (quasi-steady)."""
        return self.r1 * self.Km * np.asarray(current, dtype=np.float64) / self.B1

    def as_array(self) -> FloatArray:
        """(r1, r2, B1, B2, J1, J2, Km) as a float64 array (for the compiled kernels)."""
        return np.array(
            [self.r1, self.r2, self.B1, self.B2, self.J1, self.J2, self.Km], dtype=np.float64
        )


# Noise settings of the seed and of the study (used by the filters in reproduce.py).
# Seed section 5.2: R = diag(sigma1^2, sigma2^2), sigma_m^2 = (0.02 - 0)^2 / 12, P0 = sigma_m^2 I.
SEED_R = np.diag([1.0063e-8, 1.0083e-10])
SEED_SIGMA_M2 = 3.3333e-5
SEED_P0 = SEED_SIGMA_M2 * np.eye(4)
# A realistic speed-noise level (docs/systems/friction-drive.md §3: a realistic-noise scenario):
# 0.01 rad/s on the motor (an encoder-differentiated speed), 0.001 rad/s on the slow wheel; 100 x
# the seed's sigmas.
REALISTIC_R = np.diag([1e-4, 1e-6])
TUNED_Q_RATE = 3e-7  # per second (docs/systems/friction-drive.md §4)
# Process-noise rates (per second) on (w1, w2) of the "tuned-consistent" filter, sized from the
# measured one-step error of the filter's single 1 ms RK4 step against the fine truth
# (:func:`one_step_discretisation_error`; 50 sub-steps, square wave): the largest errors,
# 1.4e-7 rad/s on w1 and 1.7e-9 rad/s on w2, occur right after each current switch and decay
# with the 20 ms mode. q = (largest error)^2 / t_s rounded up: (2e-11, 3e-15) /s. Without it the
# filter, having no process noise on the speeds, believes a combination of (w1, w2) known to
# ~1e-8 rad/s and the systematic post-switch error gives single-step NEES of 1e2-1e3.
SPEED_Q_RATE = (2e-11, 3e-15)

DEFAULT_PARAMS = FrictionDriveParams()


def _current_column(current: float | np.ndarray, n: int) -> FloatArray:
    cur = np.asarray(current, dtype=np.float64)
    if cur.ndim == 0:
        return np.full(n, float(cur))
    cur = cur.reshape(-1)
    if cur.shape[0] == 1:
        return np.full(n, cur[0])
    if cur.shape[0] != n:
        raise ValueError(f"current: expected a scalar or shape ({n},), got {np.shape(current)}")
    return cur


def slip(x: FloatArray, params: FrictionDriveParams = DEFAULT_PARAMS) -> FloatArray:
    """Relative tangential speed Delta_v = r1 w1 - r2 w2 (seed section 2), shape (N,)."""
    return params.r1 * x[..., 0] - params.r2 * x[..., 1]


def sliding_factor(x: FloatArray, params: FrictionDriveParams = DEFAULT_PARAMS) -> FloatArray:
    """Sliding factor p(x) = (r1 w1 - r2 w2)^2 (seed eq. 7), shape (N,)."""
    return slip(x, params) ** 2


def drift(
    x: FloatArray, current: float | FloatArray, params: FrictionDriveParams = DEFAULT_PARAMS
) -> FloatArray:
    """Continuous-time right-hand side f(x) + B u of the augmented model (seed eq. 9-11).

    ``x`` (N, 4), ``current`` scalar or (N,); returns dx/dt (N, 4) with dm/dt = 0.
    """
    p = params
    w1, w2, a, m = x[:, 0], x[:, 1], x[:, 2], x[:, 3]
    cur = _current_column(current, x.shape[0])
    s = p.r1 * w1 - p.r2 * w2
    out = np.empty_like(x)
    out[:, 0] = (-a * p.r1 * s - p.B1 * w1 + p.Km * cur) / p.J1
    out[:, 1] = (a * p.r2 * s - p.B2 * w2) / p.J2
    out[:, 2] = -m * s * s * a
    out[:, 3] = 0.0
    return out


def jacobian(
    x: FloatArray,
    current: float | FloatArray | None = None,
    params: FrictionDriveParams = DEFAULT_PARAMS,
    f44: float = 0.0,
) -> FloatArray:
    """Analytic Jacobian df/dx of the augmented model, seed eq. (19); shape (N, 4, 4).

    ``f44`` sets the (4, 4) entry: 0 for the model as written, -100 for the seed's covariance
    heuristic of section 5.2 ("band-pass model for m"; docs/systems/friction-drive.md §4: Jacobian
    only, never the state prediction). The current does not enter the Jacobian (the input is
    affine).
    """
    p = params
    w1, w2, a, m = x[:, 0], x[:, 1], x[:, 2], x[:, 3]
    s = p.r1 * w1 - p.r2 * w2
    F = np.zeros((x.shape[0], 4, 4))
    F[:, 0, 0] = -(a * p.r1**2 + p.B1) / p.J1
    F[:, 0, 1] = a * p.r1 * p.r2 / p.J1
    F[:, 0, 2] = (p.r1 * p.r2 * w2 - p.r1**2 * w1) / p.J1
    F[:, 1, 0] = a * p.r1 * p.r2 / p.J2
    F[:, 1, 1] = -(a * p.r2**2 + p.B2) / p.J2
    F[:, 1, 2] = (p.r1 * p.r2 * w1 - p.r2**2 * w2) / p.J2
    F[:, 2, 0] = -2.0 * a * m * p.r1 * s
    F[:, 2, 1] = 2.0 * a * m * p.r2 * s
    F[:, 2, 2] = -m * s * s
    F[:, 2, 3] = -a * s * s
    F[:, 3, 3] = f44
    return F


def rk4_step(
    x: FloatArray,
    current: float | FloatArray,
    dt: float,
    params: FrictionDriveParams = DEFAULT_PARAMS,
    n_sub: int = 1,
) -> FloatArray:
    """Advance (N, 4) states by ``dt`` with ``n_sub`` classical RK4 sub-steps, current held."""
    h = dt / n_sub
    for _ in range(n_sub):
        k1 = drift(x, current, params)
        k2 = drift(x + 0.5 * h * k1, current, params)
        k3 = drift(x + 0.5 * h * k2, current, params)
        k4 = drift(x + h * k3, current, params)
        x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x


# --------------------------------------------------------------------------------------------
# Fixed-step path integration over a batch: numpy reference and numba kernel (same numbers).
# --------------------------------------------------------------------------------------------


def _path_args(
    x0: FloatArray, currents: FloatArray, dt: float, n_sub: int, m_path: FloatArray | None
) -> tuple[FloatArray, FloatArray, int, FloatArray | None]:
    """Validated (x0 (N, 4), currents (K,), n_sub, m_path (K,) or None) of the path integrators
    (both the numpy reference and the numba kernel refuse the same bad input)."""
    x0 = as_batch(x0, 4, "x0")
    cur = np.ascontiguousarray(np.asarray(currents, dtype=np.float64).reshape(-1))
    if not np.all(np.isfinite(cur)):
        raise ValueError("currents: contains NaN or infinite values")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: expected a finite value > 0, got {dt}")
    if int(n_sub) != n_sub or n_sub < 1:
        raise ValueError(f"n_sub: expected an integer >= 1, got {n_sub}")
    mp = None
    if m_path is not None:
        mp = np.ascontiguousarray(np.asarray(m_path, dtype=np.float64).reshape(-1))
        if mp.shape[0] != cur.shape[0]:
            raise ValueError(f"m_path: expected shape ({cur.shape[0]},), got {mp.shape}")
        if not np.all(np.isfinite(mp)):
            raise ValueError("m_path: contains NaN or infinite values")
    return x0, cur, int(n_sub), mp


def integrate_path_numpy(
    x0: FloatArray,
    currents: FloatArray,
    dt: float,
    n_sub: int = 1,
    m_path: FloatArray | None = None,
    params: FrictionDriveParams = DEFAULT_PARAMS,
    store: bool = True,
) -> FloatArray:
    """Integrate the full model over K steps of ``dt`` (RK4, ``n_sub`` sub-steps per step).

    ``currents`` (K,) holds the current of each step (zero-order hold). ``m_path`` (K,), when
    given, overrides the state m at the start of each step (an exogenous m schedule: the
    scenarios of seed eq. 28). Returns (K+1, N, 4) when ``store`` else the final (N, 4).
    """
    x, currents, n_sub, m_path = _path_args(x0, currents, dt, n_sub, m_path)
    x = x.copy()
    K = currents.shape[0]
    out = np.empty((K + 1, *x.shape)) if store else None
    if out is not None:
        out[0] = x
    for k in range(K):
        if m_path is not None:
            x[:, 3] = m_path[k]
        x = rk4_step(x, currents[k], dt, params, n_sub)
        if out is not None:
            out[k + 1] = x
    return out if out is not None else x


@numba.njit(cache=True, inline="always")
def _f_scalar(w1, w2, a, m, cur, pr):  # pragma: no cover - compiled
    r1, r2, B1, B2, J1, J2, Km = pr[0], pr[1], pr[2], pr[3], pr[4], pr[5], pr[6]
    s = r1 * w1 - r2 * w2
    d1 = (-a * r1 * s - B1 * w1 + Km * cur) / J1
    d2 = (a * r2 * s - B2 * w2) / J2
    d3 = -m * s * s * a
    return d1, d2, d3


@numba.njit(cache=True, inline="always")
def _rk4_scalar(w1, w2, a, m, cur, h, pr):  # pragma: no cover - compiled
    """One classical RK4 step of (w1, w2, alpha) over ``h`` (m and the current held)."""
    a1, b1, c1 = _f_scalar(w1, w2, a, m, cur, pr)
    a2, b2, c2 = _f_scalar(w1 + 0.5 * h * a1, w2 + 0.5 * h * b1, a + 0.5 * h * c1, m, cur, pr)
    a3, b3, c3 = _f_scalar(w1 + 0.5 * h * a2, w2 + 0.5 * h * b2, a + 0.5 * h * c2, m, cur, pr)
    a4, b4, c4 = _f_scalar(w1 + h * a3, w2 + h * b3, a + h * c3, m, cur, pr)
    return (
        w1 + (h / 6.0) * (a1 + 2.0 * a2 + 2.0 * a3 + a4),
        w2 + (h / 6.0) * (b1 + 2.0 * b2 + 2.0 * b3 + b4),
        a + (h / 6.0) * (c1 + 2.0 * c2 + 2.0 * c3 + c4),
    )


@numba.njit(cache=True)
def _integrate_path_kernel(x0, currents, dt, n_sub, m_path, use_m, pr, store):  # pragma: no cover
    N = x0.shape[0]
    K = currents.shape[0]
    n_out = K + 1 if store else 1
    out = np.empty((n_out, N, 4))
    h = dt / n_sub
    for i in range(N):
        w1, w2, a, m = x0[i, 0], x0[i, 1], x0[i, 2], x0[i, 3]
        if store:
            out[0, i, 0] = w1
            out[0, i, 1] = w2
            out[0, i, 2] = a
            out[0, i, 3] = m
        for k in range(K):
            if use_m:
                m = m_path[k]
            cur = currents[k]
            for _ in range(n_sub):
                w1, w2, a = _rk4_scalar(w1, w2, a, m, cur, h, pr)
            if store:
                out[k + 1, i, 0] = w1
                out[k + 1, i, 1] = w2
                out[k + 1, i, 2] = a
                out[k + 1, i, 3] = m
        if not store:
            out[0, i, 0] = w1
            out[0, i, 1] = w2
            out[0, i, 2] = a
            out[0, i, 3] = m
    return out


def integrate_path(
    x0: FloatArray,
    currents: FloatArray,
    dt: float,
    n_sub: int = 1,
    m_path: FloatArray | None = None,
    params: FrictionDriveParams = DEFAULT_PARAMS,
    store: bool = True,
) -> FloatArray:
    """Compiled (numba) version of :func:`integrate_path_numpy`; same arguments, same numbers."""
    x0, cur, n_sub, mp = _path_args(x0, currents, dt, n_sub, m_path)
    use_m = mp is not None
    out = _integrate_path_kernel(
        np.ascontiguousarray(x0), cur, float(dt), n_sub, mp if use_m else np.zeros(1), use_m,
        params.as_array(), store,
    )
    return out if store else out[0]


@numba.njit(cache=True)
def _time_to_alpha_kernel(x0, current, dt, alpha_level, max_steps, pr):  # pragma: no cover
    N = x0.shape[0]
    out = np.full(N, np.inf)
    xend = np.empty((N, 4))
    for i in range(N):
        w1, w2, a, m = x0[i, 0], x0[i, 1], x0[i, 2], x0[i, 3]
        if a <= alpha_level:
            out[i] = 0.0
        else:
            for k in range(max_steps):
                w1, w2, a_new = _rk4_scalar(w1, w2, a, m, current, dt, pr)
                if a_new <= alpha_level:
                    out[i] = (k + (a - alpha_level) / (a - a_new)) * dt
                    a = a_new
                    break
                a = a_new
        xend[i, 0] = w1
        xend[i, 1] = w2
        xend[i, 2] = a
        xend[i, 3] = m
    return out, xend


def time_to_alpha(
    x0: FloatArray,
    current: float,
    alpha_level: float,
    dt: float,
    t_max: float,
    params: FrictionDriveParams = DEFAULT_PARAMS,
) -> tuple[FloatArray, FloatArray]:
    """Full-model (RK4, fixed ``dt``, constant current, numba) time for alpha to fall to
    ``alpha_level``, each sample stopping at its own crossing (linear interpolation within the
    step); ``inf`` when not reached within ``t_max``. Returns ``(t_cross (N,), x_end (N, 4))``
    with ``x_end`` the state at the crossing step or at ``t_max``."""
    x0 = as_batch(x0, 4, "x0")
    if not (np.isfinite(dt) and dt > 0 and np.isfinite(t_max) and t_max >= 0):
        raise ValueError(f"dt, t_max: expected finite dt > 0 and t_max >= 0, got {dt}, {t_max}")
    if not (np.isfinite(current) and np.isfinite(alpha_level)):
        # a NaN level or current made every crossing test False: 'never fails', silently
        raise ValueError(f"current, alpha_level: expected finite values, got {current}, "
                         f"{alpha_level}")
    n = round(t_max / dt)
    return _time_to_alpha_kernel(
        np.ascontiguousarray(x0), float(current), float(dt), float(alpha_level), int(n),
        params.as_array(),
    )


# --------------------------------------------------------------------------------------------
# Quasi-steady deterioration at constant current (docs/systems/friction-drive.md §7: closed-form
# time to failure).
# --------------------------------------------------------------------------------------------


def steady_state_speeds(
    alpha: FloatArray, current: float, params: FrictionDriveParams = DEFAULT_PARAMS
) -> FloatArray:
    """Equilibrium (w1, w2) of eq. (1) at frozen alpha and constant current, shape (N, 2)."""
    a = np.asarray(alpha, dtype=np.float64)
    s = params.gain(current) / (1.0 + params.c * a)
    w2 = a * params.r2 * s / params.B2
    w1 = (params.Km * current - a * params.r1 * s) / params.B1
    return np.stack([w1, w2], axis=-1)


def quasi_steady_slip(
    alpha: FloatArray, current: float, params: FrictionDriveParams = DEFAULT_PARAMS
) -> FloatArray:
    """Slip at the mechanical equilibrium, s = G / (1 + c alpha), G = r1 Km I / B1."""
    return params.gain(current) / (1.0 + params.c * np.asarray(alpha, dtype=np.float64))


def _check_quasi_steady_args(a_s: FloatArray, m: FloatArray, current: float, name: str) -> None:
    """Finite alpha > 0, finite m and a finite current (a NaN m read as 'never fails')."""
    bad = np.flatnonzero(np.ravel(~(np.isfinite(a_s) & (a_s > 0))))
    if bad.size:
        raise ValueError(f"{name}: expected finite values > 0, bad at flat index {bad[0]}")
    bad = np.flatnonzero(np.ravel(~np.isfinite(m)))
    if bad.size:
        raise ValueError(f"m: non-finite value at flat index {bad[0]}")
    if not np.isfinite(current):
        raise ValueError(f"current: expected a finite value, got {current}")


def _phi(alpha: FloatArray, c: float) -> FloatArray:
    """Antiderivative of (1 + c a)^2 / a: ln a + 2 c a + c^2 a^2 / 2."""
    return np.log(alpha) + 2.0 * c * alpha + 0.5 * c * c * alpha * alpha


def quasi_steady_time(
    alpha_start: FloatArray,
    alpha_end: float | FloatArray,
    m: FloatArray,
    current: float,
    params: FrictionDriveParams = DEFAULT_PARAMS,
) -> FloatArray:
    """Time for alpha to fall from ``alpha_start`` to ``alpha_end`` on the quasi-steady manifold.

    With the slip at equilibrium, dalpha/dt = -m G^2 alpha / (1 + c alpha)^2, so
    t = [ln(a_s/a_e) + 2c(a_s - a_e) + c^2 (a_s^2 - a_e^2)/2] / (m G^2)
    (docs/systems/friction-drive.md §7). Returns +inf where m <= 0 (alpha never falls) and 0 where
    alpha_start <= alpha_end.
    """
    a_s = np.asarray(alpha_start, dtype=np.float64)
    a_e = np.broadcast_to(np.asarray(alpha_end, dtype=np.float64), a_s.shape)
    m = np.broadcast_to(np.asarray(m, dtype=np.float64), a_s.shape)
    _check_quasi_steady_args(a_s, m, current, "alpha_start")
    if not np.all(np.isfinite(a_e) & (a_e > 0)):
        raise ValueError("alpha_end: expected finite values > 0")
    G2 = float(params.gain(current)) ** 2
    c = params.c
    out = np.full(a_s.shape, np.inf)
    done = a_s <= a_e
    out[done] = 0.0
    ok = ~done & (m > 0)
    out[ok] = (_phi(a_s[ok], c) - _phi(a_e[ok], c)) / (m[ok] * G2)
    return out


def quasi_steady_alpha(
    alpha_start: FloatArray,
    m: FloatArray,
    current: float,
    t: FloatArray,
    params: FrictionDriveParams = DEFAULT_PARAMS,
    n_newton: int = 60,
) -> FloatArray:
    """Inverse of :func:`quasi_steady_time`: alpha after time ``t`` on the quasi-steady manifold.

    Solves phi(alpha) = phi(alpha_start) - m G^2 t by a safeguarded Newton iteration in
    log(alpha) (phi is increasing and convex in log alpha). Arrays broadcast together.
    """
    a_s, m, t = np.broadcast_arrays(
        np.asarray(alpha_start, dtype=np.float64),
        np.asarray(m, dtype=np.float64),
        np.asarray(t, dtype=np.float64),
    )
    _check_quasi_steady_args(a_s, m, current, "alpha_start")
    if not np.all(np.isfinite(t) & (t >= 0)):
        raise ValueError("t: expected finite times >= 0")
    c = params.c
    G2 = float(params.gain(current)) ** 2
    target = _phi(a_s, c) - np.maximum(m, 0.0) * G2 * t
    # Start below the root: ln a <= phi(a) - 2 c a - ..., so z0 = min(ln a_s, target) is safe.
    z = np.minimum(np.log(a_s), target)
    for _ in range(n_newton):
        a = np.exp(z)
        g = z + 2.0 * c * a + 0.5 * c * c * a * a - target  # phi in terms of z = ln a
        dg = 1.0 + 2.0 * c * a + c * c * a * a  # d phi / d ln a
        step = g / dg
        z = z - step
        if np.all(np.abs(step) < 1e-14):
            break
    return np.exp(z)


# --------------------------------------------------------------------------------------------
# Inputs and the model contract
# --------------------------------------------------------------------------------------------


def square_wave_current(
    t: FloatArray, amplitude: float = 20.0, period: float = 2.0, duty: float = 0.5
) -> FloatArray:
    """0 / ``amplitude`` square wave, on during [k T, k T + duty T) (seed 5.1; [R],
    docs/systems/friction-drive.md §3)."""
    t = np.asarray(t, dtype=np.float64)
    phase = np.mod(t, period) / period
    # Guard rounding at the switching instants of a sampled grid (t = k*dt).
    phase = np.where(np.isclose(phase, 1.0, atol=1e-9), 0.0, phase)
    return np.where(phase < duty - 1e-9, amplitude, 0.0)


class FrictionDriveModel(StateSpaceModel):
    """The augmented friction-drive model under the :class:`StateSpaceModel` contract.

    ``step`` integrates the continuous model over ``dt`` with ``n_sub`` RK4 sub-steps (the
    seed's eq. 16 prediction) and adds process noise ``Q_d = Q_rate * dt`` when ``rng`` is given.
    ``Q_rate`` is a per-second rate (docs/systems/friction-drive.md §4, (FD-7): the noise on m
    is a rate per second); ``R`` is the speed-measurement covariance (seed eq. 15). Health is the
    normalised deterioration D (seed eq. 8); failure when D >= ``params.failure_level``.
    """

    state_names = STATE_NAMES
    input_names = ("I",)
    output_names = ("w1", "w2")

    def __init__(
        self,
        params: FrictionDriveParams = DEFAULT_PARAMS,
        q_rate: FloatArray | None = None,
        R: FloatArray | None = None,
        n_sub: int = 1,
        dt: float = 1e-3,
    ) -> None:
        if int(n_sub) != n_sub or n_sub < 1:
            raise ValueError(f"n_sub: expected an integer >= 1, got {n_sub}")
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt: expected a finite value > 0, got {dt}")
        self.params = params
        self.n_sub = int(n_sub)
        self.dt = float(dt)
        q = np.diag([0.0, 0.0, 0.0, 3e-7]) if q_rate is None else np.asarray(q_rate, float)
        r = np.diag([1.0063e-8, 1.0083e-10]) if R is None else np.asarray(R, float)
        self.q_rate = q
        self._noise = GaussianNoise(Q=q * self.dt, R=r)
        self.threshold = params.failure_level

    @property
    def noise(self) -> GaussianNoise:
        """The Gaussian process and measurement noise (model contract, docs/engine.md)."""
        return self._noise

    def step(
        self,
        x: FloatArray,
        u: FloatArray | None,
        t: float,
        dt: float,
        rng: np.random.Generator | None = None,
    ) -> FloatArray:
        """One RK4 step (``n_sub`` sub-steps) of the batch (N, 4) over ``dt`` under the current
        ``u``, plus process noise when ``rng`` is given (model contract)."""
        x = as_batch(x, 4)
        if u is None:
            raise ValueError("u: the friction drive needs the motor current I")
        cur = np.asarray(u, dtype=np.float64).reshape(-1)
        x_next = rk4_step(x, cur, dt, self.params, self.n_sub)
        if rng is not None:
            # Q_d = q_rate * dt: rescale the per-self.dt noise description to this dt.
            x_next = x_next + np.sqrt(dt / self.dt) * self._noise.sample_process(x.shape[0], rng)
        return x_next

    def output(self, x: FloatArray, u: FloatArray | None = None) -> FloatArray:
        """The measured speeds (w1, w2), shape (N, 2)."""
        x = as_batch(x, 4)
        return x[:, :2].copy()

    def health(self, x: FloatArray) -> FloatArray:
        """Deterioration D = 1 - alpha / alpha0, shape (N,): 0 when new, failure at
        ``params.failure_level``."""
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        return 1.0 - x[:, 2] / self.params.alpha0


def make_drift(
    current: Callable[[float], float] | float, params: FrictionDriveParams = DEFAULT_PARAMS
) -> Callable[[FloatArray, float], FloatArray]:
    """A ``f(x (N,4), t) -> dx/dt`` closure with a time-dependent or constant current."""
    if callable(current):
        return lambda x, t: drift(x, current(t), params)
    return lambda x, t: drift(x, float(current), params)
