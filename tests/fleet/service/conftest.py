"""Fixtures of the service tests: tokens, clients, a live server (the store backends are in
tests/fleet/conftest.py).

Without chromium the browser tests skip with the reason, unless RULKIT_REQUIRE_INTEGRATION=1
(set by .ci/run), which turns the skip into a failure.
"""

import subprocess
import sys
import threading
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import pytest

from rulkit.fleet.service.pgtemp import free_port


@pytest.fixture
def sdb(db_url):
    from rulkit.fleet.service.db import ServiceDB

    s = ServiceDB(db_url)
    yield s
    s.close()


@pytest.fixture
def tokens(sdb):
    return {"write": sdb.create_token("write", "writer")[1],
            "read": sdb.create_token("read", "reader")[1]}


@pytest.fixture
def client(sdb):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # starlette: httpx -> httpx2 notice
        from fastapi.testclient import TestClient

    from rulkit.fleet.service.app import create_app

    with TestClient(create_app(sdb)) as c:
        yield c


class LiveServer:
    """uvicorn serving an app on a free loopback port in a thread of this process."""

    def __init__(self, app):
        import uvicorn

        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=self.port,
                                                    access_log=False, log_level="warning"))
        self.thread = threading.Thread(target=self.server.run, daemon=True)

    def __enter__(self):
        self.thread.start()
        deadline = time.monotonic() + 20
        while not self.server.started:
            if time.monotonic() > deadline or not self.thread.is_alive():
                raise RuntimeError("uvicorn did not start")
            time.sleep(0.02)
        return self

    def __exit__(self, *exc):
        self.server.should_exit = True
        self.thread.join(10)


@pytest.fixture
def live_server():
    """``with live_server(app) as srv: srv.url``: a real HTTP server on loopback."""
    return LiveServer


def token_cli(db: str, *args: str) -> str:
    """``rulkit token ARGS --db DB`` in another process; its standard output."""
    out = subprocess.run([sys.executable, "-c", "from rulkit.cli import main; main()", "token",
                          *args, "--db", db], check=True, capture_output=True, text=True,
                         timeout=120)
    return out.stdout


@contextmanager
def one_group(sdb, calls: list[Callable[[], object]]) -> Iterator[None]:
    """Run ``calls`` (each ingests one batch through ``sdb``) on threads while the writers'
    lock is held, as while another group is being written, so that their batches queue up;
    the body runs once all are queued and before any is written. On exit they are written,
    checked to have been one group (one transaction)."""
    sdb._write_lock.acquire()
    try:
        threads = [threading.Thread(target=call) for call in calls]
        for th in threads:
            th.start()
        while len(sdb._queue) < len(calls):
            threading.Event().wait(0.01)
        writes = sdb._writes
        yield
    finally:
        sdb._write_lock.release()
    for th in threads:
        th.join(60)
    assert sdb._writes == writes + 1
