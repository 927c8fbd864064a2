"""Property: no RUL output is negative while the component is unfailed (issue 11).

Random histories with irregular sampling and sparse units (3 acquisitions), for the learned
models (median and 90 % interval) and the safe tracker chain (filtered RUL and limits).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rulkit.fleet.learned.degradation import filtered_states, fit_model
from rulkit.fleet.learned.histories import histories_from_frame
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
