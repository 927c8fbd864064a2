"""The lean path of the service's most frequent reads (docs/service-load.md, "Lean
reads"): a page of components and a component's history, answered without FastAPI's
routing, parameter validation and dependencies.

:class:`LeanReads` is an ASGI layer inside the access log. It answers a ``GET`` of
``/api/v1/components``, ``/api/v1/components/{id}/history`` or ``/api/v1/history`` itself
when the request is one it can read exactly as the FastAPI route would: only the route's own
query parameters, each once, each in its canonical form and range (``limit=50``, never
``limit=050`` or ``limit=+50``), a bearer token the database knows. The token check, the
query and the JSON text then run in one worker thread (FastAPI hands the token's dependency
and the endpoint to the thread pool one after the other), and the response is the same
:class:`~rulkit.fleet.service.responses.OrjsonResponse` of the same body.

On SQLite the token is checked on the event loop (:mod:`.commit_watch`), and a page is
served from the :class:`~rulkit.fleet.service.page_cache.PageCache` while nothing was
committed and the clock stales no other component; only a page not found there, or a
history, goes to a worker thread.

Everything else, and every read that does not end in a 200 (an unknown component, a bad
cursor, a busy database), goes to the FastAPI app, which answers it as it always has: the
errors (401, 404, 422, 503), their bodies and the OpenAPI schema are the routes' own
(:mod:`.routes_components`), so the lean path cannot answer differently from them; it can
only answer sooner.
"""

from __future__ import annotations

import sqlite3
import time
from collections.abc import Callable, Hashable, MutableMapping
from typing import Any
from urllib.parse import parse_qsl, unquote

from fastapi.concurrency import run_in_threadpool
from fastapi.responses import Response
from fastapi.routing import APIRoute
from fastapi.security.utils import get_authorization_scheme_param

from rulkit.fleet.service.db import NotFound, ServiceDB
from rulkit.fleet.service.fleet_view import CursorError
from rulkit.fleet.service.page_cache import PageCache
from rulkit.fleet.service.responses import OrjsonResponse
from rulkit.fleet.service.routes_components import page_body, router
from rulkit.fleet.store.database_file import StoreError

PAGE = "/api/v1/components"
HISTORY_BY_QUERY = "/api/v1/history"
HISTORY_TEMPLATE = "/api/v1/components/{component:path}/history"
PAGE_CHOICES = {"level": ("ok", "warning", "alarm", "stale"), "sort": ("worst", "rul", "due")}
"""The page's parameters with a fixed set of values (the route's ``Literal`` types)."""
ROUTES = {r.path: r for r in router.routes if isinstance(r, APIRoute) and r.path in (
    PAGE, HISTORY_BY_QUERY, HISTORY_TEMPLATE)}
"""The FastAPI routes the lean path answers for, by template (the access log names them)."""
_PAGE_INTS = {"limit": 1000, "offset": 2**31 - 1}
"""The page's integer parameters and their upper bounds (``limit`` from 1, ``offset`` 0)."""


def _read_errors() -> tuple[type[BaseException], ...]:
    """What a read may raise that the FastAPI app answers with an error status."""
    errs: tuple[type[BaseException], ...] = (NotFound, CursorError, StoreError,
                                             sqlite3.Error, ConnectionError)
    try:
        import psycopg
    except ImportError:  # pragma: no cover - depends on the installed extras
        return errs
    return (*errs, psycopg.Error)


READ_ERRORS = _read_errors()


def canonical_int(text: str, low: int, high: int) -> int | None:
    """``text`` as an integer in ``[low, high]`` when it is written as the decimal digits of
    one (no sign, no leading zero, no blank); ``None`` otherwise."""
    if not text.isdigit() or not text.isascii() or (len(text) > 1 and text[0] == "0") \
            or len(text) > 10:
        return None
    v = int(text)
    return v if low <= v <= high else None


