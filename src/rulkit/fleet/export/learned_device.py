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
step (docs/fleet-models.md eq. (2)); they differ in the transform g only. The RUL is the
server's: the first measured crossing over the unit's cadence (eq. (5b)), with the table of
mu*, sigma* (:func:`rulkit.fleet.learned.first_passage.ystar_table`) written into the C
(:func:`first_passage_constants`); or, with ``DeviceSpec.one_measurement``, the closed-form
quantiles (eqs. (5), (6)) of one measurement. The models measuring the HI itself
(paris-additive, paris-multiplicative, paris-mixed, :mod:`rulkit.fleet.learned.hi_noise`) keep
that posterior and its RUL law (their own template shares the prior and the quantiles) and
update it by the iterated extended Kalman step of eq. (8). Any other model type (onset,
similarity, regression) is refused by :func:`learned_device` with its name.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from rulkit.fleet.export.device_spec import ExportError, LearnedModel
from rulkit.fleet.learned.degradation import HI_MIN, DegradationModel
from rulkit.fleet.learned.growth_filter import HI_HI, HI_LO, IEKF_ITERATIONS, IEKF_TOL
from rulkit.fleet.learned.hi_noise import HiNoiseModel
from rulkit.fleet.store.learned_state import LEVELS


@dataclass(frozen=True)
class LearnedDevice:
    """A learned model as the C template needs it (module docstring)."""

    kind: str
    template: str
    state_fields: tuple[tuple[str, str], ...]
    constants: dict[str, Any]


_SUMMARY_FIELDS = {"time_scale", "time_unit", "n_units", "n_failed", "log_likelihood",
                   "warnings", "diagnostics"}
"""Fields every exported model shares that the templates read (the time scale) or that do not
change the numbers (labels, the fit's counts, warnings and optimiser report)."""
_KNOWN_FIELDS = {
    DegradationModel: {"kind", "shape", "mean", "cov", "noise_sd", "walk_sd", *_SUMMARY_FIELDS},
    HiNoiseModel: {"noise", "shape", "mean", "cov", "hi_noise_sd", "log_noise_sd", "walk_sd",
                   *_SUMMARY_FIELDS},
}
"""Per model class, the fields its template implements or that do not change the numbers;
``time_axis`` is accepted when the time column is the age itself."""


def _check_known_fields(model: LearnedModel) -> None:
    """Refuse a model with a setting the template does not implement (a field added to the
    model class after this exporter, set to other than its default), instead of writing C
    that silently ignores it."""
    known = next(v for k, v in _KNOWN_FIELDS.items() if isinstance(model, k))
    for f in dataclasses.fields(model):
        if f.name in known:
            continue
        axis = model.time_axis or {}
        if f.name == "time_axis" and axis.get("origin", "time") == "time" and not axis.get(
                "timestamps", False):
            continue
        default = f.default if f.default is not dataclasses.MISSING else None
        if getattr(model, f.name) != default:
            raise ExportError(
                f"learned {model.name} model: its setting {f.name} = "
                f"{getattr(model, f.name)!r} has no C export yet (rulkit.fleet.export."
                "learned_device); export the tracker chain alone with --no-learned")


def _gaussian_posterior(model: LearnedModel) -> dict[str, Any]:
    """The constants of the shared prior and RUL law (learned_gaussian_prior.c.j2,
    learned_gaussian_rul.c.j2): eqs. (5)-(6) from the Gaussian posterior of (level, rate)."""
    return {
        "tau": float(model.time_scale),
        "threshold": float(model.threshold),
        "q": float(model.walk_sd) ** 2,
        "prior": [*map(float, model.mean), *map(float, model.cov)],
        "levels": [float(p) for p in LEVELS],
        "log1m_levels": [math.log1p(-p) for p in LEVELS],
    }


FP_ITERATIONS = 200
"""The cap of the C's bracketing search per quantile (``rul_quantiles``' default); the search
stops long before it (the C's first_passage_root)."""


def first_passage_constants(model: LearnedModel) -> dict[str, Any]:
    """The constants of eq. (5b) in C (learned_first_passage.c.j2): the measurement sd s at the
    threshold, the table of mu*(c, n, theta) and sigma*(c, n, theta) row-major over
    (log c, log n, theta) with its grid (the same numbers
    :func:`~rulkit.fleet.learned.filter_kernels.first_passage_quantiles` reads) and the
    search's cap."""
    from rulkit.fleet.learned.first_passage import kernel_table

    mu, sd, lc0, dlc, dlj, dth = kernel_table()
    return {
        "first_passage": True,
        "s": math.sqrt(float(model.measured_var)),
        "n_c": int(mu.shape[0]), "n_j": int(mu.shape[1]), "n_t": int(mu.shape[2]),
        "dtheta": dth,
        "ystar_mu": [float(x) for x in mu.ravel()],
        "ystar_sd": [float(x) for x in sd.ravel()],
        "log_c0": lc0, "dlog_c": dlc, "dlog_j": dlj,
        "fp_iterations": FP_ITERATIONS,
    }


