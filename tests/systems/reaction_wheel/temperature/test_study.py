"""The Table 5 study's additions at a small size: every weighting in both designs, and the
measured effect of eq. 28 on the weights (a compression, with clipped weights)."""

from __future__ import annotations

import numpy as np
import pytest

from rulkit.systems.reaction_wheel.temperature.study import (
    SEED_VARIANTS,
    eq28_weight_analysis,
    run_seed_filters,
)


@pytest.mark.slow  # 20 filter runs of the 500 s path; the tiny golden reproduction runs it too
def test_every_weighting_in_both_designs() -> None:
    t = run_seed_filters(1, 2, (20,))
    got = set(zip(t["method"], t["design"], strict=True))
    assert got == {(v, d) for v in SEED_VARIANTS for d in ("F1", "F2")}
    assert np.isfinite(t["rmspe_mean"]).all() and t["cover_mean"].between(0, 1).all()


def test_eq28_compresses_the_weights_that_bayes_spreads() -> None:
    e = eq28_weight_analysis(seed=0, n_particles=60, t_end=15.0)
    assert list(e["noise"]) == ["low", "high"]
    assert (e["log10_weight_ratio_eq28"] < e["log10_weight_ratio_bayes"]).all()
    assert (e["clipped_fraction_eq28"] > 0).all()
