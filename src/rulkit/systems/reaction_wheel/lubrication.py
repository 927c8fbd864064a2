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


def loss_rate(temperature_c: FloatArray | float, b: FloatArray | float,
              beta0: FloatArray | float) -> FloatArray:
    """Lubricant loss rate ``beta0 exp(-b / T)`` in mL/s (seed 001 eq. 7 with the sign fixed).

    Broadcasts over its arguments. Raises ``ValueError`` when a temperature is below
    :data:`T_MIN_C` or not finite (the law is singular at 0 deg C, docs/systems/reaction-wheel.md
    §4).
    """
    T = np.asarray(temperature_c, dtype=np.float64)
    check_temperature(T, "temperature_c")
    return np.asarray(beta0, dtype=np.float64) * np.exp(-np.asarray(b, dtype=np.float64) / T)


def check_temperature(T: FloatArray, name: str) -> None:
    """Raise ``ValueError`` naming ``name`` and the flat index of the first non-finite
    temperature or of the lowest one below :data:`T_MIN_C`."""
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
        """T(t) in deg C at times ``t`` (s)."""
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
            check_temperature(T, "temperature path")
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
    check_temperature(Tg, "temperature path")
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
        """The fault scenario of Table 4 this setup runs."""
        return SCENARIOS[self.scenario_id]

    @property
    def n_windows(self) -> int:
        """Number of 4-minute measurement windows in the horizon."""
        return round(self.horizon_days * DAY_S / WINDOW_S)

    @property
    def sigma_y(self) -> float:
        """Std of the window measurement noise, mL (``noise_rel`` x healthy mean window loss)."""
        sc = self.scenario
        y_ref = sc.beta0_healthy * np.exp(-sc.b_healthy / self.path.mean_c) * WINDOW_S
        return float(self.noise_rel * y_ref)
