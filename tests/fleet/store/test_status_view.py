"""`rulkit status` through rulkit.fleet.store.status_view (sqlite3, numpy, pyarrow without pandas)
prints the same bytes as the pandas path kept for a table rulkit cannot have written
(rulkit.fleet.store.cli._status_from_frame, through ComponentStore.status()), for every
format, with hostile ids, extreme floats, missing values and an empty database; its JSON
parses back to the values stored."""

import csv
import datetime
import io
import json
import math
import sqlite3
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import rulkit.fleet.store.status_view as sv
from rulkit.cli import app
from rulkit.fleet.store.ingest import ingest_into
from rulkit.fleet.store.sqlite import ComponentStore

runner = CliRunner()
NOW = "2024-05-01T12:00:00Z"

HOSTILE_IDS = ["x\x1b[2Jy", "line\nbreak", 'q"uote', "com,ma", "sl/ash", "back\\slash",
               "del\x7fete", "ünïcødé", "bidi\u202eevil", "tab\tid", "😀 astral", "a" * 100,
               "", " blank ", "NUL\x00inside", "c/\"\\,\n\x7f\x01"]
EDGE = [0.0, -0.0, 1e-300, 5e-324, -1.5, 0.0005, 0.9995, 123456.789, 1e16, 1e16 - 1,
        9999999999999998.0, -2.5e-7, 1e308, math.inf, -math.inf, 0.1 + 0.2, 2.675, 999.5,
        1e-4, 1e-5, 1e-6, 1e-7, 1.5e-7, 1e9, 1e10, 1e15, 1e21, 1e-15, 9.99e-16, 0.5e-15,
        1.5e-15, 4503599627370497.0, 0.05, 2.0, -3.0, 1e15 + 0.5]
EDGE += [np.nextafter(x, s) for x in (1e-4, 1e-6, 1e10, 1e16, 1e-15) for s in (0.0, np.inf)]
FLOAT_COLS = ("t", "hi", "fhi", "rul_low", "rul_high")
NULLABLE_COLS = ("rul_median", "failed_at", "seen")


def _random_db(path, rng, n=60, hostile=True):
    t = np.arange(6.0)
    frame = pd.DataFrame({
        "component": np.repeat([f"u{i:03d}" for i in range(n)], len(t)),
        "time": np.tile(t, n),
        "hi": np.clip(np.repeat(rng.uniform(0.05, 1.1, n), len(t))
                      * np.exp(0.05 * np.tile(t, n)) + rng.normal(0, 0.01, n * len(t)), 0, 5)})
    from rulkit.fleet.monitoring.rules import MonitoringRules

    ingest_into(path, frame, rules=MonitoringRules(time_unit="h", stale_after=3600.0))
    con = sqlite3.connect(path)
    ids = [r[0] for r in con.execute("SELECT component FROM components ORDER BY component")]
    seen = [1714564800.0 - 7200.0, 1714564800.0, 1e9, None, -5.0]
    with con:
        for new, old in zip(HOSTILE_IDS if hostile else [], ids, strict=False):  # refused ids
            con.execute("UPDATE components SET component = ? WHERE component = ?", (new, old))
        values = EDGE + rng.normal(0, 10.0 ** rng.integers(-20, 22, 200)).tolist()
        for i, comp in enumerate(r[0] for r in con.execute("SELECT component FROM components")
                                 .fetchall()):
            sets = {c: values[(7 * i + 3 * j) % len(values)] for j, c in enumerate(FLOAT_COLS)
                    if rng.random() < 0.5}
            for c in NULLABLE_COLS:
                if rng.random() < 0.5:
                    sets[c] = None if rng.random() < 0.3 else (
                        seen[i % len(seen)] if c == "seen" else values[(5 * i) % len(values)])
            sets["level"] = int(rng.integers(0, 3))
            sets["n"] = int(rng.integers(0, 10**12))
            if i % 9 == 0:  # ties on level and RUL: the id decides
                sets["rul_median"], sets["level"] = 5.0, 1
            con.execute(f"UPDATE components SET {', '.join(f'{c} = ?' for c in sets)} "
                        "WHERE component = ?", (*sets.values(), comp))
    con.close()


def _both(db, args, monkeypatch):
    new = runner.invoke(app, ["status", "--db", str(db), "--now", NOW, *args])
    with monkeypatch.context() as m:  # force the pandas implementation
        m.setattr(sv, "read_status", lambda *a, **k: None)
        old = runner.invoke(app, ["status", "--db", str(db), "--now", NOW, *args])
    return new, old


