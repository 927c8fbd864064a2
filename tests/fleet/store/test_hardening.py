"""Issue 13, store items: nothing created on rejection (3), atomic creation and busy writers
(4), foreign files never modified (5), component ids (2), time columns, NA ids and duplicated
columns (1). Each test failed on the code before the fix."""

import hashlib
import json
import sqlite3
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from rulkit.cli import app
from rulkit.fleet.rows import COMPONENT_ID_MAX_LEN
from rulkit.fleet.store.acquisitions import (
    ComponentIdError,
    IngestError,
    read_acquisitions,
)
from rulkit.fleet.store.database_file import StoreBusyError, StoreError
from rulkit.fleet.store.ingest import ingest_into
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.tracking.tracker_chain import TrackerConfig

runner = CliRunner()


def acq(comps=("a", "b"), t0=0.0, n=5, hi=0.3):
    rows = [(c, t0 + k, hi) for c in comps for k in range(n)]
    return pd.DataFrame(rows, columns=["component", "time", "hi"])


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def files(d):
    return sorted(p.name for p in d.iterdir())


# ------------------------------------------------------------------ item 3
def test_rejected_first_ingest_creates_nothing_and_retry_takes_new_settings(tmp_path):
    db = tmp_path / "f.db"
    bad = acq().assign(hi=[0.3] * 9 + [np.nan])
    bad.to_csv(tmp_path / "bad.csv", index=False)
    acq().to_csv(tmp_path / "good.csv", index=False)
    r = runner.invoke(app, ["track", "--db", str(db), str(tmp_path / "bad.csv"), "--dt", "2"])
    assert r.exit_code == 1 and "nothing was written" in r.output
    assert not db.exists()
    assert files(tmp_path) == ["bad.csv", "good.csv"]  # no -wal, -shm, temporary file
    # the corrected retry with other settings is accepted (they were not fixed by the failure)
    r = runner.invoke(app, ["track", "--db", str(db), str(tmp_path / "good.csv"), "--dt", "1"])
    assert r.exit_code == 0, r.output
    with ComponentStore(db, readonly=True) as s:
        assert s.config.dt == 1.0


def test_rejected_ingest_does_not_store_the_baseline_model(tmp_path):
    rng = np.random.default_rng(0)
    pd.DataFrame(rng.rayleigh(1.0, (200, 2)), columns=["so1", "so2"]).to_csv(
        tmp_path / "healthy.csv", index=False)
    pd.DataFrame({"component": ["a", "a"], "time": [0.0, 1.0], "so1": [1.0, "x"],
                  "so2": [1.0, 1.0]}).to_csv(tmp_path / "ci.csv", index=False)
    db = tmp_path / "ci.db"
    r = runner.invoke(app, ["track", "--db", str(db), str(tmp_path / "ci.csv"),
                            "--baseline", str(tmp_path / "healthy.csv")])
    assert r.exit_code == 1 and "column 'so1', row 2" in r.output
    assert not db.exists()
    # an existing database without a model: a rejected batch leaves it without one
    acq().to_csv(tmp_path / "good.csv", index=False)
    assert runner.invoke(app, ["track", "--db", str(db), str(tmp_path / "good.csv")]
                         ).exit_code == 0
    before = digest(db)
    r = runner.invoke(app, ["track", "--db", str(db), str(tmp_path / "ci.csv"),
                            "--baseline", str(tmp_path / "healthy.csv")])
    assert r.exit_code == 1
    assert digest(db) == before
    with ComponentStore(db, readonly=True) as s:
        assert s.hi_model is None


# ------------------------------------------------------------------ item 4
# A writer that finds the database busy past its timeout is told "nothing was written,
# retry" (StoreBusyError): a legal outcome on a loaded machine, so the worker retries as a user
# would; how long a wait takes is not what this test is about. Anything else is a failure.
_WORKER = """
import json, sys
import pandas as pd
from rulkit.fleet.store.database_file import StoreBusyError
from rulkit.fleet.store.ingest import ingest_into
from rulkit.fleet.tracking.tracker_chain import TrackerConfig
db, k = sys.argv[1], int(sys.argv[2])
rows = [(f"p{k}-{i}", float(t), 0.3) for i in range(100) for t in range(10)]
df = pd.DataFrame(rows, columns=["component", "time", "hi"])
busy = 0
while True:
    try:
        res, created = ingest_into(db, df, config=TrackerConfig(dt=1.0), source=f"w{k}",
                                   timeout=5.0)
        print(json.dumps(["ok", bool(created), res.n_rows, busy]))
        break
    except StoreBusyError:
        busy += 1
    except Exception as err:
        print(json.dumps(["err", type(err).__name__, str(err)]))
        break
"""


