"""Q formats from the settings' ranges, and the worst case: inputs at the ends of their ranges
saturate, never wrap, and raise no undefined behaviour under the sanitizers."""

import math

import numpy as np
import pytest

from rulkit.fleet.export.device_spec import DeviceSpec
from rulkit.fleet.export.fixed_point import int_bits, q, q_formats
from rulkit.fleet.export.verify import run_sanitized
from rulkit.fleet.tracking.tracker_chain import TrackerConfig


def test_formats_follow_the_ranges():
    f = q_formats(DeviceSpec("a", "t", TrackerConfig()))  # hi_max 10, design life 1e5 dt
    assert f["hi_frac"] == 27  # |HI| < 16
    assert f["dhi_frac"] == 31  # 2^16 x the floor 1e-5 exceeds 1: Q0.31
    # RUL: 4 x (1/e) 1e5 intervals = 147152 < 2^18
    assert f["rul_frac"] == 31 - 18
    slow = q_formats(DeviceSpec("a", "t", TrackerConfig(design_life=2e6)))
    assert 2.0 ** (31 - slow["dhi_frac"]) >= 2**16 / 2e6 > 2.0 ** (30 - slow["dhi_frac"])
    assert int_bits(0.5) == 0 and int_bits(1.0) == 1 and int_bits(15.9) == 4
    assert int_bits(16.0) == 5
    assert q(1.0, 31) == 2**31 - 1 and q(-5.0, 31) == -(2**31)  # saturated


@pytest.mark.parametrize("initiation", ["floor", "two-point", "measured"])
def test_worst_case_saturates_without_wrapping(cc, tmp_path, initiation):
    cfg = TrackerConfig(initiation=initiation, rul_clip=initiation == "measured",
                        hi_sigma=0.5, design_life=1e6, lambda_hi=1e3, lambda_rul=1e3)
    n = 400
    rng = np.random.default_rng(2)
    hi = np.where(np.arange(n) % 2 == 0, cfg.hi_max, 0.0)  # full-range jumps
    hi[200:] = rng.uniform(0.0, 1e-3, n - 200)  # then HI at the floor
    gaps = np.where(np.arange(n) % 3 == 0, 2.0**22, 1 / 256)  # longest and shortest dt
    t = np.cumsum(gaps)
    start = np.array([0, n])
    got = run_sanitized(DeviceSpec("w", "t", cfg), tmp_path, start, t, hi, "fixed")
    assert (got["status"] == 0).all()
    lim = 2.0**31
    scale = {"fhi": 2.0**-27, "rul": cfg.dt * 2.0 ** -q_formats(
        DeviceSpec("w", "t", cfg))["rul_frac"]}
    assert np.all(np.abs(got["fhi"]) <= lim * scale["fhi"])
    assert np.all(got["rul"] >= 0)  # -h ln h / dHI with dHI >= its floor: a wrap would flip it
    assert np.all(got["rul_low"] <= got["rul"] + scale["rul"])
    assert np.all(got["rul"] <= got["rul_high"] + scale["rul"])
    assert np.all(got["dhi"] > 0)
    assert math.isclose(got["hi"][0], cfg.hi_max)
