"""The HTTP API on both backends (docs/service.md): auth, idempotent batches, reads, acks."""

import io
import logging

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.store.sqlite import ComponentStore


def auth(token):
    return {"Authorization": f"Bearer {token}"}


def fleet_frame(n_comp=6, steps=130, seed=0):
    """Exponential HI growth at different rates: some components reach warning/alarm."""
    rng = np.random.default_rng(seed)
    rows = []
    for j in range(n_comp):
        rate = 0.004 + 0.002 * j
        for s in range(steps):
            rows.append((f"unit-{j}", float(s), 0.3 * np.exp(rate * s) + rng.normal(0, 1e-3)))
    return pd.DataFrame(rows, columns=["component", "time", "hi"])


def as_rows(df):
    return {"rows": df.to_dict(orient="records")}


def post(client, token, df):
    return client.post("/api/v1/acquisitions", json=as_rows(df), headers=auth(token))


def test_auth_required_and_roles(client, sdb, tokens):
    assert client.get("/healthz").status_code == 200
    df = fleet_frame(1, 5)
    for method, path in [("get", "/api/v1/components"), ("get", "/api/v1/alerts"),
                         ("get", "/api/v1/components/unit-0"),
                         ("get", "/api/v1/components/unit-0/history")]:
        assert getattr(client, method)(path).status_code == 401
        r = getattr(client, method)(path, headers=auth("rk_not-a-token"))
        assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer"
    assert client.post("/api/v1/acquisitions", json=as_rows(df)).status_code == 401
    r = post(client, tokens["read"], df)
    assert r.status_code == 403 and "read-only" in r.json()["detail"]
    assert sdb.components(limit=10, offset=0)[0] == 0  # nothing written
    assert post(client, tokens["write"], df).status_code == 200
    assert client.get("/api/v1/components", headers=auth(tokens["read"])).status_code == 200
    r = client.post("/api/v1/alerts/1/ack", json={"by": "a", "reason": "b"},
                    headers=auth(tokens["read"]))
    assert r.status_code == 403
    # revocation takes effect at once; only the hash is stored
    assert sdb.revoke_token(name="reader") == 1
    assert client.get("/api/v1/components", headers=auth(tokens["read"])).status_code == 401
    with sdb.store() as s:
        stored = s._conn.execute("SELECT name, role, hash FROM api_tokens").fetchall()
    flat = " ".join(str(v) for row in stored for v in row)
    assert tokens["write"] not in flat and tokens["read"] not in flat
    assert all(len(row[2]) == 64 for row in stored)


def test_a_bad_token_is_refused_before_the_bodys_errors(client, sdb, tokens):
    """401 and 403 come before the body's own 413, 415 and 422, on both backends (PostgreSQL
    checks a batch's token in the group's transaction, and the token of a body that fails
    before it)."""
    bad, huge = b'{"rows": [{"component": "c", "time": 0}]}', {"Content-Length": str(2**40)}
    for token, status in [("rk_not-a-token", 401), (tokens["read"], 403),
                          (tokens["write"], 422)]:
        r = client.post("/api/v1/acquisitions", content=bad, headers={
            **auth(token), "Content-Type": "application/json"})
        assert r.status_code == status, r.text
        r = client.post("/api/v1/acquisitions", content=b"x", headers={
            **auth(token), "Content-Type": "application/x-nothing"})
        assert r.status_code == (415 if status == 422 else status), r.text
    for token, status in [("rk_not-a-token", 401), (tokens["read"], 403),
                          (tokens["write"], 413)]:
        r = client.post("/api/v1/acquisitions", content=b"{}", headers={
            **auth(token), "Content-Type": "application/json", **huge})
        assert r.status_code == status, r.text
    assert client.post("/api/v1/acquisitions", json=as_rows(fleet_frame(1, 5)), headers=auth(
        "rk_not-a-token")).headers["www-authenticate"] == "Bearer"
    assert sdb.components(limit=1)[0] == 0


