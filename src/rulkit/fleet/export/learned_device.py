"""The learned degradation models the device can run (docs/rul-on-the-device.md section 2).

What a learned model needs on the device is two things: its **per-unit state update** (one
acquisition in, the unit's posterior out) and its **RUL quantiles** (the median and the 90 %
interval from that posterior). A model type becomes exportable by one entry in
:data:`EXPORTERS`: a function from the fitted model to a :class:`LearnedDevice`, which names

* the C template (in ``templates/``) that implements, with the constants of the entry,
  ``learned_init`` (the prior), ``learned_update`` (the state update, in place) and
  ``learned_quantiles`` (the RUL median, 5 % and 95 % quantiles);
* the state fields it adds to the component's state struct (saved with it);
* the constants, as Python floats (the generator writes them as C literals).

The three models of :mod:`rulkit.fleet.learned.degradation` (linear, exponential, paris) share
one template: a Gaussian random-effects model of a transformed HI, updated by an exact Kalman
step (docs/fleet-models.md eq. (2)) with closed-form quantiles (eqs. (5), (6)); they differ in
the transform g only. Any other model type is refused by :func:`learned_device` with its name.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from rulkit.fleet.export.device_spec import ExportError
from rulkit.fleet.learned.degradation import HI_MIN, DegradationModel
from rulkit.fleet.store.learned_state import LEVELS


@dataclass(frozen=True)
class LearnedDevice:
    """A learned model as the C template needs it (module docstring)."""

    kind: str
    template: str
    state_fields: tuple[tuple[str, str], ...]
    constants: dict[str, Any]


_KNOWN_FIELDS = {"kind", "shape", "mean", "cov", "noise_sd", "walk_sd", "time_scale",
                 "time_unit", "n_units", "n_failed", "log_likelihood", "warnings",
                 "diagnostics"}
"""Fields the template implements or that do not change the numbers (the fit's warnings and
optimiser report); ``time_axis`` is accepted when the time column is the age itself."""


def _check_known_fields(model: DegradationModel) -> None:
    """Refuse a model with a setting the template does not implement (a field added to the
    model class after this exporter, set to other than its default), instead of writing C
    that silently ignores it."""
    for f in dataclasses.fields(model):
        if f.name in _KNOWN_FIELDS:
            continue
        axis = model.time_axis or {}
        if f.name == "time_axis" and axis.get("origin", "time") == "time" and not axis.get(
                "timestamps", False):
            continue
        default = f.default if f.default is not dataclasses.MISSING else None
        if getattr(model, f.name) != default:
            raise ExportError(
                f"learned {model.kind} model: its setting {f.name} = "
                f"{getattr(model, f.name)!r} has no C export yet (rulkit.fleet.export."
                "learned_device); export the tracker chain alone with --no-learned")


def _random_effects(model: DegradationModel) -> LearnedDevice:
    """linear / exponential / paris: the Kalman posterior of (level, rate) (eq. (2))."""
    _check_known_fields(model)
    return LearnedDevice(
        kind=model.kind,
        template="learned_random_effects.c.j2",
        state_fields=(("m_z", "posterior mean of the transformed level"),
                      ("m_b", "posterior mean of the rate (per scaled time)"),
                      ("p_zz", "posterior covariance: level"),
                      ("p_zb", "posterior covariance: level, rate"),
                      ("p_bb", "posterior covariance: rate")),
        constants={
            "shape": float(model.shape),
            "log_form": model.kind == "paris" and abs(model.shape) < 1e-12,
            "hi_min": HI_MIN,
            "tau": float(model.time_scale),
            "threshold": float(model.threshold),
            "q": float(model.walk_sd) ** 2,
            "r": float(model.noise_sd) ** 2,
            "prior": [*map(float, model.mean), *map(float, model.cov)],
            "log1m_levels": [math.log1p(-p) for p in LEVELS],
        },
    )


EXPORTERS: dict[str, Callable[[DegradationModel], LearnedDevice]] = {
    "linear": _random_effects,
    "exponential": _random_effects,
    "paris": _random_effects,
}
"""Learned model kind -> its device description. Add an entry to make a new kind exportable."""


def learned_device(model: DegradationModel) -> LearnedDevice:
    """The device description of ``model``; :class:`ExportError` for a kind without one."""
    kind = str(getattr(model, "kind", type(model).__name__))
    if kind not in EXPORTERS:
        raise ExportError(
            f"learned model type {kind!r} has no C export (exportable: "
            f"{', '.join(sorted(EXPORTERS))}); export the tracker chain alone with "
            "--no-learned, or add the type to rulkit.fleet.export.learned_device.EXPORTERS")
    return EXPORTERS[kind](model)


__all__ = ["EXPORTERS", "LearnedDevice", "learned_device"]