@pytest.mark.parametrize("fmt", ["table", "csv", "json"])
@pytest.mark.parametrize("seed", [0, 1])
def test_same_output_as_the_pandas_path(tmp_path, monkeypatch, fmt, seed):
    monkeypatch.setattr(sv, "READ_ROWS", 7 if seed else sv.READ_ROWS)  # chunks of rows or one
    db = tmp_path / "s.db"
    _random_db(db, np.random.default_rng(seed))
    assert sv.read_status(db, now=0.0) is not None  # the fast path is the one compared
    for extra in ([], ["--limit", "7"], ["--limit", "1"], ["--sort", "rul"],
                  ["--sort", "due"]):
        new, old = _both(db, ["--format", fmt, *extra], monkeypatch)
        assert old.exit_code == 0, old.output
        assert new.exit_code == 0, new.output
        assert new.stdout_bytes == old.stdout_bytes, (fmt, extra)
        if fmt in ("table", "csv") and not extra:  # a non-printable id escaped: no raw ESC
            assert "\x1b" not in new.output and "\\x1b[2Jy" in new.output
            assert "line\nbreak" not in new.output and "line\\nbreak" in new.output


def test_csv_and_json_hold_the_same_records(tmp_path):
    """Both formats parse back to the same values (JSON null where CSV is empty or inf)."""
    db = tmp_path / "s.db"
    _random_db(db, np.random.default_rng(2))
    csv_out = runner.invoke(app, ["status", "--db", str(db), "--format", "csv", "--now", NOW])
    json_out = runner.invoke(app, ["status", "--db", str(db), "--format", "json", "--now", NOW])
    rows = list(csv.DictReader(io.StringIO(csv_out.output)))
    recs = json.loads(json_out.output)
    assert list(rows[0]) == list(recs[0]) == list(sv.STATUS_COLUMNS)
    assert len(rows) == len(recs) == 60
    for r, j in zip(rows, recs, strict=True):
        for c in ("rul", "rul_low", "rul_high", "hi", "t"):
            v = float(r[c]) if r[c] else None
            assert (j[c] is None) == (v is None or not math.isfinite(v)), (c, r[c], j[c])
            if j[c] is not None:
                assert j[c] == v  # both shortest round-trip texts of the same float64
        assert r["failed"] == str(j["failed"]).lower() and r["stale"] == str(j["stale"]).lower()
        assert (r["due"] or None) == j["due"] and (r["last_seen"] or None) == j["last_seen"]
        assert j["time_unit"] == "h" and "log-linear trend" in j["estimator"]
    # staleness at NOW: seen 2 h before it is stale (stale after 1 h), at it is not
    by_seen = {(j["last_seen"], j["stale"]) for j in recs if j["last_seen"]}
    assert ("2024-05-01T10:00:00Z", True) in by_seen
    assert ("2024-05-01T12:00:00Z", False) in by_seen


def _records(db):
    """The printed columns row by row (order, due dates and staleness as read_status derives
    them: the pandas path checks those), each value a plain Python value."""
    _, cols = sv.read_status(db, now=sv_now())
    plain = {c: v.tolist() if isinstance(v, np.ndarray) else list(v) for c, v in cols.items()}
    return [dict(zip(sv.STATUS_COLUMNS, row, strict=True))
            for row in zip(*(plain[c] for c in sv.STATUS_COLUMNS), strict=True)]


def sv_now():
    return datetime.datetime.fromisoformat(NOW.replace("Z", "+00:00")).timestamp()


def _ascii(text):
    """Every non-ASCII character as JSON's \\uXXXX escape (the json module's, independently)."""
    return "".join(ch if ord(ch) < 128 else json.dumps(ch)[1:-1] for ch in text)


def _expected_table(db, recs):
    """The table rendered cell by cell with format() and rulkit.tables.text_table."""
    from rulkit.fleet.tracking.tracker_chain import LEVEL_NAMES
    from rulkit.tables import safe_text, text_table

    def g3(v):
        return "-" if v is None or math.isnan(v) else format(v + 0.0, ".3g")

    def rul(r):
        if r["failed"]:
            return "failed"
        if r["rul"] is None or math.isnan(r["rul"]):
            return "-"
        return f"{g3(r['rul'])} [{g3(r['rul_low'])}, {g3(r['rul_high'])}]"

    cells = {"component": [safe_text(r["component"], 40) for r in recs],
             "level": [LEVEL_NAMES[r["level"]] for r in recs],
             "RUL (h)": [rul(r) for r in recs],
             "due": [r["due"][:16] + "Z" if r["due"] else "-" for r in recs],
             "HI": [format(r["hi"], ".3f") for r in recs],
             "n": [str(r["n"]) for r in recs],
             "last t": [format(r["t"], "g") for r in recs],
             "last seen": [r["last_seen"][:16] + "Z" if r["last_seen"] else "-" for r in recs],
             "": ["stale" if r["stale"] else "" for r in recs]}
    return text_table(cells, left=("component", "level", ""))


