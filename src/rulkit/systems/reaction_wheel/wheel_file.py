"""The wheel file: a reaction wheel described as data (docs/systems/reaction-wheel.md §7).

A TOML file with the wheel's constants (section 1.1 of the model page), its measurement noise,
the plausibility limits of its telemetry, and the settings of the three steps (the step-1
filter design, the step-2 trackers, the step-3 forecast). Every key has a unit, a range and a
default; the defaults are the seed's wheel and rulkit's resolutions, so a file names only what
differs. Read with :func:`read_wheel_file` (checked by :mod:`rulkit.machine_file`: an unknown
section or key, a boolean, a string where a number is expected, a value out of its range is
refused naming the file, section, key and unit), or start from :func:`wheel_file_template`
(``rulkit rw wheel-template``). Every ``rulkit rw`` command takes ``--wheel FILE``.

Example (a heavier wheel with its own friction law and noisier current sensor)::

    [wheel]
    J = 0.0106
    friction_law = "linear"
    viscous_at_0C = 5.1e-5
    viscous_per_C = -2.4e-7

    [noise]
    sigma_I = 0.13
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rulkit.machine_file import Field, MachineFileError, machine_values, read_machine_file
from rulkit.systems.reaction_wheel.degradation.trackers import DegradationConfig
from rulkit.systems.reaction_wheel.telemetry import TelemetryLimits
from rulkit.systems.reaction_wheel.temperature.ekf import PLAIN_EKF, EKFConfig, q_ladder
from rulkit.systems.reaction_wheel.wheel import FRICTION_LAWS, IthacoParams

_P = IthacoParams()
_E = EKFConfig()
_D = DegradationConfig()

def _positive(name: str, unit: str, default: float, doc: str, *, high: float) -> Field:
    """A field that must be > 0 (and <= ``high``)."""
    return Field(name, unit, default, doc, low=0.0, high=high, low_open=True)


#: The schema of a wheel file: sections of :class:`rulkit.machine_file.Field`.
WHEEL_SCHEMA: dict[str, tuple[Field, ...]] = {
    "wheel": (
        _positive("G_d", "A/V", _P.G_d, "driver gain", high=100.0),
        _positive("w_d", "rad/s", _P.w_d, "driver bandwidth", high=1e4),
        _positive("K_t", "N m/A", _P.K_t, "torque constant", high=10.0),
        _positive("K_e", "V s/rad", _P.K_e, "back-EMF constant", high=10.0),
        Field("K_s", "V s/rad", _P.K_s, "speed-limiter gain", low=0.0, high=1e4),
        _positive("w_s", "rad/s", _P.w_s, "speed-limiter threshold", high=1e5),
        Field("tau_c", "N m", _P.tau_c, "Coulomb friction", low=0.0, high=10.0),
        _positive("J", "kg m^2", _P.J, "flywheel inertia", high=100.0),
        Field("R_in", "ohm", _P.R_in, "input resistance", low=0.0, high=1e3),
        Field("K_f", "V/V", _P.K_f, "voltage feedback gain", low=0.0, high=100.0),
        Field("theta_a", "rad", _P.theta_a, "torque-disturbance angle", low=0.0, high=10.0),
        Field("w_a", "rad/s", _P.w_a, "torque-disturbance frequency", low=0.0, high=1e3),
        _positive("V_bus", "V", _P.V_bus, "bus voltage", high=1e3),
        Field("R_B", "ohm", _P.R_B, "bus resistance", low=0.0, high=1e3),
        Field("P_q", "W", _P.P_q, "quiescent power", low=0.0, high=1e4),
        Field("friction_law", "", _P.friction_law, "viscous friction b_v(T): the seed's "
              "resolved law (RW-7), the law as printed, or linear with the two keys below",
              choices=FRICTION_LAWS),
        _positive("viscous_at_0C", "N m s/rad", _P.viscous_at_0C, "b_v at 0 C (linear law)",
                  high=1.0),
        Field("viscous_per_C", "N m s/rad/C", _P.viscous_per_C, "d b_v / dT (linear law)",
              low=-1.0, high=1.0),
    ),
    "noise": (
        _positive("sigma_w", "rad/s", 3e-3, "speed measurement noise (sd)", high=100.0),
        _positive("sigma_I", "A", 3e-2, "current measurement noise (sd)", high=10.0),
    ),
    "telemetry": (
        _positive("max_speed_rad_s", "rad/s", 1000.0, "largest plausible |speed|", high=1e6),
        _positive("max_current_A", "A", 5.0, "largest plausible |current|", high=1e4),
        _positive("max_voltage_V", "V", 5.0, "largest plausible |command|", high=1e4),
    ),
    "temperature": (
        Field("method", "", "imm", "step-1 estimator", choices=(
            "imm", "ekf", "rbpf", "pf", "adaptive", "apf", "apf_eq28", "apf_tempered")),
        Field("particles", "", 350, "particles (particle-filter methods)", low=2, high=1e6),
        Field("design", "", "F2", "prediction design of the seed particle filters",
              choices=("F1", "F2")),
        Field("T_prior_low", "C", _E.T_prior[0], "uniform prior of T, low end", low=-100.0,
              high=300.0),
        Field("T_prior_high", "C", _E.T_prior[1], "uniform prior of T, high end",
              low=-100.0, high=300.0),
        _positive("q_T_low", "C/sample", _E.q_T[0], "smallest random-walk step of the IMM's "
              "models (geometric ladder up to q_T_high)", high=10.0),
        _positive("q_T_high", "C/sample", _E.q_T[-1], "largest random-walk step", high=10.0),
        Field("models", "", len(_E.q_T), "interacting models (1: a plain EKF at q_T_low)",
              low=1, high=12),
        Field("p_stay", "", _E.p_stay, "probability a model stays over a step", low=0.5,
              high=1.0, high_open=True),
        _positive("gate", "sigma", _E.gate, "outlier gate per channel", high=1e3),
        Field("reanchor_after", "samples", _E.reanchor_after, "refused speed samples in a "
              "row before [I, w] restart at the measurement (0: never)", low=0, high=10**6),
        _positive("reanchor_gap_s", "s", _E.reanchor_gap_s, "a gap after which [I, w] restart",
                  high=1e7),
        Field("stuck_samples", "samples", _E.stuck_samples, "equal values in a row that make "
              "a sensor stuck (0: off)", low=0, high=10**6),
        Field("spike_V", "V", _E.spike_V, "one-sample command spike size (0: off)", low=0.0,
              high=100.0),
        _positive("interval_scale", "", _E.interval_scale, "scale of the IMM interval's sd "
              "(calibrated on the benchmark battery)", high=100.0),
    ),
    "degradation": (
        Field("particles", "", _D.n_particles, "particles of the step-2 trackers", low=10,
              high=10**6),
        Field("q_b", "C/window", _D.q_b, "random-walk step of b per window", low=0.0,
              high=100.0),
        Field("q_beta0_rel", "1/window", _D.q_beta0_rel, "random-walk step of beta0 per "
              "window, relative", low=0.0, high=1.0),
        Field("b_prior_low", "C", _D.b_prior[0], "uniform prior of b, low end", low=0.0,
              high=1e4),
        Field("b_prior_high", "C", _D.b_prior[1], "uniform prior of b, high end", low=0.0,
              high=1e4),
        _positive("beta0_prior_low_rel", "", _D.beta0_prior_rel[0], "prior of beta0, low end, x "
              "the scale fitted to the first windows", high=100.0),
        _positive("beta0_prior_high_rel", "", _D.beta0_prior_rel[1], "prior of beta0, high end",
                  high=100.0),
        Field("loss_sd_mL", "mL", 0.0, "noise (sd) of one loss measurement (0: estimated from "
              "the record)", low=0.0, high=1e6),
        Field("n_nodes", "", _D.n_nodes, "Gauss nodes per window", low=1, high=12),
    ),
    "rul": (
        _positive("forecast_window_h", "h", 6.0, "forecast step", high=24.0 * 365),
        _positive("horizon_days", "days", 365.0, "longest forecast", high=1e5),
        Field("level", "", 0.9, "RUL interval level", low=0.0, high=1.0, low_open=True,
              high_open=True),
    ),
}


@dataclass(frozen=True)
class WheelFile:
    """A wheel read from a wheel file: the model's ``params``, the noise ``sigma`` = (sigma_w,
    sigma_I), the telemetry ``limits``, the step-1 ``method``/``particles``/``design`` and the
    EKF settings ``ekf``, the step-2 ``degradation`` settings with ``loss_sd_mL`` (0:
    estimated), the step-3 ``rul`` values, and ``source`` (the path, or "the seed's wheel")."""

    params: IthacoParams = field(default_factory=IthacoParams)
    sigma: tuple[float, float] = (3e-3, 3e-2)
    limits: TelemetryLimits = field(default_factory=TelemetryLimits)
    method: str = "imm"
    particles: int = 350
    design: str = "F2"
    ekf: EKFConfig = field(default_factory=EKFConfig)
    degradation: DegradationConfig = field(default_factory=DegradationConfig)
    loss_sd_mL: float = 0.0
    rul: dict[str, float] = field(default_factory=lambda: {
        "forecast_window_h": 6.0, "horizon_days": 365.0, "level": 0.9})
    source: str = "the seed's wheel (defaults)"
    values: dict[str, dict[str, Any]] = field(default_factory=dict, repr=False)


def step1_config(wheel: WheelFile, method: str | None = None) -> Any:
    """The settings object of the step-1 ``method`` (default the file's) for
    :class:`rulkit.systems.reaction_wheel.temperature.estimator.TemperatureEstimator`: the
    file's IMM for "imm"; for "ekf" the plain EKF (q_T 0.02 C per sample, its own interval)
    with the file's handling of defects; ``None`` (the method's defaults with the file's
    particles and design) for the particle filters."""
    from dataclasses import replace

    m = method or wheel.method
    if m == "imm":
        return wheel.ekf
    if m == "ekf":
        return replace(wheel.ekf, q_T=PLAIN_EKF.q_T, interval_scale=PLAIN_EKF.interval_scale)
    return None


def read_wheel_file(path: str | Path | None) -> WheelFile:
    """The wheel of the file ``path`` (``None``: the seed's wheel), every value checked; raises
    :class:`rulkit.machine_file.MachineFileError` naming the file, section and key."""
    if path is None:
        return wheel_from_values(machine_values({}, WHEEL_SCHEMA, "defaults"), "the seed's wheel")
    return wheel_from_values(read_machine_file(path, WHEEL_SCHEMA), str(path))


def wheel_from_values(v: dict[str, dict[str, Any]], source: str) -> WheelFile:
    """A :class:`WheelFile` from checked values (:func:`rulkit.machine_file.machine_values`),
    with the checks that involve several keys."""
    t, d = v["temperature"], v["degradation"]
    _require(t["T_prior_low"] < t["T_prior_high"], source, "temperature",
             "T_prior_low must be below T_prior_high")
    _require(t["q_T_low"] <= t["q_T_high"], source, "temperature",
             "q_T_low must not exceed q_T_high")
    _require(d["b_prior_low"] < d["b_prior_high"], source, "degradation",
             "b_prior_low must be below b_prior_high")
    _require(d["beta0_prior_low_rel"] < d["beta0_prior_high_rel"], source, "degradation",
             "beta0_prior_low_rel must be below beta0_prior_high_rel")
    params = IthacoParams(**v["wheel"])
    _check_friction(params, (t["T_prior_low"], t["T_prior_high"]), source)
    try:
        ekf = EKFConfig(q_T=q_ladder(t["q_T_low"], t["q_T_high"], t["models"]),
                        p_stay=t["p_stay"], T_prior=(t["T_prior_low"], t["T_prior_high"]),
                        gate=t["gate"], reanchor_after=t["reanchor_after"],
                        reanchor_gap_s=t["reanchor_gap_s"], stuck_samples=t["stuck_samples"],
                        spike_V=t["spike_V"], interval_scale=t["interval_scale"])
    except ValueError as err:
        raise MachineFileError(f"{source}: [temperature] {err}") from None
    deg = DegradationConfig(
        n_particles=d["particles"], q_b=d["q_b"], q_beta0_rel=d["q_beta0_rel"],
        b_prior=(d["b_prior_low"], d["b_prior_high"]),
        beta0_prior_rel=(d["beta0_prior_low_rel"], d["beta0_prior_high_rel"]),
        n_nodes=d["n_nodes"])
    tel = v["telemetry"]
    return WheelFile(
        params=params, sigma=(v["noise"]["sigma_w"], v["noise"]["sigma_I"]),
        limits=TelemetryLimits(tel["max_speed_rad_s"], tel["max_current_A"],
                               tel["max_voltage_V"]),
        method=t["method"], particles=t["particles"], design=t["design"], ekf=ekf,
        degradation=deg, loss_sd_mL=d["loss_sd_mL"], rul=dict(v["rul"]), source=source,
        values=v)


def _require(ok: bool, source: str, section: str, what: str) -> None:
    if not ok:
        raise MachineFileError(f"{source}: [{section}] {what}")


def _check_friction(p: IthacoParams, prior: tuple[float, float], source: str) -> None:
    """The viscous coefficient must stay positive over the temperature prior: a negative one
    feeds energy into the rotor and the model runs away (docs/systems/reaction-wheel.md
    §1.2)."""
    from rulkit.systems.reaction_wheel.wheel import viscous_coefficient

    for T in prior:
        b = float(viscous_coefficient(T, p.friction_law, p))
        if not (b > 0 and math.isfinite(b)):
            raise MachineFileError(
                f"{source}: [wheel] friction_law = {p.friction_law!r} gives a viscous "
                f"coefficient b_v({T:g} C) = {b:.4g} N m s/rad, not positive: friction would "
                "drive the rotor and the model runs away; choose a law positive over "
                "[temperature] T_prior_low..T_prior_high")


def wheel_file_template() -> str:
    """The defaults as a commented TOML file (the seed's wheel), every key with its unit, range
    and meaning."""
    from rulkit.machine_file import machine_file_template

    return machine_file_template(WHEEL_SCHEMA, "rulkit wheel file: the seed's Ithaco type-A "
                                 "wheel (docs/systems/reaction-wheel.md §7); keep only what "
                                 "differs")
