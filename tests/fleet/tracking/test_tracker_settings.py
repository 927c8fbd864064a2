"""The seed chain made safe (issue 11 item 2): measured initiation, clipping, fitted settings,
time-unit check; the seed's behaviour stays the default."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.learned.datasets import synthetic_paris_fleet
from rulkit.fleet.learned.histories import histories_from_frame
from rulkit.fleet.store.acquisitions import IngestError
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.tracking.tracker_chain import (
    TrackerConfig,
    TrackerState,
    track_series,
    tracker_update,
    tracker_update_loop,
)
from rulkit.fleet.tracking.tracker_settings import check_time_unit, fit_tracker_config

T0 = np.arange(0, 10.0)
HI0 = np.array([0.0, 0.0, 0.0, 0.01, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5])  # starts at the HI floor


def test_measured_initiation_does_not_carry_the_floor_rul():
    floor = track_series(T0, HI0[:, None], TrackerConfig(dt=1, lambda_hi=0.5, lambda_rul=0.5))
    safe = track_series(T0, HI0[:, None], TrackerConfig.safe(dt=1, lambda_hi=0.5,
                                                             lambda_rul=0.5))
    floor_rul = -1e-3 * np.log(1e-3) * 1e5  # 690.8: the floor's RUL
    assert floor["frul"][0, 0] == pytest.approx(floor_rul)
    assert floor["frul"][:, 0].min() < 0  # the seed's chain swings negative from 690
    # safe: restarted at the raw RUL of the first measured slope, then follows it
    k = 3
    assert safe["frul"][k, 0] == pytest.approx(safe["rul"][k, 0])
    assert (safe["frul"][k:, 0] < 2 * safe["rul"][k, 0]).all()
    assert (safe["frul"][:, 0] >= 0).all()
    assert not safe["valid"][k, 0]  # dRUL = 0 after the restart: not valid


def test_clip_at_zero_is_counted():
    t = np.arange(0, 13.0) * 10
    hi = np.array([0.56, 0.57, 0.58, 0.6, 0.62, 0.65, 0.69, 0.74, 0.8, 0.87, 0.95, 0.99, 0.995])
    kw = dict(dt=10, lambda_hi=0.64, lambda_rul=0.1, design_life=1e4, initiation="two-point")
    seed = track_series(t, hi[:, None], TrackerConfig(**kw))
    safe = track_series(t, hi[:, None], TrackerConfig(**kw, rul_clip=True))
    neg = seed["frul"][:, 0] < 0
    assert neg.sum() == 4
    np.testing.assert_array_equal(safe["clipped"][:, 0], neg)
    assert (safe["frul"][:, 0] >= 0).all()
    assert not seed["clipped"].any()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_vectorised_safe_chain_equals_the_loop_reference(seed):
    rng = np.random.default_rng(seed)
    b = 7
    cfg = TrackerConfig.safe(dt=1.0, lambda_hi=0.3, lambda_rul=0.2, design_life=200.0)
    st_v = st_l = TrackerState.empty(b)
    t = np.zeros(b)
    for _ in range(15):
        t = t + rng.uniform(0.5, 1.5, b)
        hi = np.clip(0.05 * t + 0.05 * rng.standard_normal(b), 0, 1.2)
        hi[rng.random(b) < 0.2] = np.nan  # no acquisition for some
        st_v, _ = tracker_update(st_v, t, hi, cfg)
        st_l = tracker_update_loop(st_l, t, hi, cfg)
        t = np.where(np.isnan(hi), st_v.t if np.isfinite(st_v.t).all() else t, t)
        np.testing.assert_allclose(st_v.abg, st_l.abg, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(st_v.ab, st_l.ab, rtol=1e-12, atol=1e-12)


def test_fitted_settings_from_histories():
    df, _ = synthetic_paris_fleet(np.random.default_rng(3), 20, noise_sd=0.01)
    h = histories_from_frame(df)
    cfg = fit_tracker_config(h)
    assert cfg.initiation == "measured" and cfg.rul_clip
    # the generator's HI noise is 0.01; the quadratic fits' misfit of the Paris curvature
    # near failure can only add to the residuals (measured: 0.014 to 0.025 on seeds 0-11 of
    # this fleet, 0.020 on this one)
    assert 0.009 <= cfg.hi_sigma <= 0.03
    life = h.t[h.start[1:] - 1].max()
    assert cfg.design_life == pytest.approx(100 * life)
    assert 1e-4 <= cfg.lambda_hi <= 1e3 and 1e-4 <= cfg.lambda_rul <= 1e3
    assert TrackerConfig.from_dict(cfg.to_dict()) == cfg


def test_old_stored_settings_keep_the_seed_behaviour():
    d = TrackerConfig().to_dict()
    del d["rul_clip"]  # a database written before the field existed
    assert TrackerConfig.from_dict(d).rul_clip is False


def test_design_life_in_another_time_unit_is_refused(tmp_path):
    epoch = 1.7e9 + 3600.0 * np.arange(30)  # hourly, epoch seconds
    with pytest.raises(ValueError, match=r"design_life = 100000.*time unit"):
        check_time_unit(TrackerConfig(), epoch)
    check_time_unit(TrackerConfig(design_life=3.6e8), epoch)  # the same life in seconds
    df = pd.DataFrame({"component": "c", "time": epoch, "hi": np.linspace(0.1, 0.2, 30)})
    with ComponentStore(tmp_path / "s.db") as s, pytest.raises(IngestError, match="time unit"):
        s.ingest(df)
    with ComponentStore(tmp_path / "s.db", readonly=True) as s:
        assert s.counts() == (0, 0, 0)


def test_the_intervals_median_is_numpys():
    """check_intervals' median (one partition, no NaN check) equals np.median bit for bit, odd
    and even sizes, ties and one value."""
    from rulkit.fleet.tracking.tracker_settings import _median

    rng = np.random.default_rng(4)
    for n in [1, 2, 3, 4, 7, 10, 101, 1000]:
        for d in (rng.exponential(3.0, n), rng.integers(1, 4, n).astype(float),
                  np.full(n, 0.1) * rng.uniform(0.9, 1.1)):
            assert _median(d.copy()) == np.median(d), (n, d)