@pytest.mark.parametrize(("seed", "hostile", "chunk"),
                         [(0, True, 4096), (3, True, 7), (1, False, 4096), (2, False, 7)])
def test_formats_against_an_independent_rendering(tmp_path, monkeypatch, seed, hostile, chunk):
    """Each format's bytes equal the same rows rendered the plain way: JSON as orjson writes
    a list of dicts (non-ASCII escaped by the json module), CSV as pyarrow writes a table
    built by pa.array from Python lists, the table's rows by format() and text_table; with
    hostile ids or printable ASCII ones (the table's byte-matrix layout), read and written in
    one chunk of rows or many."""
    import orjson
    import pyarrow as pa
    import pyarrow.csv as pacsv

    from rulkit.fleet.tracking.tracker_chain import LEVEL_NAMES
    from rulkit.tables import safe_text

    monkeypatch.setattr(sv, "CHUNK_ROWS", chunk)
    monkeypatch.setattr(sv, "READ_ROWS", chunk)
    db = tmp_path / "s.db"
    _random_db(db, np.random.default_rng(seed), hostile=hostile)
    recs = _records(db)
    out = {fmt: runner.invoke(app, ["status", "--db", str(db), "--now", NOW, "--format", fmt])
           for fmt in ("table", "csv", "json")}
    assert all(r.exit_code == 0 for r in out.values()), {k: r.output for k, r in out.items()}

    named = [{**r, "level": LEVEL_NAMES[r["level"]]} for r in recs]
    want_json = _ascii(orjson.dumps(named).decode()).encode() + b"\n"
    assert out["json"].stdout_bytes == want_json

    def col(c, typ):
        vals = [r[c] for r in named]
        if typ == pa.float64():
            vals = [None if v is None or math.isnan(v) else v for v in vals]
        return pa.array(vals, type=typ)

    types = {**dict.fromkeys(sv.FLOAT_COLUMNS, pa.float64()),
             **dict.fromkeys(sv.BOOL_COLUMNS, pa.bool_()), "n": pa.int64()}
    arrays = [pa.array([c if c.isprintable() else safe_text(c) for c in
                        (r["component"] for r in recs)], type=pa.string())]
    arrays += [col(c, types.get(c, pa.string())) for c in sv.STATUS_COLUMNS[1:]]
    buf = io.BytesIO()
    pacsv.write_csv(pa.Table.from_arrays(arrays, names=list(sv.STATUS_COLUMNS)), buf,
                    pacsv.WriteOptions(quoting_style="needed"))
    assert out["csv"].stdout_bytes == buf.getvalue()

    table = out["table"].output.split("\n", 1)[1]  # after the counts line
    assert table.startswith(_expected_table(db, recs))


@pytest.mark.parametrize("fmt", ["table", "csv", "json"])
def test_empty_database_same_output(tmp_path, monkeypatch, fmt):
    db = tmp_path / "e.db"
    ComponentStore(db).close()
    new, old = _both(db, ["--format", fmt], monkeypatch)
    assert new.exit_code == old.exit_code == 0, (new.output, old.output)
    assert new.stdout_bytes == old.stdout_bytes


@pytest.mark.parametrize("bad", ["NULL", "'abc'", "'1.5'", "3"])
def test_row_rulkit_cannot_have_written_takes_the_pandas_path(tmp_path, monkeypatch, bad):
    """A NULL (how SQLite stores NaN), text among numbers or an unknown level: read_status
    declines and the command names the row as before."""
    db = tmp_path / "b.db"
    _random_db(db, np.random.default_rng(3), n=5)
    con = sqlite3.connect(db)
    with con:  # the same table without its NOT NULL constraints, then one bad value
        con.execute("CREATE TABLE c2 AS SELECT * FROM components")
        con.execute("DROP TABLE components")
        con.execute("ALTER TABLE c2 RENAME TO components")
        col = "level" if bad == "3" else "hi"
        con.execute(f"UPDATE components SET {col} = {bad} WHERE rowid = 2")
    con.close()
    # '1.5' in a REAL column is stored as the number 1.5 (SQLite's type affinity)
    assert (sv.read_status(db, now=0.0) is None) == (bad != "'1.5'")
    monkeypatch.setattr(sv, "READ_ROWS", 1)  # the bad row in the second chunk read
    assert (sv.read_status(db, now=0.0) is None) == (bad != "'1.5'")
    new, old = _both(db, ["--format", "json"], monkeypatch)
    assert (new.exit_code, new.output) == (old.exit_code, old.output)
    if bad != "'1.5'":
        assert new.exit_code == 1 and "table components" in new.output


