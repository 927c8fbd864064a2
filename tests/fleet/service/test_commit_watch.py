"""The watch's connection (src/rulkit/fleet/service/commit_watch.py): its commit counter moves
with every commit of another connection, of this process or another, and the token check it
serves sees a revocation made by another process on the very next request."""

import sqlite3
import subprocess
import sys

import pandas as pd

from rulkit.fleet.service.commit_watch import CommitWatch
from rulkit.fleet.service.db import ServiceDB, hash_token
from rulkit.fleet.service.loadgen import request, start_server

from .conftest import token_cli


def _other_process(code: str) -> None:
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_version_moves_with_every_other_connections_commit(tmp_path):
    db = str(tmp_path / "fleet.db")
    sdb = ServiceDB(db)
    watch = CommitWatch(db)
    try:
        v0 = watch.version()
        assert watch.version() == v0  # nothing committed
        sdb.create_token("read", "a")  # a pooled connection of this process
        v1 = watch.version()
        assert v1 != v0 and watch.version() == v1
        sdb.ingest(pd.DataFrame({"component": ["c"], "time": [0.0], "hi": [0.2]}), "test")
        v2 = watch.version()  # the group commits' own connection
        assert v2 != v1
        _other_process(f"import sqlite3; c = sqlite3.connect({db!r}); "
                       "c.execute(\"INSERT INTO meta VALUES ('test', 'x')\"); c.commit()")
        v3 = watch.version()
        assert v3 != v2 and watch.version() == v3
        with sqlite3.connect(db) as con:  # a read in another connection commits nothing
            con.execute("SELECT COUNT(*) FROM components").fetchone()
        assert watch.version() == v3
    finally:
        watch.close()
        sdb.close()


def test_token_rows_are_read_every_time(tmp_path):
    db = str(tmp_path / "fleet.db")
    sdb = ServiceDB(db)
    try:
        tid, token = sdb.create_token("write", "ops")
        assert sdb.watch is not None
        assert sdb.watch.token_row(hash_token(token)) == (tid, "ops", "write")
        assert sdb.check_token(token).role == "write"
        with sqlite3.connect(db) as con:
            con.execute("UPDATE api_tokens SET revoked = 1 WHERE id = ?", (tid,))
        assert sdb.watch.token_row(hash_token(token)) is None
        assert sdb.check_token(token) is None
    finally:
        sdb.close()


def test_revocation_by_another_process_takes_effect_on_the_next_request(tmp_path):
    db = str(tmp_path / "fleet.db")
    sdb = ServiceDB(db)
    _, write = sdb.create_token("write", "ops")
    _, read = sdb.create_token("read", "dash")
    sdb.close()
    srv = start_server(db)
    try:
        page = "/api/v1/components?limit=5"
        batch = {"rows": [{"component": "c0", "time": 0.0, "hi": 0.2}]}
        for _ in range(3):  # the page cached, the token checked each time
            assert request(srv.port, "GET", page, token=read)[0] == 200
        assert request(srv.port, "POST", "/api/v1/acquisitions", batch, write)[0] == 200
        token_cli(db, "revoke", "--name", "dash")
        assert request(srv.port, "GET", page, token=read)[0] == 401
        assert request(srv.port, "GET", "/api/v1/summary", token=read)[0] == 401
        token_cli(db, "revoke", "--name", "ops")
        batch["rows"][0]["time"] = 1.0
        assert request(srv.port, "POST", "/api/v1/acquisitions", batch, write)[0] == 401
        fresh = token_cli(db, "create", "--role", "write", "--name", "new").strip().splitlines()[-1]
        assert request(srv.port, "POST", "/api/v1/acquisitions", batch, fresh)[0] == 200
        assert request(srv.port, "GET", page, token=fresh)[0] == 200
    finally:
        srv.stop()
