"""Prediction scores (docs/fleet-models.md section 5, eq. (13))."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from rulkit.fleet.learned.scoring import crps_grid, score
from rulkit.metrics import crps_normal


class _Normal:
    """A stand-in model whose RUL is N(mu, sd^2) (for the CRPS oracle)."""

    def __init__(self, mu, sd):
        self.mu, self.sd = np.asarray(mu), np.asarray(sd)

    def rul_cdf(self, state, r):
        return stats.norm.cdf(r, self.mu[:, None], self.sd[:, None])


class _State(list):
    pass


def test_crps_grid_equals_the_closed_form_of_a_normal():
    mu, sd, y = np.array([50.0, 80.0]), np.array([5.0, 12.0]), np.array([47.0, 100.0])
    got = crps_grid(_Normal(mu, sd), _State([0, 1]), y, cap=400.0, n_grid=2000)
    np.testing.assert_allclose(got, crps_normal(mu, sd, y), rtol=1e-3)  # trapezoid, O(h^2)


def test_score_uses_the_last_half_of_life():
    t = np.array([0.0, 40.0, 60.0, 90.0])
    pred = pd.DataFrame({"t": t, "t_first": 0.0, "t_fail": 100.0, "true_rul": 100.0 - t,
                         "median": [10.0, 60.0, 44.0, 10.0], "low": [0, 50, 30, 20],
                         "high": [20, 70, 50, 30], "crps": [1.0, 2.0, 3.0, 5.0]})
    s = score(pred)
    assert s.n_late == 2  # t >= 50
    assert s.median_rel_err == pytest.approx(np.median([0.1, 0.0]))
    assert s.coverage_90 == 0.5 and s.score == pytest.approx(0.04)