def test_a_token_not_known_to_write_is_refused_before_its_body_is_read(
        client, sdb, tokens, monkeypatch):
    """An unknown or read-only token, or one refused since it last wrote, gets its 401 or
    403 before the body is decoded or anything reaches the writer, on both backends
    (PostgreSQL checks a known write token only in the group's transaction, so a token
    revoked after it wrote is refused there once, then at the door)."""
    import rulkit.fleet.service.routes_acquisitions as routes

    decoded = []
    real = routes.batch_frame
    monkeypatch.setattr(routes, "batch_frame",
                        lambda body, ctype: decoded.append(1) or real(body, ctype))
    df = fleet_frame(2, 5)
    writes = sdb._writes
    for token, status in [("rk_" + "x" * 43, 401), (tokens["read"], 403)]:
        assert post(client, token, df).status_code == status
    assert (decoded, sdb._writes) == ([], writes)
    assert post(client, tokens["write"], df).status_code == 200
    assert (len(decoded), sdb._writes) == (1, writes + 1)
    sdb.revoke_token(name="writer")
    assert post(client, tokens["write"], fleet_frame(2, 5, seed=1)).status_code == 401
    seen = len(decoded)  # 1 on SQLite (refused at the door), 2 on PostgreSQL
    assert post(client, tokens["write"], fleet_frame(2, 5, seed=2)).status_code == 401
    assert len(decoded) == seen
    assert sdb.components(limit=1)[0] == 2


def test_ingest_matches_direct_store_and_is_idempotent(client, sdb, tokens, tmp_path):
    df = fleet_frame()
    first, second = df[df.time < 90], df[df.time >= 80]  # 10 steps overlap per component
    r1 = post(client, tokens["write"], first)
    assert r1.status_code == 200, r1.text
    assert r1.json()["ingested"] == len(first) and r1.json()["duplicates"] == 0
    r2 = post(client, tokens["write"], second)
    assert r2.status_code == 200, r2.text
    n_overlap = len(df[(df.time >= 80) & (df.time < 90)])
    assert r2.json()["duplicates"] == n_overlap
    assert r2.json()["ingested"] == len(second) - n_overlap
    # oracle: the same acquisitions through the embedded SQLite store directly
    with ComponentStore(tmp_path / "oracle.db") as ref:
        ref_alerts = ref.ingest(df).alerts
        ref_status = ref.status().set_index("component")
        ref_hist = ref.history("unit-5")
    page = client.get("/api/v1/components", params={"limit": 100},
                      headers=auth(tokens["read"])).json()
    assert page["total"] == 6
    assert [c["component"] for c in page["items"]] == ref_status.index.tolist()  # worst first
    for c in page["items"]:
        ref = ref_status.loc[c["component"]]
        assert c["level"] == ["ok", "warning", "alarm"][int(ref["level"])]
        for k, rk in [("hi", "hi"), ("fhi", "fhi"), ("rul", "rul_median"),
                      ("rul_low", "rul_low"), ("rul_high", "rul_high"), ("last_time", "t")]:
            if c[k] is None:  # JSON null: not finite
                assert not np.isfinite(ref[rk]), k
            else:
                assert c[k] == pytest.approx(ref[rk], rel=1e-12, abs=1e-12), k
        assert c["n"] == 130 and c["failed"] == (c["level"] == "alarm")
        assert c["rul_state"] == ("failed" if c["failed"] else "estimated")
    alerts = [a for r in (r1, r2) for a in r.json()["alerts"]]
    assert [(a["component"], a["time"], a["level"]) for a in alerts] == [
        (a.component, a.t, a.name) for a in ref_alerts]
    h = client.get("/api/v1/components/unit-5/history", headers=auth(tokens["read"])).json()
    assert h["n"] == 130 and h["history"]["t"] == ref_hist["t"].tolist()
    np.testing.assert_allclose(h["history"]["fhi"], ref_hist["fhi"], rtol=1e-12)
    # re-sending everything is a no-op reported as duplicates
    before = sdb.components(limit=100, offset=0)
    r3 = post(client, tokens["write"], df)
    assert r3.json() == {"ingested": 0, "duplicates": len(df), "components": 0,
                         "new_components": 0, "alerts": []}
    assert sdb.components(limit=100, offset=0) == before


