"""The service's outermost layer of its own (docs/service.md): one access-log line and the
request metrics per request, the security headers, and a JSON 500 for a bug.

A plain ASGI middleware: it sees the response's first message to read the status and add the
headers, and forwards every message as it comes (Starlette's ``BaseHTTPMiddleware`` runs the
app in a task group and copies the body through a memory stream, a fixed cost per request of
the order of the rest of a page's work). The log names the route template
(``/api/v1/components/{component}``), the status and the duration, never the path itself
(component ids), a token or a body.
"""

from __future__ import annotations

import logging
import time
from collections.abc import MutableMapping
from typing import Any

from starlette.datastructures import MutableHeaders
from starlette.responses import JSONResponse

from rulkit.fleet.service.metrics import Metrics

log = logging.getLogger("rulkit.service")

CSP = ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
       "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'; "
       "require-trusted-types-for 'script'; trusted-types 'none'")
"""The Content-Security-Policy of every response outside ``/api/`` (the dashboard)."""


class AccessLog:
    """ASGI middleware over ``app``: counts and times each HTTP request in ``metrics`` by
    route template and status, logs it, sets ``X-Content-Type-Options`` (and the CSP outside
    ``/api/``), and answers an exception that escapes the app with a logged 500."""

    def __init__(self, app: Any, metrics: Metrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: MutableMapping[str, Any], receive: Any, send: Any) -> None:
        """Serve one ASGI connection (lifespan and websockets pass through)."""
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        t0 = time.perf_counter()
        status = [0]
        api = scope["path"].startswith("/api/")

        async def send_with_headers(message: MutableMapping[str, Any]) -> None:
            if message["type"] == "http.response.start":
                status[0] = message["status"]
                headers = MutableHeaders(scope=message)
                if not api:
                    headers["Content-Security-Policy"] = CSP
                headers["X-Content-Type-Options"] = "nosniff"
            await send(message)

        try:
            await self.app(scope, receive, send_with_headers)
        except Exception:
            self.metrics.inc("rulkit_errors_total", "bug")
            log.exception("%s %s failed", scope["method"], _template(scope))
            if status[0]:  # the response had started: the connection is all that is left
                raise
            await JSONResponse({"detail": "internal error (logged)"}, status_code=500)(
                scope, receive, send_with_headers)
        self._record(scope, status[0], time.perf_counter() - t0)

    def _record(self, scope: MutableMapping[str, Any], status: int, dt: float) -> None:
        method, template = scope["method"], _template(scope)
        self.metrics.inc("rulkit_http_requests_total", method, template, str(status))
        self.metrics.observe("rulkit_http_request_seconds", dt, method, template)
        log.info("%s %s %d %.1f ms", method, template, status, 1e3 * dt,
                 extra={"method": method, "route": template, "status": status,
                        "ms": round(1e3 * dt, 1)})


def _template(scope: MutableMapping[str, Any]) -> str:
    """The matched route's template (the router sets ``scope["route"]``)."""
    return str(getattr(scope.get("route"), "path", "<unmatched>"))


__all__ = ["CSP", "AccessLog"]
