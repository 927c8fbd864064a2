"""A real `rulkit serve` process on loopback: short bounded load, and kill -9 mid-batch.

The full load test is benchmarks/bench_service.py (figures in docs/service-load.md).
"""

import threading
import time

import numpy as np
import pandas as pd

from rulkit.fleet.service.db import ServiceDB
from rulkit.fleet.service.loadgen import request, run_load, start_server, verify_exactly_once
from rulkit.fleet.store.postgres import open_store


def test_short_load_stores_every_acquisition_once(db_url):
    sdb = ServiceDB(db_url)
    _, token = sdb.create_token("write", "load")
    sdb.close()
    srv = start_server(db_url)
    try:
        res = run_load(srv.port, token, writers=8, readers=8, batches=4, batch_size=100,
                       max_reads=50)
        # writer 0's batches again: all duplicates
        again = run_load(srv.port, token, writers=1, readers=0, batches=4, batch_size=100)
    finally:
        srv.stop()
    assert res.errors == [] and again.errors == []
    assert res.duplicates == 0 and again.duplicates == 400
    assert len(res.get_latency) >= 8
    verify_exactly_once(db_url, writers=8, batches=4, batch_size=100)


def big_batch(k, n_comp=100, steps=50):
    t = np.arange(steps, dtype=float)
    comp = np.repeat([f"b{k}-{i}" for i in range(n_comp)], steps)
    hi = 0.2 + 0.001 * np.tile(t, n_comp)
    return pd.DataFrame({"component": comp, "time": np.tile(t, n_comp), "hi": hi})


def test_kill_9_mid_batch_keeps_committed_and_drops_partial(db_url):
    sdb = ServiceDB(db_url)
    _, token = sdb.create_token("write", "kill")
    sdb.close()
    batches = [big_batch(k) for k in range(10)]
    bodies = [{"rows": b.to_dict(orient="records")} for b in batches]
    acked, failed = [], []
    srv = start_server(db_url)

    def send():
        for k, body in enumerate(bodies):
            try:
                status, _ = request(srv.port, "POST", "/api/v1/acquisitions", body, token)
            except OSError:
                failed.append(k)
                return
            assert status == 200
            acked.append(k)

    th = threading.Thread(target=send)
    th.start()
    deadline = time.monotonic() + 60
    while len(acked) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.05)  # into the next batch
    srv.kill()
    th.join(60)
    assert len(acked) >= 2 and failed, "the kill must hit a batch in flight"
    with open_store(db_url, create=False) as store:
        hist = store.history()
        status = store.status()
    per_batch = hist["component"].str.split("-").str[0].value_counts()
    n_rows = len(batches[0])
    for k in range(len(batches)):
        got = int(per_batch.get(f"b{k}", 0))
        assert got in (0, n_rows), f"batch {k}: {got} of {n_rows} rows committed (partial)"
        if k in acked:
            assert got == n_rows, f"acknowledged batch {k} lost"
    assert status["n"].sum() == len(hist)
    # the database reopens; re-sending every batch up to the one in flight is idempotent
    sdb = ServiceDB(db_url)
    try:
        for b in batches[: failed[0] + 1]:
            out = sdb.ingest(b, "resend")
            assert out["ingested"] + out["duplicates"] == n_rows
        assert sdb.components(limit=1, offset=0)[0] == (failed[0] + 1) * 100
    finally:
        sdb.close()
    with open_store(db_url, create=False) as store:
        assert store.counts()[2] == (failed[0] + 1) * n_rows
