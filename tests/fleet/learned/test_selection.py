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


def _result(name, crps, loglik):
    """A scored candidate whose held-out predictions have the per-unit CRPS ``crps`` (one
    late prediction per unit, life 1)."""
    import pandas as pd

    from rulkit.fleet.learned.scoring import Scores
    from rulkit.fleet.learned.selection import CandidateResult

    n = len(crps)
    pred = pd.DataFrame({"unit": np.arange(n), "t": 0.9, "t_first": 0.0, "t_fail": 1.0,
                         "true_rul": 0.1, "crps": crps})
    scores = Scores(median_rel_err=0.1, coverage_90=0.9, score=float(np.mean(crps)), n_late=n)
    return CandidateResult(name, object(), scores, 0.0, heldout_loglik=loglik), pred


@pytest.mark.parametrize(("offsets", "logliks", "chosen", "reason"), [
    # b is far worse on every unit: the score decides, whatever the likelihoods
    ((0.0, 0.5), (1.0, 9.0), "a", "the lowest held-out score; no other"),
    # b ties a on score (noisy, unit by unit): the better likelihood decides
    (None, (1.0, 9.0), "b", "the best held-out likelihood of the 2 growth models among the 2"),
    # a tie with a baseline without a likelihood: the one growth model
    (None, (1.0, float("nan")), "a", "the one growth model among the 2"),
])
def test_choose_says_what_decided(offsets, logliks, chosen, reason):
    from rulkit.fleet.learned.selection import choose

    rng = np.random.default_rng(0)
    base = rng.uniform(0.1, 0.2, 12)
    if offsets is None:  # b within noise of a, its mean a little higher: a is the best score
        noise = rng.normal(0.0, 0.05, 12)
        other = base + noise - noise.mean() + 1e-3
    else:
        other = base + offsets[1]
    (ra, pa), (rb, pb) = _result("a", base, logliks[0]), _result("b", other, logliks[1])
    name, why = choose([ra, rb], {"a": pa, "b": pb})
    assert name == chosen and why.startswith(reason), why
