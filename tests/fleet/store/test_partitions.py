"""rulkit track over a directory of Parquet partitions: on Dask workers as serially."""

import sqlite3

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from rulkit.cli import app
from rulkit.fleet.learned.onset import OnsetModel
from rulkit.fleet.monitoring.rules import MonitoringRules
from rulkit.fleet.store.acquisitions import IngestError
from rulkit.fleet.store.ingest import ingest_into
from rulkit.fleet.store.partitions import track_directory
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.tracking.tracker_chain import TrackerConfig

CFG = TrackerConfig(dt=1.0, lambda_hi=0.5, lambda_rul=0.5, design_life=1e4, warn_rul=40.0)


def fleet(n_comp=40, steps=60, seed=0):
    rng = np.random.default_rng(seed)
    rate = rng.uniform(0.005, 0.03, n_comp)
    t = np.arange(steps, dtype=float)
    hi = 0.3 * np.exp(np.outer(rate, t)) + rng.normal(0, 2e-3, (n_comp, steps))
    return pd.DataFrame({"component": np.repeat([f"u{i:03d}" for i in range(n_comp)], steps),
                         "time": np.tile(t, n_comp), "hi": hi.ravel()})


def partitions(df, d, k=3):
    """Time-sliced partitions: every component spans every file."""
    d.mkdir()
    edges = np.linspace(df.time.min(), df.time.max() + 1, k + 1)
    for i in range(k):
        part = df[(df.time >= edges[i]) & (df.time < edges[i + 1])]
        part.to_parquet(d / f"part-{i}.parquet", index=False)
    return d


def tables(db):
    with ComponentStore(db, readonly=True) as store:  # every acquisition, decoded
        history = store.history().drop(columns="ingest")
    con = sqlite3.connect(db)
    out = {
        "history": history,
        # seen: the calendar time of the ingestion (each run has its own)
        "components": pd.read_sql("SELECT * FROM components ORDER BY component", con)
        .drop(columns="seen"),
        "alerts": pd.read_sql("SELECT component, t, level, previous, hi, fhi, frul, valid, "
                              "rul_low, rul_high FROM alerts ORDER BY component, t", con),
        "level_counts": pd.read_sql("SELECT level, n FROM level_counts WHERE n > 0 ORDER BY "
                                    "level", con)}
    counted = pd.read_sql("SELECT level, COUNT(*) AS n FROM components GROUP BY level "
                          "ORDER BY level", con)
    con.close()
    pd.testing.assert_frame_equal(out["level_counts"], counted)  # kept by every write
    return out


@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as lc, distributed.Client(lc) as c:
        yield c


def test_dask_run_stores_what_the_serial_run_stores(tmp_path, cluster):
    df = fleet()
    first, rest = df[df.time < 20], df[df.time >= 20]
    d = partitions(rest, tmp_path / "parts")
    for name, scheduler in (("serial", None), ("dask", cluster)):
        db = tmp_path / f"{name}.db"
        ingest_into(db, first, config=CFG)  # stored state the partitions continue from
        res, created = track_directory(db, d, config=CFG, scheduler=scheduler, buckets=5)
        assert not created and res.n_rows == len(rest) and res.n_components == 40
    serial, dask = tables(tmp_path / "serial.db"), tables(tmp_path / "dask.db")
    assert len(serial["alerts"]) > 0
    for t in serial:
        pd.testing.assert_frame_equal(dask[t], serial[t], check_exact=True)
    # re-running is a no-op: every row already stored
    res, _ = track_directory(tmp_path / "dask.db", d, config=CFG, scheduler=cluster)
    assert res.n_rows == 0 and res.n_duplicates == len(rest)
    # a new database (the buckets become it) as the serial run makes it
    for name, scheduler in (("new-serial", None), ("new-dask", cluster)):
        res, created = track_directory(tmp_path / f"{name}.db", d, config=CFG,
                                       scheduler=scheduler)
        assert created and res.n_rows == len(rest) and res.n_new_components == 40
    serial, dask = tables(tmp_path / "new-serial.db"), tables(tmp_path / "new-dask.db")
    for t in serial:
        pd.testing.assert_frame_equal(dask[t], serial[t], check_exact=True)


