"""Similarity baseline (docs/fleet-models.md eq. (12)) against direct residual sums."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.learned.histories import histories_from_frame
from rulkit.fleet.learned.similarity import SimilarityModel, fit_similarity, library


def _hist(rng, n_units=6):
    rows = []
    for u in range(n_units):
        life = rng.uniform(80, 120)
        t = np.sort(rng.uniform(1, life, 10))
        hi = 0.2 + 0.8 * (t / life) ** 2 + 0.01 * rng.standard_normal(t.size)
        if u % 2 == 0:
            t, hi = np.append(t, life * 1.01), np.append(hi, 1.01)
        rows.append(pd.DataFrame({"component": f"u{u}", "time": t, "hi": hi}))
    return histories_from_frame(pd.concat(rows, ignore_index=True))


def test_distances_equal_direct_weighted_residuals():
    h = _hist(np.random.default_rng(0))
    coefs, lives, var = library(h, 100.0)
    m = SimilarityModel(coefs=tuple(coefs.ravel()), lives=tuple(lives), noise_var=var,
                        time_scale=100.0, window=5.0, temperature=1.0)
    st = m.replay(h)
    u = 1  # a censored unit
    sl = h.rows(u)
    last = np.array([sl.stop - 1])
    logw, rem = m.neighbours(st.take(last))
    x, hh = h.t[sl] / 100.0, h.hi[sl]
    w = (1 - 1 / 5.0) ** (x.size - 1 - np.arange(x.size))
    d = np.array([np.sum(w * (hh - np.polyval(c[::-1], x)) ** 2) / w.sum() for c in coefs])
    ref = -0.5 * w.sum() * d / var
    alive = lives > x[-1]
    ref = np.where(alive, ref, -np.inf)
    ref -= np.log(np.exp(ref - ref.max()).sum()) + ref.max()
    np.testing.assert_allclose(logw[0], ref, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(rem[0][alive], (lives[alive] - x[-1]) * 100.0, rtol=1e-12)


def test_quantiles_invert_the_cdf_and_round_trip():
    h = _hist(np.random.default_rng(1))
    m = fit_similarity(h, window=5.0, temperature=10.0, bandwidth=0.2)
    st = m.replay(h)
    med, lo, hi = m.rul_quantiles(st)
    ok = h.hi < 1.0
    f = m.rul_cdf(st.take(ok), np.column_stack([lo[ok], med[ok], hi[ok]]))
    np.testing.assert_allclose(f, np.tile([0.05, 0.5, 0.95], (ok.sum(), 1)), atol=1e-6)
    assert (med[~ok] == 0).all()
    assert SimilarityModel.from_dict(m.to_dict()) == m
    assert len(m.without(0).lives) == len(m.lives) - 1
    back = m.state_from_columns(st.columns())
    np.testing.assert_array_equal(back.s, st.s)


def test_fit_refuses_a_library_without_failed_units():
    h = _hist(np.random.default_rng(2))
    with pytest.raises(ValueError, match="no failed unit"):
        fit_similarity(h.select([1, 3, 5]))
