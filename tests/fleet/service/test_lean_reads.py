"""The lean reads (src/rulkit/fleet/service/lean_reads.py): every request answered exactly as
the FastAPI routes answer it (status, body bytes, headers), on both backends; the lean path
answers the valid pages and histories, and nothing else."""

import warnings
from urllib.parse import quote

import pytest

from rulkit.fleet.service.lean_reads import LeanReads, canonical_int

from .test_api import auth, fleet_frame, post


@pytest.fixture
def clients(sdb):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # starlette: httpx -> httpx2 notice
        from fastapi.testclient import TestClient

    from rulkit.fleet.service.app import create_app

    lean_app = create_app(sdb)
    with TestClient(lean_app) as lean, TestClient(create_app(sdb, lean_reads=False)) as full:
        yield lean, full, lean_app


def _lean_layer(app) -> LeanReads:
    layer = app.middleware_stack
    while not isinstance(layer, LeanReads):
        layer = layer.app
    return layer


def _requests(cursor: str, tokens: dict[str, str]) -> list[tuple[str, dict[str, str], bool]]:
    """(path, headers, whether the lean path answers it)."""
    r, w = auth(tokens["read"]), auth(tokens["write"])
    page = "/api/v1/components"
    hist = "/api/v1/components/unit-1/history"
    lean = [(page, r), (page, w), (f"{page}?limit=3", r), (f"{page}?limit=3&offset=2", r),
            (f"{page}?sort=rul&level=alarm&limit=2", r), (f"{page}?sort=due&level=ok", r),
            (f"{page}?level=stale", r), (f"{page}?level=warning&sort=worst", r),
            (f"{page}?limit=2&after={quote(cursor)}", r), (f"{page}?limit=1000", r),
            (f"{page}?offset=2147483647", r), (hist, r), (f"{hist}?limit=5", r),
            (f"{hist}?limit=100000", r), ("/api/v1/components/a%2Fb/history", r),
            ("/api/v1/history?component=unit-2&limit=7", r), ("/api/v1/history?component=a/b", r),
            (f"{page}?limit=3", {"Authorization": f"bearer  {tokens['read']} "})]
    full = [(page, {}), (page, auth("rk_nope")), (page, {"Authorization": "Basic eDp5"}),
            (page, {"Authorization": "Bearer"}), (f"{page}?limit=0", r),
            (f"{page}?limit=1001", r), (f"{page}?limit=050", r), (f"{page}?limit=+5", r),
            (f"{page}?limit=5&limit=6", r), (f"{page}?limit=", r), (f"{page}?level=bad", r),
            (f"{page}?sort=", r), (f"{page}?after=garbage", r), (f"{page}?after={'x' * 2001}", r),
            (f"{page}?foo=1", r), (f"{page}?offset=-1", r), (f"{page}?offset=2147483648", r),
            ("/api/v1/components/nope/history", r), (f"{hist}?limit=0", r),
            (f"{hist}?limit=100001", r), (f"{hist}?limit=1e3", r), (hist, {}),
            ("/api/v1/components/a%00b/history", r), ("/api/v1/components//history", r),
            ("/api/v1/components/a%2Fhistory", r), ("/api/v1/components/unit-1", r),
            ("/api/v1/history?component=", r), ("/api/v1/history?component=nope", r),
            ("/api/v1/history", r), (f"/api/v1/history?component={'x' * 513}", r),
            ("/api/v1/history?component=unit-2&limit=-3", r),
            ("/api/v1/history?component=unit-2", {})]
    return [(p, h, True) for p, h in lean] + [(p, h, False) for p, h in full]


def test_lean_reads_answer_as_the_routes_do(clients, sdb, tokens):
    from .test_api import clone_component

    lean, full, lean_app = clients
    assert post(lean, tokens["write"], fleet_frame()).status_code == 200
    clone_component(sdb, "unit-0", ["a/b"])
    cursor = full.get("/api/v1/components?limit=2", headers=auth(tokens["read"])).json()["next"]
    lean.get("/healthz")
    layer = _lean_layer(lean_app)
    statuses = set()
    for path, headers, answered in _requests(cursor, tokens):
        before = layer.served
        got, want = lean.get(path, headers=headers), full.get(path, headers=headers)
        assert layer.served - before == answered, path
        assert (got.status_code, got.content) == (want.status_code, want.content), path
        for h in ("content-type", "content-length", "x-content-type-options",
                  "www-authenticate"):
            assert got.headers.get(h) == want.headers.get(h), (path, h)
        statuses.add(got.status_code)
    assert statuses == {200, 401, 404, 422}
    metrics = lean.get("/metrics").text
    assert ('rulkit_http_requests_total{method="GET",route="/api/v1/components/'
            '{component:path}/history",status="200"}') in metrics