def query_args(scope: MutableMapping[str, Any], allowed: tuple[str, ...]
               ) -> dict[str, str] | None:
    """The query's parameters, when each is one of ``allowed``, given once and not empty
    (as Starlette decodes them); ``None`` otherwise."""
    pairs = parse_qsl(scope["query_string"].decode("latin-1"), keep_blank_values=True)
    args = dict(pairs)
    if len(args) != len(pairs) or not all(k in allowed and v for k, v in pairs):
        return None
    return args


def page_args(args: dict[str, str]) -> dict[str, Any] | None:
    """The keyword arguments of :meth:`ServiceDB.components` of a page's query, or ``None``
    when one value is not what the route accepts in canonical form."""
    out: dict[str, Any] = {"limit": 50, "offset": 0, "level": None, "sort": "worst",
                           "after": None}
    for key, text in args.items():
        if key in _PAGE_INTS:
            v = canonical_int(text, 1 if key == "limit" else 0, _PAGE_INTS[key])
            if v is None:
                return None
            out[key] = v
        elif key in PAGE_CHOICES:
            if text not in PAGE_CHOICES[key]:
                return None
            out[key] = text
        elif len(text) > 2000:  # after: the route's max_length
            return None
        else:
            out[key] = text
    return out


def bearer_token(scope: MutableMapping[str, Any]) -> str | None:
    """The request's bearer credentials, read as FastAPI's ``HTTPBearer`` reads them (the
    first ``Authorization`` header); ``None`` without one."""
    for name, value in scope["headers"]:
        if name == b"authorization":
            scheme, cred = get_authorization_scheme_param(value.decode("latin-1"))
            return cred if scheme.lower() == "bearer" and cred else None
    return None


def history_tail(scope: MutableMapping[str, Any]) -> str | None:
    """The component of ``/api/v1/components/{id}/history`` when ``id`` is one path
    segment, not empty (``/`` in it encoded as ``%2F``), without a NUL character."""
    raw = (scope.get("raw_path") or b"").decode("latin-1").split("?", 1)[0]
    head = PAGE + "/"
    if not raw.startswith(head) or not raw.endswith("/history"):
        return None
    seg = raw[len(head):-len("/history")]
    component = unquote(seg)
    if not seg or "/" in seg or "\x00" in component \
            or scope["path"] != f"{head}{component}/history":
        return None
    return component


Read = Callable[[ServiceDB, float], dict[str, Any]]
"""A read of the lean path: the body of its 200 from the database, staleness judged at the
calendar time it is given."""
clock = time.time
"""The calendar time the lean reads judge staleness at (seconds since 1970)."""


def history_read(component: str, args: dict[str, str]) -> Read | None:
    """The history read of ``component`` with the query's ``limit`` (default 10000), or
    ``None`` when the limit is not what the route accepts in canonical form."""
    limit = canonical_int(args.get("limit", "10000"), 1, 100_000)
    if limit is None:
        return None
    return lambda sdb, now: sdb.history(component, limit=limit, now=now)


