"""The FastAPI application of ``rulkit serve`` (docs/service.md).

``create_app(db)`` serves one component database (SQLite path or ``postgresql://`` URL):

* ``GET /healthz`` (liveness: the process answers), ``GET /readyz`` (readiness: the database
  answers), ``GET /metrics`` (Prometheus text format, :mod:`.metrics`), ``GET /openapi.json``,
  the dashboard at ``/`` (static files of this package);
* ``/api/v1``: ``POST acquisitions``, ``GET summary``, ``GET components``,
  ``GET components/{id}``, ``GET components/{id}/history`` (also
  ``GET history?component=id``), ``GET alerts``,
  ``POST alerts/{id}/ack``.

Every ``/api/v1`` endpoint requires ``Authorization: Bearer <token>`` (401 without a valid one);
``POST`` endpoints require a write token (403 with a read token). Bodies are read with bounded
memory and time (:mod:`.bodies`); every response the API can give is in the OpenAPI schema,
whose batch rows require ``hi`` or exactly the CI columns of the database's HI model. The
access log names the route template (``/api/v1/components/{component}``), the status and the
duration, never the path itself (component ids), a token or a body.
"""


import logging
import sqlite3
import time
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal
from urllib.parse import unquote

import orjson
from fastapi import Depends, FastAPI, HTTPException, Query, Request
from fastapi import Path as PathParam
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, JSONResponse, PlainTextResponse, Response
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, Field

from rulkit import __version__
from rulkit.fleet.service.access_log import AccessLog
from rulkit.fleet.service.bodies import batch_frame, http_error, read_body
from rulkit.fleet.service.db import NotFound, ServiceDB, Token
from rulkit.fleet.service.fleet_view import CursorError
from rulkit.fleet.service.metrics import CONTENT_TYPE, Metrics
from rulkit.fleet.store.acquisitions import ConflictError, IngestError
from rulkit.fleet.store.database_file import StoreError
from rulkit.fleet.tracking.health_index import HealthIndexModel

log = logging.getLogger("rulkit.service")

STATIC = resources.files("rulkit.fleet.service") / "static"


class OrjsonResponse(JSONResponse):
    """A JSON response written by orjson: a page of components or a history of 10^4 rows is
    written in one C call instead of pydantic's walk of an untyped ``dict[str, Any]``
    (validation, then serialisation); NaN and infinities become ``null``, numpy numbers and
    arrays are written as their values."""

    def render(self, content: Any) -> bytes:
        """The body: ``content`` as UTF-8 JSON."""
        return orjson.dumps(content, option=orjson.OPT_SERIALIZE_NUMPY)


class ErrorBody(BaseModel):
    """An error response."""

    detail: str | list[Any] = Field(description="What was refused and why.")


def _responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    text = {401: "Missing, invalid or revoked token", 403: "Read-only token on a write",
            404: "No such component or alert", 408: "The body did not arrive in time",
            409: "Contradicts stored data; nothing written", 413: "Batch too large",
            415: "Unsupported content type", 422: "Invalid request; nothing written",
            503: "Database busy or unavailable; retry (Retry-After)"}
    return {c: {"model": ErrorBody, "description": text[c]} for c in codes}


class AckBody(BaseModel):
    by: str = Field(min_length=1, max_length=200, description="Who acknowledges the alert.")
    reason: str = Field(min_length=1, max_length=2000, description="Why (kept with the alert).")


def _row_schema(hi_model: HealthIndexModel | None) -> dict[str, Any]:
    """The JSON schema of one batch row for this database: ``hi``, or exactly the CI
    columns of its HI model."""
    num = {"type": "number"}
    base = {"component": {"type": "string", "minLength": 1, "maxLength": 128},
            "time": {"type": "number", "description": "Acquisition time."}}
    with_hi = {"type": "object", "required": ["component", "time", "hi"],
               "properties": {**base, "hi": {**num, "minimum": 0,
                                             "description": "Health index."}},
               "additionalProperties": False}
    if hi_model is None:
        return with_hi
    names = list(hi_model.names)
    with_ci = {"type": "object", "required": ["component", "time", *names],
               "properties": {**base, **dict.fromkeys(names, num)},
               "additionalProperties": False}
    return {"oneOf": [with_hi, with_ci]}


