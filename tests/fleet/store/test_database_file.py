"""The database as a file: opened through SQLite only, read through its write-ahead log, each
failure named (corrupt, full, busy, read-only), readers who cannot write.

Each scenario failed on the code before: a database killed during its final checkpoint was
refused as corrupt; a full disk was reported as corruption; a read-only user could not run
``rulkit status`` or left files that blocked the owner; a killed first ingest left its
temporary file behind.
"""

import os
import pickle
import shutil
import sqlite3
import struct
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from rulkit.cli import app
from rulkit.cli import errors as cli_errors
from rulkit.fleet.store import database_file
from rulkit.fleet.store.database_file import (
    StoreBusyError,
    StoreCorruptError,
    StoreError,
    StoreFullError,
    StoreReadOnlyError,
)
from rulkit.fleet.store.ingest import ingest_into
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.store.status_view import read_status

runner = CliRunner()


def acq(comps=20, steps=10, t0=0.0):
    t = t0 + np.arange(steps, dtype=float)
    return pd.DataFrame({"component": np.repeat([f"u{i:03d}" for i in range(comps)], steps),
                         "time": np.tile(t, comps),
                         "hi": 0.2 + 0.001 * np.tile(t, comps)})


def files(d):
    return sorted(p.name for p in d.iterdir())


# ------------------------------------------------------------------ killed mid-checkpoint
_WRITER = """
import os, sys
import numpy as np, pandas as pd
from rulkit.fleet.store.sqlite import ComponentStore
db, n = sys.argv[1], int(sys.argv[2])
with ComponentStore(db) as s:
    s._conn.execute("PRAGMA wal_autocheckpoint=0")  # everything stays in the log
    for k in range(n):
        t = 100.0 + k
        s.ingest(pd.DataFrame({"component": [f"u{i:03d}" for i in range(2000)], "time": t,
                               "hi": 0.3}), f"batch {k}")
    os._exit(0)  # killed before the final checkpoint: the log holds every commit
"""


def _latest_committed_frames(wal: bytes) -> dict[int, bytes]:
    """Page number -> the page's last committed version in a write-ahead log file."""
    page_size = struct.unpack(">I", wal[8:12])[0]
    pages: dict[int, bytes] = {}
    pending: dict[int, bytes] = {}
    off = 32
    while off + 24 + page_size <= len(wal):
        pgno, commit = struct.unpack(">II", wal[off:off + 8])
        pending[pgno] = wal[off + 24:off + 24 + page_size]
        if commit:
            pages.update(pending)
            pending = {}
        off += 24 + page_size
    return pages


