"""Leave-one-unit-out predictions: the all-unit fit they start from may be given."""

import numpy as np
import pandas as pd

from rulkit.fleet.learned import candidates
from rulkit.fleet.learned.datasets import synthetic_growth_fleet
from rulkit.fleet.learned.evaluate import predictions
from rulkit.fleet.learned.histories import histories_from_frame


def test_predictions_from_a_given_all_unit_fit_equal_those_that_fit_it(monkeypatch):
    """Given the fit on all units, the folds start from it (the same predictions to the bit)
    and it is not fitted again (one fit per fold only)."""
    df, _ = synthetic_growth_fleet(np.random.default_rng(4), 8, n_acq=10, h0=0.2)
    hist = histories_from_frame(df, "fleet")
    kinds = ("paris-additive",)
    full = candidates.fit_candidate("paris-additive", hist)
    fit = candidates.fit_candidate
    calls = []
    monkeypatch.setattr(candidates, "fit_candidate",
                        lambda *a, **k: calls.append(k.get("start")) or fit(*a, **k))
    own = predictions(hist, kinds, folds=3)
    assert len(calls) == 4 and calls[0] is None  # the fit on all units, then 3 folds
    calls.clear()
    given = predictions(hist, kinds, folds=3, fitted={"paris-additive": full})
    assert len(calls) == 3 and all(c is full for c in calls)
    pd.testing.assert_frame_equal(own, given, check_exact=True)
    assert np.isfinite(own["paris-additive"]).any()
