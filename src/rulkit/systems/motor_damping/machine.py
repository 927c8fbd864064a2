"""The motor of ``rulkit motor damping`` described as data: a TOML machine file with the motor's
constants, the failure point, the noise levels, the plausible ranges of a pull-up record and the
filter settings (docs/systems/motor-damping.md §8).

Every value has a unit and a range (:data:`MOTOR_SCHEMA`, read by
:func:`rulkit.machine_file.read_machine_file`); a key left out takes its default, and the
defaults are the synthetic motor of docs/systems/motor-damping.md §5 (so no file means the
motor the reproduction simulates). A noise level of 0 means "estimate it from the data".

Example::

    machine = read_motor_machine("my-motor.toml")    # or read_motor_machine(None): defaults
    analyse_pullup(data, machine.constants, **machine.analysis_kwargs())
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from rulkit.machine_file import Field, Machine, Schema
from rulkit.systems.motor_damping.macro import MACRO_MODELS
from rulkit.systems.motor_damping.micro import MicroEKFSettings
from rulkit.systems.motor_damping.motor import MotorConstants
from rulkit.systems.motor_damping.pullup import PullupLimits

__all__ = ["MOTOR_SCHEMA", "MotorMachine", "read_motor_machine"]

_M = MotorConstants()
_MICRO = MicroEKFSettings()

MOTOR_SCHEMA: dict[str, tuple[Field, ...]] = {
    "motor": (
        Field("K", "N m/A", _M.K, low=1e-5, high=10.0, doc="torque constant"),
        Field("J", "kg m^2", _M.J, low=1e-7, high=10.0, doc="rotor and wheel inertia"),
        Field("T_L", "N m", _M.T_L, low=0.0, high=10.0, doc="constant load (friction) torque"),
    ),
    "failure": (
        Field("design_speed", "rad/s", 300.0, low=0.0, low_open=True, high=1e4,
              doc="design point: speed"),
        Field("design_torque", "N m", 16e-3, low=0.0, high=100.0,
              doc="design point: output torque at that speed"),
        Field("c_fail", "N m s", 0.0, low=0.0, high=1.0,
              doc="failure damping; 0: from the design point and the measured steady current "
                  "(MD-12)"),
    ),
    "noise": (
        Field("sigma_w", "rad/s", 0.0, low=0.0, high=100.0,
              doc="speed noise sd; 0: estimated from the data"),
        Field("sigma_dw", "rad/s^2", 0.0, low=0.0, high=1e4,
              doc="acceleration noise sd; 0: estimated from the data"),
    ),
    "limits": (
        Field("max_speed", "rad/s", 1000.0, low=1.0, high=1e5,
              doc="largest plausible absolute speed (1000 rad/s = 9549 rpm: larger looks like "
                  "rpm)"),
        Field("max_current", "A", 20.0, low=1e-3, high=1e4,
              doc="largest plausible absolute current (larger looks like mA)"),
        Field("max_step", "s", 1.0, low=1e-6, high=60.0,
              doc="largest plausible sampling step within a cycle (larger looks like ms)"),
        Field("min_step", "s", 1e-5, low=1e-9, high=1.0,
              doc="smallest plausible sampling step within a cycle"),
        Field("min_samples", "", 20, low=3, high=10**7, doc="fewest samples per cycle"),
    ),
    "micro": (
        Field("scheme", "", _MICRO.scheme, choices=("rk4", "seed-euler"),
              doc="discretisation of the micro EKF (MD-3..MD-5 for seed-euler)"),
        Field("c_prior", "N m s", _MICRO.c_prior, low=0.0, high=1.0,
              doc="prior mean of each cycle's damping"),
        Field("c_prior_sd", "N m s", _MICRO.c_prior_sd, low=0.0, low_open=True, high=1.0,
              doc="prior sd of each cycle's damping"),
        Field("q_w", "(rad/s)^2", _MICRO.q_w, low=0.0, high=1e4,
              doc="process variance of the speed per sample"),
        Field("q_c", "(N m s)^2", _MICRO.q_c, low=0.0, high=1.0,
              doc="random-walk variance of the damping per sample"),
        Field("gate", "", 100.0, low=0.0, high=1e12,
              doc="NIS above which a sample is not used for the damping (100: a 10-sigma "
                  "innovation; 0: off)"),
    ),
    "macro": (
        Field("model", "", "linear", choices=MACRO_MODELS,
              doc="trend law: linear (MD-6) or quadratic"),
        Field("q_a", "(N m s)^2/cycle^3", 0.0, low=0.0, high=1.0,
              doc="random-walk density of the highest trend state (0: a deterministic law)"),
    ),
    "rul": (
        Field("mc_samples", "", 2000, low=1, high=10**7, doc="Monte Carlo RUL samples"),
        Field("horizon", "cycles", 1000.0, low=1.0, high=1e7,
              doc="prediction horizon (RUL censored beyond it)"),
    ),
}


@dataclass(frozen=True)
class MotorMachine(Machine):
    """A motor machine file, read and checked against :data:`MOTOR_SCHEMA` (``values`` and
    ``source`` as in :class:`rulkit.machine_file.Machine`)."""

    schema: ClassVar[Schema] = MOTOR_SCHEMA

    @property
    def constants(self) -> MotorConstants:
        """The motor constants K, J, T_L (the pull-up current shape is measured, not given)."""
        m = self.values["motor"]
        return MotorConstants(K=m["K"], J=m["J"], T_L=m["T_L"])

    @property
    def limits(self) -> PullupLimits:
        """The plausible ranges of a record."""
        return PullupLimits(**self.values["limits"])

    @property
    def micro(self) -> MicroEKFSettings:
        """The micro EKF settings (noise sds are set per record by the analysis)."""
        return MicroEKFSettings(**self.values["micro"])

    def analysis_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :func:`rulkit.systems.motor_damping.analysis.analyse_pullup`
        (a 0 noise level or failure damping becomes ``None``: estimated / from the design
        point)."""
        f, n = self.values["failure"], self.values["noise"]
        return {
            "design_speed": f["design_speed"], "design_torque": f["design_torque"],
            "c_fail": f["c_fail"] or None, "sigma_w": n["sigma_w"] or None,
            "sigma_dw": n["sigma_dw"] or None, "q_a": self.values["macro"]["q_a"],
            "macro_model": self.values["macro"]["model"],
            "mc_samples": self.values["rul"]["mc_samples"],
            "horizon": self.values["rul"]["horizon"], "micro": self.micro,
        }


def read_motor_machine(path: str | Path | None = None) -> MotorMachine:
    """The motor machine file at ``path`` checked against :data:`MOTOR_SCHEMA`, the defaults
    filled in (``None``: the defaults alone). Raises
    :class:`rulkit.machine_file.MachineFileError` naming the file, section and key."""
    return MotorMachine.read(path)
