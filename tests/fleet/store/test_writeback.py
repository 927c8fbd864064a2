"""A new database's pages sent to the disk while it is written (rulkit.fleet.store.writeback):
the requests made while the batch runs, the same database as without them, and nothing left
behind (thread, descriptor, file) when the batch fails."""

import os
import sqlite3
import threading

import numpy as np
import pandas as pd
import pytest

import rulkit.fleet.store.writeback as writeback
from rulkit.fleet.store.ingest import ingest_into
from rulkit.fleet.store.sqlite import ComponentStore


def _batch():
    rng = np.random.default_rng(5)
    rows = [(f"u{i:02d}", float(s), min(0.05 * np.exp((0.02 + 0.004 * i) * s)
                                        + abs(rng.normal(0, 0.01)), 1.2))
            for i in range(6) for s in range(40)]
    return pd.DataFrame(rows, columns=["component", "time", "hi"]).sort_values(
        "time", kind="stable")


def _dump(db):
    con = sqlite3.connect(db)
    try:
        cols = [c for (c,) in con.execute("SELECT name FROM pragma_table_info('components')")
                if c not in ("seen", "due")]  # the clock at the ingestion
        return (con.execute(f"SELECT {', '.join(cols)} FROM components ORDER BY 1").fetchall(),
                con.execute("SELECT * FROM history ORDER BY rowid").fetchall(),
                con.execute("SELECT component, t, level, hi, rul FROM alerts ORDER BY id"
                            ).fetchall())
    finally:
        con.close()


def _open_fds():
    return set(os.listdir("/proc/self/fd")) if os.path.isdir("/proc/self/fd") else set()


@pytest.fixture
def small_pieces(monkeypatch):
    """Blocks of 10 rows, so that the batch is written in many pieces."""
    monkeypatch.setattr(ComponentStore, "BLOCK_ROWS", 10)


def test_the_writes_are_started_while_the_batch_runs_and_change_nothing(
        tmp_path, monkeypatch, small_pieces):
    """The kernel is asked to write the new file while its history is inserted (each history
    insert here waits for a request made after the file grew, so the test does not depend on
    the thread's timing); the database equals the one built without the requests (every
    value, the history's blobs byte for byte, in rowid order)."""
    real = writeback._sync_file_range()
    if real is None:
        pytest.skip("no sync_file_range on this system")
    calls = []
    asked = threading.Event()

    def counted():
        def fn(fd, offset, nbytes, flags):
            size = os.fstat(fd).st_size
            calls.append((size, flags))
            if size > 0:
                asked.set()
            return real(fd, offset, nbytes, flags)
        return fn

    df = _batch()
    monkeypatch.setattr(writeback, "_sync_file_range", lambda: None)
    ingest_into(tmp_path / "plain.db", df)
    monkeypatch.setattr(writeback, "PERIOD", 0.001)
    monkeypatch.setattr(writeback, "_sync_file_range", counted)
    write = ComponentStore._write_history

    def after_a_request(self, rows):
        write(self, rows)
        asked.clear()
        assert asked.wait(30.0), "no request to write the file"

    monkeypatch.setattr(ComponentStore, "_write_history", after_a_request)
    fds = _open_fds()
    ingest_into(tmp_path / "early.db", df)
    assert calls and all(flags == writeback._SYNC_FILE_RANGE_WRITE for _, flags in calls)
    assert max(size for size, _ in calls) > 0  # asked while the file held pages
    assert not [t for t in threading.enumerate() if t.name == "rulkit-writeback"]
    assert _open_fds() == fds
    assert _dump(tmp_path / "early.db") == _dump(tmp_path / "plain.db")


def test_a_batch_that_fails_late_leaves_no_file_thread_or_descriptor(
        tmp_path, monkeypatch, small_pieces):
    """An error in a later piece of the batch (here the third piece's history insert):
    no database, no temporary file, the writeback thread stopped and its descriptor closed."""
    monkeypatch.setattr(writeback, "PERIOD", 0.0)
    inserted = []
    write = ComponentStore._write_history

    def fail_third(self, rows):
        inserted.append(len(rows))
        if len(inserted) == 3:
            raise sqlite3.OperationalError("disk I/O error")
        write(self, rows)

    monkeypatch.setattr(ComponentStore, "_write_history", fail_third)
    fds = _open_fds()
    with pytest.raises(Exception, match="disk I/O error"):
        ingest_into(tmp_path / "f.db", _batch())
    assert len(inserted) == 3
    assert list(tmp_path.iterdir()) == []
    assert not [t for t in threading.enumerate() if t.name == "rulkit-writeback"]
    assert _open_fds() == fds


def test_a_file_that_cannot_be_opened_is_left_to_the_final_fsync(tmp_path):
    """No descriptor (the file is gone): no thread, and stop and close do nothing."""
    wb = writeback.EarlyWriteback(tmp_path / "missing.db")
    assert wb.fd is None
    wb.start()
    assert not [t for t in threading.enumerate() if t.name == "rulkit-writeback"]
    wb.close()
    wb.close()
