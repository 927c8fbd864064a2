"""The compiled export against Python: the database `rulkit track` writes (double, to a
relative 1e-12), the number formats within their bounds over long records, one run under the
sanitizers."""

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.export.device_spec import DeviceSpec, spec_from_database
from rulkit.fleet.export.verify import (
    build,
    long_record_case,
    python_reference,
    relative_error,
    run_sanitized,
    scaled_error,
    segments,
)
from rulkit.fleet.learned.datasets import (
    fatigue_histories,
    synthetic_linear_fleet,
    synthetic_paris_fleet,
)
from rulkit.fleet.learned.degradation import fit_model
from rulkit.fleet.learned.histories import histories_from_frame
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.tracking.health_index import HealthIndexModel
from rulkit.fleet.tracking.tracker_chain import TrackerConfig
from rulkit.fleet.tracking.tracker_settings import fit_tracker_config

REAL = ("fhi", "dhi", "rul", "frul", "drul", "d2rul")


def _fleet(name):
    if name == "fatigue":
        return fatigue_histories().to_frame().drop(columns="failed")
    rng = np.random.default_rng(3)
    gen = synthetic_paris_fleet if name == "paris" else synthetic_linear_fleet
    return gen(rng, 12)[0]


# (fleet, learned kind, fixed shape: skips the profile-likelihood grid; the export does not
# care how the model was fitted)
CASES = [("fatigue", "paris", -1.5), ("fatigue", "exponential", 0.0),
         ("paris", "paris", -0.5), ("linear", "linear", 0.0)]


def _database(tmp_path, frame, kind, shape, config):
    hist = histories_from_frame(frame, "test")
    db = tmp_path / "fleet.db"
    with ComponentStore(db, config=config) as store:
        if kind is not None:
            store.set_degradation_model(fit_model(hist, kind, shape=shape))
        res = store.ingest(frame)
    return db, res


def _history(db):
    with ComponentStore(db, readonly=True) as store:
        return store.history()


@pytest.mark.parametrize(("fleet", "kind", "shape"), CASES)
def test_double_equals_the_database_rulkit_track_wrote(cc, tmp_path, fleet, kind, shape):
    frame = _fleet(fleet)
    config = fit_tracker_config(histories_from_frame(frame, "test"))
    db, res = _database(tmp_path, frame, kind, shape, config)
    spec = spec_from_database(db)
    assert spec.learned is not None and spec.learned.kind == kind
    hist = _history(db)
    start, df = segments(hist.rename(columns={"t": "time"}))
    lib = build(spec, tmp_path / "c")
    got = lib.run(start, df["time"], df["hi"], through_bytes=True)
    assert (got["status"] == 0).all()
    for col in REAL:
        assert relative_error(got[col], df[col]).max() <= 1e-12, col
    np.testing.assert_array_equal(got["valid"], df["valid"])
    # the tracker's own confidence limits and alert levels (the history holds the learned
    # interval and the store's alert rules, docs/systems/embedded-rul.md section 7, instead)
    ref = python_reference(spec, start, df["time"].to_numpy(), df["hi"].to_numpy())
    # the learned RUL (eq. (5b), the server's first measured crossing) against Python's and
    # the database's (its median and interval in rul_median, rul_low, rul_high); tolerance:
    # tests/fleet/export/test_learned_device.py
    for col, db_col in (("rul_median", "rul_median"), ("rul_p05", "rul_low"),
                        ("rul_p95", "rul_high")):
        assert relative_error(got[col], ref[col]).max() <= 1e-6, col
        assert relative_error(got[col], df[db_col]).max() <= 1e-6, col
    for col in ("rul_low", "rul_high"):
        assert relative_error(got[col], ref[col]).max() <= 1e-12, col
    np.testing.assert_array_equal(got["level"], ref["level"])
    np.testing.assert_array_equal(got["new_alert"], ref["new_alert"])
    assert res.alerts and ref["new_alert"].sum() > 0  # every fleet runs to failure


