"""ServiceDB's reads beside the routes (src/rulkit/fleet/service/db.py): the stale horizon
that bounds a cached page's clock window, against the stale flags recomputed at every
instant of a fine grid."""

import math

import numpy as np
import pandas as pd

from rulkit.fleet.monitoring.rules import MonitoringRules, stale
from rulkit.fleet.service.db import STALE_MARGIN, ServiceDB
from rulkit.fleet.store.postgres import open_store

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