def _iso(seconds):
    """The oracle of a date-time: the standard library's, to the second, UTC."""
    if seconds is None or not math.isfinite(seconds):
        return None
    stamp = datetime.datetime.fromtimestamp(round(seconds), tz=datetime.UTC)
    return stamp.strftime("%Y-%m-%dT%H:%M:%SZ")


def _finite(v):
    return v if v is not None and math.isfinite(v) else None


@pytest.mark.parametrize("seed", [0, 1])
def test_json_parses_back_to_the_stored_values(tmp_path, seed):
    """json.loads of the output against the database read with sqlite3: every float equal
    to the stored one (shortest round-trip text), null where it is missing or not finite,
    every hostile id intact, the text ASCII."""
    db = tmp_path / "s.db"
    _random_db(db, np.random.default_rng(seed))
    out = runner.invoke(app, ["status", "--db", str(db), "--format", "json", "--now", NOW])
    assert out.exit_code == 0, out.output
    assert out.stdout_bytes.isascii() and out.stdout_bytes.endswith(b"]\n")
    recs = {r["component"]: r for r in json.loads(out.stdout_bytes)}
    con = sqlite3.connect(db)
    stored = con.execute("SELECT component, level, hi, n, t, rul_median, rul_low, rul_high, "
                         "failed_at, seen FROM components").fetchall()
    con.close()
    assert set(recs) == {r[0] for r in stored} and len(recs) == len(stored)
    assert set(HOSTILE_IDS) <= set(recs)
    levels = {0: "ok", 1: "warning", 2: "alarm"}
    now = datetime.datetime.fromisoformat(NOW).timestamp()
    for comp, level, hi, n, t, med, low, high, failed_at, seen in stored:
        r = recs[comp]
        failed = failed_at is not None and math.isfinite(failed_at)
        due = None if failed or med is None or seen is None else _finite(seen + med * 3600.0)
        want = {"level": levels[level], "failed": failed,
                "stale": seen is not None and now - seen > 3600.0, "rul": _finite(med),
                "rul_low": _finite(low), "rul_high": _finite(high), "hi": _finite(hi),
                "n": n, "t": _finite(t), "last_seen": _iso(seen), "due": _iso(due),
                "time_unit": "h"}
        assert {k: r[k] for k in want} == want, comp
        for k in ("rul", "rul_low", "rul_high", "hi", "t"):  # bit for bit, the sign of 0 too
            if r[k] is not None:
                assert math.copysign(1.0, r[k]) == math.copysign(1.0, want[k]), (comp, k)


def _fitted_db(path):
    """A database whose RULs come from a fitted model (a transformed-noise growth model)."""
    from dataclasses import replace

    from rulkit.fleet.learned.datasets import synthetic_growth_fleet
    from rulkit.fleet.learned.hi_noise import HiNoiseModel
    from rulkit.fleet.time_axis import TimeAxis

    fleet, _ = synthetic_growth_fleet(np.random.default_rng(0), 6, n_acq=12)
    axis = TimeAxis(unit="d", origin="first")
    model = HiNoiseModel(noise="additive", shape=0.0, mean=(-2.3, 1.5), cov=(0.01, 0.0, 0.2),
                         hi_noise_sd=0.02, log_noise_sd=0.0, walk_sd=0.05, time_scale=300.0)
    with ComponentStore(path) as store:
        store.set_degradation_model(replace(model, time_axis=axis.to_dict(),
                                            time_unit=axis.unit))
        store.ingest(fleet)


@pytest.mark.parametrize("fmt", ["table", "csv", "json"])
@pytest.mark.parametrize("fitted", [False, True])
def test_status_imports_no_pandas(tmp_path, fmt, fitted):
    """Nor any other module the command does not use (each costs start-up time), also when a
    fitted model gives the RULs (its classes load without pandas)."""
    db = tmp_path / "p.db"
    if fitted:
        _fitted_db(db)
    else:
        _random_db(db, np.random.default_rng(4), n=5)
    code = ("import atexit, sys\n"
            "atexit.register(lambda: sys.stderr.write(' '.join(m for m in ('pandas', 'scipy', "
            "'rich', 'numba', 'matplotlib', 'fastapi', 'pyarrow.compute', 'threadpoolctl', "
            "'rulkit.systems.reaction_wheel.pipeline') if m in sys.modules)))\n"
            "from rulkit.cli import main\n"
            f"sys.argv = ['rulkit', 'status', '--db', {str(db)!r}, '--format', {fmt!r}]\n"
            "main()\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stderr == ""