_STATE_FIELDS = (("m_z", "posterior mean of the transformed level"),
                 ("m_b", "posterior mean of the rate (per scaled time)"),
                 ("p_zz", "posterior covariance: level"),
                 ("p_zb", "posterior covariance: level, rate"),
                 ("p_bb", "posterior covariance: rate"))


def _random_effects(model: DegradationModel) -> LearnedDevice:
    """linear / exponential / paris: the Kalman posterior of (level, rate) (eq. (2))."""
    if not isinstance(model, DegradationModel):
        raise ExportError(f"learned {model.name} model: expected a DegradationModel")
    _check_known_fields(model)
    return LearnedDevice(
        kind=model.kind,
        template="learned_random_effects.c.j2",
        state_fields=_STATE_FIELDS,
        constants={
            **_gaussian_posterior(model),
            "shape": float(model.shape),
            "log_form": model.kind == "paris" and abs(model.shape) < 1e-12,
            "hi_min": HI_MIN,
            "r": float(model.noise_sd) ** 2,
            "measured_var": float(model.measured_var),
        },
    )


def _hi_noise(model: HiNoiseModel) -> LearnedDevice:
    """paris-additive / -multiplicative / -mixed (and -iid, without the walk): the same
    posterior of (level, rate) on the Box-Cox scale, updated from the HI itself by the
    iterated extended Kalman step of eq. (8) (:func:`rulkit.fleet.learned.filter_kernels.
    assimilate`, operation by operation); the RUL of the first measurement >= 1 (the
    measurement variance at hi = 1 added to the level's)."""
    if not isinstance(model, HiNoiseModel):
        raise ExportError(f"learned {model.name} model: expected a HiNoiseModel")
    _check_known_fields(model)
    lam = float(model.shape)
    log_form = abs(lam) < 1e-12
    from rulkit.fleet.learned.filter_kernels import boxcox  # the filter's own clip bounds

    z_lo, z_hi = (float(boxcox(h, lam)) for h in (HI_LO, HI_HI))
    params = model.params()
    return LearnedDevice(
        kind=model.name,
        template="learned_hi_noise.c.j2",
        state_fields=_STATE_FIELDS,
        constants={
            **_gaussian_posterior(model),
            "shape": lam,
            "log_form": log_form,
            "inv_shape": 0.0 if log_form else 1.0 / lam,
            "z_lo": z_lo,
            "z_hi": z_hi,
            "hi_lo_text": f"{HI_LO:g}",
            "hi_hi_text": f"{HI_HI:g}",
            "r_log": params.r_log,
            "r_hi": params.r_hi,
            "measured_var": float(model.measured_var),
            "iekf_tol": IEKF_TOL,
            "iekf_iterations": IEKF_ITERATIONS,
        },
    )


EXPORTERS: dict[str, Callable[[Any], LearnedDevice]] = {
    "linear": _random_effects,
    "exponential": _random_effects,
    "paris": _random_effects,
    "paris-additive": _hi_noise,
    "paris-multiplicative": _hi_noise,
    "paris-mixed": _hi_noise,
    "paris-additive-iid": _hi_noise,
}
"""Learned model name -> its device description. Add an entry to make a new kind exportable."""


def learned_device(model: LearnedModel, one_measurement: bool = False) -> LearnedDevice:
    """The device description of ``model`` with the RUL of the first measured crossing
    (eq. (5b); ``one_measurement``: eq. (5) of one measurement); :class:`ExportError` for a
    kind without one."""
    kind = str(getattr(model, "name", None) or getattr(model, "kind", type(model).__name__))
    if kind not in EXPORTERS:
        raise ExportError(
            f"learned model type {kind!r} has no C export (exportable: "
            f"{', '.join(sorted(EXPORTERS))}); export the tracker chain alone with "
            "--no-learned, or add the type to rulkit.fleet.export.learned_device.EXPORTERS")
    dev = EXPORTERS[kind](model)
    event = {"first_passage": False} if one_measurement else first_passage_constants(model)
    return dataclasses.replace(dev, constants={**dev.constants, **event})


__all__ = ["EXPORTERS", "FP_ITERATIONS", "LearnedDevice", "first_passage_constants",
           "learned_device"]