def test_a_learned_models_own_state_columns_come_back_from_the_buckets(tmp_path, cluster):
    # the onset mixture's state columns (weights and Gaussians per onset) differ from the
    # growth models': the buckets' databases and the merge take the stored model's columns
    model = OnsetModel(noise="additive", grid=(0.0, 10.0, 20.0), onset_mean=10.0, onset_sd=8.0,
                       shape=0.0, mean=(-2.3, 1.5), cov=(0.01, 0.0, 0.2), hi_noise_sd=0.02,
                       log_noise_sd=0.0, walk_sd=0.05, time_scale=60.0)
    df = fleet(n_comp=12, steps=30)
    first, rest = df[df.time < 10], df[df.time >= 10]
    d = partitions(rest, tmp_path / "parts")
    got = {}
    for name, scheduler in (("serial", None), ("dask", cluster)):
        db = tmp_path / f"{name}.db"
        ingest_into(db, first, config=CFG)
        with ComponentStore(db) as s:
            assert s.set_degradation_model(model) == 12
        track_directory(db, d, config=CFG, scheduler=scheduler, buckets=3)
        con = sqlite3.connect(db)
        got[name] = {**tables(db), "model_state": pd.read_sql(
            "SELECT * FROM model_state ORDER BY component", con)}
        con.close()
    assert list(got["dask"]["model_state"].columns) == ["component", "t0",
                                                        *model.state_columns]
    assert got["serial"]["history"]["rul_median"].notna().all()
    for t in got["serial"]:
        pd.testing.assert_frame_equal(got["dask"][t], got["serial"][t], check_exact=True)


def test_the_alert_rules_reach_the_dask_buckets(tmp_path, cluster):
    """Rules given to track_directory (as rulkit track --alarm-hi ... passes them) rule the
    buckets as they rule the serial run: on a new database and when they replace the stored
    ones; other rules than the defaults change the levels, so a bucket that ran the defaults
    would differ."""
    df = fleet(n_comp=12, steps=40)
    first, rest = df[df.time < 20], df[df.time >= 20]
    d = partitions(rest, tmp_path / "parts")
    rules = MonitoringRules(alarm_hi=0.45, alarm_hits=2, alarm_window=3, lead_time=15.0)
    for name, scheduler in (("serial", None), ("dask", cluster)):
        ingest_into(tmp_path / f"{name}.db", first, config=CFG)  # stored with the defaults
        for db in (tmp_path / f"{name}.db", tmp_path / f"new-{name}.db"):
            track_directory(db, d, config=CFG, scheduler=scheduler, buckets=3, rules=rules)
            with ComponentStore(db, readonly=True) as s:
                assert s.rules == rules
    default = tmp_path / "default.db"
    track_directory(default, d, config=CFG, scheduler=cluster, buckets=3)
    for prefix in ("", "new-"):
        serial, dask = (tables(tmp_path / f"{prefix}{n}.db") for n in ("serial", "dask"))
        for t in serial:
            pd.testing.assert_frame_equal(dask[t], serial[t], check_exact=True)
    assert not tables(default)["components"]["level"].equals(
        tables(tmp_path / "new-dask.db")["components"]["level"])


def test_a_bad_partition_writes_and_creates_nothing(tmp_path, cluster):
    df = fleet(n_comp=6, steps=10)
    df.loc[25, "hi"] = np.nan
    d = partitions(df, tmp_path / "bad")
    with pytest.raises(IngestError, match="NaN"):
        track_directory(tmp_path / "b.db", d, config=CFG, scheduler=cluster)
    assert not (tmp_path / "b.db").exists()


@pytest.mark.parametrize("ids", [
    ["u1", "u1", None, "u2", "u2", "u2"],  # a missing id
    [1, 1, 1, 2, 2, 2],  # numbers, taken as their text
    ["u1", " u1", "u1 ", "u2", "u2 ", "u2"],  # one component, written with blanks
    [b"u1", b"u1", b"u1", b"\xff", b"u2", b"u2"],  # bytes: refused
], ids=["null", "numbers", "blanks", "bytes"])
def test_dask_reads_the_ids_as_the_serial_run(tmp_path, cluster, ids):
    """The buckets split the components by the ids the ingestion stores (stripped, numbers as
    text) and refuse the ids it refuses, with its message and row."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    d = tmp_path / "p"
    d.mkdir()
    t = np.arange(6.0)
    pq.write_table(pa.table({"component": pa.array(ids), "time": t, "hi": 0.3 + 0.01 * t}),
                   d / "p0.parquet")
    got = {}
    for name, scheduler in (("serial", None), ("dask", cluster)):
        try:
            res, _ = track_directory(tmp_path / f"{name}.db", d, config=CFG,
                                     scheduler=scheduler, buckets=2)
            got[name] = (res.n_rows, res.n_components, tables(tmp_path / f"{name}.db"))
        except IngestError as err:
            got[name] = (type(err), str(err))
            assert not (tmp_path / f"{name}.db").exists()
    if isinstance(got["serial"][0], type):
        assert got["dask"] == got["serial"]
    else:
        assert got["dask"][:2] == got["serial"][:2]
        for t in got["serial"][2]:
            pd.testing.assert_frame_equal(got["dask"][2][t], got["serial"][2][t],
                                          check_exact=True)


def test_track_command_takes_a_directory(tmp_path):
    d = partitions(fleet(n_comp=5, steps=12), tmp_path / "p")
    r = CliRunner().invoke(app, ["track", "--db", str(tmp_path / "c.db"), str(d)])
    assert r.exit_code == 0, r.output
    assert "ingested 60 acquisitions of 5 components" in r.output
