"""Reaction-wheel bearing lubricant-loss model (seed 001 eqs 7-9, 29-36;
docs/systems/reaction-wheel.md §4-5).

Physics only: the loss-rate law, the two fault scenarios of Table 4, the step-2/3 temperature
paths over months, the 4-minute measurement windows and the fast window sums

    S_k(b) = sum_{j in window k} exp(-b / T^_j)          (docs/systems/reaction-wheel.md §4; 4800
    samples of 0.05 s)

evaluated for many particles at once by Gauss quadrature on each window's empirical
distribution of ``u = 1/T^`` (see :func:`window_quadrature`).

Conventions (docs/systems/reaction-wheel.md §4):

* loss rate ``beta(t) = beta0 exp(-b / T(t))`` with ``b`` and ``T`` in deg C (the "+b/T" of the
  printed eqs 29, 30, 34 is a lost minus sign);
* cumulative loss ``X(t_k) = sum_j beta0(t_j) exp(-b(t_j)/T_j) dt + sigma_B W(t_k)``, each sample
  with the parameters of its own time;
* measurement every window: ``y_k = X_k - X_{k-1}``.

Every setting the seeds leave open is a named field of a dataclass here, marked [R].
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: Sample interval of the step-1 temperature estimate, s (seed 001 section 4.2).
SAMPLE_DT = 0.05
#: Samples per measurement window: 4 minutes of 0.05 s samples (seed 001 eq. 29).
WINDOW_SAMPLES = 4800
#: Window length, s.
WINDOW_S = SAMPLE_DT * WINDOW_SAMPLES
#: Seconds per day.
DAY_S = 86400.0
#: Lowest temperature (deg C) accepted by the loss law: exp(-b/T) is singular at T = 0
#: (docs/systems/reaction-wheel.md §4).
T_MIN_C = 5.0


# ---------------------------------------------------------------------------------------------
# Loss law and fault scenarios
# ---------------------------------------------------------------------------------------------


def loss_rate(temperature_c: FloatArray | float, b: FloatArray | float,
              beta0: FloatArray | float) -> FloatArray:
    """Lubricant loss rate ``beta0 exp(-b / T)`` in mL/s (seed 001 eq. 7 with the sign fixed).

    Broadcasts over its arguments. Raises ``ValueError`` when a temperature is below
    :data:`T_MIN_C` or not finite (the law is singular at 0 deg C, docs/systems/reaction-wheel.md
    §4).
    """
    T = np.asarray(temperature_c, dtype=np.float64)
    _check_temperature(T, "temperature_c")
    return np.asarray(beta0, dtype=np.float64) * np.exp(-np.asarray(b, dtype=np.float64) / T)


def _check_temperature(T: FloatArray, name: str) -> None:
    if T.size == 0:
        return
    if not np.all(np.isfinite(T)):
        i = int(np.flatnonzero(~np.isfinite(T.ravel()))[0])
        raise ValueError(f"{name}: non-finite temperature at flat index {i}")
    lo = float(T.min())
    if lo < T_MIN_C:
        i = int(np.argmin(T.ravel()))
        raise ValueError(
            f"{name}: temperature {lo:.4g} C at flat index {i} is below {T_MIN_C} C; the loss law "
            "exp(-b/T) with T in deg C is singular at 0 C (docs/systems/reaction-wheel.md §4)"
        )


@dataclass(frozen=True)
class FaultScenario:
    """Piecewise-constant degradation parameters of one fault scenario (seed 001 Table 4).

    ``b`` in deg C, ``beta0`` in mL/s; the fault sets in at ``fault_time_s`` (159 min, inside
    window 40, i.e. index 39).
    """

    name: str
    b_fault: float
    beta0_fault: float
    b_healthy: float = 37.0
    beta0_healthy: float = 7.494e-6
    fault_time_s: float = 159.0 * 60.0

    def parameters(self, t: FloatArray | float) -> tuple[FloatArray, FloatArray]:
        """True ``(b(t), beta0(t))`` at times ``t`` (s); the fault value applies for t > 159 min."""
        t = np.asarray(t, dtype=np.float64)
        after = t > self.fault_time_s
        return (np.where(after, self.b_fault, self.b_healthy),
                np.where(after, self.beta0_fault, self.beta0_healthy))


#: Scenario 1, excessive lubricant loss (seed 001 Table 4).
SCENARIO_1 = FaultScenario("excessive loss", b_fault=25.0, beta0_fault=8.054e-6)
#: Scenario 2, insufficient lubricant injection (seed 001 Table 4).
SCENARIO_2 = FaultScenario("insufficient injection", b_fault=49.0, beta0_fault=7.000e-6)
SCENARIOS: dict[int, FaultScenario] = {1: SCENARIO_1, 2: SCENARIO_2}


# ---------------------------------------------------------------------------------------------
# Temperature paths over months [R]
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TemperaturePath:
    """Lubricant temperature over months, deg C [R] (the seeds show only plots: Figs 18, 20).

    ``T(t) = mean + orbit_amplitude sin(2 pi t / orbit_period)
    + season_amplitude sin(2 pi t / season_period) + drift_per_day * t / 1 day``.

    The orbital cycle moves T between consecutive 4-minute windows, which is what makes ``b``
    identifiable (docs/systems/reaction-wheel.md §4: ln z ~ b (1/T_{k-1} - 1/T_k)); the seasonal
    term gives the periodic three-month path of scenario 1 (Fig 18) and the drift the slowly rising
    path of scenario 2 (Fig 20). The same path is the truth of step 2 and the assumed future path of
    step 3.
    """

    mean_c: float = 30.0
    orbit_amplitude_c: float = 3.0
    orbit_period_s: float = 95.0 * 60.0
    season_amplitude_c: float = 5.0
    season_period_s: float = 90.0 * DAY_S
    drift_c_per_day: float = 0.0

    def __call__(self, t: FloatArray | float) -> FloatArray:
        t = np.asarray(t, dtype=np.float64)
        return (self.mean_c
                + self.orbit_amplitude_c * np.sin(2.0 * np.pi * t / self.orbit_period_s)
                + self.season_amplitude_c * np.sin(2.0 * np.pi * t / self.season_period_s)
                + self.drift_c_per_day * t / DAY_S)

    def derivative(self, t: FloatArray | float) -> FloatArray:
        """dT/dt in C/s (used by the Euler-Maclaurin window sums)."""
        t = np.asarray(t, dtype=np.float64)
        wo = 2.0 * np.pi / self.orbit_period_s
        ws = 2.0 * np.pi / self.season_period_s
        return (self.orbit_amplitude_c * wo * np.cos(wo * t)
                + self.season_amplitude_c * ws * np.cos(ws * t) + self.drift_c_per_day / DAY_S)


#: Scenario 1 path [R]: periodic over three months (seed 001 Fig 18, shape only).
PATH_SCENARIO_1 = TemperaturePath()
#: Scenario 2 path [R]: slowly rising, +6 C over 90 days (seed 001 Fig 20, shape only).
PATH_SCENARIO_2 = TemperaturePath(season_amplitude_c=0.0, drift_c_per_day=6.0 / 90.0)
PATHS: dict[int, TemperaturePath] = {1: PATH_SCENARIO_1, 2: PATH_SCENARIO_2}


# ---------------------------------------------------------------------------------------------
# True window increments and measurements
# ---------------------------------------------------------------------------------------------


def true_window_increments(path: TemperaturePath, scenario: FaultScenario, n_windows: int,
                           *, window_samples: int = WINDOW_SAMPLES, dt: float = SAMPLE_DT,
                           method: str = "euler-maclaurin", chunk_windows: int = 256
                           ) -> FloatArray:
    """Noise-free loss per window ``sum_j beta0(t_j) exp(-b(t_j)/T(t_j)) dt``, shape (n_windows,).

    Sample ``j`` of window ``k`` is at ``t = (k * window_samples + j) * dt``, each sample with the
    parameters of its own time (docs/systems/reaction-wheel.md §4). ``method="direct"`` sums every
    0.05 s sample (the oracle; 155 million terms for three months). ``"euler-maclaurin"`` (default)
    uses
    ``sum_{j<n} f(a + j h) = (1/h) int f - [f(a+nh) - f(a)]/2 + h [f'(a+nh) - f'(a)]/12``
    (next term O(h^3 f''')), the integral by 12-point Gauss-Legendre per window (the integrand
    is analytic and varies on the 95-minute orbit scale); the window containing the fault time,
    where the parameters jump, is summed directly. Tested against ``"direct"``.
    """
    if n_windows < 1:
        raise ValueError(f"n_windows: expected >= 1, got {n_windows}")
    if method == "direct":
        out = np.empty(n_windows)
        j = np.arange(window_samples, dtype=np.float64)
        for k0 in range(0, n_windows, chunk_windows):
            k1 = min(n_windows, k0 + chunk_windows)
            t = ((np.arange(k0, k1, dtype=np.float64)[:, None] * window_samples) + j) * dt
            T = path(t)
            _check_temperature(T, "temperature path")
            b, beta0 = scenario.parameters(t)
            out[k0:k1] = (beta0 * np.exp(-b / T)).sum(axis=1) * dt
        return out
    if method != "euler-maclaurin":
        raise ValueError(f"method: expected 'direct' or 'euler-maclaurin', got {method!r}")
    L = window_samples * dt
    a = np.arange(n_windows, dtype=np.float64) * L
    e = a + L
    xg, wg = np.polynomial.legendre.leggauss(12)
    tg = a[:, None] + 0.5 * L * (xg[None, :] + 1.0)
    b, beta0 = scenario.parameters(tg)
    Tg = path(tg)
    _check_temperature(Tg, "temperature path")
    integral = 0.5 * L * (wg * beta0 * np.exp(-b / Tg)).sum(axis=1)
    # parameters of the window itself at both ends (a jump between windows must not leak in)
    bb, be = scenario.parameters(a + 0.5 * L)
    bb, be = np.asarray(bb), np.asarray(be)

    def f_and_df(t: FloatArray) -> tuple[FloatArray, FloatArray]:
        T = path(t)
        f = be * np.exp(-bb / T)
        return f, f * bb * path.derivative(t) / (T * T)

    fa, dfa = f_and_df(a)
    fe, dfe = f_and_df(e)
    out = (integral / dt - 0.5 * (fe - fa) + dt * (dfe - dfa) / 12.0) * dt
    k_fault = int(scenario.fault_time_s // L)
    if 0 <= k_fault < n_windows:
        j = np.arange(window_samples, dtype=np.float64)
        t = (k_fault * window_samples + j) * dt
        b1, be1 = scenario.parameters(t)
        out[k_fault] = (be1 * np.exp(-b1 / path(t))).sum() * dt
    return out


def measurement_noise_std(sigma_b: float, window_s: float = WINDOW_S) -> float:
    """Std of ``y_k`` from the Wiener term: ``sigma_B sqrt(window)`` (seed 001 eq. 9)."""
    return float(sigma_b * np.sqrt(window_s))


def simulate_measurements(y_true: FloatArray, sigma_y: float, rngs: list[np.random.Generator]
                          ) -> FloatArray:
    """Measured window losses ``y_k = X_k - X_{k-1}`` for each run, shape (R, W).

    ``y_true`` (W,) noise-free increments; ``sigma_y`` the std of the Wiener increment over a
    window; one generator per run (so a run's data do not depend on how runs are batched).
    """
    y_true = np.asarray(y_true, dtype=np.float64)
    if sigma_y < 0 or not np.isfinite(sigma_y):
        raise ValueError(f"sigma_y: expected a finite value >= 0, got {sigma_y}")
    return np.stack([y_true + sigma_y * g.standard_normal(y_true.size) for g in rngs])


# ---------------------------------------------------------------------------------------------
# Window sums by Gauss quadrature on the distribution of u = 1/T within each window
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class WindowQuadrature:
    """Gauss rule per window for the empirical distribution of ``u = 1/T^`` in that window.

    ``u_j = center + scale * x_j``; ``nodes`` (..., W, n) hold the standardised nodes ``x_i`` and
    ``weights`` (..., W, n) the Gauss weights (summing to 1); ``count`` is the number of samples
    per window. Then ``S_k(b) ~= count * exp(-b c_k) * sum_i w_ki exp(-b s_k x_ki)``, exact for
    any ``b`` when ``exp(-b s x)`` is a polynomial of degree <= 2n - 1 in x.
    """

    center: FloatArray
    scale: FloatArray
    nodes: FloatArray
    weights: FloatArray
    count: float

    @property
    def n_windows(self) -> int:
        return int(self.center.shape[-1])

    @property
    def n_nodes(self) -> int:
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
        return np.log(self.count) - b * c + np.log(inner)

    def sums(self, b: FloatArray, k: int | slice) -> FloatArray:
        """``S_k(b)`` for particles ``b`` (see :meth:`log_sums`)."""
        return np.exp(self.log_sums(b, k))


def window_quadrature(u: FloatArray, n_nodes: int = 5, *, count: float | None = None,
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
                            count=float(m if count is None else count))


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


# ---------------------------------------------------------------------------------------------
# The error-process shortcut for T^ over months (docs/systems/reaction-wheel.md §4)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class EstimateErrorProcess:
    """Error of the step-1 estimate ``T^ - T`` as bias + stationary AR(1), held over blocks [R].

    ``e_i = bias + d_i``, ``d_i = rho d_{i-1} + std sqrt(1 - rho^2) eta_i`` with
    ``rho = exp(-hold_s / tau_s)``; the value is held for ``hold_samples`` 0.05 s samples (a
    step-1 estimate changes little within 2 s; the sample-to-sample jitter only adds a
    negligible convexity bias to window sums and is reported as ``white_std``, not simulated).
    The statistics come from measured step-1 runs (:func:`fit_error_process`); ``source`` says
    where they came from.
    """

    bias_c: float = 0.0
    std_c: float = 0.5
    tau_s: float = 60.0
    hold_samples: int = 40
    white_std_c: float = 0.0
    source: str = "placeholder [R] (not measured)"

    @property
    def hold_s(self) -> float:
        return self.hold_samples * SAMPLE_DT

    def estimate_blocks(self, path: TemperaturePath, k0: int, n_windows: int,
                        rngs: list[np.random.Generator], state: FloatArray | None = None
                        ) -> tuple[FloatArray, FloatArray]:
        """Synthetic ``T^`` per hold block for windows ``k0 .. k0+n_windows-1`` of every run.

        Returns ``(T_hat (R, n_windows, m), state (R,))`` with m = WINDOW_SAMPLES/hold_samples;
        ``state`` carries the AR(1) value into the next call (None starts from the stationary
        law). The true T of a block is taken at its middle sample.
        """
        if WINDOW_SAMPLES % self.hold_samples:
            raise ValueError(f"hold_samples must divide {WINDOW_SAMPLES}, got {self.hold_samples}")
        m = WINDOW_SAMPLES // self.hold_samples
        n_blocks = n_windows * m
        rho = float(np.exp(-self.hold_s / self.tau_s)) if self.tau_s > 0 else 0.0
        innov = self.std_c * np.sqrt(1.0 - rho * rho)
        R = len(rngs)
        if state is None:  # drawn before the innovations: chunking does not change the stream
            state = self.std_c * np.stack([g.standard_normal() for g in rngs])
        eta = np.stack([g.standard_normal(n_blocks) for g in rngs])
        d = _ar1(eta * innov, rho, np.asarray(state, dtype=np.float64))
        t_block = np.asarray((k0 * WINDOW_SAMPLES + (np.arange(n_blocks) + 0.5)
                              * self.hold_samples) * SAMPLE_DT, dtype=np.float64)
        T_hat = path(t_block)[None, :] + self.bias_c + d
        return T_hat.reshape(R, n_windows, m), d[:, -1].copy()


def _ar1(innovations: FloatArray, rho: float, d0: FloatArray) -> FloatArray:
    """``d_i = rho d_{i-1} + innovations_i`` along the last axis, starting from ``d_{-1} = d0``."""
    return _ar1_kernel(np.ascontiguousarray(innovations), float(rho),
                       np.ascontiguousarray(d0, dtype=np.float64))


@numba.njit(cache=True)
def _ar1_kernel(innov: FloatArray, rho: float, d0: FloatArray) -> FloatArray:  # pragma: no cover
    R, n = innov.shape
    out = np.empty((R, n))
    for r in range(R):
        d = d0[r]
        for i in range(n):
            d = rho * d + innov[r, i]
            out[r, i] = d
    return out


def fit_error_process(errors: FloatArray, *, hold_samples: int = 40, dt: float = SAMPLE_DT,
                      source: str = "measured") -> EstimateErrorProcess:
    """Fit :class:`EstimateErrorProcess` to step-1 errors ``T^ - T``, shape (R, n) at ``dt``.

    bias = mean error; the error is averaged over hold blocks; std = std of the block means;
    ``tau = -hold_s / ln(rho_1)`` from the pooled lag-1 autocorrelation of the block means (a
    lag-1 autocorrelation <= 0 gives tau = 0, i.e. independent blocks; tau is capped at the
    record length); ``white_std`` = std of the residual within blocks.
    """
    e = np.atleast_2d(np.asarray(errors, dtype=np.float64))
    if not np.all(np.isfinite(e)):
        raise ValueError("errors: non-finite values")
    n_blocks = e.shape[1] // hold_samples
    if n_blocks < 3:
        raise ValueError(f"errors: need at least 3 blocks of {hold_samples} samples per run")
    bias = float(e.mean())
    blocks = e[:, : n_blocks * hold_samples].reshape(e.shape[0], n_blocks, hold_samples)
    bm = blocks.mean(axis=-1)
    white = float((blocks - bm[..., None]).std())
    d = bm - bias
    std = float(d.std())
    num = float((d[:, 1:] * d[:, :-1]).mean())
    rho = num / max(float((d * d).mean()), 1e-300)
    hold_s = hold_samples * dt
    # rho <= 0: independent blocks (tau = 0); rho >= 1 (a trend-like error over the record,
    # end effects can push the estimate past 1): capped at the record length
    record_s = n_blocks * hold_s
    if rho <= 0.0:
        tau = 0.0
    elif rho >= 1.0:
        tau = record_s
    else:
        tau = min(float(-hold_s / np.log(rho)), record_s)
    return EstimateErrorProcess(bias_c=bias, std_c=std, tau_s=tau, hold_samples=hold_samples,
                                white_std_c=white, source=source)


def synthetic_estimate_quadrature(path: TemperaturePath, error: EstimateErrorProcess,
                                  n_windows: int, rngs: list[np.random.Generator], *,
                                  n_nodes: int = 5, chunk_windows: int = 1024
                                  ) -> WindowQuadrature:
    """Window quadrature of ``1/T^`` for each run with ``T^ = T + error`` over ``n_windows``.

    Streams the synthetic estimate in chunks (three months = 32,400 windows never exist in
    memory at once); returns a :class:`WindowQuadrature` with arrays of shape (R, W[, n]).
    """
    R = len(rngs)
    center = np.empty((R, n_windows))
    scale = np.empty((R, n_windows))
    nodes = np.empty((R, n_windows, n_nodes))
    weights = np.empty((R, n_windows, n_nodes))
    state = None
    for k0 in range(0, n_windows, chunk_windows):
        k1 = min(n_windows, k0 + chunk_windows)
        T_hat, state = error.estimate_blocks(path, k0, k1 - k0, rngs, state)
        # a synthetic estimate below 5 C (possible only for huge error statistics) is clipped
        # there [R]: the loss law is singular at 0 C and step-1 priors start at 15 C
        np.maximum(T_hat, T_MIN_C, out=T_hat)
        _check_temperature(T_hat, "synthetic T^")
        q = window_quadrature(1.0 / T_hat, n_nodes, count=WINDOW_SAMPLES)
        center[:, k0:k1], scale[:, k0:k1] = q.center, q.scale
        nodes[:, k0:k1], weights[:, k0:k1] = q.nodes, q.weights
    return WindowQuadrature(center, scale, nodes, weights, float(WINDOW_SAMPLES))


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
    _check_temperature(T, "temperature path")
    return window_quadrature(1.0 / T, n_nodes, count=window_s / SAMPLE_DT)


@dataclass(frozen=True)
class LubricationSetup:
    """Everything that defines the step-2/3 truth for one scenario [R] where marked."""

    scenario_id: int
    horizon_days: float = 90.0
    #: Wiener intensity as a fraction of the healthy window loss at the path mean [R].
    noise_rel: float = 0.01
    path: TemperaturePath = field(default_factory=TemperaturePath)

    @property
    def scenario(self) -> FaultScenario:
        return SCENARIOS[self.scenario_id]

    @property
    def n_windows(self) -> int:
        return round(self.horizon_days * DAY_S / WINDOW_S)

    @property
    def sigma_y(self) -> float:
        """Std of the window measurement noise, mL (``noise_rel`` x healthy mean window loss)."""
        sc = self.scenario
        y_ref = sc.beta0_healthy * np.exp(-sc.b_healthy / self.path.mean_c) * WINDOW_S
        return float(self.noise_rel * y_ref)
