"""ServiceDB beside the routes (src/rulkit/fleet/service/db.py): the stale horizon that
bounds a cached page's clock window, against the stale flags recomputed at every instant of
a fine grid; the ingest's token check inside the group commit's transaction."""

import math

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.monitoring.rules import MonitoringRules, stale
from rulkit.fleet.service.db import STALE_MARGIN, ServiceDB, TokenRefused
from rulkit.fleet.service.loadgen import request, start_server
from rulkit.fleet.store.acquisitions import IngestError
from rulkit.fleet.store.postgres import open_store

from .conftest import one_group, token_cli

T0 = 1.7e9


def _fleet(db: str, seen: list[float], stale_after: float | None) -> None:
    with open_store(db) as s:
        s.set_rules(MonitoringRules(stale_after=stale_after))
        for i, t in enumerate(seen):
            s.now = t
            s.ingest(pd.DataFrame({"component": [f"c{i}"], "time": [0.0], "hi": [0.3]}), "t")


def test_stale_horizon_keeps_the_stale_set_and_is_tight(db_url):
    after = 100.0
    seen = [T0, T0 + 10.0, T0 + 10.0 + 1e-4, T0 + 25.0]
    _fleet(db_url, seen, after)
    sdb = ServiceDB(db_url)
    try:
        for now in (T0 + 50.0, T0 + 100.5, T0 + 109.0, T0 + 110.0 - 5e-4, T0 + 124.0,
                    T0 + 200.0):
            until = sdb.stale_horizon(now)
            flags = stale(np.array(seen), now, MonitoringRules(stale_after=after))
            if math.isinf(until):
                assert flags.all()
                continue
            for t in np.linspace(now, until, 101)[:-1]:  # the window: the same stale set
                assert (stale(np.array(seen), t, MonitoringRules(stale_after=after))
                        == flags).all(), (now, t)
            if until > now:  # just past it, one more component is stale
                later = stale(np.array(seen), until + 2 * STALE_MARGIN,
                              MonitoringRules(stale_after=after))
                assert later.sum() > flags.sum(), now
        # within the margin of the cutoff nothing is certain: an empty window
        assert sdb.stale_horizon(T0 + 110.0 - 5e-4) <= T0 + 110.0 - 5e-4
    finally:
        sdb.close()


def test_stale_horizon_without_a_stale_rule_is_unbounded(db_url):
    _fleet(db_url, [T0], None)
    sdb = ServiceDB(db_url)
    try:
        assert sdb.stale_horizon(T0 + 1e6) == math.inf
    finally:
        sdb.close()


def _batch(prefix: str, t: float = 1.0) -> pd.DataFrame:
    return pd.DataFrame({"component": [f"{prefix}{i}" for i in range(5)], "time": t,
                         "hi": 0.3})


def _outcome(sdb: ServiceDB, df: pd.DataFrame, source: str, token: str | None) -> object:
    try:
        return sdb.ingest(df, source, token=token)
    except (TokenRefused, IngestError) as err:
        return err


def test_a_group_checks_its_tokens_in_its_transaction(db_url):
    """One group of five batches: a write token's and a token-less batch are written, a
    read-only token's (403), an unknown token's and one revoked by another connection after
    the batch was queued but before the group's transaction (401) are not, nothing of
    them."""
    sdb = ServiceDB(db_url)
    other = ServiceDB(db_url)  # another connection pool: the revoking side
    try:
        write, read = sdb.create_token("write", "ops")[1], sdb.create_token("read", "dash")[1]
        gone = sdb.create_token("write", "gone")[1]
        cases = [("w", "api:", write), ("r", "api:", read), ("g", "api:", gone),
                 ("u", "api:", "rk_" + "x" * 43), ("d", "direct", None)]
        out: dict[str, object] = {}
        with one_group(sdb, [lambda c=c: out.__setitem__(
                c[0], _outcome(sdb, _batch(c[0]), c[1], c[2])) for c in cases]):
            assert other.revoke_token(name="gone") == 1  # queued, not yet written
        assert [getattr(out[k], "status", None) for k in "rgu"] == [403, 401, 401]
        assert out["w"]["ingested"] == 5 and out["d"]["ingested"] == 5  # type: ignore[index]
        names = [c["component"] for c in sdb.components(limit=100)[1]]
        assert sorted(names) == [f"{p}{i}" for p in "dw" for i in range(5)]
        with sdb.store() as s:
            sources = [r[0] for r in s._conn.execute(
                "SELECT source FROM ingests ORDER BY id").fetchall()]
        assert sorted(sources) == ["api:ops", "direct"]
    finally:
        sdb.close()
        other.close()


def test_a_bad_token_is_refused_before_the_batchs_own_error(db_url):
    """An invalid batch with a refused token gets the token's refusal (as a check before
    the body gives it); with a write token, its own error."""
    sdb = ServiceDB(db_url)
    try:
        write, read = sdb.create_token("write", "ops")[1], sdb.create_token("read", "dash")[1]
        bad = pd.DataFrame({"component": ["c"], "time": [0.0], "hi": [-1.0]})
        assert _outcome(sdb, bad, "api:", "rk_unknown").status == 401  # type: ignore[attr-defined]
        assert _outcome(sdb, bad, "api:", read).status == 403  # type: ignore[attr-defined]
        assert _outcome(sdb, bad, "api:", "").status == 401  # type: ignore[attr-defined]
        assert isinstance(_outcome(sdb, bad, "api:", write), IngestError)
        assert sdb.components(limit=1)[0] == 0
    finally:
        sdb.close()


@pytest.mark.parametrize("db_url", ["postgresql"], indirect=True)
def test_revocation_by_another_process_refuses_the_next_post_on_postgresql(db_url):
    """``rulkit token revoke`` in another process: the server's next batch of that token is
    refused (401) and nothing of it is written; a new token works at once."""
    sdb = ServiceDB(db_url)
    write = sdb.create_token("write", "ops")[1]
    sdb.close()
    srv = start_server(db_url)
    try:
        batch = {"rows": [{"component": "c0", "time": 0.0, "hi": 0.2}]}
        assert request(srv.port, "POST", "/api/v1/acquisitions", batch, write)[0] == 200
        token_cli(db_url, "revoke", "--name", "ops")
        batch["rows"][0]["time"] = 1.0
        assert request(srv.port, "POST", "/api/v1/acquisitions", batch, write)[0] == 401
        fresh = token_cli(db_url, "create", "--role", "write", "--name", "new")
        fresh = fresh.strip().splitlines()[-1]
        batch["rows"][0]["time"] = 2.0
        assert request(srv.port, "POST", "/api/v1/acquisitions", batch, fresh)[0] == 200
    finally:
        srv.stop()
    with open_store(db_url) as s:
        assert s._conn.execute("SELECT n FROM components").fetchone()[0] == 2