def test_conflicts_and_invalid_batches_change_nothing(client, sdb, tokens):
    df = fleet_frame(2, 20)
    assert post(client, tokens["write"], df).status_code == 200
    before = (sdb.components(limit=10, offset=0), sdb.alerts(state="all", component=None,
                                                              limit=10, offset=0))
    changed = df.iloc[[25]].copy()
    changed["hi"] += 0.01
    new = pd.DataFrame({"component": ["fresh"], "time": [0.0], "hi": [0.3]})
    r = post(client, tokens["write"], pd.concat([new, changed]))
    assert r.status_code == 409
    assert "row 2 (component 'unit-1'): time 5.0 is already stored" in r.json()["detail"]
    gap = pd.DataFrame({"component": ["unit-0"], "time": [4.5], "hi": [0.3]})
    r = post(client, tokens["write"], gap)
    assert r.status_code == 409 and "row 1 (component 'unit-0')" in r.json()["detail"]
    bad_rows = [
        ({"rows": [{"component": "x", "time": 1.0, "hi": 0.2}, {"component": "x", "time": 2.0,
                                                                 "hi": -0.5}]}, "row 2"),
        ({"rows": [{"component": "x", "time": 1.0, "hi": "high"}]}, "row 1"),
        ({"rows": [{"component": "x", "time": 1.0}]}, "no value column"),
        ({"rows": [{"component": 5, "time": 1.0, "hi": 0.2}]}, "row 1"),
        ({"rows": [{"component": "x", "time": 2.0, "hi": 0.2},
                   {"component": "x", "time": 1.0, "hi": 0.2}]}, "row 2"),
        ({"rows": []}, "0 rows"),
        ({"rows": [{"component": "a\x00b", "time": 1.0, "hi": 0.2}]}, "non-printable"),
        ({"nope": 1}, "rows"),
    ]
    for body, needle in bad_rows:
        r = client.post("/api/v1/acquisitions", json=body, headers=auth(tokens["write"]))
        assert r.status_code == 422, (body, r.text)
        assert needle in r.json()["detail"], (needle, r.json())
    r = client.post("/api/v1/acquisitions", content=b'{"rows": [{"component": "x", "time": NaN, '
                    b'"hi": 0.2}]}', headers={**auth(tokens["write"]),
                                              "Content-Type": "application/json"})
    assert r.status_code == 422 and "row 1" in r.json()["detail"]
    r = client.post("/api/v1/acquisitions", content=b"x", headers={
        **auth(tokens["write"]), "Content-Type": "image/png"})
    assert r.status_code == 415
    after = (sdb.components(limit=10, offset=0), sdb.alerts(state="all", component=None,
                                                             limit=10, offset=0))
    assert after == before


def test_csv_and_parquet_uploads(client, sdb, tokens):
    df = fleet_frame(3, 10)
    buf = io.BytesIO()
    df.iloc[:15].to_parquet(buf)
    r = client.post("/api/v1/acquisitions", content=df.iloc[15:].to_csv(index=False),
                    headers={**auth(tokens["write"]), "Content-Type": "text/csv"})
    assert r.status_code == 200 and r.json()["ingested"] == 15
    r = client.post("/api/v1/acquisitions", content=buf.getvalue(), headers={
        **auth(tokens["write"]), "Content-Type": "application/vnd.apache.parquet"})
    assert r.status_code == 409  # unit-0 at t < its stored last time, not stored: refused
    parts = [df[df.component == "unit-0"], df[df.component != "unit-0"]]
    # the CSV part holds unit-1 (t >= 5) and unit-2; re-sending it is all duplicates
    r = client.post("/api/v1/acquisitions", content=parts[1].iloc[5:].to_csv(index=False),
                    headers={**auth(tokens["write"]), "Content-Type": "text/csv"})
    assert r.status_code == 200 and r.json()["duplicates"] == 15
    r = client.post("/api/v1/acquisitions", content=b"component,time,hi\nx,1,\n",
                    headers={**auth(tokens["write"]), "Content-Type": "text/csv"})
    assert r.status_code == 422 and "row 1" in r.json()["detail"]
    r = client.post("/api/v1/acquisitions", content=b"PAR1garbage", headers={
        **auth(tokens["write"]), "Content-Type": "application/vnd.apache.parquet"})
    assert r.status_code == 422 and "Parquet" in r.json()["detail"]


