"""What one component type runs on the device: the HI map, the tracker settings and the learned
model (docs/device-export.md section 1).

A :class:`DeviceSpec` is read from a fleet database (:func:`spec_from_database`: the stored
:class:`~rulkit.fleet.tracking.health_index.HealthIndexModel`, the
:class:`~rulkit.fleet.tracking.tracker_chain.TrackerConfig` and the learned model of
``rulkit fit``) or from a TOML configuration file (:func:`spec_from_file`: tracker settings
and, optionally, a learned model; the CI -> HI map needs a fitted baseline, so it comes from a
database only). The generator (:mod:`rulkit.fleet.export.generator`) turns a device into C.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from rulkit.fleet.learned.degradation import KINDS, DegradationModel
from rulkit.fleet.learned.hi_noise import NOISES, HiNoiseModel
from rulkit.fleet.tracking.health_index import HealthIndexModel
from rulkit.fleet.tracking.tracker_chain import TrackerConfig
from rulkit.machine_file import Field, MachineFileError, read_machine_file


class ExportError(ValueError):
    """The input cannot be exported to C; the message says which part and why."""


LearnedModel = DegradationModel | HiNoiseModel
"""The learned model types a device can run: a Gaussian posterior of (level, rate) with the RUL
law of docs/fleet-models.md eqs. (5)-(6) (rulkit.fleet.export.learned_device)."""


@dataclass(frozen=True)
class DeviceSpec:
    """One component type as the device runs it.

    ``name``: a label written into the sources; ``source``: where the description came from (the
    database or file path); ``config``: the tracker chain; ``hi_model``: CI -> HI (None: the
    device is given the HI); ``learned``: the learned degradation model (None: tracker only);
    ``one_measurement``: the learned RUL is eq. (5) of one measurement (closed form, no table)
    instead of the server's first measured crossing over the unit's cadence, eq. (5b)
    (docs/rul-on-the-device.md section 2).
    """

    name: str
    source: str
    config: TrackerConfig
    hi_model: HealthIndexModel | None = None
    learned: LearnedModel | None = None
    one_measurement: bool = False


def spec_from_database(path: str | Path, name: str | None = None) -> DeviceSpec:
    """The device stored in the fleet database at ``path`` (read-only; nothing is written)."""
    from rulkit.fleet.store.database_file import StoreError
    from rulkit.fleet.store.sqlite import ComponentStore

    p = Path(path)
    try:
        with ComponentStore(p, readonly=True) as store:
            config, hi_model, learned = store.config, store.hi_model, store.degradation
    except FileNotFoundError as err:
        raise ExportError(f"{p}: no such database") from err
    except StoreError as err:
        raise ExportError(str(err)) from err
    if learned is not None and not isinstance(learned, DegradationModel | HiNoiseModel):
        kinds = (*KINDS, *(f"paris-{n}" for n in NOISES))
        raise ExportError(
            f"{p}: the learned model type {learned.name!r} ({type(learned).__name__}) has no C "
            f"export; the device runs the learned types {', '.join(kinds)} (rulkit fit "
            "--model NAME); refit with one of them, or export the tracker chain alone with "
            "--no-learned")
    return DeviceSpec(name=name or p.stem, source=str(p), config=config, hi_model=hi_model,
                      learned=learned)


_DEFAULT = TrackerConfig()


def _positive(name: str, unit: str, default: float, doc: str) -> Field:
    return Field(name, unit, default, doc, low=0.0, low_open=True)


CONFIG_SCHEMA: dict[str, tuple[Field, ...]] = {
    "component": (
        Field("name", "", "component", doc="label written into the generated sources"),
    ),
    "tracker": (
        _positive("dt", "time unit", _DEFAULT.dt, "nominal acquisition interval"),
        _positive("lambda_hi", "", _DEFAULT.lambda_hi, "tracking index of the HI tracker"),
        _positive("lambda_rul", "", _DEFAULT.lambda_rul, "tracking index of the RUL tracker"),
        _positive("design_life", "time unit", _DEFAULT.design_life, "dHI floor = 1/design_life"),
        Field("hi_floor", "", _DEFAULT.hi_floor, "RUL evaluated at max(fHI, hi_floor)",
              low=0.0, low_open=True),
        Field("hi_sigma", "", _DEFAULT.hi_sigma, "HI standard deviation of the limits",
              low=0.0),
        Field("load_factor", "", _DEFAULT.load_factor, "load +- of the limits", low=0.0,
              high=1.0, high_open=True),
        Field("load_exponent", "", -1.0, "growth rate ~ load^q; -1: the Paris exponent",
              low=-1.0),
        _positive("paris_exponent", "", _DEFAULT.paris_exponent, "Paris exponent m"),
        Field("initiation", "", _DEFAULT.initiation, "track start",
              choices=("floor", "two-point", "measured")),
        Field("rul_clip", "", _DEFAULT.rul_clip, "clip fRUL at 0"),
        Field("valid_drul_low", "", _DEFAULT.valid_drul[0], "validity: dRUL/dt above"),
        Field("valid_drul_high", "", _DEFAULT.valid_drul[1], "validity: dRUL/dt below"),
        Field("valid_d2rul", "1/time unit", _DEFAULT.valid_d2rul, "validity: |d2RUL/dt2| below",
              low=0.0),
        Field("warn_hi", "", _DEFAULT.warn_hi, "warning HI level"),
        Field("warn_rul", "time unit", _DEFAULT.warn_rul, "warning when a valid RUL is below",
              low=0.0),
        Field("alarm_hi", "", _DEFAULT.alarm_hi, "alarm HI level"),
        _positive("hi_max", "", _DEFAULT.hi_max, "largest accepted HI"),
    ),
    "learned": (
        Field("kind", "", "none", "learned model", choices=("none", "linear", "exponential",
                                                             "paris")),
        Field("shape", "", 0.0, "phi (exponential) or lam = 1 - m/2 (paris)"),
        Field("mean_a", "", 0.0, "prior mean of the intercept (transformed HI)"),
        Field("mean_b", "1/scaled time", 0.0, "prior mean of the rate"),
        _positive("cov_aa", "", 1.0, "prior variance of the intercept"),
        Field("cov_ab", "", 0.0, "prior covariance"),
        _positive("cov_bb", "", 1.0, "prior variance of the rate"),
        _positive("noise_sd", "", 0.01, "measurement noise sd (transformed HI)"),
        Field("walk_sd", "", 0.0, "random-walk sd per sqrt(scaled time)", low=0.0),
        _positive("time_scale", "time unit", 1.0, "tau: scaled time x = t / tau"),
        Field("time_unit", "", "", "label of the time unit"),
    ),
}
"""The configuration file of :func:`spec_from_file` (``rulkit.machine_file`` schema)."""


def spec_from_file(path: str | Path) -> DeviceSpec:
    """The device described by the TOML file at ``path`` (:data:`CONFIG_SCHEMA`)."""
    values = read_machine_file(path, CONFIG_SCHEMA)
    tr = dict(values["tracker"])
    tr["valid_drul"] = (tr.pop("valid_drul_low"), tr.pop("valid_drul_high"))
    if tr["load_exponent"] < 0:
        tr["load_exponent"] = None
    try:
        config = TrackerConfig(**tr)
    except ValueError as err:
        raise MachineFileError(f"{path}: [tracker] {err}") from err
    lv = values["learned"]
    learned = None
    if lv["kind"] != "none":
        try:
            learned = DegradationModel(
                kind=lv["kind"], shape=lv["shape"], mean=(lv["mean_a"], lv["mean_b"]),
                cov=(lv["cov_aa"], lv["cov_ab"], lv["cov_bb"]), noise_sd=lv["noise_sd"],
                walk_sd=lv["walk_sd"], time_scale=lv["time_scale"], time_unit=lv["time_unit"])
        except ValueError as err:
            raise MachineFileError(f"{path}: [learned] {err}") from err
    return DeviceSpec(name=values["component"]["name"], source=str(path), config=config,
                      learned=learned)


__all__ = ["CONFIG_SCHEMA", "DeviceSpec", "ExportError", "LearnedModel", "spec_from_database",
           "spec_from_file"]