def _ci_fleet(rng, n_units=6, n_acq=60, n_ci=3):
    """CIs whose healthy part is correlated Rayleigh and whose degradation grows."""
    mix = np.array([[1.0, 0.0, 0.0], [0.6, 0.8, 0.0], [0.3, 0.2, 0.9]])[:n_ci, :n_ci]
    base = rng.rayleigh(size=(2000, n_ci)) @ mix.T
    rows = []
    for u in range(n_units):
        t = np.arange(1.0, n_acq + 1)
        growth = 0.02 * np.exp(rng.uniform(0.03, 0.08) * t)
        ci = rng.rayleigh(size=(n_acq, n_ci)) @ mix.T + growth[:, None]
        rows.append(pd.DataFrame({"component": f"b{u}", "time": t,
                                  **{f"ci{j + 1}": ci[:, j] for j in range(n_ci)}}))
    return base, pd.concat(rows, ignore_index=True)


def test_double_from_condition_indicators(cc, tmp_path):
    rng = np.random.default_rng(5)
    base, frame = _ci_fleet(rng)
    hi_model = HealthIndexModel.fit(base, pfa=1e-3)
    db = tmp_path / "ci.db"
    with ComponentStore(db, config=TrackerConfig.safe(hi_sigma=0.02), hi_model=hi_model) as st:
        st.ingest(frame)
    spec = spec_from_database(db)
    assert spec.hi_model is not None and spec.learned is None
    hist = _history(db)
    start, df = segments(frame)
    lib = build(spec, tmp_path / "c")
    got = lib.run(start, df["time"], df[["ci1", "ci2", "ci3"]].to_numpy())
    ref = hist.sort_values(["component", "t"]).reset_index(drop=True)
    assert relative_error(got["hi"], ref["hi"]).max() <= 1e-12
    for col in ("fhi", "dhi", "rul", "frul"):
        assert relative_error(got[col], ref[col]).max() <= 1e-12, col
    # the chain's limits and levels against the Python chain (the database holds the store's
    # RUL interval and alert rules, docs/systems/embedded-rul.md sections 6-7)
    py = python_reference(spec, start, df["time"].to_numpy(), ref["hi"].to_numpy())
    for col in ("rul_low", "rul_high"):
        assert relative_error(got[col], py[col]).max() <= 1e-12, col
    np.testing.assert_array_equal(got["level"], py["level"])
    assert py["level"].max() >= 1  # the comparison covers alerts


def _near_threshold(ref, cfg, rows, tol):
    """Rows where a flag may differ: the reference lies within tol of a decision threshold."""
    lo, hi = cfg.valid_drul
    def near(x, level, scale):
        return np.abs(x - level) <= tol * scale
    drul_s = np.max(np.abs(ref["drul"]))
    d2_s = np.max(np.abs(ref["d2rul"]))
    return (near(ref["drul"], lo, drul_s) | near(ref["drul"], hi, drul_s)
            | near(np.abs(ref["d2rul"]), cfg.valid_d2rul, d2_s) | near(ref["fhi"], cfg.warn_hi, 1)
            | near(ref["fhi"], cfg.alarm_hi, 1)
            | near(ref["frul"], cfg.warn_rul, np.max(np.abs(ref["frul"]))))[rows]


@pytest.mark.parametrize("number", ["float", "fixed"])
def test_number_formats_within_their_bounds_over_long_records(cc, tmp_path, number):
    from rulkit.fleet.export.verify import ERROR_BOUNDS

    spec, start, t, hi = long_record_case()
    cfg = spec.config
    if number == "fixed":
        spec = DeviceSpec("long", "test", cfg)
    ref = python_reference(spec, start, t, hi)
    got = build(spec, tmp_path / number, number).run(start, t, hi, through_bytes=True)
    assert (got["status"] == 0).all()
    bounds = ERROR_BOUNDS[number]
    for col, bound in bounds.items():
        if col in ref:
            assert scaled_error(got[col], ref[col]) <= bound, col
    for flag in ("valid", "level"):
        bad = np.flatnonzero(got[flag] != ref[flag])
        assert _near_threshold(ref, cfg, bad, 10 * bounds["frul"]).all(), flag
    assert ref["level"].max() == 2  # the records reach the alarm


def test_one_run_under_the_sanitizers(cc, tmp_path):
    frame = _fleet("fatigue")
    hist = histories_from_frame(frame, "test")
    spec = DeviceSpec("crack", "test", fit_tracker_config(hist), None,
                      fit_model(hist, "paris", shape=-1.5))
    start, df = segments(frame)
    ref = build(spec, tmp_path / "lib").run(start, df["time"], df["hi"])
    got = run_sanitized(spec, tmp_path / "san", start, df["time"], df["hi"])
    for col in ref:
        np.testing.assert_array_equal(got[col], ref[col])