def _acq_body(hi_model: HealthIndexModel | None) -> dict[str, Any]:
    row = _row_schema(hi_model)
    return {
        "required": True,
        "description": (
            "A batch: JSON {\"rows\": [{component, time, hi or the CI columns}, ...]}, or a "
            "CSV (text/csv) or Parquet (application/vnd.apache.parquet) file with those "
            "columns."),
        "content": {
            "application/json": {"schema": {
                "type": "object", "required": ["rows"], "additionalProperties": False,
                "properties": {"rows": {"type": "array", "items": row, "minItems": 1}}}},
            "text/csv": {"schema": {"type": "string"}},
            "application/vnd.apache.parquet": {"schema": {"type": "string",
                                                          "format": "binary"}},
        },
    }


def create_app(db: str | Path | ServiceDB, *, pool_size: int = 8) -> FastAPI:
    """The service app over ``db`` (a path, URL, or an open :class:`ServiceDB`)."""
    sdb = db if isinstance(db, ServiceDB) else ServiceDB(db, pool_size=pool_size)
    with sdb.store() as s:
        hi_model = s.hi_model
    app = FastAPI(
        title="rulkit fleet service",
        version=__version__,
        description="Component health index (HI) and remaining useful life (RUL) of a fleet: "
                    "ingest acquisitions, read component state and history, acknowledge "
                    "alerts. Bearer token auth on /api/v1 (write token for POST).",
        docs_url=None, redoc_url=None,
    )
    app.state.db = sdb
    app.state.metrics = metrics = Metrics()
    bearer = HTTPBearer(auto_error=False, description="A token from `rulkit token create`.")

    def authenticated(
        creds: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)],
    ) -> Token:
        if creds is None or creds.scheme.lower() != "bearer":
            raise http_error(401, "missing bearer token", {"WWW-Authenticate": "Bearer"})
        tok = sdb.check_token(creds.credentials)
        if tok is None:
            raise http_error(401, "invalid or revoked token", {"WWW-Authenticate": "Bearer"})
        return tok

    def writer(tok: Annotated[Token, Depends(authenticated)]) -> Token:
        if not tok.can_write:
            raise http_error(403, "this token is read-only; writes and acknowledgements need "
                                  "a write token")
        return tok

    app.add_middleware(AccessLog, metrics=metrics)

    def _busy(request: Request, exc: Exception) -> JSONResponse:
        log.warning("database busy or unavailable: %s", type(exc).__name__)
        metrics.inc("rulkit_errors_total", "database")
        return JSONResponse({"detail": "database busy or unavailable, retry"}, status_code=503,
                            headers={"Retry-After": "1"})

    app.add_exception_handler(StoreError, _busy)  # StoreBusyError, or a broken database
    app.add_exception_handler(sqlite3.OperationalError, _busy)
    app.add_exception_handler(ConnectionError, _busy)
    try:
        import psycopg

        app.add_exception_handler(psycopg.OperationalError, _busy)
    except ImportError:  # pragma: no cover
        pass

    @app.get("/healthz", tags=["service"])
    def healthz() -> dict[str, Any]:
        """Liveness: the process answers (no auth, no database access)."""
        return {"status": "ok", "version": __version__}

    @app.get("/readyz", tags=["service"], responses=_responses(503))
    def readyz() -> dict[str, Any]:
        """Readiness: the database answers (no auth); 503 while it does not."""
        with sdb.store() as s:
            s._conn.execute("SELECT 1").fetchone()
        return {"status": "ok", "backend": sdb.dialect, "version": __version__}

    @app.get("/metrics", tags=["service"], response_class=PlainTextResponse)
    def prometheus() -> PlainTextResponse:
        """Counters and latency histograms in the Prometheus text format (no auth)."""
        return PlainTextResponse(metrics.render(), media_type=CONTENT_TYPE)

    @app.post("/api/v1/acquisitions", tags=["acquisitions"],
              openapi_extra={"requestBody": _acq_body(hi_model)},
              responses=_responses(401, 403, 408, 409, 413, 415, 422, 503))
    async def post_acquisitions(
        request: Request, tok: Annotated[Token, Depends(writer)]
    ) -> dict[str, Any]:
        """Ingest a batch: validated completely, applied in one transaction.

        Rows already stored (same component, time and HI) are skipped and counted in
        ``duplicates``; the response lists the new alerts."""
        ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
        t0 = time.perf_counter()
        try:
            body = await read_body(request)
            df = await run_in_threadpool(batch_frame, body, ctype)
            del body
            out = await run_in_threadpool(sdb.ingest, df, f"api:{tok.name}")
        except ConflictError as err:
            metrics.inc("rulkit_ingest_batches_total", "conflict")
            raise http_error(409, str(err)) from None
        except IngestError as err:
            metrics.inc("rulkit_ingest_batches_total", "invalid")
            raise http_error(422, str(err)) from None
        except HTTPException as err:
            metrics.inc("rulkit_ingest_batches_total",
                        "too_large" if err.status_code == 413 else "invalid")
            raise
        except StoreError:
            metrics.inc("rulkit_ingest_batches_total", "busy")
            raise
        metrics.inc("rulkit_ingest_batches_total", "applied")
        metrics.inc("rulkit_ingested_acquisitions_total", by=out["ingested"])
        metrics.inc("rulkit_duplicate_acquisitions_total", by=out["duplicates"])
        metrics.observe("rulkit_ingest_seconds", time.perf_counter() - t0)
        return out

    @app.get("/api/v1/summary", tags=["components"], response_model=dict[str, Any],
             response_class=OrjsonResponse, responses=_responses(401, 503))
    def get_summary(_tok: Annotated[Token, Depends(authenticated)]) -> Response:
        """Counts per level and of stale components, what gives the RUL (estimator, time
        unit, interval), the alert rules and the fitted model's warnings."""
        return OrjsonResponse(sdb.summary())

    @app.get("/api/v1/components", tags=["components"], response_model=dict[str, Any],
             response_class=OrjsonResponse, responses=_responses(401, 422, 503))
    def list_components(
        _tok: Annotated[Token, Depends(authenticated)],
        limit: Annotated[int, Query(ge=1, le=1000)] = 50,
        offset: Annotated[int, Query(ge=0, le=2**31 - 1)] = 0,
        level: Annotated[Literal["ok", "warning", "alarm", "stale"] | None, Query()] = None,
        sort: Annotated[Literal["worst", "rul", "due"], Query()] = "worst",
        after: Annotated[str | None, Query(max_length=2000)] = None,
    ) -> Response:
        """Components worst first (alert level, then RUL median ascending, unknown last), or
        by RUL median or due date; each with its RUL median and interval, due date, level,
        failed and stale flags. ``next`` is the cursor of the following page (``null``
        after the last): pass it as ``after`` with the same sort and level, and every page
        costs what the first does (``offset`` skips rows, at a cost that grows with it)."""
        try:
            total, items, nxt = sdb.components(limit=limit, offset=offset, level=level,
                                               sort=sort, after=after)
        except CursorError as err:
            raise http_error(422, str(err)) from None
        return OrjsonResponse({"total": total, "limit": limit, "offset": offset,
                               "sort": sort, "items": items, "next": nxt})

    def _component_id(component: str) -> str:
        if "\x00" in component:
            raise http_error(404, "no such component")
        return component

    def _raw_tail(request: Request) -> str:
        """The percent-encoded path after /api/v1/components/ (ids may hold "/" as %2F)."""
        raw = request.scope.get("raw_path") or request.url.path.encode()
        return raw.decode("latin-1").split("?", 1)[0][len("/api/v1/components/"):]

    @app.get("/api/v1/components/{component:path}/history", tags=["components"],
             response_model=dict[str, Any],
             response_class=OrjsonResponse, responses=_responses(401, 404, 422, 503))
    def component_history(
        component: Annotated[str, PathParam(description="Component id, '/' encoded as %2F")],
        request: Request,
        _tok: Annotated[Token, Depends(authenticated)],
        limit: Annotated[int, Query(ge=1, le=100_000)] = 10_000,
    ) -> Response:
        """The component's last ``limit`` acquisitions (HI, fHI, the RUL median and
        interval, level; time ascending), the component now, its HI forecast to the
        threshold with its band, and its alerts."""
        tail = _raw_tail(request)
        try:
            if not tail.endswith("/history"):  # an id ending in %2Fhistory: the component
                return OrjsonResponse(sdb.component(_component_id(unquote(tail))))
            return OrjsonResponse(sdb.history(_component_id(unquote(tail[:-len("/history")])),
                                              limit=limit))
        except NotFound as err:
            raise http_error(404, str(err)) from None

    @app.get("/api/v1/components/{component:path}", tags=["components"],
             response_model=dict[str, Any],
             response_class=OrjsonResponse, responses=_responses(401, 404, 422, 503))
    def get_component(
        component: Annotated[str, PathParam(description="Component id, '/' encoded as %2F")],
        request: Request,
        _tok: Annotated[Token, Depends(authenticated)],
    ) -> Response:
        """One component's state and its number of open alerts."""
        try:
            return OrjsonResponse(sdb.component(_component_id(unquote(_raw_tail(request)))))
        except NotFound as err:
            raise http_error(404, str(err)) from None

    @app.get("/api/v1/history", tags=["components"], response_model=dict[str, Any],
             response_class=OrjsonResponse, responses=_responses(401, 404, 422, 503))
    def history_by_query(
        component: Annotated[str, Query(min_length=1, max_length=512,
                                        description="Component id (any, also '.' or '..')")],
        _tok: Annotated[Token, Depends(authenticated)],
        limit: Annotated[int, Query(ge=1, le=100_000)] = 10_000,
    ) -> Response:
        """As ``GET /api/v1/components/{id}/history``, the id in the query: browsers rewrite
        the path segments ``.`` and ``..`` (also percent-encoded), so a component named so
        is only reachable this way."""
        try:
            return OrjsonResponse(sdb.history(_component_id(component), limit=limit))
        except NotFound as err:
            raise http_error(404, str(err)) from None

    @app.get("/api/v1/alerts", tags=["alerts"], response_model=dict[str, Any],
             response_class=OrjsonResponse, responses=_responses(401, 422, 503))
    def list_alerts(
        _tok: Annotated[Token, Depends(authenticated)],
        state: Annotated[Literal["open", "acknowledged", "all"], Query()] = "open",
        component: Annotated[str | None, Query()] = None,
        limit: Annotated[int, Query(ge=1, le=1000)] = 100,
        offset: Annotated[int, Query(ge=0, le=2**31 - 1)] = 0,
    ) -> Response:
        """Alerts, highest level then newest first; ``state`` open (default), acknowledged
        or all."""
        if component is not None and "\x00" in component:
            return OrjsonResponse({"total": 0, "limit": limit, "offset": offset, "items": []})
        total, items = sdb.alerts(state=state, component=component, limit=limit, offset=offset)
        return OrjsonResponse({"total": total, "limit": limit, "offset": offset,
                               "items": items})

    @app.post("/api/v1/alerts/{alert_id}/ack", tags=["alerts"],
              responses=_responses(401, 403, 404, 409, 422, 503))
    def ack_alert(
        alert_id: Annotated[int, PathParam(ge=1, le=2**53)],
        body: AckBody,
        tok: Annotated[Token, Depends(writer)],
    ) -> dict[str, Any]:
        """Acknowledge an alert: who and why are kept with it (and the token's name)."""
        for v in (body.by, body.reason):
            if "\x00" in v:
                raise http_error(422, "'by' and 'reason' must not contain NUL characters")
        try:
            return sdb.ack(alert_id, by=body.by, reason=body.reason, token_name=tok.name)
        except NotFound as err:
            raise http_error(404, str(err)) from None
        except ConflictError as err:
            raise http_error(409, str(err)) from None

    @app.get("/", include_in_schema=False)
    def dashboard() -> FileResponse:
        return FileResponse(str(STATIC / "index.html"), media_type="text/html")

    app.mount("/static", StaticFiles(directory=str(STATIC)), name="static")
    return app