def test_database_killed_during_its_final_checkpoint_is_read_through_the_log(tmp_path):
    db = tmp_path / "c.db"
    ingest_into(db, acq(comps=2000, steps=1))
    r = subprocess.run([sys.executable, "-c", _WRITER, str(db), "5"], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    wal = (tmp_path / "c.db-wal").read_bytes()
    frames = _latest_committed_frames(wal)
    assert max(frames) * len(frames[1]) > db.stat().st_size  # the log grows the file
    # a checkpoint copies pages in ascending order: killed after page 1, the main file
    # claims more pages than it has yet, and only the log makes it whole
    with open(db, "r+b") as f:
        f.write(frames[1])
    (tmp_path / "c.db-shm").unlink()
    with ComponentStore(db, readonly=True) as s:
        assert s.counts() == (2000, 12000, 12000)
    r = runner.invoke(app, ["status", "--db", str(db), "--limit", "1"])
    assert r.exit_code == 0, r.output
    acq(comps=3, steps=2, t0=200.0).to_csv(tmp_path / "more.csv", index=False)
    r = runner.invoke(app, ["track", "--db", str(db), str(tmp_path / "more.csv")])
    assert r.exit_code == 0, r.output
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA integrity_check").fetchone() == ("ok",)
    assert con.execute("SELECT SUM(n) FROM history").fetchone() == (12006,)
    con.close()


def test_a_damaged_database_is_reported_as_damaged_with_its_exit_code(tmp_path):
    db = tmp_path / "d.db"
    ingest_into(db, acq(comps=500, steps=4))
    raw = bytearray(db.read_bytes())
    page = 4096
    raw[page * 3:page * 6] = b"\x5a" * (page * 3)  # garbage over table pages
    db.write_bytes(bytes(raw))
    with pytest.raises(StoreCorruptError, match=r"damaged .*integrity_check"):
        with ComponentStore(db) as s:
            s.status()
    r = runner.invoke(app, ["status", "--db", str(db)])
    assert r.exit_code == cli_errors.EXIT_CORRUPT, r.output
    assert "damaged" in r.output


def test_exit_codes_of_the_store_errors_are_the_cli_codes():
    assert StoreBusyError.exit_code == cli_errors.EXIT_BUSY
    assert StoreCorruptError.exit_code == cli_errors.EXIT_CORRUPT
    assert StoreFullError.exit_code == cli_errors.EXIT_IO
    assert StoreReadOnlyError.exit_code == cli_errors.EXIT_NOPERM
    assert StoreError.exit_code == cli_errors.EXIT_INPUT


# ------------------------------------------------------------------ full disk
def test_disk_full_is_named_and_writes_nothing(tmp_path, monkeypatch):
    db = tmp_path / "f.db"
    ingest_into(db, acq())
    before = ComponentStore(db, readonly=True)
    counts = before.counts()
    before.close()
    connect = database_file._connect

    def small_disk(path, timeout, readonly):  # SQLite's page limit: SQLITE_FULL
        conn, immutable = connect(path, timeout, readonly)
        pages = conn.execute("PRAGMA page_count").fetchone()[0]
        conn.execute(f"PRAGMA max_page_count={pages + 2}")
        return conn, immutable

    monkeypatch.setattr(database_file, "_connect", small_disk)
    acq(comps=2000, steps=5, t0=100.0).to_csv(tmp_path / "big.csv", index=False)
    r = runner.invoke(app, ["track", "--db", str(db), str(tmp_path / "big.csv")])
    assert r.exit_code == cli_errors.EXIT_IO, r.output
    assert "disk is full" in r.output and "nothing was written" in r.output
    assert "malformed" not in r.output and "backup" not in r.output
    monkeypatch.undo()
    with ComponentStore(db, readonly=True) as s:
        assert s.counts() == counts


_FULL_TMPFS = """
set -e
mount -t tmpfs -o size=400k tmpfs "$1"
cp "$2" "$1/f.db"
"$3" -c "from rulkit.cli import main; main()" track --db "$1/f.db" "$4" || echo "exit=$?"
"$3" -c "from rulkit.cli import main; main()" status --db "$1/f.db" --limit 1 >/dev/null
echo "status=$?"
"""


def test_a_really_full_file_system_gets_the_disk_full_message(tmp_path):
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        pytest.skip("needs root and unshare to mount a small private tmpfs")
    db = tmp_path / "f.db"
    ingest_into(db, acq())
    acq(comps=4000, steps=5, t0=100.0).to_csv(tmp_path / "big.csv", index=False)
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    r = subprocess.run(["unshare", "--mount", "--propagation", "private", "sh", "-c",
                        _FULL_TMPFS, "sh", str(mnt), str(db), sys.executable,
                        str(tmp_path / "big.csv")],
                       capture_output=True, text=True, timeout=300)
    if "mount" in r.stderr and "exit=" not in r.stdout:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip()[:200]}")
    assert f"exit={cli_errors.EXIT_IO}" in r.stdout, (r.stdout, r.stderr)
    assert "disk is full" in r.stderr and "malformed" not in r.stderr
    assert "status=0" in r.stdout, (r.stdout, r.stderr)


# ------------------------------------------------------------------ busy
def test_busy_is_named_busy(tmp_path):
    db = tmp_path / "b.db"
    ingest_into(db, acq())
    holder = sqlite3.connect(db, isolation_level=None)
    holder.execute("BEGIN EXCLUSIVE")
    try:
        acq(t0=50.0).to_csv(tmp_path / "n.csv", index=False)
        r = runner.invoke(app, ["track", "--db", str(db), str(tmp_path / "n.csv"),
                                "--wait", "0.1"])
        assert r.exit_code == cli_errors.EXIT_BUSY, r.output
        assert "busy" in r.output and "malformed" not in r.output
    finally:
        holder.execute("ROLLBACK")
        holder.close()


# ------------------------------------------------------------------ readers who cannot write
def _as_nobody(fn, *args):
    """``fn(*args)`` in a forked child running as user nobody; returns its result or raises
    what it raised (pickled back)."""
    if os.geteuid() != 0:
        pytest.skip("needs root to run a child as another user")
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        os.close(r)
        try:
            os.setgroups([])
            os.setgid(65534)
            os.setuid(65534)
            out = ("ok", fn(*args))
        except BaseException as err:
            out = ("err", err)
        with os.fdopen(w, "wb") as f:
            pickle.dump(out, f)
        os._exit(0)
    os.close(w)
    with os.fdopen(r, "rb") as f:
        data = f.read()
    os.waitpid(pid, 0)
    kind, val = pickle.loads(data)
    if kind == "err":
        raise val
    return val


def _status_rows(db):
    _, cols = read_status(db, now=0.0)
    return len(cols["component"]), sorted(cols["component"])[:3]


def _store_counts(db):
    with ComponentStore(db, readonly=True) as s:
        return s.counts()


