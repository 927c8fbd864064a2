"""Service metrics in the Prometheus text format (``GET /metrics``, docs/service.md).

A few counters and histograms kept in memory by one process (thread-safe), written in the text
exposition format 0.0.4 that Prometheus scrapes:

* ``rulkit_http_requests_total{method, route, status}``: requests answered (``route`` is the
  route template, never the path, so component ids stay out of the metrics);
* ``rulkit_http_request_seconds{method, route}``: latency histogram;
* ``rulkit_ingested_acquisitions_total``, ``rulkit_duplicate_acquisitions_total``,
  ``rulkit_ingest_batches_total{outcome}`` (applied, conflict, invalid, too_large, busy):
  what the ingestion did;
* ``rulkit_ingest_seconds``: time of each batch's validation and transaction (histogram);
* ``rulkit_page_cache_total{outcome}``: pages of components served from the page cache
  (``hit``) or read for it (``miss``; SQLite only, :mod:`.page_cache`);
* ``rulkit_errors_total{kind}``: server-side failures (busy or unreachable database, bugs);
* ``rulkit_gc_seconds{generation}``: the pauses of Python's cyclic garbage collector (every
  thread waits for a collection, so one over the objects of the whole process is a request's
  latency), once :meth:`Metrics.watch_gc` is on (``rulkit serve``).
"""

from __future__ import annotations

import gc
import threading
import time
from bisect import bisect_left
from collections import defaultdict
from collections.abc import Callable

BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)
"""Upper bounds (seconds) of the latency histograms."""
CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"


def _labels(names: tuple[str, ...], values: tuple[str, ...]) -> str:
    if not names:
        return ""
    esc = (v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") for v in values)
    return "{" + ",".join(f'{n}="{v}"' for n, v in zip(names, esc, strict=True)) + "}"


class _Histogram:
    def __init__(self) -> None:
        self.counts = [0] * (len(BUCKETS) + 1)
        self.total = 0.0

    def observe(self, v: float) -> None:
        self.counts[bisect_left(BUCKETS, v)] += 1
        self.total += v


class Metrics:
    """The service's counters and histograms (module docstring)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._counters: dict[str, dict[tuple[str, ...], float]] = defaultdict(
            lambda: defaultdict(float))
        self._hists: dict[str, dict[tuple[str, ...], _Histogram]] = defaultdict(dict)
        self._meta: dict[str, tuple[str, str, tuple[str, ...]]] = {}
        for name, kind, help_, labels in (
            ("rulkit_http_requests_total", "counter", "HTTP requests answered.",
             ("method", "route", "status")),
            ("rulkit_http_request_seconds", "histogram", "HTTP request latency.",
             ("method", "route")),
            ("rulkit_ingested_acquisitions_total", "counter",
             "Acquisitions stored by ingestion.", ()),
            ("rulkit_duplicate_acquisitions_total", "counter",
             "Acquisitions already stored, skipped.", ()),
            ("rulkit_ingest_batches_total", "counter", "Batches by outcome.", ("outcome",)),
            ("rulkit_ingest_seconds", "histogram", "Validation and transaction of a batch.",
             ()),
            ("rulkit_page_cache_total", "counter",
             "Pages of components from the page cache (hit) or read for it (miss).",
             ("outcome",)),
            ("rulkit_errors_total", "counter", "Server-side failures.", ("kind",)),
            ("rulkit_gc_seconds", "histogram", "Pauses of the cyclic garbage collector.",
             ("generation",)),
        ):
            self._meta[name] = (kind, help_, labels)

    def inc(self, name: str, *labels: str, by: float = 1.0) -> None:
        """Add ``by`` to counter ``name`` with label values ``labels``."""
        with self._lock:
            self._counters[name][labels] += by

    def observe(self, name: str, value: float, *labels: str) -> None:
        """Record ``value`` (seconds) in histogram ``name``."""
        with self._lock:
            h = self._hists[name].get(labels)
            if h is None:
                h = self._hists[name][labels] = _Histogram()
            h.observe(value)

    def watch_gc(self) -> Callable[[str, dict[str, int]], None]:
        """Time every collection of the cyclic garbage collector into ``rulkit_gc_seconds``:
        adds a callback to :data:`gc.callbacks` and returns it (remove it to stop)."""
        started = [0.0]

        def on_gc(phase: str, info: dict[str, int]) -> None:
            if phase == "start":
                started[0] = time.perf_counter()
            else:
                self.observe("rulkit_gc_seconds", time.perf_counter() - started[0],
                             str(info["generation"]))

        gc.callbacks.append(on_gc)
        return on_gc

    def render(self) -> str:
        """Everything in the Prometheus text format."""
        lines: list[str] = []
        with self._lock:
            for name, (kind, help_, names) in self._meta.items():
                lines += [f"# HELP {name} {help_}", f"# TYPE {name} {kind}"]
                if kind == "counter":
                    series = self._counters.get(name) or ({(): 0.0} if not names else {})
                    lines += [f"{name}{_labels(names, k)} {v:g}" for k, v in series.items()]
                else:
                    for k, h in self._hists.get(name, {}).items():
                        cum = 0
                        for bound, c in zip((*BUCKETS, float("inf")), h.counts, strict=True):
                            cum += c
                            le = "+Inf" if bound == float("inf") else f"{bound:g}"
                            lines.append(f"{name}_bucket{_labels((*names, 'le'), (*k, le))} "
                                         f"{cum}")
                        lines.append(f"{name}_sum{_labels(names, k)} {h.total:.6g}")
                        lines.append(f"{name}_count{_labels(names, k)} {cum}")
        return "\n".join(lines) + "\n"
