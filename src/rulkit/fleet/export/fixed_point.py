"""Q formats of the fixed-point tracker chain, chosen from the ranges of its quantities
(docs/rul-on-the-device.md section 3).

Time is counted in nominal acquisition intervals (``config.dt``): rates become increments per
interval and the RUL a number of intervals, so the arithmetic needs no time constant. Every
value is an int32 ``round(v * 2^f)``; products and quotients are formed in int64, rounded to
nearest (half away from zero) and saturated to int32, never wrapped.

* HI, fHI (and the Paris-law terms ``-ln h``, ``-h ln h``): ``Q(i).(31-i)`` with ``i`` the
  integer bits of ``hi_max`` (default 10: Q4.27, resolution 7.5e-9);
* dHI per interval: the floor dt / design_life (the slowest rate the tracker reports) gets 16
  bits of headroom: |dHI dt| < 2^ceil(log2(2^16 dt / design_life)), at most 1 (Q0.31); the
  floor then holds at least 2^15 steps of resolution (3e-5 relative), and a rate 65536 times
  the floor, a component crossing the HI range in 1/65536 of its design life, saturates;
* RUL, fRUL, the confidence limits (intervals), dRUL (dimensionless), d2RUL (per interval):
  one format whose integer part holds four times the largest Paris-law RUL, (1/e) design_life
  / dt intervals (the tracker may overshoot it; beyond, it saturates);
* gains: Q2.29 (alpha, beta, gamma of the alpha-beta-gamma tracker reach 2 for large
  tracking indices);
* time stamps: uint32 ticks of 1/256 interval (wrapping counter), dt in Q23.8 intervals;
* 1/(1 +- delta)^q of the confidence limits: Q(i).(30-i) from the value.

Only the seed's Paris exponent m = 2 (one logarithm, no power) is supported in fixed point; the
learned models (erfc, the normal quantile) and the CI -> HI map need floating point.
"""

from __future__ import annotations

import math
from typing import Any

from rulkit.fleet.export.device_spec import DeviceSpec, ExportError

TICK_FRAC = 8
GAIN_FRAC = 29
DHI_HEADROOM = 2.0**16
RUL_MARGIN = 4.0


def int_bits(max_abs: float) -> int:
    """Integer bits b (sign excluded) with ``max_abs < 2^b``."""
    if not math.isfinite(max_abs) or max_abs <= 0:
        raise ExportError(f"fixed point: no Q format holds {max_abs!r}")
    return max(0, math.ceil(math.log2(max_abs * (1 + 1e-12))))


def q(value: float, frac: int) -> int:
    """round(value 2^frac), saturated to int32 (the C template's rounding)."""
    v = round(value * 2.0**frac)
    return max(-(2**31), min(2**31 - 1, v))


def q_formats(device: DeviceSpec) -> dict[str, int]:
    """Fractional bits of each quantity from the settings (module docstring)."""
    cfg = device.config
    hi_frac = 31 - int_bits(cfg.hi_max + 1.0)
    floor = cfg.dt / cfg.design_life
    dhi_frac = 31 + max(0, -math.ceil(math.log2(min(1.0, DHI_HEADROOM * floor))))
    max_rul = cfg.design_life / cfg.dt / math.e
    rul_frac = 31 - int_bits(RUL_MARGIN * max_rul)
    if rul_frac < 4:
        raise ExportError(f"fixed point: design_life / dt = {cfg.design_life / cfg.dt:g} "
                          "intervals leaves the RUL fewer than 4 fractional bits in int32")
    return {"hi_frac": hi_frac, "dhi_frac": dhi_frac, "rul_frac": rul_frac,
            "gain_frac": GAIN_FRAC, "tick_frac": TICK_FRAC}


def fixed_context(device: DeviceSpec) -> dict[str, Any]:
    """The fixed-point constants of the template ``device_fixed.c.j2``; :class:`ExportError`
    for what fixed point does not cover (module docstring)."""
    cfg = device.config
    if device.learned is not None:
        raise ExportError(
            f"fixed point covers the tracker chain only; this export holds the learned "
            f"{device.learned.name} model (erfc and the normal quantile need floating point): "
            "use --number float, or --no-learned")
    if device.hi_model is not None:
        raise ExportError("fixed point takes the HI as input; this export holds a CI -> HI "
                          "map (use --number float, or --no-ci to give the device the HI)")
    if cfg.paris_exponent != 2.0:
        raise ExportError(f"fixed point supports the Paris exponent m = 2 only, got "
                          f"m = {cfg.paris_exponent:g} (use --number float)")
    f = q_formats(device)
    g = cfg.gains()
    dt = cfg.dt
    qexp = cfg.paris_exponent if cfg.load_exponent is None else cfg.load_exponent
    inv_up = 1.0 / (1.0 + cfg.load_factor) ** qexp
    inv_down = 1.0 / (1.0 - cfg.load_factor) ** qexp
    inv_frac = 30 - int_bits(max(inv_up, inv_down, 1.0))
    hf, rf, gf = f["hi_frac"], f["rul_frac"], f["gain_frac"]
    consts = {
        "alpha1": q(g.alpha1, gf), "beta1": q(g.beta1, gf), "alpha2": q(g.alpha2, gf),
        "beta2": q(g.beta2, gf), "gamma2": q(g.gamma2, gf),
        "dhi_min": max(1, q(dt / cfg.design_life, f["dhi_frac"])),
        "hi_floor": q(cfg.hi_floor, hf), "hi_max": q(cfg.hi_max, hf), "one": q(1.0, hf),
        "hi_sigma": q(cfg.hi_sigma, hf), "ln2": q(math.log(2.0), 31),
        "inv_load_up": q(inv_up, inv_frac), "inv_load_down": q(inv_down, inv_frac),
        "inv_frac": inv_frac,
        "valid_lo": q(cfg.valid_drul[0], rf), "valid_hi": q(cfg.valid_drul[1], rf),
        "valid_d2rul": q(cfg.valid_d2rul * dt, rf), "warn_hi": q(cfg.warn_hi, hf),
        "warn_rul": q(cfg.warn_rul / dt, rf), "alarm_hi": q(cfg.alarm_hi, hf),
        "dt_ticks": 1 << TICK_FRAC, "time_shift": rf + f["dhi_frac"] - hf,
    }
    if gf + hf - TICK_FRAC - f["dhi_frac"] < 0:
        raise ExportError(f"fixed point: design_life / dt = {cfg.design_life / cfg.dt:g} and "
                          f"hi_max = {cfg.hi_max:g} need more than 32 bits")
    return {"fx": {**f, **consts, "ticks_per_dt": 1 << TICK_FRAC},
            "dt_text": f"{dt:g} {'time units' if not device.learned else device.learned.time_unit}"}


__all__ = ["DHI_HEADROOM", "GAIN_FRAC", "TICK_FRAC", "fixed_context", "int_bits", "q", "q_formats"]
