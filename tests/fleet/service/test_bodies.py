"""Bounded request bodies and hostile inputs (rulkit.fleet.service.bodies): memory stays
bounded by the body cap, decoded rows are capped before they are decoded, and no input gives
a 500. Each scenario failed on the code before (401 MB added by a 200 MB upload, 2.4 GB by a
small Parquet file, 500 on a lone surrogate, deep nesting and non-UTF-8 Parquet ids)."""

import http.client
import io
import json

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from rulkit.fleet.service.db import ServiceDB
from rulkit.fleet.service.loadgen import start_server


def auth(token):
    return {"Authorization": f"Bearer {token}"}


@pytest.fixture
def server(tmp_path):
    db = str(tmp_path / "fleet.db")
    sdb = ServiceDB(db)
    _, token = sdb.create_token("write", "w")
    sdb.close()
    srv = start_server(db, pool=2)
    yield srv, token
    srv.stop()


def _chunked_post(port, token, chunks, ctype="text/csv"):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=120)
    try:
        conn.putrequest("POST", "/api/v1/acquisitions")
        conn.putheader("Authorization", f"Bearer {token}")
        conn.putheader("Content-Type", ctype)
        conn.putheader("Transfer-Encoding", "chunked")
        conn.endheaders()
        try:
            for c in chunks:
                conn.send(b"%x\r\n%s\r\n" % (len(c), c))
            conn.send(b"0\r\n\r\n")
        except OSError:
            pass  # the server answered 413 and closed before the upload ended
        return conn.getresponse().status
    finally:
        conn.close()


def test_a_large_chunked_upload_is_cut_off_with_bounded_memory(server):
    srv, token = server
    before = srv.memory_mb()[1]
    line = b"c0,1.0,0.5\n" * 100_000  # 1.1 MB
    status = _chunked_post(srv.port, token, [b"component,time,hi\n"] + [line] * 180)
    assert status == 413
    grown = srv.memory_mb()[1] - before
    assert grown < 200, f"peak memory grew by {grown:.0f} MB for a 200 MB upload"


def test_a_parquet_file_of_many_rows_is_refused_from_its_metadata(server, tmp_path):
    srv, token = server
    n = 1_000_000
    t = pa.table({"component": pa.array(["c0"] * n), "time": pa.array([1.0] * n),
                  "hi": pa.array([0.5] * n)})
    buf = io.BytesIO()
    with pq.ParquetWriter(buf, t.schema, compression="zstd") as w:
        for _ in range(6):  # 6 million rows in a file of a few kB
            w.write_table(t)
    body = buf.getvalue()
    assert len(body) < 1_000_000
    before = srv.memory_mb()[1]
    conn = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=120)
    conn.request("POST", "/api/v1/acquisitions", body=body,
                 headers={**auth(token), "Content-Type": "application/vnd.apache.parquet"})
    r = conn.getresponse()
    detail = json.loads(r.read())["detail"]
    conn.close()
    assert r.status == 413 and "6000000 rows" in detail
    grown = srv.memory_mb()[1] - before
    assert grown < 50, f"peak memory grew by {grown:.0f} MB before the refusal"


def test_hostile_bodies_get_client_errors_never_500(client, tokens):
    h = auth(tokens["write"])
    bad = [
        (b'{"rows": [{"component": "a\\udc80b", "time": 0, "hi": 0.1}]}', "application/json"),
        (b"[" * 100_000 + b"]" * 100_000, "application/json"),
        (b'{"rows": ' + b"[" * 5000 + b"]" * 5000 + b"}", "application/json"),
        (b'{"rows": [{"component": "a", "time": 1e999, "hi": 0.1}]}', "application/json"),
        (b'{"rows": [{"component": "a", "time": ' + b"9" * 400 + b', "hi": 0.1}]}',
         "application/json"),
        (b'{"rows": [{"component": "a", "time": 0, "hi": true}]}', "application/json"),
        (b"component,time,hi\n\xff\xfe,0,0.1\n", "text/csv"),
        (b"\x00\x01garbage", "application/vnd.apache.parquet"),
    ]
    t = pa.table({"component": pa.array([b"\xff\xfe\x80", b"ok"], pa.binary()),
                  "time": [0.0, 1.0], "hi": [0.1, 0.2]})
    buf = io.BytesIO()
    pq.write_table(t, buf)
    bad.append((buf.getvalue(), "application/vnd.apache.parquet"))
    for body, ctype in bad:
        r = client.post("/api/v1/acquisitions", content=body,
                        headers={**h, "Content-Type": ctype})
        assert r.status_code in (413, 422), (body[:60], r.status_code, r.text[:300])
        assert isinstance(r.json()["detail"], str)


def test_openapi_documents_every_answer_and_requires_hi(client):
    spec = client.get("/openapi.json").json()
    post = spec["paths"]["/api/v1/acquisitions"]["post"]
    assert {"401", "403", "409", "413", "415", "422", "503"} <= set(post["responses"])
    row = post["requestBody"]["content"]["application/json"]["schema"]["properties"]["rows"]
    assert row["items"]["required"] == ["component", "time", "hi"]
    for path in ("/api/v1/components/{component}", "/api/v1/components/{component}/history"):
        assert {"401", "404"} <= set(spec["paths"][path]["get"]["responses"])
    ack = spec["paths"]["/api/v1/alerts/{alert_id}/ack"]["post"]["responses"]
    assert {"401", "403", "404", "409"} <= set(ack)
