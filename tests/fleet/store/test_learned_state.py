"""Every candidate's state in the component database: track writes what the model says at
each acquisition (the model's own replay is the oracle), at ages on the stored time axis."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.learned.datasets import synthetic_growth_fleet
from rulkit.fleet.learned.hi_noise import HiNoiseModel
from rulkit.fleet.learned.histories import histories_from_frame
from rulkit.fleet.learned.onset import OnsetModel
from rulkit.fleet.learned.similarity import fit_similarity
from rulkit.fleet.store.database_file import StoreError
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.time_axis import TimeAxis

GROWTH = {"shape": 0.0, "mean": (-2.3, 1.5), "cov": (0.01, 0.0, 0.2), "hi_noise_sd": 0.02,
          "log_noise_sd": 0.0, "walk_sd": 0.05, "time_scale": 300.0}


@pytest.fixture(scope="module")
def fleet():
    df, _ = synthetic_growth_fleet(np.random.default_rng(0), 6, n_acq=12)
    return df


def _model(fleet, axis, k):
    if k == 0:
        m = HiNoiseModel(noise="additive", **GROWTH)
    elif k == 1:
        m = OnsetModel(noise="additive", grid=(0.0, 0.5, 1.0), onset_mean=0.4, onset_sd=0.3,
                       **GROWTH)
    else:
        m = fit_similarity(histories_from_frame(fleet), window=5.0, temperature=10.0,
                           bandwidth=0.2)
    return replace(m, time_axis=axis.to_dict(), time_unit=axis.unit)


@pytest.mark.parametrize("k", [0, 1, 2])
@pytest.mark.parametrize("origin", ["time", "first"])
def test_track_writes_the_models_own_quantiles(fleet, tmp_path, k, origin):
    axis = TimeAxis(unit="d", origin=origin)
    model = _model(fleet, axis, k)
    acq = fleet.assign(time=fleet["time"] + 50.0)  # ages + 50: "first" must remove it
    half = acq.groupby("component").cumcount() < 6
    db = tmp_path / "m.db"
    with ComponentStore(db) as s:
        assert s.set_degradation_model(model) == 0
        s.ingest(acq[half])
    with ComponentStore(db) as s:  # opened again: the schema keeps the model's own columns
        s.ingest(acq[~half])  # a second batch continues the stored states
        got = s.history()
        cols = [r[1] for r in s._conn.execute("PRAGMA table_info(model_state)")]
    assert cols == ["component", "t0", *model.state_columns]
    h = histories_from_frame(acq, axis=axis)
    med, lo, hi = model.rul_quantiles(model.replay(h))
    ref = pd.DataFrame({"component": h.names[h.unit], "median": med, "low": lo, "high": hi})
    ref = ref.assign(t=h.raw_time).sort_values(["component", "t"]).reset_index(drop=True)
    # the same state to ~1e-12; the closed-form roots amplify the last digits (rtol 1e-7)
    np.testing.assert_allclose(got["rul_median"], ref["median"], rtol=1e-7)
    np.testing.assert_allclose(got["rul_low"], ref["low"], rtol=1e-7)
    np.testing.assert_allclose(got["rul_high"], ref["high"], rtol=1e-7)


def test_a_stored_history_is_replayed_into_a_new_model(fleet, tmp_path):
    axis = TimeAxis(unit="d", origin="first")
    db = tmp_path / "r.db"
    with ComponentStore(db) as s:
        s.ingest(fleet)
        model = _model(fleet, axis, 1)
        assert s.set_degradation_model(model) == 6
        n = s._conn.execute("SELECT COUNT(*) FROM model_state").fetchone()[0]
    assert n == 6


def test_the_time_axis_of_stored_components_cannot_change(fleet, tmp_path):
    db = tmp_path / "a.db"
    first = _model(fleet, TimeAxis(unit="d", origin="first"), 0)
    with ComponentStore(db) as s:
        s.set_degradation_model(first)
        s.ingest(fleet)
        other = replace(first, time_axis=TimeAxis(unit="d").to_dict())
        with pytest.raises(StoreError, match="whose times were read as"):
            s.set_degradation_model(other)
    legacy = tmp_path / "legacy.db"
    with ComponentStore(legacy) as s:
        s.ingest(fleet)
        stamps = replace(first, time_axis=TimeAxis(unit="h", timestamps=True,
                                                   origin="first").to_dict())
        with pytest.raises(StoreError, match="before a time axis was stored"):
            s.set_degradation_model(stamps)