def test_listing_filters_pagination_and_lookup(client, tokens):
    df = fleet_frame()
    post(client, tokens["write"], df)
    h = auth(tokens["read"])
    full = client.get("/api/v1/components", params={"limit": 100}, headers=h).json()["items"]
    key = [(-{"alarm": 2, "warning": 1, "ok": 0}[c["level"]],
            1e308 if c["rul"] is None else c["rul"], c["component"]) for c in full]
    assert key == sorted(key)  # worst first: level, then RUL, then id
    by_rul = client.get("/api/v1/components", params={"limit": 100, "sort": "rul"},
                        headers=h).json()["items"]
    assert [c["rul"] for c in by_rul] == sorted(c["rul"] for c in full)
    summary = client.get("/api/v1/summary", headers=h).json()
    assert summary["total"] == len(full) and summary["estimator"] == "trend"
    assert summary["counts"] == {lv: sum(c["level"] == lv for c in full)
                                 for lv in ("ok", "warning", "alarm")} | {"stale": 0}
    pages = [client.get("/api/v1/components", params={"limit": 4, "offset": o},
                        headers=h).json()["items"] for o in (0, 4)]
    assert pages[0] + pages[1] == full
    for level in ("ok", "warning", "alarm"):
        got = client.get("/api/v1/components", params={"level": level}, headers=h).json()
        assert got["items"] == [c for c in full if c["level"] == level]
        assert got["total"] == len(got["items"])
    assert {c["level"] for c in full} >= {"ok", "alarm"}
    assert client.get("/api/v1/components", params={"level": "bad"}, headers=h
                      ).status_code == 422
    assert client.get("/api/v1/components", params={"limit": 0}, headers=h).status_code == 422
    one = client.get("/api/v1/components/unit-0", headers=h).json()
    assert one["component"] == "unit-0" and one["open_alerts"] == 0
    r = client.get("/api/v1/components/nope", headers=h)
    assert r.status_code == 404
    assert client.get("/api/v1/components/nope/history", headers=h).status_code == 404


def clone_component(sdb, source, new_ids):
    """Copy a stored component's row under other ids, bypassing the ingest validation: the
    API and the page must cope with whatever a database holds (older versions, other
    writers), whatever id alphabet ingestion accepts today."""
    from rulkit.fleet.store.tracker_rows import ROW_FIELDS

    cols = ", ".join((*ROW_FIELDS, "max_level"))
    with sdb.store() as s, s._transaction("IMMEDIATE") as conn:
        for c in new_ids:
            conn.execute(f"INSERT INTO components (component, {cols}) SELECT ?, {cols} "
                         "FROM components WHERE component = ?", (c, source))


def test_ids_with_slashes_and_odd_characters_round_trip(client, sdb, tokens):
    ids = ["a/b", "x/history", "<script>alert(1)</script>", "\x1b[2J\x1b]0;pwn\x07", "é ü"]
    df = pd.DataFrame({"component": ["seed"], "time": 1.0, "hi": 0.3})
    assert post(client, tokens["write"], df).status_code == 200
    clone_component(sdb, "seed", ids)
    # control characters are outside the ingest id alphabet (issue 13 item 2): refused, by name
    bad = pd.DataFrame({"component": ["\x1b[2J\x1b]0;pwn\x07"], "time": 1.0, "hi": 0.3})
    r = post(client, tokens["write"], bad)
    assert r.status_code == 422 and "non-printable character" in r.text, r.text
    from urllib.parse import quote

    for c in ids:
        r = client.get("/api/v1/components/" + quote(c, safe=""), headers=auth(tokens["read"]))
        assert r.status_code == 200 and r.json()["component"] == c, c
        r = client.get("/api/v1/components/" + quote(c, safe="") + "/history",
                       headers=auth(tokens["read"]))
        assert r.status_code == 200 and r.json()["component"] == c, c
        assert r.json()["returned"] == 0  # cloned state, no history rows