def test_concurrent_first_ingests_create_one_complete_database(tmp_path):
    # Fresh interpreters, not fork: forking a test process that already runs threads (the
    # service tests' servers, pyarrow's pools) can deadlock a child.
    for trial in range(3):
        db = tmp_path / f"c{trial}.db"
        procs = [subprocess.Popen([sys.executable, "-c", _WORKER, str(db), str(k)],
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                 for k in range(4)]
        done = [p.communicate(timeout=600) for p in procs]  # a hang guard only
        out = [json.loads((o.strip().splitlines() or ["[\"no output\"]"])[-1])
               for o, _ in done]
        assert all(o[0] == "ok" for o in out), (out, [e[-2000:] for _, e in done])
        assert sum(o[1] for o in out) == 1  # exactly one process created the database
        with ComponentStore(db, readonly=True) as s:
            assert s.counts() == (400, 4000, 4000)
        assert not [f for f in files(tmp_path) if f.endswith(".creating")]


def test_busy_writer_gets_a_retryable_error_not_a_traceback(tmp_path):
    db = tmp_path / "b.db"
    ingest_into(db, acq())
    holder = sqlite3.connect(db, isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")  # another writer holds the lock
    try:
        t0 = time.monotonic()
        with pytest.raises(StoreBusyError, match=r"busy .* nothing was written, retry"):
            ingest_into(db, acq(t0=10), timeout=0.2)
        assert time.monotonic() - t0 < 10
        acq(t0=10).to_csv(tmp_path / "next.csv", index=False)
        r = runner.invoke(app, ["track", "--db", str(db), str(tmp_path / "next.csv"),
                                "--wait", "0.2"])
        assert r.exit_code == 75, r.output
        assert r.exception is None or isinstance(r.exception, SystemExit)
        assert "busy" in r.output and "retry" in r.output
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    res, _ = ingest_into(db, acq(t0=10))  # retried once the lock is free
    assert res.n_rows == 10


# ------------------------------------------------------------------ item 5
def _foreign_sqlite(path):
    con = sqlite3.connect(path)
    con.execute("CREATE TABLE t (x)")
    con.execute("INSERT INTO t VALUES (1)")
    con.commit()
    con.close()


@pytest.mark.parametrize("kind", ["foreign-sqlite", "empty", "csv"])
@pytest.mark.parametrize("command", ["status", "track"])
def test_commands_never_modify_a_file_that_is_not_a_rulkit_database(tmp_path, kind, command):
    db = tmp_path / "other.db"
    if kind == "foreign-sqlite":
        _foreign_sqlite(db)
    elif kind == "empty":
        db.write_bytes(b"")
    else:
        db.write_text("component,time,hi\na,0,0.1\n")
    before = digest(db)
    acq().to_csv(tmp_path / "a.csv", index=False)
    args = ["status", "--db", str(db)] if command == "status" else [
        "track", "--db", str(db), str(tmp_path / "a.csv")]
    r = runner.invoke(app, args)
    assert r.exit_code == 1, r.output
    assert "not a rulkit component database" in r.output
    assert str(db) in r.output
    assert digest(db) == before
    assert files(tmp_path) == ["a.csv", "other.db"]  # no -wal / -shm beside it


def test_status_opens_read_only(tmp_path):
    db = tmp_path / "s.db"
    ingest_into(db, acq())
    db.chmod(0o444)
    try:
        r = runner.invoke(app, ["status", "--db", str(db)])
        assert r.exit_code == 0, r.output
        with ComponentStore(db, readonly=True) as s, pytest.raises(StoreError):
            with s._transaction():
                s._conn.execute("DELETE FROM components")
    finally:
        db.chmod(0o644)


# ------------------------------------------------------------------ item 2
@pytest.mark.parametrize(
    ("cid", "message"),
    [
        ("\x1b[2J\x1b[HALARM gearA", r".*non-printable character \\x1b "),
        ("gear\nALARM forged", r".*non-printable character \\n "),
        ("a\u202eb", r".*non-printable character \\u202e "),
        ("x" * (COMPONENT_ID_MAX_LEN + 1), ".*129 characters, longer than the limit of 128"),
        ("   ", "empty component name"),
    ],
)
def test_component_ids_outside_the_alphabet_are_refused(tmp_path, cid, message):
    df = acq(comps=["ok1", cid, "ok2"], n=2)
    with pytest.raises(ComponentIdError, match=r"row 3: " + message):
        ingest_into(tmp_path / "i.db", df)
    assert not (tmp_path / "i.db").exists()
    # through the CLI: one escaped line, no control character reaches the terminal
    df.to_parquet(tmp_path / "ids.parquet")
    r = runner.invoke(app, ["track", "--db", str(tmp_path / "i.db"),
                            str(tmp_path / "ids.parquet")])
    assert r.exit_code == 1
    assert "\x1b" not in r.output and "\u202e" not in r.output
    assert len(r.output.strip().splitlines()) == 1


def test_longest_printable_ids_accepted_and_printed_escaped(tmp_path):
    cid = "ü-" + "x" * (COMPONENT_ID_MAX_LEN - 2)
    df = acq(comps=[cid, "bracket[bold]"], n=3)
    res, _ = ingest_into(tmp_path / "i.db", df)
    assert res.n_components == 2
    # rows written by another program are escaped on output, not trusted
    con = sqlite3.connect(tmp_path / "i.db")
    con.execute("UPDATE components SET component = ?, level = 2 WHERE component = ?",
                ("\x1b]0;pwned\x07evil\nALARM x", "bracket[bold]"))
    con.commit()
    con.close()
    r = runner.invoke(app, ["status", "--db", str(tmp_path / "i.db")])
    assert r.exit_code == 0, r.output
    assert "\x1b" not in r.output and "\x07" not in r.output
    assert "\\x1b]0;pwned\\x07evil\\nALARM x" in r.output


# ------------------------------------------------------------------ item 1 (track part)
def test_parquet_datetime_time_column_is_seconds_not_nanoseconds(tmp_path):
    t = pd.date_range("2024-01-01", periods=30, freq="h")  # hourly acquisitions
    df = pd.DataFrame({"component": "g", "time": t, "hi": np.linspace(0.2, 0.3, 30)})
    df.to_parquet(tmp_path / "dt.parquet")
    db = tmp_path / "dt.db"
    r = runner.invoke(app, ["track", "--db", str(db), str(tmp_path / "dt.parquet"),
                            "--dt", "3600", "--design-life", "3.6e8"])
    assert r.exit_code == 0, r.output
    assert "no new warnings or alarms" in r.output  # before: ALARM at the first acquisition
    with ComponentStore(db, readonly=True) as s:
        hist = s.history("g")
    np.testing.assert_allclose(hist["t"], (t - pd.Timestamp("1970-01-01")).total_seconds())
    # the same instants as ISO 8601 text in a CSV give the same times
    df.assign(time=t.strftime("%Y-%m-%dT%H:%M:%S")).to_csv(tmp_path / "dt.csv", index=False)
    # (design life in seconds: the default 1e5 is refused for hourly epoch seconds, issue 11)
    got = ingest_into(tmp_path / "dt2.db", read_acquisitions(tmp_path / "dt.csv"),
                      config=TrackerConfig(dt=3600, design_life=3.6e8))[0]
    assert got.n_rows == 30
    with ComponentStore(tmp_path / "dt2.db", readonly=True) as s:
        np.testing.assert_array_equal(s.history("g")["t"], hist["t"])


@pytest.mark.parametrize("ext", ["csv", "parquet"])
def test_na_and_none_ids_are_ids_in_csv_and_parquet_alike(tmp_path, ext):
    df = acq(comps=["NA", "None", "null", "007"], n=2)
    path = tmp_path / f"na.{ext}"
    df.to_csv(path, index=False) if ext == "csv" else df.to_parquet(path)
    res, _ = ingest_into(tmp_path / "na.db", read_acquisitions(path))
    assert res.n_components == 4
    with ComponentStore(tmp_path / "na.db", readonly=True) as s:
        assert sorted(s.status()["component"]) == ["007", "NA", "None", "null"]
    # an empty id cell is missing in both formats
    bad = df.assign(component=df["component"].where(df.index != 3, None))
    path2 = tmp_path / f"empty.{ext}"
    bad.to_csv(path2, index=False) if ext == "csv" else bad.to_parquet(path2)
    with pytest.raises(IngestError, match="row 4: empty component name"):
        ingest_into(tmp_path / "na2.db", read_acquisitions(path2))


def test_duplicated_column_names_are_refused(tmp_path):
    (tmp_path / "dup.csv").write_text("component,time,hi,hi\na,0,0.1,0.9\na,1,0.1,0.9\n")
    with pytest.raises(IngestError, match=r"column 'hi' appears twice .*columns 3 and 4"):
        read_acquisitions(tmp_path / "dup.csv")
    df = pd.DataFrame([["a", 0.0, 0.1, 0.9]], columns=["component", "time", "hi", "hi"])
    with pytest.raises(IngestError, match="column 'hi' appears twice"):
        ingest_into(tmp_path / "dup.db", df)
    assert not (tmp_path / "dup.db").exists()


def test_time_interval_overflowing_float64_names_row_and_column(tmp_path):
    # before: "ValueError: dt: must be finite" from inside the tracker, no file, no row
    df = pd.DataFrame({"component": "a", "time": [-1.7e308, 1.7e308, 1.71e308],
                       "hi": [0.2, 0.3, 0.4]})
    df.to_csv(tmp_path / "big.csv", index=False)
    r = runner.invoke(app, ["track", "--db", str(tmp_path / "big.db"), str(tmp_path / "big.csv")])
    assert r.exit_code == 1, r.output
    assert r.exception is None or isinstance(r.exception, SystemExit)
    assert "big.csv: row 2 (component 'a'), column 'time': the interval" in r.output
    assert not (tmp_path / "big.db").exists()


# ------------------------------------------------------------------ scale path
@pytest.mark.parametrize("chunk", [1, 7, 10_000])
def test_blocked_ingest_matches_the_direct_tracker_run(tmp_path, monkeypatch, chunk):
    """History written block by block in key order equals one vectorised run over the panel
    (tracker_update and trend_update on all components at once, the alert rules row by row),
    alerts in acquisition order."""
    from rulkit.fleet.monitoring.rules import MonitoringRules
    from rulkit.fleet.monitoring.unit_trend import (
        TrendConfig,
        TrendState,
        rul_quantiles,
        trend_posterior,
        trend_update,
    )
    from rulkit.fleet.tracking.tracker_chain import TrackerState, tracker_update

    monkeypatch.setattr(ComponentStore, "BLOCK_ROWS", chunk)
    monkeypatch.setattr(ComponentStore, "HISTORY_CHUNK", max(1, chunk // 3))
    rng = np.random.default_rng(7)
    names = ["zeta", "Alpha", "ä-unit", "b", "c10", "c9"]
    steps = [12, 5, 9, 1, 12, 7]
    rows = []
    for name, k in zip(names, steps, strict=True):
        h0 = rng.uniform(0.3, 0.6)
        for s in range(k):
            rows.append((name, float(s), h0 * np.exp(0.08 * s) + rng.normal(0, 1e-3)))
    df = pd.DataFrame(rows, columns=["component", "time", "hi"]).sample(frac=1, random_state=1)
    df = df.sort_values("time", kind="stable")  # interleaved, times increasing per component
    cfg = TrackerConfig(dt=1.0, lambda_hi=0.5, lambda_rul=0.5, warn_rul=50.0)
    rules = MonitoringRules(lead_time=8.0)
    res, _ = ingest_into(tmp_path / "b.db", df, config=cfg, rules=rules)
    with ComponentStore(tmp_path / "b.db", readonly=True) as s:
        hist = s.history()
    state, trend = TrackerState.empty(len(names)), TrendState.empty(len(names))
    expect, alerts = [], []
    level, failed = np.zeros(len(names), dtype=int), np.zeros(len(names), dtype=bool)
    for s in range(max(steps)):
        tt = np.array([float(s) if s < k else np.nan for k in steps])
        hh = np.array([df[(df.component == n) & (df.time == s)].hi.sum() if s < k else np.nan
                       for n, k in zip(names, steps, strict=True)])
        state, _ = tracker_update(state, tt, hh, cfg)
        trend = trend_update(trend, tt, hh, TrendConfig())
        med, low, _ = rul_quantiles(trend_posterior(trend, TrendConfig()), rules.levels)
        for j, n in enumerate(names):
            if s < steps[j]:
                failed[j] |= hh[j] >= 1.0
                lv = 2 if failed[j] else int(np.isfinite(med[j]) and low[j] < 8.0)
                m, lo = (0.0, 0.0) if failed[j] else (med[j], low[j])
                expect.append((n, s, state.fhi[j], state.frul[j], m, lo, lv))
                if lv > level[j]:
                    alerts.append((n, lv))
                    level[j] = lv
    exp = pd.DataFrame(expect, columns=["component", "t", "fhi", "frul", "rul_median",
                                        "rul_low", "level"])
    exp = exp.sort_values(["component", "t"]).reset_index(drop=True)
    exp["rul_low"] = exp["rul_low"].where(exp["rul_median"].notna(), 0.0)  # stored: [0, inf)
    np.testing.assert_array_equal(hist["component"], exp["component"])
    np.testing.assert_array_equal(hist["t"], exp["t"])
    np.testing.assert_array_equal(hist["level"], exp["level"])
    for c in ("fhi", "frul", "rul_median", "rul_low"):
        np.testing.assert_allclose(hist[c], exp[c], rtol=1e-12, atol=1e-12)
    assert alerts, "the fixture must raise alerts"
    got = [(a.component, a.level) for a in res.alerts]
    assert sorted(got) == sorted(alerts)
    # ordered by acquisition rank: a component's warning precedes its alarm
    for n in names:
        lv = [lv for c, lv in got if c == n]
        assert lv == sorted(lv)
