"""Selection picks the generating model on clearly separated synthetic fleets."""

from __future__ import annotations

import numpy as np
import pytest

from rulkit.fleet.learned.datasets import synthetic_growth_fleet
from rulkit.fleet.learned.histories import histories_from_frame
from rulkit.fleet.learned.selection import fold_groups, select_model


def _fleet(seed, **kw):
    df, _ = synthetic_growth_fleet(np.random.default_rng(seed), 16, n_acq=20, **kw)
    return histories_from_frame(df)


@pytest.mark.parametrize(("fleet", "truth"), [
    ({"noise": "additive", "m": 2.0, "h0": 0.1, "hi_noise_sd": 0.03}, "paris-additive"),
    ({"noise": "multiplicative", "m": 3.0, "h0": 0.2, "log_noise_sd": 0.15},
     "paris-multiplicative"),
])
def test_picks_the_noise_scale_that_generated_the_fleet(fleet, truth):
    names = ("paris-additive", "paris-multiplicative")
    sel = select_model(_fleet(1, **fleet), names, folds=4)
    assert sel.chosen == truth
    t = sel.table()
    assert tuple(t["candidate"]) == names
    assert (t["chosen"] == "<- chosen").sum() == 1
    assert np.isfinite(t["heldout_coverage_90"]).all()


@pytest.mark.slow
def test_picks_the_onset_model_on_an_onset_fleet():
    h = _fleet(2, noise="additive", m=2.0, h0=0.1, hi_noise_sd=0.02, onset_frac=0.6)
    assert select_model(h, ("paris-additive", "onset"), folds=4).chosen == "onset"


def test_folds_deal_failed_units_by_failure_time():
    h = _fleet(3, noise="additive")
    groups = fold_groups(h, 3)
    assert sorted(u for g in groups for u in g) == sorted(np.flatnonzero(h.failed))
    tf = h.failure_time()
    firsts = [tf[g[0]] for g in groups]
    assert firsts == sorted(firsts)  # the 3 shortest lives open the 3 folds
    assert len(fold_groups(h, 0)) == int(h.failed.sum())


def test_a_candidate_that_cannot_be_fitted_stays_in_the_table():
    h = _fleet(4, noise="additive")
    one = h.select([int(np.flatnonzero(h.failed)[0]), *np.flatnonzero(~h.failed)])
    sel = select_model(one, ("regression", "similarity"), folds=2)
    t = sel.table().set_index("candidate")
    assert sel.chosen == "regression"
    assert "not fitted" in t.loc["similarity", "chosen"]
