"""The service's Prometheus metrics (src/rulkit/fleet/service/metrics.py)."""

import gc
import re

from rulkit.fleet.service.metrics import Metrics


def _gc_count(m: Metrics, generation: int) -> int:
    got = re.search(rf'rulkit_gc_seconds_count{{generation="{generation}"}} (\d+)', m.render())
    return int(got.group(1)) if got else 0


def test_watch_gc_times_each_collection_by_generation():
    m = Metrics()
    assert _gc_count(m, 2) == 0
    callback = m.watch_gc()
    try:
        gc.collect(2)
        gc.collect(0)
        seen = _gc_count(m, 2)
    finally:
        gc.callbacks.remove(callback)
    assert seen >= 1 and _gc_count(m, 0) >= 1
    gc.collect(2)  # no longer watched
    assert _gc_count(m, 2) == seen
    assert re.search(r'rulkit_gc_seconds_sum{generation="2"} [0-9.e-]+\n', m.render())
