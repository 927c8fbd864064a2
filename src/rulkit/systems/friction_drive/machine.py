"""The friction drive of ``rulkit drive`` described as data: a TOML machine file with the drive's
constants, the failure level, the speed sensors, the plausible ranges of a record, the
augmented EKF's tuning and the RUL settings (docs/systems/friction-drive.md §9).

Every value has a unit and a range (:data:`DRIVE_SCHEMA`, read by
:func:`rulkit.machine_file.read_machine_file`); a key left out takes its default. The defaults
are the seed's drive (Table 1, alpha0 = 10, D_f = 0.99), its speed noise (sigma = 1e-4 and 1e-5
rad/s), its initial covariance, and the filter tuning that is consistent on the seed's jump
scenario (docs/systems/friction-drive.md §4).

Units: ``alpha`` (the contact quality, F_c = alpha * slip) is in N s/m; ``m`` (the wear rate of
(FD-3), dalpha/dt = -m (slip)^2 alpha) in s/m^2; process-noise rates are variances per second.

Example::

    machine = read_drive_machine("my-drive.toml")    # or read_drive_machine(None): defaults
    machine.params                                     # FrictionDriveParams
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from rulkit.machine_file import Field, Machine, Schema
from rulkit.model import FloatArray
from rulkit.systems.friction_drive.drive import (
    DEFAULT_PARAMS,
    SEED_R,
    SEED_SIGMA_M2,
    SPEED_Q_RATE,
    FrictionDriveParams,
)

__all__ = ["DRIVE_Q_RATE", "DRIVE_SCHEMA", "DriveMachine", "read_drive_machine"]

_P = DEFAULT_PARAMS
_SEED_SD = math.sqrt(SEED_SIGMA_M2)  # seed 5.2: P0 = sigma_m^2 I, sigma_m^2 = 0.02^2 / 12
DRIVE_Q_RATE = 3e-8
"""Default process-noise rate on m (per second) of ``rulkit drive``: with the midpoint Jacobian
and the speed noise of the reproduction's ``tuned-consistent`` filter, the rate that does best
where m is constant and where it drifts slowly (docs/systems/friction-drive.md §4, the tuning
table of the reproduction); no random-walk rate is consistent through an abrupt jump of m."""

DRIVE_SCHEMA: dict[str, tuple[Field, ...]] = {
    "drive": (
        Field("r1", "m", _P.r1, low=1e-4, high=10.0, doc="roller (motor side) radius"),
        Field("r2", "m", _P.r2, low=1e-4, high=10.0, doc="wheel radius"),
        Field("B1", "N m s", _P.B1, low=1e-8, high=100.0, doc="motor viscous friction"),
        Field("B2", "N m s", _P.B2, low=1e-8, high=100.0, doc="wheel viscous friction"),
        Field("J1", "kg m^2", _P.J1, low=1e-8, high=100.0, doc="motor and roller inertia"),
        Field("J2", "kg m^2", _P.J2, low=1e-8, high=1e4, doc="wheel inertia"),
        Field("Km", "N m/A", _P.Km, low=1e-5, high=100.0, doc="motor torque constant"),
        Field("alpha0", "N s/m", _P.alpha0, low=0.0, low_open=True, high=1e6,
              doc="contact quality when new (D = 1 - alpha/alpha0)"),
    ),
    "failure": (
        Field("level", "", _P.failure_level, low=0.0, high=1.0, low_open=True, high_open=True,
              doc="deterioration D_f declared a failure (FD-5)"),
    ),
    "sensors": (
        Field("sigma_w1", "rad/s", float(np.sqrt(SEED_R[0, 0])), low=0.0, low_open=True,
              high=100.0, doc="motor speed noise sd"),
        Field("sigma_w2", "rad/s", float(np.sqrt(SEED_R[1, 1])), low=0.0, low_open=True,
              high=100.0, doc="wheel speed noise sd"),
    ),
    "limits": (
        Field("max_current", "A", 100.0, low=1e-3, high=1e5,
              doc="largest plausible absolute current (larger looks like mA)"),
        Field("min_step", "s", 1e-5, low=1e-9, high=1.0,
              doc="smallest plausible sampling step"),
        Field("max_step", "s", 0.01, low=1e-6, high=1.0,
              doc="largest plausible sampling step (larger looks like ms; the filter needs "
                  "steps of a few ms)"),
        Field("max_gap_steps", "", 1000, low=1, high=10**7,
              doc="longest time gap bridged by prediction, in sampling steps"),
        Field("max_gated_fraction", "", 0.05, low=0.0, high=1.0,
              doc="largest fraction of samples outside the gate before the record is refused "
                  "as not described by this machine"),
    ),
    "filter": (
        Field("q_m", "(s/m^2)^2/s", DRIVE_Q_RATE, low=0.0, high=1.0,
              doc="process-noise rate on m (FD-7)"),
        Field("q_w1", "(rad/s)^2/s", SPEED_Q_RATE[0], low=0.0, high=1e6,
              doc="process-noise rate on the motor speed"),
        Field("q_w2", "(rad/s)^2/s", SPEED_Q_RATE[1], low=0.0, high=1e6,
              doc="process-noise rate on the wheel speed"),
        Field("q_alpha", "(N s/m)^2/s", 0.0, low=0.0, high=1e6,
              doc="process-noise rate on alpha"),
        Field("jacobian_at", "", "midpoint", choices=("midpoint", "start"),
              doc="where F of Phi = expm(F t_s) is taken (start: seed eq. 17-19)"),
        Field("f44", "1/s", 0.0, low=-1e4, high=0.0,
              doc="Jacobian-only (4,4) entry (seed 5.2 uses -100; 0: the model as written)"),
        Field("max_substep", "s", 1e-3, low=1e-6, high=0.01,
              doc="longest RK4 sub-step of the mean prediction"),
        Field("alpha_init", "N s/m", _P.alpha0, low=0.0, high=1e6,
              doc="prior mean of alpha at the first sample"),
        Field("alpha_sd", "N s/m", _SEED_SD, low=0.0, low_open=True, high=1e6,
              doc="prior sd of alpha"),
        Field("m_init", "s/m^2", 0.01, low=0.0, high=1e3, doc="prior mean of m"),
        Field("m_sd", "s/m^2", _SEED_SD, low=0.0, low_open=True, high=1e3,
              doc="prior sd of m"),
        Field("gate", "", 1e4, low=0.0, high=1e12,
              doc="NIS above which a sample is not trusted (1e4: a 100-sigma innovation; an "
                  "abrupt change of m gives a few hundred; 0: off)"),
    ),
    "rul": (
        Field("current", "A", 20.0, low=0.0, low_open=True, high=1e5,
              doc="future current, held constant (seed section 6)"),
        Field("samples", "", 100, low=2, high=10**6, doc="Monte Carlo trajectories"),
        Field("bound_sds", "", 3.0, low=0.0, low_open=True, high=10.0,
              doc="c of the optimistic/pessimistic trajectories (alpha +- c sd, m -+ c sd)"),
        Field("horizon_h", "h", 2000.0, low=1e-3, high=1e7,
              doc="prediction horizon (RUL censored beyond it)"),
        Field("transient", "s", 10.0, low=0.0, high=1e4,
              doc="spin-up integrated with the full model before the closed form (FD-11)"),
        Field("lsoda_checks", "", 3, low=0, high=1000,
              doc="trajectories re-run with LSODA over the whole horizon (a cross-check)"),
    ),
}


@dataclass(frozen=True)
class DriveMachine(Machine):
    """A drive machine file, read and checked against :data:`DRIVE_SCHEMA` (``values`` and
    ``source`` as in :class:`rulkit.machine_file.Machine`)."""

    schema: ClassVar[Schema] = DRIVE_SCHEMA

    @property
    def params(self) -> FrictionDriveParams:
        """The drive's constants and failure level."""
        return FrictionDriveParams(**self.values["drive"],
                                   failure_level=self.values["failure"]["level"])

    @property
    def R(self) -> FloatArray:
        """Speed-measurement covariance diag(sigma_w1^2, sigma_w2^2), (2, 2)."""
        s = self.values["sensors"]
        return np.diag([s["sigma_w1"] ** 2, s["sigma_w2"] ** 2])

    @property
    def q_rates(self) -> FloatArray:
        """Process-noise rates (per second) on (w1, w2, alpha, m), (4,)."""
        f = self.values["filter"]
        return np.array([f["q_w1"], f["q_w2"], f["q_alpha"], f["q_m"]])

    def prior(self, w1: float, w2: float) -> tuple[FloatArray, FloatArray]:
        """Mean (4,) and covariance (4, 4) at the first sample: the measured speeds with the
        sensors' variances, alpha and m from ``[filter]``."""
        f = self.values["filter"]
        x0 = np.array([w1, w2, f["alpha_init"], f["m_init"]])
        P0 = np.diag([*np.diag(self.R), f["alpha_sd"] ** 2, f["m_sd"] ** 2])
        return x0, P0


def read_drive_machine(path: str | Path | None = None) -> DriveMachine:
    """The drive machine file at ``path`` checked against :data:`DRIVE_SCHEMA`, the defaults
    filled in (``None``: the defaults alone). Raises
    :class:`rulkit.machine_file.MachineFileError` naming the file, section and key."""
    return DriveMachine.read(path)