class LeanReads:
    """ASGI layer over ``app`` (the FastAPI app's middleware stack): answers the reads of
    the module docstring itself, hands everything else to ``app``. ``served`` counts the
    requests it answered, ``cache`` holds the pages (SQLite)."""

    def __init__(self, app: Any) -> None:
        self.app = app
        self.served = 0
        self.cache = PageCache()

    async def __call__(self, scope: MutableMapping[str, Any], receive: Any, send: Any) -> None:
        """Serve one ASGI call (anything but a plain ``GET`` passes through)."""
        if scope["type"] == "http" and scope["method"] == "GET" and not scope.get("root_path"):
            found = self._plan(scope)
            if found is not None:
                template, read, key = found
                sdb: ServiceDB = scope["app"].state.db
                if sdb.watch is not None:
                    response = await self._watched(scope, sdb, read, key)
                else:
                    response = await run_in_threadpool(self._answer, scope, read)
                if response is not None:
                    self.served += 1
                    scope["route"] = ROUTES[template]
                    await response(scope, receive, send)
                    return
        await self.app(scope, receive, send)

    def _plan(self, scope: MutableMapping[str, Any]
              ) -> tuple[str, Read, Hashable | None] | None:
        """(the route's template, the read, the page's cache key or ``None`` for a history)
        of a request the lean path answers, or ``None``."""
        path = scope["path"]
        if path == PAGE:
            args = query_args(scope, ("limit", "offset", "level", "sort", "after"))
            kw = None if args is None else page_args(args)
            if kw is None:
                return None
            return PAGE, lambda sdb, now: page_body(sdb, **kw, now=now), tuple(kw.items())
        if path == HISTORY_BY_QUERY:
            args = query_args(scope, ("component", "limit"))
            component = None if args is None else args.pop("component", None)
            if args is None or component is None or len(component) > 512 \
                    or "\x00" in component:
                return None
            read = history_read(component, args)
            return None if read is None else (HISTORY_BY_QUERY, read, None)
        if path.endswith("/history"):
            component = history_tail(scope)
            args = None if component is None else query_args(scope, ("limit",))
            read = None if args is None or component is None else history_read(component, args)
            return None if read is None else (HISTORY_TEMPLATE, read, None)
        return None

    async def _watched(self, scope: MutableMapping[str, Any], sdb: ServiceDB, read: Read,
                       key: Hashable | None) -> Response | None:
        """On SQLite: the token checked on the event loop, then the page from the cache or
        the read in a worker thread; ``None`` as :meth:`_answer`."""
        assert sdb.watch is not None
        token = bearer_token(scope)
        try:
            if token is None or sdb.check_token(token) is None:
                return None
            if key is None:
                return await run_in_threadpool(self._read, sdb, read, clock())
            version, now = sdb.watch.version(), clock()
        except READ_ERRORS:
            return None
        body = self.cache.get(key, version, now)
        metrics = scope["app"].state.metrics
        if body is not None:
            metrics.inc("rulkit_page_cache_total", "hit")
            return Response(body, media_type=OrjsonResponse.media_type)
        metrics.inc("rulkit_page_cache_total", "miss")
        return await run_in_threadpool(self._fill, sdb, read, key, version, now)

    def _fill(self, sdb: ServiceDB, read: Read, key: Hashable, version: int, now: float
              ) -> OrjsonResponse | None:
        """In a worker thread: the page read at ``now``, kept in the cache under ``version``
        (read before it) until the clock stales another component."""
        try:
            response = OrjsonResponse(read(sdb, now))
            until = sdb.stale_horizon(now)
        except READ_ERRORS:
            return None
        self.cache.put(key, version, now, until, bytes(response.body))
        return response

    @staticmethod
    def _read(sdb: ServiceDB, read: Read, now: float) -> OrjsonResponse | None:
        """In a worker thread: the 200 of ``read``, or ``None`` for one the FastAPI app
        answers with an error."""
        try:
            return OrjsonResponse(read(sdb, now))
        except READ_ERRORS:
            return None

    def _answer(self, scope: MutableMapping[str, Any],
                read: Read) -> OrjsonResponse | None:
        """In a worker thread: the 200 with its JSON text, or ``None`` (no valid token, or
        a read the FastAPI app answers with an error)."""
        sdb: ServiceDB = scope["app"].state.db
        token = bearer_token(scope)
        if token is None:
            return None
        try:
            if sdb.check_token(token) is None:
                return None
        except READ_ERRORS:
            return None
        return self._read(sdb, read, clock())


__all__ = ["HISTORY_BY_QUERY", "HISTORY_TEMPLATE", "PAGE", "PAGE_CHOICES", "READ_ERRORS",
           "ROUTES", "LeanReads", "Read", "bearer_token", "canonical_int", "clock", "history_read",
           "history_tail", "page_args", "query_args"]