def test_canonical_int_takes_only_plain_digits_in_range():
    assert [canonical_int(t, 1, 1000) for t in ("1", "50", "1000")] == [1, 50, 1000]
    assert [canonical_int(t, 0, 9) for t in ("0", "00", "07", "+1", "-1", " 1", "1 ", "",
                                             "١", "10", "1_0")] == \
        [0, None, None, None, None, None, None, None, None, None, None]


def test_a_page_is_read_again_once_another_process_commits(tmp_path):
    """The server's cached page, then a write by this process (another one to the server):
    the next GET has it."""
    import pandas as pd

    from rulkit.fleet.service.db import ServiceDB
    from rulkit.fleet.service.loadgen import request, start_server
    from rulkit.fleet.store.postgres import open_store

    db = str(tmp_path / "fleet.db")
    sdb = ServiceDB(db)
    _, token = sdb.create_token("read", "dash")
    sdb.close()
    srv = start_server(db)
    try:
        path = "/api/v1/components?limit=5&sort=rul"
        first = [request(srv.port, "GET", path, token=token) for _ in range(3)]
        assert first[0] == first[1] == first[2] == (200, first[0][1])
        assert first[0][1]["total"] == 0
        for k in range(3):
            with open_store(db, create=False) as store:
                store.ingest(pd.DataFrame({"component": [f"n{k}"], "time": [0.0],
                                           "hi": [0.3]}), "other process")
            status, body = request(srv.port, "GET", path, token=token)
            assert status == 200 and body["total"] == k + 1
            assert {i["component"] for i in body["items"]} == {f"n{j}" for j in range(k + 1)}
    finally:
        srv.stop()


def test_the_clock_moving_the_stale_cutoff_is_seen(tmp_path, monkeypatch):
    """A cached page at one clock; the clock passes a component's stale time: the page,
    its filter and its total change, as a fresh read at that time gives them."""
    import pandas as pd

    from rulkit.fleet.monitoring.rules import MonitoringRules
    from rulkit.fleet.service import lean_reads
    from rulkit.fleet.service.app import create_app
    from rulkit.fleet.service.db import ServiceDB
    from rulkit.fleet.service.routes_components import page_body
    from rulkit.fleet.store.postgres import open_store

    t0, after = 1.7e9, 3600.0
    db = str(tmp_path / "fleet.db")
    with open_store(db) as s:
        s.set_rules(MonitoringRules(stale_after=after))
        for i, seen in enumerate((t0, t0 + 60.0)):
            s.now = seen
            s.ingest(pd.DataFrame({"component": [f"c{i}"], "time": [0.0], "hi": [0.3]}), "t")
    sdb = ServiceDB(db)
    _, token = sdb.create_token("read", "dash")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from fastapi.testclient import TestClient
    app = create_app(sdb)
    try:
        with TestClient(app) as client:
            layer = _lean_layer(app)
            pages = {"all": "/api/v1/components", "stale": "/api/v1/components?level=stale"}

            def read(now: float, cached: bool) -> dict[str, list[str]]:
                monkeypatch.setattr(lean_reads, "clock", lambda: now)
                out = {}
                for name, path in pages.items():
                    hits = layer.cache.hits
                    got = client.get(path, headers=auth(token))
                    assert got.status_code == 200 and layer.cache.hits - hits == cached
                    level = None if name == "all" else name
                    want = page_body(sdb, limit=50, offset=0, level=level, sort="worst",
                                     after=None, now=now)
                    assert got.json() == want, (now, name)
                    out[name] = [i["component"] for i in got.json()["items"] if i["stale"]]
                return out

            assert read(t0 + after - 1.0, False) == {"all": [], "stale": []}
            assert read(t0 + after - 0.5, True) == {"all": [], "stale": []}
            assert read(t0 + after + 1.0, False) == {"all": ["c0"], "stale": ["c0"]}
            assert read(t0 + after + 30.0, True) == {"all": ["c0"], "stale": ["c0"]}
            assert read(t0 + after + 61.0, False) == {"all": ["c0", "c1"],
                                                      "stale": ["c0", "c1"]}
            assert read(t0 + after - 1.0, False) == {"all": [], "stale": []}  # set back
            metrics = client.get("/metrics").text
            assert 'rulkit_page_cache_total{outcome="hit"} 4' in metrics
            assert 'rulkit_page_cache_total{outcome="miss"} 8' in metrics
    finally:
        sdb.close()