def test_alerts_ack_keeps_who_and_why(client, sdb, tokens):
    r = post(client, tokens["write"], fleet_frame())
    new = r.json()["alerts"]
    assert new, "the fixture fleet must raise alerts"
    h = auth(tokens["read"])
    open_ = client.get("/api/v1/alerts", headers=h).json()
    assert open_["total"] == len(new)
    assert {a["id"] for a in open_["items"]} == {a["id"] for a in new}
    aid = new[0]["id"]
    r = client.post(f"/api/v1/alerts/{aid}/ack", json={"by": "ops <b>", "reason": "replaced"},
                    headers=auth(tokens["write"]))
    assert r.status_code == 200
    ack = r.json()["acknowledged"]
    assert ack["by"] == "ops <b>" and ack["reason"] == "replaced" and ack["token_name"] == "writer"
    r = client.post(f"/api/v1/alerts/{aid}/ack", json={"by": "x", "reason": "y"},
                    headers=auth(tokens["write"]))
    assert r.status_code == 409 and "ops <b>" in r.json()["detail"]
    assert client.post("/api/v1/alerts/999999/ack", json={"by": "x", "reason": "y"},
                       headers=auth(tokens["write"])).status_code == 404
    assert client.post(f"/api/v1/alerts/{aid + 1}/ack", json={"by": "", "reason": "y"},
                       headers=auth(tokens["write"])).status_code == 422
    done = client.get("/api/v1/alerts", params={"state": "acknowledged"}, headers=h).json()
    assert [a["id"] for a in done["items"]] == [aid]
    assert client.get("/api/v1/alerts", headers=h).json()["total"] == len(new) - 1
    comp = new[0]["component"]
    hist = client.get(f"/api/v1/components/{comp}/history", headers=h).json()
    assert aid in [a["id"] for a in hist["alerts"]]


def test_logs_never_hold_tokens_or_ids(client, tokens, caplog):
    caplog.set_level(logging.DEBUG)
    secret_id = "secret-component-7f3a"
    df = pd.DataFrame({"component": [secret_id], "time": [1.0], "hi": [0.2]})
    post(client, tokens["write"], df)
    client.get(f"/api/v1/components/{secret_id}", headers=auth(tokens["read"]))
    client.get("/api/v1/components", headers=auth("rk_wrong-token-value"))
    # everything the server side logged (httpx is the test's client, not the server)
    text = "\n".join(r.getMessage() for r in caplog.records if not r.name.startswith("httpx"))
    assert "/api/v1/components/{component:path}" in text  # the route template is logged
    for s in (secret_id, tokens["write"], tokens["read"], "rk_wrong-token-value"):
        assert s not in text


def test_dashboard_served_from_package_with_csp(client):
    r = client.get("/")
    assert r.status_code == 200 and "<table id=\"fleet-table\">" in r.text
    assert "script-src 'self'" in r.headers["content-security-policy"]
    assert "http" not in r.text.replace('http-equiv', '')  # no external asset
    for asset in ("/static/app.js", "/static/style.css"):
        assert client.get(asset).status_code == 200
    assert ".innerHTML =" not in client.get("/static/app.js").text


def test_components_named_dot_and_dotdot_are_reachable(client, tokens):
    """Browsers rewrite the path segments '.' and '..' (also as %2E): the dashboard asks for
    a history with the id in the query, which reaches every id."""
    df = pd.DataFrame({"component": [".", "..", "a/.."] * 3,
                       "time": np.repeat([0.0, 1.0, 2.0], 3), "hi": 0.3})
    assert post(client, tokens["write"], df).status_code == 200
    for name in (".", "..", "a/.."):
        r = client.get("/api/v1/history", params={"component": name},
                       headers=auth(tokens["read"]))
        assert r.status_code == 200 and r.json()["component"] == name
        assert r.json()["returned"] == 3
    assert client.get("/api/v1/history", params={"component": "nope"},
                      headers=auth(tokens["read"])).status_code == 404