@pytest.fixture
def shared_db():
    """A database owned by root, mode 0644, in a directory other users can reach (pytest's
    own temporary directories are private to root)."""
    import tempfile
    from pathlib import Path

    d = Path(tempfile.mkdtemp(prefix="rulkit-shared-"))
    d.chmod(0o755)
    db = d / "fleet.db"
    ingest_into(db, acq())
    db.chmod(0o644)
    yield d, db
    shutil.rmtree(d, ignore_errors=True)


@pytest.mark.parametrize("dir_mode", [0o755, 0o1777])
def test_a_reader_who_cannot_write_reads_and_leaves_nothing_behind(shared_db, dir_mode):
    d, db = shared_db
    d.chmod(dir_mode)
    assert _as_nobody(_status_rows, db) == (20, ["u000", "u001", "u002"])
    assert _as_nobody(_store_counts, db) == (20, 200, 200)
    assert files(d) == ["fleet.db"]  # no -wal/-shm owned by the reader
    # the owner writes on as before
    res, _ = ingest_into(db, acq(t0=100.0))
    assert res.n_rows == 200
    assert files(d) == ["fleet.db"]


def test_a_reader_who_cannot_write_sees_an_active_writers_log(shared_db):
    d, db = shared_db
    d.chmod(0o755)
    with ComponentStore(db) as owner:  # the owner's connection keeps -wal/-shm open
        owner.ingest(acq(t0=100.0))
        assert (d / "fleet.db-wal").exists()
        assert _as_nobody(_status_rows, db)[0] == 20
        assert _as_nobody(_store_counts, db) == (20, 400, 400)
        owner.ingest(acq(t0=200.0))
    assert _as_nobody(_store_counts, db) == (20, 600, 600)


def test_a_reader_cannot_write(shared_db):
    _, db = shared_db

    def write(db):
        with ComponentStore(db) as s:
            s.ingest(acq(t0=100.0))

    with pytest.raises(StoreReadOnlyError, match="cannot be written by this user"):
        _as_nobody(write, db)
    assert _store_counts(db) == (20, 200, 200)


# ------------------------------------------------------------------ killed first ingest
def test_a_killed_first_ingest_leaves_no_temporary_file_for_long(tmp_path):
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    db = tmp_path / "k.db"
    stale = [tmp_path / f".k.db.{gone.pid}.deadbeef.creating",
             tmp_path / f".k.db.{gone.pid}.deadbeef.creating-journal"]
    for p in stale:
        p.write_bytes(b"partial")
    alive = tmp_path / f".k.db.{os.getpid()}.0badf00d.creating"  # a creation in progress
    alive.write_bytes(b"partial")
    ingest_into(db, acq())
    assert files(tmp_path) == [alive.name, "k.db"]


def test_nothing_but_sqlite_opens_the_database_file(tmp_path, monkeypatch):
    """A plain open() of the database in a process holding SQLite connections drops their
    POSIX locks (docs: database_file); opening, probing, reading and writing use none."""
    import builtins
    import io

    db = tmp_path / "o.db"
    ingest_into(db, acq())
    opened = []
    real_open, real_io_open, real_os_open = builtins.open, io.open, os.open

    def spy(opener):
        def f(file, *a, **k):
            if str(file).startswith(str(db)):
                opened.append(str(file))
            return opener(file, *a, **k)
        return f

    monkeypatch.setattr(builtins, "open", spy(real_open))
    monkeypatch.setattr(io, "open", spy(real_io_open))
    monkeypatch.setattr(os, "open", spy(real_os_open))
    with ComponentStore(db) as s, ComponentStore(db, readonly=True) as r:
        s.ingest(acq(t0=100.0))
        assert r.counts()[2] == 400
        ingest_into(db, acq(t0=200.0))
        read_status(db, now=0.0)
    assert opened == []


@pytest.mark.parametrize("links", [True, False], ids=["hard link", "no hard links"])
def test_link_into_place_publishes_once(tmp_path, monkeypatch, links):
    """A finished private database becomes the path, or gives way to one that appeared
    first (then nothing of the existing file changes), with or without hard links."""
    from rulkit.fleet.store.database_file import creation_path, link_into_place

    if not links:
        def no_link(src, dst):
            raise OSError(1, "hard links not supported")
        monkeypatch.setattr(os, "link", no_link)
    target = tmp_path / "fleet.db"
    mine = creation_path(target)
    assert mine.parent == tmp_path and mine.name.endswith(".creating")
    mine.write_bytes(b"mine")
    assert link_into_place(mine, target) and target.read_bytes() == b"mine"
    theirs = creation_path(target)
    theirs.write_bytes(b"theirs")
    assert not link_into_place(theirs, target) and target.read_bytes() == b"mine"
