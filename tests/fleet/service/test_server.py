"""The server of rulkit serve (rulkit.fleet.service.server): half-sent requests are cut off,
a shutdown finishes the batch in flight, JSON logs. The first failed on the code before
(1,000 partial requests were held with no timeout)."""

import json
import logging
import socket
import threading
import time

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.service.app import create_app
from rulkit.fleet.service.db import ServiceDB
from rulkit.fleet.service.loadgen import request, start_server
from rulkit.fleet.service.server import JsonFormatter, config, protocol


def test_half_sent_requests_are_closed_and_the_server_keeps_serving(tmp_path):
    db = str(tmp_path / "fleet.db")
    ServiceDB(db).close()
    srv = start_server(db, options=("--header-timeout", "1"))
    socks = []
    try:
        for _ in range(200):
            s = socket.create_connection(("127.0.0.1", srv.port), timeout=30)
            s.sendall(b"GET /api/v1/components HTTP/1.1\r\nHost: x\r\nX-Slow: ")
            socks.append(s)
        closed = 0
        for s in socks:  # each is closed by the server (recv gives EOF), not by our timeout
            try:
                closed += s.recv(1024) == b""
            except ConnectionResetError:
                closed += 1
        assert closed == len(socks)
        assert request(srv.port, "GET", "/healthz")[0] == 200
    finally:
        for s in socks:
            s.close()
        srv.stop()


@pytest.mark.parametrize("parser", ["httptools", "h11"])
def test_both_parsers_close_half_sent_requests_and_serve(tmp_path, parser):
    import uvicorn

    sdb = ServiceDB(str(tmp_path / "fleet.db"))
    cfg = config(create_app(sdb), "127.0.0.1", 0, log_level="warning")
    cfg.http = protocol(0.5, parser)
    server = uvicorn.Server(cfg)
    th = threading.Thread(target=server.run, daemon=True)
    th.start()
    try:
        while not server.started:
            time.sleep(0.02)
        port = server.servers[0].sockets[0].getsockname()[1]
        with socket.create_connection(("127.0.0.1", port), timeout=30) as s:
            s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\nX-Slow: ")
            t0 = time.monotonic()
            try:
                assert s.recv(1024) == b""  # closed by the server, not by our timeout
            except ConnectionResetError:
                pass
            assert time.monotonic() - t0 < 20
        assert request(port, "GET", "/healthz")[0] == 200
        assert cfg.http.__mro__[2].__module__.endswith(f".{parser}_impl")
    finally:
        server.should_exit = True
        th.join(30)
        sdb.close()


def test_shutdown_finishes_the_batch_in_flight(tmp_path):
    import uvicorn

    db = str(tmp_path / "fleet.db")
    sdb = ServiceDB(db)
    _, token = sdb.create_token("write", "w")
    started, release = threading.Event(), threading.Event()
    ingest = sdb.ingest

    def held(df, source, **kw):  # the batch is in flight when the shutdown starts
        started.set()
        release.wait(60)
        return ingest(df, source, **kw)

    sdb.ingest = held
    cfg = config(create_app(sdb), "127.0.0.1", 0, grace=30, log_level="warning")
    server = uvicorn.Server(cfg)
    th = threading.Thread(target=server.run, daemon=True)
    th.start()
    while not server.started:
        time.sleep(0.02)
    port = server.servers[0].sockets[0].getsockname()[1]
    out = {}
    body = {"rows": [{"component": f"c{i}", "time": 1.0, "hi": 0.3} for i in range(500)]}
    poster = threading.Thread(target=lambda: out.update(r=request(
        port, "POST", "/api/v1/acquisitions", body, token)))
    poster.start()
    assert started.wait(60)
    server.should_exit = True  # what SIGTERM / SIGINT does
    time.sleep(0.2)
    release.set()
    poster.join(60)
    th.join(60)
    assert out["r"][0] == 200 and out["r"][1]["ingested"] == 500
    sdb.close()
    reopened = ServiceDB(db)
    assert reopened.components(limit=1, offset=0)[0] == 500
    reopened.close()


def test_json_logs_one_object_per_line():
    rec = logging.LogRecord("rulkit.service", logging.INFO, __file__, 1, "%s %s", ("GET", "/x"),
                            None)
    rec.route, rec.status, rec.ms = "/x", 200, 1.5
    out = json.loads(JsonFormatter().format(rec))
    assert out["message"] == "GET /x" and out["status"] == 200 and out["level"] == "info"


def test_metrics_readiness_and_liveness(client, tokens):
    rows = pd.DataFrame({"component": "a", "time": np.arange(5.0), "hi": 0.3})
    r = client.post("/api/v1/acquisitions", json={"rows": rows.to_dict(orient="records")},
                    headers={"Authorization": f"Bearer {tokens['write']}"})
    assert r.status_code == 200
    client.post("/api/v1/acquisitions", json={"rows": [{"component": "a"}]},
                headers={"Authorization": f"Bearer {tokens['write']}"})
    assert client.get("/healthz").json()["status"] == "ok"
    assert client.get("/readyz").json()["status"] == "ok"
    text = client.get("/metrics").text
    assert "rulkit_ingested_acquisitions_total 5" in text
    assert 'rulkit_ingest_batches_total{outcome="applied"} 1' in text
    assert 'rulkit_ingest_batches_total{outcome="invalid"} 1' in text
    assert ('rulkit_http_requests_total{method="POST",route="/api/v1/acquisitions",'
            'status="200"} 1') in text
    assert 'rulkit_http_request_seconds_bucket{method="POST",route="/api/v1/acquisitions",' \
           'le="+Inf"} 2' in text
