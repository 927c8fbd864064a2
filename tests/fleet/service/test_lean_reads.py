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
