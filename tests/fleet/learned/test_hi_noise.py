"""Growth with HI-scale noise (docs/fleet-models.md eq. (7)-(8)): fit, online update, RUL."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rulkit.fleet.learned.datasets import synthetic_growth_fleet
from rulkit.fleet.learned.degradation import UnitState, fit_model
from rulkit.fleet.learned.hi_noise import HiNoiseModel, fit_hi_noise
from rulkit.fleet.learned.histories import histories_from_frame


def _model(noise="mixed", walk=0.05):
    return HiNoiseModel(noise=noise, shape=0.0, mean=(-2.3, 2.0), cov=(1e-3, 0.0, 0.05),
                        hi_noise_sd=0.02, log_noise_sd=0.03 if noise == "mixed" else 0.0,
                        walk_sd=walk, time_scale=300.0)


@pytest.fixture(scope="module")
def additive_fleet():
    df, _ = synthetic_growth_fleet(np.random.default_rng(0), 20, m=2.0, h0=0.1,
                                   noise="additive", hi_noise_sd=0.02, n_acq=25)
    return histories_from_frame(df)


def test_additive_noise_recovers_the_exponent_the_log_scale_model_misses(additive_fleet):
    """Exponential growth (m = 2) with additive noise sd 0.02: the additive model finds m = 2
    and the noise; the model with all noise on the log scale learns a wrong shape and a lower
    likelihood of the same HI (the failure that motivated it)."""
    add = fit_hi_noise(additive_fleet, "additive")
    assert add.paris_exponent == pytest.approx(2.0, abs=0.5)
    assert add.hi_noise_sd == pytest.approx(0.02, rel=0.2)
    logscale = fit_model(additive_fleet, "paris")
    assert abs(logscale.paris_exponent - 2.0) > 0.5
    assert add.log_likelihood > logscale.log_likelihood + 50


def test_online_update_equals_replay(additive_fleet):
    m = _model()
    h = additive_fleet.select(list(range(6)))
    ref = m.replay(h).take(h.start[1:] - 1)
    st = m.empty_state(h.n_units)
    for k in range(int(np.diff(h.start).max())):
        t, hi = np.full(h.n_units, np.nan), np.full(h.n_units, np.nan)
        for u in range(h.n_units):
            if h.start[u] + k < h.start[u + 1]:
                t[u], hi[u] = h.t[h.start[u] + k], h.hi[h.start[u] + k]
        st = m.update(st, t, hi)
    np.testing.assert_allclose(st.m, ref.m, rtol=1e-12)
    np.testing.assert_allclose(st.p, ref.p, rtol=1e-12)
    assert list(st.n) == list(np.diff(h.start))
    with pytest.raises(ValueError, match="unit index 0"):
        m.update(st, np.full(h.n_units, 1.0), np.full(h.n_units, 0.5))


def test_rul_is_that_of_a_measurement_reaching_one():
    """eq. (5) on the measured HI: the level's variance gains the measurement noise at hi = 1
    (dhi/dz = 1 there), so the median is unchanged and the interval wider than the latent
    HI's; quantiles invert the CDF."""
    m = _model()
    st = UnitState(m=np.array([[-0.4, 2.0]]), p=np.array([[1e-3, 1e-4, 1e-3]]),
                   t=np.array([100.0]), hi=np.array([0.7]), n=np.array([10]))
    med, lo, hi = m.rul_quantiles(st)
    f = m.rul_cdf(st, np.column_stack([lo, med, hi]))
    np.testing.assert_allclose(f[0], [0.05, 0.5, 0.95], atol=1e-6)
    latent = HiNoiseModel(**{**m.to_dict(), "mean": m.mean, "cov": m.cov, "warnings": (),
                             "hi_noise_sd": 1e-12, "log_noise_sd": 0.0, "noise": "additive"})
    lmed, llo, lhi = latent.rul_quantiles(st)
    assert med[0] == pytest.approx(lmed[0], rel=0.02)
    assert hi[0] - lo[0] > lhi[0] - llo[0]
    assert m.measured_var == pytest.approx(0.02**2 + 0.03**2)


def test_hi_forecast_reaches_one_at_the_latent_rul():
    """The latent HI's median reaches 1 where the latent model's RUL median is (both from the
    level's Gaussian: g(1) = 0 crossed by the median path), and the band orders."""
    m = HiNoiseModel(noise="additive", shape=0.0, mean=(-2.3, 2.0), cov=(1e-3, 0.0, 0.05),
                     hi_noise_sd=1e-9, log_noise_sd=0.0, walk_sd=0.0, time_scale=300.0)
    st = UnitState(m=np.array([[-0.4, 2.0]]), p=np.array([[1e-6, 0.0, 1e-8]]),
                   t=np.array([100.0]), hi=np.array([0.7]), n=np.array([10]))
    med = m.rul_quantiles(st, (0.5,))[0]
    got = m.hi_quantiles(st, med[:, None], (0.5, 0.05, 0.95))
    assert got[0][0, 0] == pytest.approx(1.0, abs=1e-6)
    assert got[1][0, 0] < got[0][0, 0] < got[2][0, 0]


def test_dict_round_trip_and_names():
    m = _model()
    assert HiNoiseModel.from_dict(m.to_dict()) == m
    assert m.name == "paris-mixed" and _model("additive", 0.0).name == "paris-additive-iid"
    mult = HiNoiseModel(**{**m.to_dict(), "mean": m.mean, "cov": m.cov, "warnings": (),
                           "noise": "multiplicative", "hi_noise_sd": 0.0})
    assert mult.name == "paris-multiplicative"
    with pytest.raises(ValueError, match="noise"):
        _model("log")
    assert math.isnan(m.log_likelihood)
