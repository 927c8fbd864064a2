"""Friction-drive deterioration: augmented EKF, consistency checks, observability and Monte Carlo
RUL (seed 003, Rodriguez Obando, Martinez & Berenguer, IFAC 2017; docs/systems/friction-drive.md).

The experiment composes the physics of :mod:`rulkit.systems.friction_drive.drive` with the generic
:class:`rulkit.estimation.ekf.ExtendedKalmanFilter` (continuous model, RK4 mean prediction,
``Phi = expm(F t_s)`` with the analytic F of seed eq. 19, Van Loan ``Q_d``), the consistency
checks of :mod:`rulkit.estimation.consistency` and :class:`rulkit.prognosis.rul.RULDistribution`.

Everything returns plain data (dataclasses of arrays and dicts); figures and the report are made
by :mod:`rulkit.systems.friction_drive.report`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from rulkit.estimation.consistency import (
    InnovationCheck,
    StateErrorCheck,
    check_innovations,
    state_error_check,
)
from rulkit.estimation.ekf import ExtendedKalmanFilter
from rulkit.model import FloatArray
from rulkit.systems.friction_drive import drive as fd
from rulkit.systems.friction_drive.deterioration import DriveTrack, EKFSettings, track
from rulkit.systems.friction_drive.drive import (
    REALISTIC_R,
    SEED_P0,
    SEED_R,
    SEED_SIGMA_M2,
    SPEED_Q_RATE,
    TUNED_Q_RATE,
)
from rulkit.systems.friction_drive.observability import Observability, observability
from rulkit.systems.friction_drive.rul import (
    HOUR,
    TRANSIENT_DT,
    RULResult,
    predict_rul,
    time_to_failure_reference,
)

# Configurations whose study units draw their noise from a separate seeded stream (run).
ADDED_CONFIGS = ("tuned-consistent", "tuned-consistent-realistic")
# Innovation tests of every run (reported by report.py): Ljung-Box over MAX_LAG lags
# of the whitened innovations, white when every component's p > WHITENESS_ALPHA / m.
MAX_LAG = 20
WHITENESS_ALPHA = 0.01
# The tuning study of ``rulkit drive``'s filter: process-noise rates on m and scenarios.
TUNING_Q_M = (1e-9, 1e-8, 3e-8, 1e-7, 3e-7, 1e-6, 1e-5)
TUNING_SCENARIOS = ("constant", "drift", "jump")

# Seed values quoted in the report (seed sections 4.3, 6 and Fig. 8).
SEED_VALUES = {
    "rul_mean_h": 106.09,
    "rul_std_h": 3.36,
    "chebyshev_n4_c3": 0.555,
    "erf_c3": 0.997,
}


# ------------------------------------------------------------------------------------------
# Scenarios and filter configurations
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Scenario:
    """A truth scenario (seed 5.1 and eq. 28): input kind and the schedule of m.

    ``m_kind``: "constant" (assumption i), "jump" (ii: m -> ``m_jump`` at ``t_jump``) or
    "drift" (iii: dm/dt = ``drift_rate``). ``current``: "square" (0/20 A, period 2 s, on during
    [2k, 2k+1) s; [R], docs/systems/friction-drive.md §3) or "constant" (20 A from rest).
    """

    name: str
    m_kind: str = "jump"
    current: str = "square"
    amplitude: float = 20.0
    alpha0: float = 10.0
    m0: float = 0.01
    m_jump: float = 0.02
    t_jump: float = 10.0
    drift_rate: float = 5e-4
    duration: float = 20.0

    def __post_init__(self) -> None:
        if self.m_kind not in ("constant", "jump", "drift"):
            raise ValueError(f"Scenario.m_kind: expected constant|jump|drift, got {self.m_kind!r}")
        if self.current not in ("square", "constant"):
            raise ValueError(f"Scenario.current: expected square|constant, got {self.current!r}")
        if not self.duration > 0:
            raise ValueError(f"Scenario.duration: expected > 0, got {self.duration}")

    def m_of_t(self, t: FloatArray) -> FloatArray:
        """The true mass parameter m at times ``t`` (constant, jump or drift schedule)."""
        t = np.asarray(t, dtype=np.float64)
        if self.m_kind == "constant":
            return np.full(t.shape, self.m0)
        if self.m_kind == "jump":
            return np.where(t < self.t_jump, self.m0, self.m_jump)
        return self.m0 + self.drift_rate * t

    def current_of_t(self, t: FloatArray) -> FloatArray:
        """The input current at times ``t`` (square wave or constant)."""
        t = np.asarray(t, dtype=np.float64)
        if self.current == "square":
            return fd.square_wave_current(t, self.amplitude)
        return np.full(t.shape, self.amplitude)


SCENARIOS = {
    "constant": Scenario("constant", m_kind="constant"),
    "jump": Scenario("jump", m_kind="jump"),
    "drift": Scenario("drift", m_kind="drift"),
    "constant-current": Scenario("constant-current", m_kind="constant", current="constant"),
}


@dataclass(frozen=True)
class FilterConfig:
    """An EKF tuning: ``q_m`` the process-noise rate on m (per second; Q_d ~ q_m t_s), ``f44``
    the Jacobian-only (4,4) entry (seed 5.2), ``R_filter`` and the truth's ``R_truth``.

    ``q_speed`` process-noise rates (per second) on (w1, w2), zero in the seed (eq. 15/27).
    ``jacobian_at``: where F of ``Phi = expm(F t_s)`` is evaluated: "start" (the prior mean
    x_hat_{k-1}, seed eq. 17-19 as written) or "midpoint" (the mean after half an RK4 step
    under the step's current; second order in t_s, see :func:`make_ekf`)."""

    name: str
    q_m: float
    f44: float = 0.0
    R_filter: FloatArray = field(default_factory=lambda: SEED_R.copy())
    R_truth: FloatArray = field(default_factory=lambda: SEED_R.copy())
    label: str = ""
    q_speed: tuple[float, float] = (0.0, 0.0)
    jacobian_at: str = "start"

    def __post_init__(self) -> None:
        if self.jacobian_at not in ("start", "midpoint"):
            raise ValueError(
                "FilterConfig.jacobian_at: expected 'start' or 'midpoint', "
                f"got {self.jacobian_at!r}"
            )
        if len(self.q_speed) != 2 or not all(np.isfinite(q) and q >= 0 for q in self.q_speed):
            raise ValueError(f"FilterConfig.q_speed: expected two finite rates >= 0, "
                             f"got {self.q_speed!r}")


def seed_configs(dt: float = 1e-3) -> dict[str, FilterConfig]:
    """The tunings compared in the study.

    - ``seed``: Q = diag(0, 0, 0, 3.3333e-5) per step as printed (seed eq. 15, 27), i.e.
      q_m = 3.3333e-5 / t_s per second, F44 = 0;
    - ``seed-f44``: the same with the seed's F44 = -100 heuristic (Jacobian only);
    - ``tuned``: q_m = 3e-7 / s (docs/systems/friction-drive.md §4);
    - ``tuned-low-q``: q_m = 3e-8 / s (less process noise than ``tuned``: whiter innovations
      when m is constant, slower tracking of a change);
    - ``tuned-realistic``: the tuned filter with 100 x the seed's speed-noise sigmas;
    - ``tuned-consistent``: ``tuned`` with Phi from the Jacobian at the step midpoint and process
      noise ``SPEED_Q_RATE`` on the speeds (the two measured causes of the NEES spikes after the
      current switches; the other configurations keep the seed's start-of-step Jacobian and no
      speed noise, so their numbers are unchanged);
    - ``tuned-consistent-realistic``: the same with 100 x the seed's speed-noise sigmas.
    """
    return {
        "seed": FilterConfig("seed", SEED_SIGMA_M2 / dt, 0.0, label="seed Q as printed"),
        "seed-f44": FilterConfig(
            "seed-f44", SEED_SIGMA_M2 / dt, -100.0, label="seed Q, F44 = -100"
        ),
        "tuned": FilterConfig("tuned", TUNED_Q_RATE, 0.0, label="q_m = 3e-7 /s"),
        "tuned-low-q": FilterConfig("tuned-low-q", 0.1 * TUNED_Q_RATE, 0.0,
                                    label="q_m = 3e-8 /s"),
        "tuned-realistic": FilterConfig(
            "tuned-realistic",
            TUNED_Q_RATE,
            0.0,
            REALISTIC_R.copy(),
            REALISTIC_R.copy(),
            label="q_m = 3e-7 /s, sigma x100",
        ),
        "tuned-consistent": FilterConfig(
            "tuned-consistent", TUNED_Q_RATE, 0.0, q_speed=SPEED_Q_RATE, jacobian_at="midpoint",
            label="q_m = 3e-7 /s, q_w, midpoint F",
        ),
        "tuned-consistent-realistic": FilterConfig(
            "tuned-consistent-realistic", TUNED_Q_RATE, 0.0, REALISTIC_R.copy(),
            REALISTIC_R.copy(), label="q_m = 3e-7 /s, q_w, midpoint F, sigma x100",
            q_speed=SPEED_Q_RATE, jacobian_at="midpoint",
        ),
    }


# (filter config, scenario) pairs of a full study: every config on the jump scenario, the tuned
# filter on every scenario.
DEFAULT_PAIRS = (
    ("seed", "jump"),
    ("seed-f44", "jump"),
    ("tuned", "jump"),
    ("tuned-realistic", "jump"),
    ("tuned", "constant"),
    ("tuned-low-q", "constant"),
    ("tuned-low-q", "jump"),
    ("tuned", "drift"),
    ("tuned", "constant-current"),
    ("tuned-consistent", "jump"),
    ("tuned-consistent", "constant"),
    ("tuned-consistent-realistic", "jump"),
)


# ------------------------------------------------------------------------------------------
# Truth
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Truth:
    """A simulated truth: times ``t`` (K+1,), states ``X`` (K+1, 4) at the sample times,
    ``currents`` (K,) held over each step, of the drive ``params``."""

    scenario: Scenario
    dt: float
    t: FloatArray
    X: FloatArray
    currents: FloatArray
    params: fd.FrictionDriveParams = fd.DEFAULT_PARAMS


def simulate_truth(scenario: Scenario, dt: float = 1e-3, n_sub: int = 10,
                   params: fd.FrictionDriveParams = fd.DEFAULT_PARAMS) -> Truth:
    """Integrate the full model with ``n_sub`` RK4 sub-steps per sample
    (docs/systems/friction-drive.md §4: the truth uses finer sub-steps than the filter). m follows
    the scenario's schedule, evaluated at the middle of each sample interval (exact for constant m
    and for the jump at a sample time)."""
    K = round(scenario.duration / dt)
    t = np.arange(K + 1, dtype=np.float64) * dt
    currents = scenario.current_of_t(t[:-1])
    m_path = scenario.m_of_t(t[:-1] + 0.5 * dt)
    if scenario.m_kind == "jump":  # the jump falls on a sample time: use the step-start value
        m_path = scenario.m_of_t(t[:-1])
    x0 = np.array([[0.0, 0.0, scenario.alpha0, scenario.m0]])
    X = fd.integrate_path(x0, currents, dt, n_sub=n_sub, m_path=m_path, params=params)[:, 0, :]
    X[:, 3] = scenario.m_of_t(t)
    return Truth(scenario, dt, t, X, currents, params)


def one_step_discretisation_error(truth: Truth, n_sub: int = 1) -> FloatArray:
    """Error of the filter's mean prediction over one sample: ``truth.X[k+1]`` minus ``n_sub``
    RK4 sub-steps from ``truth.X[k]`` under the truth's held current, shape (K, 4) (the
    discretisation mismatch between a fine truth and the filter; sizes ``SPEED_Q_RATE``)."""
    m_fixed = truth.X[:-1].copy()
    pred = fd.rk4_step(m_fixed, truth.currents, truth.dt, truth.params, n_sub=n_sub)
    pred[:, 3] = truth.X[1:, 3]  # m follows the scenario's schedule, not the model
    return truth.X[1:] - pred


def switch_steps(currents: FloatArray) -> NDArray[np.intp]:
    """Indices k of the steps whose held current differs from the previous step's (the steps
    that start at a current switch), shape (n_switch,)."""
    c = np.asarray(currents, dtype=np.float64)
    return np.flatnonzero(np.diff(c) != 0) + 1


def nees_near_switches(nees: FloatArray, currents: FloatArray, window: int = 50
                       ) -> NDArray[np.bool_]:
    """Boolean mask (K,) of the NEES entries within ``window`` steps after a current switch
    (``nees[k]`` is the NEES of the estimate after step k)."""
    near = np.zeros(np.shape(nees)[0], bool)
    for k in switch_steps(currents):
        near[k : k + window] = True
    return near


# ------------------------------------------------------------------------------------------
# The EKF over a batch of units
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FilterRun:
    """Filter output for B units over T steps (stored compactly: no full P history).

    ``x`` (T+1, B, 4) posterior means (row 0: the prior), ``Pdiag`` (T+1, B, 4), ``P_final``
    (B, 4, 4), ``nu`` (T, B, 2), ``S`` (T, B, 2, 2), ``nees`` (T, B) against the truth.
    """

    t: FloatArray
    x: FloatArray
    Pdiag: FloatArray
    P_final: FloatArray
    nu: FloatArray
    S: FloatArray
    nees: FloatArray
    seconds: float


def make_ekf(
    q_m: FloatArray, f44: FloatArray, R: FloatArray, dt: float,
    params: fd.FrictionDriveParams = fd.DEFAULT_PARAMS,
    q_speed: FloatArray | None = None,
    midpoint: FloatArray | None = None,
    substeps: int = 1,
) -> ExtendedKalmanFilter:
    """The augmented EKF of seed 4.2 for B units (continuous model, Q as spectral density).

    ``q_m`` (B,) process-noise rates on m, ``f44`` (B,) Jacobian-only (4,4) entries, ``R``
    (B, 2, 2), ``q_speed`` (B, 2) rates on (w1, w2) (default 0, as in the seed), ``substeps``
    RK4 sub-steps of the mean prediction per sample. Inputs are passed as ``u`` (B, 1)
    currents.

    ``midpoint`` (B,) bool (default all False): evaluate the Jacobian of ``Phi = expm(F t_s)``
    at the mean after half an RK4 step under the step's current instead of at the prior mean
    (the engine EKF's ``jacobian_at`` mask). The start-of-step F makes Phi first order in t_s:
    right after a current switch the speeds, and with them the alpha column of F (proportional
    to the slip), change within the step, Phi maps the alpha error into the speeds with the
    wrong gain, and the filter (no process noise on the speeds) is overconfident in a (w1, w2)
    combination. The midpoint F is second order (the mean prediction is unchanged).
    """
    q_m = np.asarray(q_m, dtype=np.float64)
    f44 = np.asarray(f44, dtype=np.float64)
    B = q_m.shape[0]
    Qc = np.zeros((B, 4, 4))
    Qc[:, 3, 3] = q_m
    if q_speed is not None:
        qs = np.broadcast_to(np.asarray(q_speed, dtype=np.float64), (B, 2))
        Qc[:, 0, 0], Qc[:, 1, 1] = qs[:, 0], qs[:, 1]
    mid = np.zeros(B, bool) if midpoint is None else np.broadcast_to(np.asarray(midpoint, bool),
                                                                      (B,))
    H = np.zeros((2, 4))
    H[0, 0] = H[1, 1] = 1.0

    def f(x: FloatArray, u: FloatArray, t: float) -> FloatArray:
        return fd.drift(x, np.asarray(u).reshape(-1), params)

    def jac_f(x: FloatArray, u: FloatArray, t: float) -> FloatArray:
        J = fd.jacobian(x, None, params)
        J[:, 3, 3] = f44
        return J

    return ExtendedKalmanFilter(
        f,
        lambda x, u, t: x[:, :2],
        Qc,
        np.asarray(R, dtype=np.float64),
        jac_f=jac_f,
        jac_h=lambda x, u, t: np.broadcast_to(H, (x.shape[0], 2, 4)),
        continuous=True,
        dt=dt,
        jacobian_at=mid,
        substeps=substeps,
    )


def run_filter(
    ekf: ExtendedKalmanFilter,
    ys: FloatArray,
    currents: FloatArray,
    x0: FloatArray,
    P0: FloatArray,
    truth: FloatArray | None = None,
) -> FilterRun:
    """Run ``ekf`` over ``ys`` (T, B, 2) with inputs ``currents`` (T, B); ``x0`` (B, 4), ``P0``
    (4, 4) or (B, 4, 4) describe the state at t = 0 (one step before ``ys[0]``). ``truth``
    (T+1, B, 4), when given, gives the NEES per step."""
    T, B, _ = ys.shape
    x = np.array(x0, dtype=np.float64)
    P = np.broadcast_to(np.asarray(P0, dtype=np.float64), (B, 4, 4)).copy()
    xs = np.empty((T + 1, B, 4))
    Pd = np.empty((T + 1, B, 4))
    nu = np.empty((T, B, 2))
    S = np.empty((T, B, 2, 2))
    nees = np.full((T, B), np.nan)
    xs[0] = x
    Pd[0] = np.diagonal(P, axis1=1, axis2=2)
    t0 = time.perf_counter()
    for k in range(T):
        u = currents[k][:, None]
        x, P = ekf.predict(x, P, k, u)
        x, P, inn = ekf.update(x, P, ys[k], k, u)
        xs[k + 1] = x
        Pd[k + 1] = np.diagonal(P, axis1=1, axis2=2)
        nu[k] = inn.nu
        S[k] = inn.S
        if truth is not None:
            e = truth[k + 1] - x
            try:
                nees[k] = np.einsum("bi,bi->b", e, np.linalg.solve(P, e[..., None])[..., 0])
            except np.linalg.LinAlgError:  # a numerically singular P: NEES undefined there
                nees[k] = np.nan
    return FilterRun(
        t=np.arange(T + 1) * ekf.dt,
        x=xs,
        Pdiag=Pd,
        P_final=P,
        nu=nu,
        S=S,
        nees=nees,
        seconds=time.perf_counter() - t0,
    )


# ------------------------------------------------------------------------------------------
# Convergence from wrong initial estimates (docs/systems/friction-drive.md §4, last line)
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ConvergenceRow:
    """Settling times of one run started from (alpha_hat0, m_hat0); nan when never settled."""

    alpha_hat0: float
    m_hat0: float
    alpha_settle_s: float
    m_settle_s: float
    alpha_final_err: float
    m_final_rel_err: float


def convergence_study(
    truth: Truth,
    rng: np.random.Generator,
    *,
    alpha0s: tuple[float, ...] = (5.0, 8.0, 11.0),
    m0s: tuple[float, ...] = (0.0, 0.02),
    q_m: float = TUNED_Q_RATE,
    duration: float = 3.0,
    alpha_tol: float = 0.01,
    m_tol: float = 0.1,
) -> list[ConvergenceRow]:
    """Tuned EKF from wrong initial alpha/m (w at rest), P0 as in the seed; time after which
    |alpha_hat - alpha| <= alpha_tol * alpha and |m_hat - m| <= m_tol * m hold for good."""
    K = round(duration / truth.dt)
    combos = [(a, m) for a in alpha0s for m in m0s]
    B = len(combos)
    ys = truth.X[1 : K + 1, None, :2] + rng.standard_normal((K, B, 2)) * np.sqrt(np.diag(SEED_R))
    cur = np.repeat(truth.currents[:K, None], B, axis=1)
    x0 = np.array([[0.0, 0.0, a, m] for a, m in combos])
    ekf = make_ekf(np.full(B, q_m), np.zeros(B), np.broadcast_to(SEED_R, (B, 2, 2)), truth.dt,
                   truth.params)
    run = run_filter(ekf, ys, cur, x0, SEED_P0)
    t = run.t
    tx = truth.X[: K + 1]
    out = []
    for b, (a, m) in enumerate(combos):
        out.append(ConvergenceRow(
            alpha_hat0=a, m_hat0=m,
            alpha_settle_s=_time_within(t, run.x[:, b, 2], tx[:, 2], alpha_tol * tx[:, 2], 0.0),
            m_settle_s=_time_within(t, run.x[:, b, 3], tx[:, 3], m_tol * tx[:, 3], 0.0),
            alpha_final_err=float(run.x[-1, b, 2] - tx[-1, 2]),
            m_final_rel_err=float((run.x[-1, b, 3] - tx[-1, 3]) / tx[-1, 3]),
        ))
    return out


# ------------------------------------------------------------------------------------------
# The whole study
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class UnitSummary:
    """Per (config, scenario, run) summary of a filter run. ``max_nees_switch`` /
    ``max_nees_other``: largest NEES within 50 steps after a current switch / elsewhere (jump
    scenario: without the second after the jump of m); ``*_excl_jump``: the checks without
    that second."""

    config: str
    scenario: str
    run: int
    innovations: InnovationCheck
    state_errors: StateErrorCheck
    alpha_hat: float
    alpha_true: float
    sigma_alpha: float
    m_hat: float
    m_true: float
    sigma_m: float
    m_rel_error: float
    jump_tracking_s: float
    alpha_converged_s: float
    innovations_excl_jump: InnovationCheck | None = None
    max_nees_switch: float = float("nan")
    max_nees_other: float = float("nan")
    state_errors_excl_jump: StateErrorCheck | None = None


@dataclass
class FrictionDriveResult:
    """Everything the report needs."""

    dt: float
    n_runs: int
    seed: int
    pairs: tuple[tuple[str, str], ...]
    truths: dict[str, Truth]
    runs: dict[tuple[str, str], FilterRun]
    summaries: list[UnitSummary]
    observability: list[Observability]
    rul: dict[str, RULResult]
    convergence: list[ConvergenceRow]
    rul_truth_h: float
    filter_seconds: float
    settings: dict
    tuning: list[TuningRow] = field(default_factory=list)
    params: fd.FrictionDriveParams = fd.DEFAULT_PARAMS


def _time_within(t: FloatArray, est: FloatArray, target: FloatArray,
                 tol: FloatArray | float, t_from: float) -> float:
    """First time >= t_from after which |est - target| <= tol holds for good (nan if never)."""
    ok = np.abs(est - target) <= tol
    sel = t >= t_from
    t, ok = t[sel], ok[sel]
    if ok.size == 0 or not ok[-1]:
        return float("nan")
    bad = np.flatnonzero(~ok)
    return float(t[bad[-1] + 1] - t_from) if bad.size else 0.0


@dataclass(frozen=True)
class FrictionDriveConfig:
    """Settings of the seed-003 study (defaults: the full run without the tuning study; the CLI
    runs it with ``tuning_runs=8``, and ``--quick`` uses ``n_runs=1, n_validate=3,
    tuning_runs=2``).

    ``n_runs`` runs per (filter config, scenario) pair of ``pairs``, filtered over ``duration``
    s at ``dt``; the Monte Carlo RUL (``n_rul`` trajectories, ``n_validate`` of them checked
    against LSODA) for ``rul_configs`` on the jump scenario; ``truth_substeps`` RK4 sub-steps
    of the truth per filter step; ``converge``: also the convergence study from wrong initial
    estimates; ``tuning_runs`` runs per (q_m of ``tuning_q_m``, scenario) of the tuning study of
    ``rulkit drive``'s filter (:func:`tuning_study`; 0: none). ``params``: the drive (the seed's
    by default; another one from a machine file: its constants and failure level for the truth,
    every filter and the RUL; the scenarios start at its ``alpha0``). ``seed`` drives every
    draw."""

    n_runs: int = 1
    seed: int = 0
    dt: float = 1e-3
    duration: float = 20.0
    pairs: tuple[tuple[str, str], ...] = DEFAULT_PAIRS
    n_rul: int = 100
    rul_configs: tuple[str, ...] = ("tuned", "seed", "seed-f44")
    n_validate: int = 5
    truth_substeps: int = 10
    converge: bool = True
    tuning_q_m: tuple[float, ...] = TUNING_Q_M
    tuning_runs: int = 0
    params: fd.FrictionDriveParams = fd.DEFAULT_PARAMS

    def __post_init__(self) -> None:
        if self.n_runs < 1:
            raise ValueError(f"n_runs: expected >= 1, got {self.n_runs}")
        if int(self.seed) != self.seed or self.seed < 0:
            raise ValueError(f"seed: expected a non-negative integer, got {self.seed!r}")
        if not self.duration >= 3.0:
            raise ValueError(
                f"duration: expected >= 3 s (a 2 s observability window), got {self.duration}"
            )
        configs = seed_configs(self.dt)
        for c, s in self.pairs:
            if c not in configs or s not in SCENARIOS:
                raise ValueError(f"pairs: unknown config/scenario {c!r}/{s!r}")


class _Batch(NamedTuple):
    """The study's units (config, scenario, run) as one batch: measurements ``ys`` (T, B, 2),
    currents (T, B), true states (T + 1, B, 4) and initial estimates ``x0`` (B, 4)."""

    units: list[tuple[str, str, int]]
    ys: FloatArray
    cur: FloatArray
    truth: FloatArray
    x0: FloatArray


def run(config: FrictionDriveConfig | None = None) -> FrictionDriveResult:
    """Run the whole seed-003 study (docs/systems/friction-drive.md §8).

    For every (config, scenario) pair and run: measurements with the config's truth noise, an
    initial estimate drawn from N(x_true(0), P0) (consistent start), the augmented EKF over
    ``duration`` s at ``dt``; then consistency verdicts, windowed observability under both
    inputs and, for ``rul_configs`` on the jump scenario (run 0), the Monte Carlo RUL at
    t = ``duration``. Seeded: ``numpy.random.default_rng(seed)`` drives all draws (units of
    the configurations added later, ``ADDED_CONFIGS``, from ``default_rng([seed, 1])``).
    """
    cfg = config or FrictionDriveConfig()
    rng = np.random.default_rng(cfg.seed)
    configs = seed_configs(cfg.dt)
    truths = _simulate_truths(cfg)
    batch = _draw_batch(cfg, truths, configs, rng)
    units = batch.units
    ekf = make_ekf(
        np.array([configs[c].q_m for c, _, _ in units]),
        np.array([configs[c].f44 for c, _, _ in units]),
        np.stack([configs[c].R_filter for c, _, _ in units]),
        cfg.dt,
        cfg.params,
        q_speed=np.array([configs[c].q_speed for c, _, _ in units]),
        midpoint=np.array([configs[c].jacobian_at == "midpoint" for c, _, _ in units]),
    )
    res = run_filter(ekf, batch.ys, batch.cur, batch.x0, SEED_P0, batch.truth)
    summaries = [_summarise_unit(res, b, unit, truths[unit[1]], batch)
                 for b, unit in enumerate(units)]
    runs = {(c, s): _first_run(res, b) for b, (c, s, r) in enumerate(units) if r == 0}
    duration, dt = cfg.duration, cfg.dt
    obs = [
        observability(truths["jump"], duration - 2.0 - dt, 2.0),
        observability(truths["constant-current"], duration - 2.0 - dt, 2.0),
    ]
    rul = {}
    for c in cfg.rul_configs:
        b = units.index((c, "jump", 0)) if (c, "jump", 0) in units else None
        if b is None:
            continue
        rul[c] = predict_rul(res.x[-1, b], res.P_final[b], rng, t_pred=duration,
                             n_samples=cfg.n_rul, n_validate=cfg.n_validate, params=cfg.params)
    rul_truth = float(time_to_failure_reference(truths["jump"].X[-1:], params=cfg.params)[0]
                      / HOUR)
    conv = (convergence_study(truths["jump"], rng, duration=min(3.0, duration))
            if cfg.converge else [])
    tuning = (tuning_study(_tuning_truths(cfg, truths), cfg.tuning_q_m, cfg.tuning_runs,
                           np.random.default_rng([cfg.seed, 2])) if cfg.tuning_runs else [])
    return FrictionDriveResult(
        dt=dt, n_runs=cfg.n_runs, seed=cfg.seed, pairs=tuple(cfg.pairs), truths=truths,
        runs=runs, summaries=summaries, observability=obs, rul=rul, convergence=conv,
        rul_truth_h=rul_truth, filter_seconds=res.seconds,
        settings={"dt": dt, "duration": duration, "n_rul": cfg.n_rul,
                  "truth_substeps": cfg.truth_substeps, "n_validate": cfg.n_validate,
                  "B": len(units), "transient": 10.0, "transient_dt": TRANSIENT_DT},
        tuning=tuning, params=cfg.params,
    )


def _simulate_truths(cfg: FrictionDriveConfig) -> dict[str, Truth]:
    """The true trajectory of every scenario of the study (and of the two the observability
    and RUL always use), over ``cfg.duration``."""
    scen_names = sorted({s for _, s in cfg.pairs} | {"jump", "constant-current"})
    truths = {}
    for s in scen_names:
        sc = Scenario(**{**SCENARIOS[s].__dict__, "duration": cfg.duration,
                         "alpha0": cfg.params.alpha0})
        truths[s] = simulate_truth(sc, cfg.dt, cfg.truth_substeps, cfg.params)
    return truths


def _draw_batch(cfg: FrictionDriveConfig, truths: dict[str, Truth],
                configs: dict[str, FilterConfig], rng: np.random.Generator) -> _Batch:
    """Measurements and initial estimates of every unit, drawn in unit order."""
    T = next(iter(truths.values())).currents.shape[0]
    units = [(c, s, r) for (c, s) in cfg.pairs for r in range(cfg.n_runs)]
    B = len(units)
    ys = np.empty((T, B, 2))
    cur = np.empty((T, B))
    truth_b = np.empty((T + 1, B, 4))
    x0 = np.empty((B, 4))
    # Units of configurations added after the study's first release draw from their own stream,
    # so adding them leaves every other number of a seeded study (filters, RUL, convergence)
    # unchanged.
    rng_added = np.random.default_rng([cfg.seed, 1])
    for b, (c, s, _r) in enumerate(units):
        tr = truths[s]
        g = rng_added if c in ADDED_CONFIGS else rng
        Lr = np.sqrt(np.diag(configs[c].R_truth))
        ys[:, b] = tr.X[1:, :2] + g.standard_normal((T, 2)) * Lr
        cur[:, b] = tr.currents
        truth_b[:, b] = tr.X
        x0[b] = tr.X[0] + g.standard_normal(4) * np.sqrt(np.diag(SEED_P0))
    return _Batch(units, ys, cur, truth_b, x0)


def _summarise_unit(res: FilterRun, b: int, unit: tuple[str, str, int], truth: Truth,
                    batch: _Batch) -> UnitSummary:
    """Consistency verdicts, final estimates and settling times of unit ``b``."""
    c, s, r = unit
    sc = truth.scenario
    t = res.t
    T = batch.cur.shape[0]
    nu, S = res.nu[:, b], res.S[:, b]
    inn = check_innovations(nu, S, max_lag=MAX_LAG, whiteness_alpha=WHITENESS_ALPHA)
    inn_x = None
    se_x = None
    err = batch.truth[:, b] - res.x[:, b]
    valid = np.ones(T, bool)
    if sc.m_kind == "jump":  # the same tests without the second after the jump
        cut = (t[1:] >= sc.t_jump) & (t[1:] < sc.t_jump + 1.0)
        inn_x = check_innovations(np.where(cut[:, None], np.nan, nu), S, max_lag=MAX_LAG,
                                  whiteness_alpha=WHITENESS_ALPHA)
        valid = ~cut  # not the jump's second
        se_x = state_error_check(res.nees[valid, b], err[1:][valid], res.Pdiag[1:, b][valid])
    # NEES needs the full P; we keep diag only, so the state check uses the per-step NEES
    # computed in the loop and the diagonal for the coverage.
    se = state_error_check(res.nees[:, b], err[1:], res.Pdiag[1:, b])
    near = nees_near_switches(res.nees[:, b], batch.cur[:, b])
    n_sw, n_other = res.nees[near & valid, b], res.nees[~near & valid, b]
    max_sw = float(np.nanmax(n_sw)) if n_sw.size else float("nan")
    max_other = float(np.nanmax(n_other)) if n_other.size else float("nan")
    xb = res.x[-1, b]
    Pd = res.Pdiag[-1, b]
    m_true = truth.X[-1, 3]
    jump_s = float("nan")
    if sc.m_kind == "jump":
        jump_s = _time_within(t, res.x[:, b, 3], truth.X[:, 3], 0.05 * sc.m_jump, sc.t_jump)
    conv = _time_within(t, res.x[:, b, 2], truth.X[:, 2], 3.0 * np.sqrt(res.Pdiag[:, b, 2]),
                        0.0)
    return UnitSummary(
        config=c, scenario=s, run=r, innovations=inn, state_errors=se,
        alpha_hat=float(xb[2]), alpha_true=float(truth.X[-1, 2]),
        sigma_alpha=float(np.sqrt(Pd[2])), m_hat=float(xb[3]), m_true=float(m_true),
        sigma_m=float(np.sqrt(Pd[3])), m_rel_error=float((xb[3] - m_true) / m_true),
        jump_tracking_s=jump_s, alpha_converged_s=conv, innovations_excl_jump=inn_x,
        max_nees_switch=max_sw, max_nees_other=max_other, state_errors_excl_jump=se_x,
    )


def _first_run(res: FilterRun, b: int) -> FilterRun:
    """Unit ``b`` of the batched filter run, kept for the figures (run 0 of each pair)."""
    return FilterRun(
        t=res.t, x=res.x[:, b : b + 1], Pdiag=res.Pdiag[:, b : b + 1],
        P_final=res.P_final[b : b + 1], nu=res.nu[:, b][:, None], S=res.S[:, b][:, None],
        nees=res.nees[:, b : b + 1], seconds=res.seconds,
    )


# ------------------------------------------------------------------------------------------
# Tuning of the command's filter: q_m against consistency (docs/systems/friction-drive.md §4)
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TuningRow:
    """One run of the tuning study: the innovation checks of the whole run and (jump
    scenario) without the second after the jump, the largest per-step NIS, the error of m at
    the end in its standard deviations and the time to track a jump of m within 5 %."""

    q_m: float
    scenario: str
    run: int
    mean_nis: float
    nis_ok: bool
    white: bool
    consistent: bool
    consistent_excl_jump: bool | None
    ljung_box_p_min: float
    max_nis: float
    m_error_sd: float
    jump_tracking_s: float


def _tuning_truths(cfg: FrictionDriveConfig, truths: dict[str, Truth]) -> dict[str, Truth]:
    out = {}
    for s in TUNING_SCENARIOS:
        sc = Scenario(**{**SCENARIOS[s].__dict__, "duration": cfg.duration,
                         "alpha0": cfg.params.alpha0})
        out[s] = (truths[s] if s in truths
                  else simulate_truth(sc, cfg.dt, cfg.truth_substeps, cfg.params))
    return out


def tuning_study(truths: dict[str, Truth], q_ms: tuple[float, ...], runs: int,
                 rng: np.random.Generator) -> list[TuningRow]:
    """``rulkit drive``'s filter (the compiled kernel of
    :mod:`rulkit.systems.friction_drive.deterioration`: midpoint Jacobian, ``SPEED_Q_RATE`` on
    the speeds, no gate) with each process-noise rate ``q_m`` on each scenario of ``truths``,
    ``runs`` noise draws each (the same draws for every q_m): which tuning is consistent where
    (docs/systems/friction-drive.md §4). The prior is the first measured speeds (variance R)
    and alpha, m drawn from the seed's P0 around the truth."""
    rows = []
    for name, tr in truths.items():
        T = tr.t.size
        cur = np.append(tr.currents, tr.currents[-1])
        for r in range(runs):
            ys = tr.X[:, :2] + rng.standard_normal((T, 2)) * np.sqrt(np.diag(SEED_R))
            x0 = tr.X[0] + rng.standard_normal(4) * np.sqrt(np.diag(SEED_P0))
            x0[:2] = ys[0]
            P0 = SEED_P0.copy()
            P0[0, 0], P0[1, 1] = SEED_R[0, 0], SEED_R[1, 1]
            for q in q_ms:
                run = track(ys, cur, x0, P0, EKFSettings(tr.dt, 1, 0.0, 0.0, True),
                            tr.params, np.array([*SPEED_Q_RATE, 0.0, q]), SEED_R)
                rows.append(_tuning_row(run, tr, q, name, r))
    return rows


def _tuning_row(run: DriveTrack, tr: Truth, q: float, name: str, r: int) -> TuningRow:
    sc = tr.scenario
    nu, S = run.nu[1:], run.S[1:]
    full = check_innovations(nu, S, max_lag=MAX_LAG, whiteness_alpha=WHITENESS_ALPHA)
    excl = None
    track_s = float("nan")
    if sc.m_kind == "jump" and sc.t_jump < tr.t[-1]:
        cut = (tr.t[1:] >= sc.t_jump) & (tr.t[1:] < sc.t_jump + 1.0)
        excl = check_innovations(np.where(cut[:, None], np.nan, nu), S, max_lag=MAX_LAG,
                                 whiteness_alpha=WHITENESS_ALPHA).consistent
        track_s = _time_within(tr.t, run.x[:, 3], tr.X[:, 3], 0.05 * sc.m_jump, sc.t_jump)
    return TuningRow(
        q_m=q, scenario=name, run=r, mean_nis=full.mean_nis, nis_ok=full.nis_ok,
        white=full.white, consistent=full.consistent, consistent_excl_jump=excl,
        ljung_box_p_min=float(min(full.ljung_box_p)), max_nis=float(np.nanmax(run.nis)),
        m_error_sd=float((run.x[-1, 3] - tr.X[-1, 3]) / run.sd[-1, 3]),
        jump_tracking_s=track_s)
