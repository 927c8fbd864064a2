"""A fit that cannot fail quietly: checks of the histories before a fit and of the fit after it.

docs/fleet-models.md section 8. Each check returns warnings (one sentence on what was found,
one on what to do) or raises :class:`~rulkit.fleet.learned.histories.HistoryError` when nothing
sensible can be learned. ``rulkit fit`` and ``rulkit evaluate`` print the warnings; ``fit``
stores them with the model (``rulkit status`` shows them).

Histories (:func:`check_histories`): ages that look like epoch timestamps, HI on another scale
than failure at 1 (e.g. percent), lone hi = 0 rows among clearly positive values, units with
one acquisition, HI that falls over time, few failed units, columns the reader ignored.
Fits (:func:`check_fit`): the optimiser stopping without converging, parameters at a bound,
the Paris exponent at an end of its range, a fleet whose growth rate is not positive, and the
held-out 90 % interval coverage far from nominal.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rulkit.fleet.learned.histories import Histories, HistoryError

COVERAGE_BAND = (0.8, 0.97)
"""Held-out 90 % coverage outside this band is reported (a calibrated model lands near 0.9)."""
EPOCH_LIKE = 1e8


def _row(h: Histories, i: int) -> str:
    r = int(h.row[i]) if h.row is not None else i + 1
    return f"row {r} (component {h.names[h.unit[i]]!r})"


def check_histories(h: Histories) -> list[str]:
    """Warnings about implausible histories; :class:`HistoryError` for unusable ones."""
    out: list[str] = []
    for check in (_epoch_ages, _hi_scale, _lone_zeros, _one_row_units, _falling_hi,
                  _few_failed, _ignored_columns):
        msg = check(h)
        if msg:
            out.append(msg)
    return out


def _epoch_ages(h: Histories) -> str:
    if h.axis.origin != "time" or h.axis.timestamps:
        return ""
    raw = h.raw_time if h.raw_time is not None else h.t
    first = raw[h.start[:-1]]
    spans = raw[h.start[1:] - 1] - first
    lo = float(first.min())
    if lo < EPOCH_LIKE or float(np.median(spans)) > 1e-3 * lo:
        return ""
    return (f"time: every unit starts at an age above {lo:.3g} while its history spans "
            f"{float(np.median(spans)):.3g} (median): these look like epoch timestamps, not "
            "ages since install; the models' prior sits at age 0. Give ages, or fit with "
            "--age-from first (age since each unit's first acquisition)")


def _hi_scale(h: Histories) -> str:
    top = float(h.hi.max())
    if top <= 2.0:
        return ""
    first = h.hi[h.start[:-1]]
    msg = (f"hi reaches {top:.4g} and the median unit starts at {float(np.median(first)):.4g}; "
           "failure is at hi = 1 and a run-to-failure history ends at its first hi >= 1. Is "
           "the HI in percent (divide by 100) or on another scale? Normalise it so that "
           "failure is 1")
    if float(np.median(first)) >= 1.0:
        raise HistoryError(f"{h.source}: {msg}")
    return msg


def _lone_zeros(h: Histories) -> str:
    zero = h.hi <= 1e-6
    n = int(zero.sum())
    if n == 0 or n > 0.05 * h.hi.size or float(np.median(h.hi)) < 0.02:
        return ""
    i = int(np.flatnonzero(zero)[0])
    pos = h.hi[~zero]
    return (f"{_row(h, i)}: hi = 0 among values of at least {float(np.quantile(pos, 0.01)):.3g} "
            f"(1 % quantile; {n} such row(s)): a missing value written as 0? The growth-scale "
            "models (paris, exponential) read it as a huge drop and can learn a wrong shape; "
            "the additive-noise candidates are robust to it. Drop the row if it is not a "
            "measurement")


def _one_row_units(h: Histories) -> str:
    counts = np.diff(h.start)
    single = int((counts == 1).sum())
    if single == h.n_units:
        raise HistoryError(
            f"{h.source}: every unit has a single acquisition: a history needs several "
            "acquisitions per unit to learn how the HI grows (is this a summary file with one "
            "row per unit?)")
    if single <= 0.25 * h.n_units:
        return ""
    return (f"{single} of {h.n_units} units have one acquisition: their growth is not "
            "observed, and the fleet's rate is learned from the others; add their history if "
            "you have it")


def _falling_hi(h: Histories) -> str:
    counts = np.diff(h.start)
    multi = counts >= 3
    if multi.sum() < 2:
        return ""
    delta = (h.hi[h.start[1:] - 1] - h.hi[h.start[:-1]])[multi]
    falling = int((delta < 0).sum())
    if falling <= 0.5 * delta.size:
        return ""
    return (f"hi falls over time in {falling} of {delta.size} units: rulkit expects a health "
            "index that grows to failure at 1 (give 1 - health, or normalise so that failure "
            "is 1)")


def _few_failed(h: Histories) -> str:
    n = int(h.failed.sum())
    if n >= 3:
        return ""
    return (f"only {n} failed unit(s): where the HI crosses 1 is learned from few examples "
            "and the held-out check has little to score; treat the intervals with care")


def _ignored_columns(h: Histories) -> str:
    if not h.extra_columns:
        return ""
    return (f"column(s) {list(h.extra_columns)} ignored (read: component, time, hi, failed, "
            "installed)")


# ------------------------------------------------------------------------------ fits
_BOUND_TEXT = {
    "noise": ("the {what} sd sits at its floor (1e-4 x the data's spread): the data look "
              "noise-free on this scale (smoothed or quantised HI?), so the intervals may be "
              "too narrow; compare the held-out coverage"),
    "noise_hi": ("the {what} sd sits at its ceiling: the model does not follow the data; try "
                 "another candidate (--model)"),
    "spread": ("the units' spread of {what} sits at its floor: every unit is modelled with the "
               "same {what}; fine if all units start alike, otherwise check the time column "
               "(ages since install?)"),
    "coupled": ("level and rate are perfectly correlated in the prior (the rate's spread beyond "
                "what the level explains sits at its floor): a degenerate fleet prior; RUL "
                "intervals of new units may be too narrow"),
    "walk_hi": ("the random walk sits at its ceiling: the paths wander more than the growth "
                "law explains; try another candidate (--model)"),
    "onset": ("the onset prior sits at an end of its grid: onsets are earlier or later than "
              "the observed ages allow; the onset candidate may not suit this fleet"),
}
_BOUNDS = {"log_noise_var": ("noise", "measurement noise"), "log_r_log": ("noise", "multiplicative "
           "noise"), "log_r_hi": ("noise", "HI noise"), "log_l11": ("spread", "level"),
           "log_l22": ("coupled", ""), "log_walk_var": ("walk", ""), "log_q": ("walk", ""),
           "mu_s": ("onset", ""), "log_sd_s": ("onset", "")}


def check_fit(model: Any, coverage: float = math.nan) -> list[str]:
    """Warnings about a fitted candidate (module docstring); ``coverage`` its held-out 90 %
    interval coverage (NaN: not measured)."""
    out: list[str] = []
    name = getattr(model, "name", "model")
    diag = getattr(model, "diagnostics", None)
    if diag is not None:
        if diag.optim.stalled:
            out.append(f"{name}: the optimiser stopped before converging "
                       f"({diag.optim.stalled}); the fit may not be the best one. Check the "
                       "histories (outliers, units with one acquisition) or use another "
                       "candidate")
        out += _bound_warnings(name, model, diag.optim.at_bound)
        if diag.shape_at_edge:
            out.append(f"{name}: the Paris exponent m = {model.paris_exponent:g} is at an end "
                       "of the range searched (0 to 8): the growth is slower or faster than "
                       "any Paris law there; consider the onset or similarity candidates")
        if diag.grid_error > 0:
            out.append(f"{name}: the onset grid stopped at its largest size "
                       f"({len(model.grid)} values) with the likelihood still moving by "
                       f"{diag.grid_error:.3g} nats when its step is halved: the onsets are "
                       "more tightly grouped than the grid resolves, and the growth law may be "
                       "biased. Check the histories' time axis (one unit far from the others "
                       "stretches the grid) or prefer another candidate")
    out += _rate_warnings(name, model)
    if math.isfinite(coverage) and not COVERAGE_BAND[0] <= coverage <= COVERAGE_BAND[1]:
        side = "narrow" if coverage < COVERAGE_BAND[0] else "wide"
        out.append(f"{name}: its 90 % intervals held the truth in {coverage:.0%} of the "
                   f"held-out predictions (nominal 90 %): too {side}; the noise or shape model "
                   "does not suit this fleet. Compare the candidates' table, or treat the "
                   "intervals with care")
    return out


def _bound_warnings(name: str, model: Any, at_bound: tuple[str, ...]) -> list[str]:
    out = []
    for entry in at_bound:
        p, _, side = entry.partition(":")
        kind, what = _BOUNDS.get(p, ("", ""))
        if kind == "walk":  # at its floor: independent errors suffice, not a problem
            kind = "walk_hi" if side == "high" else ""
        elif kind == "noise" and side == "high":
            kind = "noise_hi"
        elif kind in ("spread", "coupled") and side == "high":
            kind = ""
        if kind:
            out.append(f"{name}: " + _BOUND_TEXT[kind].format(what=what))
    return out


def _rate_warnings(name: str, model: Any) -> list[str]:
    mean, cov = getattr(model, "mean", None), getattr(model, "cov", None)
    if mean is None or cov is None:
        return []
    from scipy.special import ndtr

    never = float(ndtr(-mean[1] / math.sqrt(cov[2])))
    if mean[1] <= 0:
        return [f"{name}: the fleet's mean growth rate is not positive: under this model most "
                "units never reach hi = 1. Is the HI decreasing, or not normalised so that "
                "failure is 1?"]
    if never > 0.2:
        return [f"{name}: {never:.0%} of the prior's units have a non-positive rate and never "
                "fail: the growth is poorly determined (short histories, few failures); "
                "RUL intervals of new units will be open-ended"]
    return []


__all__ = ["COVERAGE_BAND", "check_fit", "check_histories"]
