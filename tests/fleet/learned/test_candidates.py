"""Every candidate offers one interface and round-trips through its stored dict."""

from __future__ import annotations

import numpy as np
import pytest

from rulkit.fleet.learned.candidates import (
    ALL_CANDIDATES,
    check_name,
    fit_candidate,
    model_from_dict,
    model_to_dict,
)
from rulkit.fleet.learned.datasets import synthetic_growth_fleet
from rulkit.fleet.learned.degradation import DegradationModel
from rulkit.fleet.learned.hi_noise import HiNoiseModel
from rulkit.fleet.learned.histories import histories_from_frame


@pytest.fixture(scope="module")
def hist():
    df, _ = synthetic_growth_fleet(np.random.default_rng(0), 8, n_acq=10, h0=0.2)
    return histories_from_frame(df.assign(time=df["time"] / 24.0), unit="d")


GROWTH = {"shape": 0.0, "mean": (-1.6, 1.6), "cov": (0.01, 0.0, 0.1), "walk_sd": 0.01,
          "time_scale": 10.0}


@pytest.mark.parametrize("name", ["paris", "paris-additive", "onset", "similarity",
                                  "regression"])
def test_fit_store_and_interface(hist, name):
    # the growth models start from a fixed shape (m = 2), which keeps this test short
    additive = HiNoiseModel(noise="additive", hi_noise_sd=0.02, log_noise_sd=0.0, **GROWTH)
    start = {"paris": DegradationModel(kind="paris", noise_sd=0.05, **GROWTH),
             "paris-additive": additive}.get(name)
    fitted = {"paris-additive": additive}
    m = fit_candidate(name, hist, start=start, fixed_shape=start is not None, fitted=fitted)
    assert m.name == name and m.time_unit == "d" and m.time_axis["unit"] == "d"
    back = model_from_dict(model_to_dict(m))
    assert back == m
    st = m.replay(hist)
    assert tuple(st.columns()) == m.state_columns
    med, lo, hi = m.rul_quantiles(st.take(np.arange(5)))
    assert (lo <= med).all() and (med <= hi).all()


def test_a_model_stored_without_type_is_the_transformed_model():
    d = DegradationModel(kind="linear", shape=0.0, mean=(0.1, 0.8), cov=(0.01, 0.0, 0.04),
                         noise_sd=0.03, walk_sd=0.0, time_scale=10.0).to_dict()
    assert isinstance(model_from_dict(d), DegradationModel)
    with pytest.raises(ValueError, match="stored model type"):
        model_from_dict({"type": "neural"})


def test_names():
    for n in ALL_CANDIDATES:
        check_name(n)
    with pytest.raises(ValueError, match="expected one of"):
        check_name("arima")
