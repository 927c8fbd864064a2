"""Property: no RUL is negative or outside its own interval, for every estimator.

Random histories with irregular sampling and sparse units (3 acquisitions), for every
candidate model (median and 90 % interval of one distribution: never negative, the median
inside [5 %, 95 %], 0 once the measured HI reached 1) and the safe tracker chain (filtered RUL
and limits never negative).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rulkit.fleet.learned.degradation import filtered_states, fit_model
from rulkit.fleet.learned.hi_noise import HiNoiseModel, fit_hi_noise
from rulkit.fleet.learned.histories import histories_from_frame
from rulkit.fleet.learned.onset import OnsetModel
from rulkit.fleet.learned.regression import fit_regression
from rulkit.fleet.learned.similarity import fit_similarity
from rulkit.fleet.tracking.tracker_chain import TrackerConfig, track_series


@st.composite
def fleets(draw):
    n_units = draw(st.integers(2, 5))
    rows = []
    for u in range(n_units):
        n = draw(st.sampled_from([3, 3, 4, 7]))
        gaps = draw(st.lists(st.floats(0.01, 50.0), min_size=n, max_size=n))
        t = np.cumsum(gaps)
        hi = draw(st.lists(st.floats(0.0, 1.5), min_size=n, max_size=n))
        rows.append(pd.DataFrame({"component": f"u{u}", "time": t, "hi": hi}))
    df = pd.concat(rows, ignore_index=True)
    df.loc[df.index[-1], "hi"] = 1.0 + draw(st.floats(0.0, 0.5))  # at least one failure
    return df


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(fleets(), st.sampled_from(["linear", "paris", "exponential"]))
def test_learned_rul_never_negative_while_unfailed(df, kind):
    h = histories_from_frame(df)
    shape = {"linear": None, "paris": -0.5, "exponential": -0.1}[kind]
    m = fit_model(h, kind, shape=shape)
    s = filtered_states(m, h)
    med, lo, hi = m.rul_quantiles(s)
    unfailed = h.hi < 1.0
    for q in (med, lo, hi):
        assert not np.isnan(q).any()
        assert (q[unfailed] >= 0).all()
        assert (q[~unfailed] == 0).all()
    assert (lo <= med).all() and (med <= hi).all()


def _check(model, h):
    med, lo, hi = model.rul_quantiles(model.replay(h))
    unfailed = h.hi < 1.0
    for q in (med, lo, hi):
        assert not np.isnan(q).any()
        assert (q[unfailed] >= 0).all()
        assert (q[~unfailed] == 0).all()
    assert (lo <= med).all() and (med <= hi).all()


noise_sd = st.floats(1e-3, 0.3)
shapes = st.sampled_from([1.0, 0.5, 0.0, -0.5, -1.5])


@st.composite
def growth_models(draw):
    """HI-noise and onset models with parameters drawn over a wide range (no fitting)."""
    mean = (draw(st.floats(-3.0, 0.5)), draw(st.floats(-1.0, 3.0)))
    sa, sb = draw(st.floats(1e-3, 1.0)), draw(st.floats(1e-3, 2.0))
    rho = draw(st.floats(-0.9, 0.9))
    common = {"shape": draw(shapes), "mean": mean, "cov": (sa * sa, rho * sa * sb, sb * sb),
              "hi_noise_sd": draw(noise_sd), "log_noise_sd": draw(noise_sd),
              "walk_sd": draw(st.floats(0.0, 0.5)), "time_scale": draw(st.floats(1.0, 100.0))}
    if draw(st.booleans()):
        return HiNoiseModel(noise="mixed", **common)
    grid = tuple(np.linspace(0.0, draw(st.floats(0.5, 3.0)), draw(st.integers(2, 6))).tolist())
    return OnsetModel(noise="mixed", grid=grid, onset_mean=draw(st.floats(0.0, 2.0)),
                      onset_sd=draw(st.floats(0.05, 2.0)), **common)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(fleets(), growth_models())
def test_growth_model_rul_inside_its_interval(df, model):
    _check(model, histories_from_frame(df))


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(fleets())
def test_fitted_candidates_rul_inside_their_intervals(df):
    """paris-additive (one fixed shape), the regression and similarity baselines, fitted."""
    h = histories_from_frame(df)
    _check(fit_hi_noise(h, "additive", shape=0.0), h)
    _check(fit_regression(h, shape=0.0, window=5.0), h)
    _check(fit_similarity(h, window=5.0, temperature=10.0, bandwidth=0.2), h)


@settings(max_examples=25, deadline=None)
@given(fleets())
def test_safe_tracker_rul_never_negative(df):
    h = histories_from_frame(df)
    cfg = TrackerConfig.safe(dt=5.0, lambda_hi=0.5, lambda_rul=0.5, design_life=1e4)
    for u in range(h.n_units):
        s = h.rows(u)
        out = track_series(h.t[s], h.hi[s][:, None], cfg)
        assert (out["frul"] >= 0).all()
        assert (out["rul_low"] >= 0).all() and (out["rul_high"] >= 0).all()
