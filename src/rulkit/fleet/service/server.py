"""The HTTP server of ``rulkit serve``: uvicorn with a header deadline and a graceful stop.

uvicorn bounds the idle time between requests (keep-alive) but not the time a client may take
to send a request's headers, so a thousand half-sent requests held the server's connections
for as long as their clients liked. :class:`HeaderDeadline` closes a connection whose
request line and headers are not complete within ``header_timeout`` seconds of the connection
(or of the previous response), and one whose body stalls (no data for ``header_timeout``
seconds); the acquisitions' body also has its own deadline
(:func:`rulkit.fleet.service.bodies.read_body`). On SIGTERM or SIGINT, :func:`serve` stops
accepting connections and lets the requests in flight finish (an ingestion commits and is
answered) for up to ``grace`` seconds before it exits.

Before it serves, :func:`serve` collects the start-up's garbage and freezes what is left
(:func:`gc.freeze`): the ~10^5 objects of the libraries and the app are then never scanned
again, so a full collection, when one comes, looks at what the requests made since instead
of stopping every thread over the whole heap (``benchmarks/profile_page.py`` times both;
docs/service-load.md, "Lean reads"). The app's metrics time each collection
(``rulkit_gc_seconds``).
"""

from __future__ import annotations

import asyncio
import gc
import logging
from typing import Any

from uvicorn.protocols.http.h11_impl import H11Protocol

HEADER_TIMEOUT = 10.0
"""Seconds a client has to send a request line and its headers."""
GRACE = 30.0
"""Seconds the requests in flight get to finish on shutdown."""


class HeaderDeadline:
    """A deadline on each request's headers, mixed into one of uvicorn's HTTP/1.1 protocols
    (:func:`protocol`)."""

    header_timeout = HEADER_TIMEOUT
    loop: asyncio.AbstractEventLoop
    transport: asyncio.Transport
    cycle: Any

    def connection_made(self, transport: asyncio.Transport) -> None:
        """Accept the connection and start the headers' deadline."""
        super().connection_made(transport)  # type: ignore[misc]
        self._deadline: asyncio.TimerHandle | None = None
        self._last_data = self.loop.time()
        self._arm()

    def _arm(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
        self._deadline = self.loop.call_later(self.header_timeout, self._expire)

    def _expire(self) -> None:
        if self.transport.is_closing():
            return
        if self.cycle is None or self.cycle.response_complete:  # headers not in time
            self.transport.close()
        elif self.cycle.more_body and (
                self.loop.time() - self._last_data > self.header_timeout):
            self.transport.close()  # a body that stalled
        else:  # the app is answering: look again later
            self._arm()

    def data_received(self, data: bytes) -> None:
        """Note when data last arrived (a stalled body is cut off)."""
        self._last_data = self.loop.time()
        super().data_received(data)  # type: ignore[misc]

    def on_response_complete(self) -> None:
        """After each response the next request's headers get a new deadline."""
        super().on_response_complete()  # type: ignore[misc]
        self._arm()

    def connection_lost(self, exc: Exception | None) -> None:
        """Stop the deadline with the connection."""
        if self._deadline is not None:
            self._deadline.cancel()
        super().connection_lost(exc)  # type: ignore[misc]


def protocol(header_timeout: float, parser: str = "auto") -> type[asyncio.Protocol]:
    """The HTTP/1.1 protocol with ``header_timeout``: ``parser`` ``"httptools"`` (llhttp, in
    C), ``"h11"`` (pure Python) or ``"auto"`` (httptools when it is installed)."""
    base: type = H11Protocol
    if parser != "h11":
        try:
            from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol
        except ImportError:
            if parser == "httptools":
                raise
        else:
            base = HttpToolsProtocol
    made: type[asyncio.Protocol] = type(f"HeaderDeadline{base.__name__}", (HeaderDeadline, base),
                                        {"header_timeout": header_timeout})
    return made


def config(app: Any, host: str, port: int, *, header_timeout: float = HEADER_TIMEOUT,
           grace: float = GRACE, log_level: str = "info") -> Any:
    """The uvicorn configuration of ``rulkit serve`` (access log off: it would print paths,
    hence component ids; the app logs route templates)."""
    import uvicorn

    return uvicorn.Config(app, host=host, port=port, access_log=False, log_level=log_level,
                          http=protocol(header_timeout), timeout_keep_alive=5,
                          timeout_graceful_shutdown=int(grace), log_config=None)


class JsonFormatter(logging.Formatter):
    """One JSON object per log line (``--log-format json``): time (ISO 8601, UTC), level,
    logger, message and the request fields the access log adds (method, route, status,
    ms)."""

    FIELDS = ("method", "route", "status", "ms")

    def format(self, record: logging.LogRecord) -> str:
        """The record as one line of JSON."""
        import datetime as dt
        import json

        out: dict[str, Any] = {
            "time": dt.datetime.fromtimestamp(record.created, dt.UTC).isoformat(
                timespec="milliseconds"),
            "level": record.levelname.lower(), "logger": record.name,
            "message": record.getMessage()}
        out.update({k: getattr(record, k) for k in self.FIELDS if hasattr(record, k)})
        if record.exc_info:
            out["error"] = self.formatException(record.exc_info)
        return json.dumps(out, ensure_ascii=True)


def setup_logging(fmt: str) -> None:
    """Log INFO and above to stderr as text lines or, for ``fmt == "json"``, JSON lines."""
    handler = logging.StreamHandler()
    handler.setFormatter(JsonFormatter() if fmt == "json" else logging.Formatter(
        "%(asctime)s %(name)s %(levelname)s %(message)s"))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(logging.INFO)


def serve(app: Any, host: str, port: int, **kwargs: Any) -> None:
    """Run ``app`` until SIGTERM / SIGINT, then finish the requests in flight (module
    docstring)."""
    import uvicorn

    server = uvicorn.Server(config(app, host, port, **kwargs))
    metrics = getattr(app.state, "metrics", None)
    if metrics is not None:
        metrics.watch_gc()
    gc.collect()
    gc.freeze()
    server.run()
