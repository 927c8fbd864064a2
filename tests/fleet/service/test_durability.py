"""Acknowledged means durable, whatever another process does to the database file.

A service process whose connection pool has grown acknowledges batches while other processes
run ``rulkit status``, ``rulkit track`` and plain read-only checks on the same SQLite file;
then it is killed (``kill -9``) or stopped (SIGTERM, closing its connections). Every
acknowledged row must be visible to other processes at once and after the stop. Before the
store opened files only through SQLite, the pool's probe of the file (a plain ``open()``)
dropped the server's POSIX locks, another process deleted the write-ahead log the server was
still writing to, and the acknowledged rows vanished.
"""

import signal
import sqlite3
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

SERVER = r"""
import signal, sys
import pandas as pd
from rulkit.fleet.service.db import ServiceDB

sdb = ServiceDB(sys.argv[1], pool_size=4)

def grow():
    with sdb.store(), sdb.store(), sdb.store():  # three connections at once: the pool grows
        pass

def stop(*_):
    sdb.close()
    print("closed", flush=True)
    sys.exit(0)

signal.signal(signal.SIGTERM, stop)
grow()
print("ready", flush=True)
for line in sys.stdin:
    k = int(line)
    grow()
    df = pd.DataFrame({"component": [f"s{i}" for i in range(100)], "time": float(k),
                       "hi": 0.3})
    out = sdb.ingest(df, f"batch {k}")
    print(f"acked {k} {out['ingested']}", flush=True)
"""


def _cli(*args):
    return subprocess.run([sys.executable, "-c", "from rulkit.cli import main; main()", *args],
                          capture_output=True, text=True, timeout=120)


def _count_elsewhere(db):
    """History acquisitions (packed: a row's n) as another process sees them."""
    r = subprocess.run([sys.executable, "-c", "import sqlite3, sys; c = sqlite3.connect("
                        "sys.argv[1]); print(c.execute('SELECT COALESCE(SUM(n), 0) FROM "
                        "history WHERE component LIKE \"s%\"').fetchone()[0])", str(db)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    return int(r.stdout)


@pytest.mark.parametrize("stop", ["kill -9", "SIGTERM"])
def test_acknowledged_batches_survive_other_processes_and_the_stop(tmp_path, stop):
    db = tmp_path / "fleet.db"
    pd.DataFrame({"component": "t0", "time": np.arange(3.0), "hi": 0.2}).to_csv(
        tmp_path / "first.csv", index=False)
    assert _cli("track", "--db", str(db), str(tmp_path / "first.csv")).returncode == 0
    srv = subprocess.Popen([sys.executable, "-c", SERVER, str(db)], stdin=subprocess.PIPE,
                           stdout=subprocess.PIPE, text=True)
    try:
        assert srv.stdout.readline().strip() == "ready"
        for k in range(2):
            # another process reads, then (the second time) writes with rulkit track
            assert _cli("status", "--db", str(db), "--limit", "1").returncode == 0
            if k % 2:
                pd.DataFrame({"component": "t0", "time": [10.0 + k], "hi": 0.2}).to_csv(
                    tmp_path / "one.csv", index=False)
                r = _cli("track", "--db", str(db), str(tmp_path / "one.csv"))
                assert r.returncode == 0, r.stderr
            srv.stdin.write(f"{k}\n")
            srv.stdin.flush()
            assert srv.stdout.readline().split() == ["acked", str(k), "100"]
            assert _count_elsewhere(db) == 100 * (k + 1), f"acknowledged batch {k} unseen"
        if stop == "kill -9":
            srv.kill()
        else:
            srv.send_signal(signal.SIGTERM)
            assert srv.stdout.readline().strip() == "closed"
        srv.wait(60)
    finally:
        if srv.poll() is None:
            srv.kill()
            srv.wait(60)
    assert _count_elsewhere(db) == 200
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA integrity_check").fetchone() == ("ok",)
    assert con.execute("SELECT SUM(n) FROM components").fetchone()[0] == 200 + 3 + 1
    con.close()


def test_the_service_continues_from_rows_another_process_wrote(tmp_path, db_url, request):
    """The service's writer starts a batch from the component rows it kept only while no
    other connection wrote: here ``rulkit track`` in another process appends to a component
    between two of the service's batches, and the service continues from track's row (on
    both backends; the reference on the same backend)."""
    from rulkit.fleet.service.db import ServiceDB
    from rulkit.fleet.store.postgres import open_store

    def frame(times, names):
        return pd.DataFrame([(c, float(t), 0.3 + 0.01 * t + 0.001 * j) for t in times
                             for j, c in enumerate(names)], columns=["component", "time", "hi"])

    db, ref = db_url, str(tmp_path / "ref.db")
    if "postgresql" in request.node.callspec.id:
        ref = request.getfixturevalue("pg_server").create_schema()
    sdb = ServiceDB(db)
    try:
        sdb.ingest(frame([0, 1], ["s0", "s1"]), "first", now=1.7e9)
        frame([2, 3], ["s0"]).to_csv(tmp_path / "more.csv", index=False)
        r = _cli("track", "--db", str(db), str(tmp_path / "more.csv"))
        assert r.returncode == 0, r.stderr
        sdb.ingest(frame([4], ["s0", "s1"]), "second", now=1.7e9)
    finally:
        sdb.close()
    with open_store(ref) as store:  # the same acquisitions, every row read back
        for times, names in (([0, 1], ["s0", "s1"]), ([2, 3], ["s0"]), ([4], ["s0", "s1"])):
            store.ingest(frame(times, names))
    with open_store(db) as got, open_store(ref) as want:
        cols = ["component", "t", "n", "hi", "fhi", "dhi", "rul", "frul", "drul", "d2rul"]
        pd.testing.assert_frame_equal(got.status()[cols], want.status()[cols],
                                      check_exact=True)
        assert got.status().set_index("component")["n"].to_dict() == {"s0": 5, "s1": 3}
