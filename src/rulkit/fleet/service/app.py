"""The FastAPI application of ``rulkit serve`` (docs/service.md).

``create_app(db)`` serves one component database (SQLite path or ``postgresql://`` URL):

* ``GET /healthz`` (no auth), ``GET /openapi.json``, the dashboard at ``/`` (static files of this
  package; the page asks for a token and calls the API with it);
* ``/api/v1``: ``POST acquisitions``, ``GET summary``, ``GET components``,
  ``GET components/{id}``, ``GET components/{id}/history``, ``GET alerts``,
  ``POST alerts/{id}/ack``.

Every ``/api/v1`` endpoint requires ``Authorization: Bearer <token>`` (401 without a valid one);
``POST`` endpoints require a write token (403 with a read token). The access log written here
names the route template (``/api/v1/components/{component}``), the status and the duration,
never the path itself (component ids), a token or a body.
"""


import io
import logging
import sqlite3
import time
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal
from urllib.parse import unquote

import pandas as pd
from fastapi import Depends, FastAPI, HTTPException, Query, Request
from fastapi import Path as PathParam
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, JSONResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, Field

from rulkit import __version__
from rulkit.fleet.service.db import ConflictError, NotFound, ServiceDB, Token
from rulkit.fleet.store.acquisitions import IngestError
from rulkit.fleet.store.database_file import StoreError

log = logging.getLogger("rulkit.service")

MAX_BODY = 64 * 1024 * 1024  # bytes of one upload
MAX_ROWS = 1_000_000  # acquisitions in one batch
STATIC = resources.files("rulkit.fleet.service") / "static"
CSP = ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
       "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'")


class AckBody(BaseModel):
    by: str = Field(min_length=1, max_length=200, description="Who acknowledges the alert.")
    reason: str = Field(min_length=1, max_length=2000, description="Why (kept with the alert).")


_ROW_SCHEMA = {
    "type": "object",
    "required": ["component", "time"],
    "properties": {
        "component": {"type": "string", "minLength": 1},
        "time": {"type": "number"},
        "hi": {"type": "number", "description": "Health index (or give the CI columns)."},
    },
    "additionalProperties": {"type": "number", "description": "A CI of the stored HI model."},
}
_ACQ_BODY = {
    "required": True,
    "description": (
        "A batch: JSON {\"rows\": [{component, time, hi or the CI columns}, ...]}, or a CSV "
        "(text/csv) or Parquet (application/vnd.apache.parquet) file with those columns."),
    "content": {
        "application/json": {"schema": {
            "type": "object", "required": ["rows"],
            "properties": {"rows": {"type": "array", "items": _ROW_SCHEMA, "minItems": 1}}}},
        "text/csv": {"schema": {"type": "string"}},
        "application/vnd.apache.parquet": {"schema": {"type": "string", "format": "binary"}},
    },
}


def _err(status: int, detail: str, headers: dict[str, str] | None = None) -> HTTPException:
    return HTTPException(status_code=status, detail=detail, headers=headers)


def _parse_body(body: bytes, ctype: str) -> pd.DataFrame:
    """The batch as a DataFrame; 415/422 for what cannot be read."""
    if ctype in ("application/json", ""):
        import json

        try:
            obj = json.loads(body)
        except (ValueError, UnicodeDecodeError) as err:
            raise _err(422, f"body: not valid JSON ({err})") from None
        rows = obj.get("rows") if isinstance(obj, dict) else None
        if not isinstance(rows, list):
            raise _err(422, 'body: expected a JSON object {"rows": [...]}')
        if len(rows) > MAX_ROWS:
            raise _err(413, f"body: {len(rows)} rows, at most {MAX_ROWS} per batch")
        for i, r in enumerate(rows):
            if not isinstance(r, dict):
                raise _err(422, f"row {i + 1}: expected an object with component, time, hi")
            c = r.get("component")
            if not isinstance(c, str):
                raise _err(422, f"row {i + 1}: 'component' must be a string, got "
                                f"{type(c).__name__}")
            for k, v in r.items():
                if k != "component" and not (
                        v is None or (isinstance(v, (int, float)) and not isinstance(v, bool))):
                    raise _err(422, f"row {i + 1} (component {c!r}): {k!r} must be a number, "
                                    f"got {type(v).__name__}")
        df = pd.DataFrame.from_records(rows) if rows else pd.DataFrame()
        # from_records orders columns by first appearance; missing keys are NaN and the
        # store's validation names the row
        return df
    if ctype in ("text/csv", "text/plain"):
        try:
            return pd.read_csv(io.BytesIO(body), dtype={"component": str},
                               keep_default_na=False, na_values=[""])
        except (ValueError, pd.errors.ParserError, UnicodeDecodeError) as err:
            raise _err(422, f"CSV body: {str(err).strip()}") from None
    if ctype in ("application/vnd.apache.parquet", "application/x-parquet",
                 "application/octet-stream"):
        try:
            return pd.read_parquet(io.BytesIO(body))
        except Exception as err:  # pyarrow raises many kinds on bad bytes
            raise _err(422, f"Parquet body: cannot read ({type(err).__name__}: "
                            f"{str(err).strip()[:200]})") from None
    raise _err(415, f"unsupported content type {ctype!r}: use application/json, text/csv or "
                    "application/vnd.apache.parquet")


def create_app(db: str | Path | ServiceDB, *, pool_size: int = 8) -> FastAPI:
    """The service app over ``db`` (a path, URL, or an open :class:`ServiceDB`)."""
    sdb = db if isinstance(db, ServiceDB) else ServiceDB(db, pool_size=pool_size)
    app = FastAPI(
        title="rulkit fleet service",
        version=__version__,
        description="Component health index (HI) and remaining useful life (RUL) of a fleet: "
                    "ingest acquisitions, read component state and history, acknowledge "
                    "alerts. Bearer token auth on /api/v1 (write token for POST).",
        docs_url=None, redoc_url=None,
    )
    app.state.db = sdb
    bearer = HTTPBearer(auto_error=False, description="A token from `rulkit token create`.")

    def authenticated(
        creds: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)],
    ) -> Token:
        if creds is None or creds.scheme.lower() != "bearer":
            raise _err(401, "missing bearer token", {"WWW-Authenticate": "Bearer"})
        tok = sdb.check_token(creds.credentials)
        if tok is None:
            raise _err(401, "invalid or revoked token", {"WWW-Authenticate": "Bearer"})
        return tok

    def writer(tok: Annotated[Token, Depends(authenticated)]) -> Token:
        if not tok.can_write:
            raise _err(403, "this token is read-only; writes and acknowledgements need a "
                            "write token")
        return tok

    @app.middleware("http")
    async def access_log(request: Request, call_next: Any) -> Any:
        t0 = time.perf_counter()
        response = await call_next(request)
        route = request.scope.get("route")
        template = getattr(route, "path", "<unmatched>")
        log.info("%s %s %d %.1f ms", request.method, template, response.status_code,
                 1e3 * (time.perf_counter() - t0))
        if not request.url.path.startswith("/api/"):
            response.headers["Content-Security-Policy"] = CSP
        response.headers["X-Content-Type-Options"] = "nosniff"
        return response

    def _busy(request: Request, exc: Exception) -> JSONResponse:
        log.warning("database busy or unavailable: %s", type(exc).__name__)
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
        """Liveness and database reachability (no auth)."""
        with sdb.store() as s:
            s._conn.execute("SELECT 1").fetchone()
        return {"status": "ok", "backend": sdb.dialect, "version": __version__}

    @app.post("/api/v1/acquisitions", tags=["acquisitions"], openapi_extra={
        "requestBody": _ACQ_BODY},
        responses={409: {"description": "A row contradicts stored acquisitions"},
                   413: {"description": "Batch too large"},
                   415: {"description": "Unsupported content type"},
                   422: {"description": "Invalid batch (nothing written)"}})
    async def post_acquisitions(
        request: Request, tok: Annotated[Token, Depends(writer)]
    ) -> dict[str, Any]:
        """Ingest a batch: validated completely, applied in one transaction.

        Rows already stored (same component, time and HI) are skipped and counted in
        ``duplicates``; the response lists the new alerts."""
        ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
        size = request.headers.get("content-length")
        if size is not None and size.isdigit() and int(size) > MAX_BODY:
            raise _err(413, f"body larger than {MAX_BODY} bytes")
        body = await request.body()
        if len(body) > MAX_BODY:
            raise _err(413, f"body larger than {MAX_BODY} bytes")
        df = await run_in_threadpool(_parse_body, body, ctype)
        if len(df) > MAX_ROWS:
            raise _err(413, f"{len(df)} rows, at most {MAX_ROWS} per batch")
        try:
            return await run_in_threadpool(sdb.ingest, df, f"api:{tok.name}")
        except ConflictError as err:
            raise _err(409, str(err)) from None
        except IngestError as err:
            raise _err(422, str(err)) from None

    @app.get("/api/v1/summary", tags=["components"])
    def get_summary(_tok: Annotated[Token, Depends(authenticated)]) -> dict[str, Any]:
        """Counts per level and of stale components, what gives the RUL (estimator, time
        unit, interval), the alert rules and the fitted model's warnings."""
        return sdb.summary()

    @app.get("/api/v1/components", tags=["components"])
    def list_components(
        _tok: Annotated[Token, Depends(authenticated)],
        limit: Annotated[int, Query(ge=1, le=1000)] = 50,
        offset: Annotated[int, Query(ge=0, le=2**31 - 1)] = 0,
        level: Annotated[Literal["ok", "warning", "alarm", "stale"] | None, Query()] = None,
        sort: Annotated[Literal["worst", "rul", "due"], Query()] = "worst",
    ) -> dict[str, Any]:
        """Components worst first (alert level, then RUL median ascending, unknown last), or
        by RUL median or due date; each with its RUL median and interval, due date, level,
        failed and stale flags."""
        total, items = sdb.components(limit=limit, offset=offset, level=level, sort=sort)
        return {"total": total, "limit": limit, "offset": offset, "sort": sort,
                "items": items}

    def _component_id(component: str) -> str:
        if "\x00" in component:
            raise _err(404, "no such component")
        return component

    def _raw_tail(request: Request) -> str:
        """The percent-encoded path after /api/v1/components/ (ids may hold "/" as %2F)."""
        raw = request.scope.get("raw_path") or request.url.path.encode()
        return raw.decode("latin-1").split("?", 1)[0][len("/api/v1/components/"):]

    @app.get("/api/v1/components/{component:path}/history", tags=["components"])
    def component_history(
        component: Annotated[str, PathParam(description="Component id, '/' encoded as %2F")],
        request: Request,
        _tok: Annotated[Token, Depends(authenticated)],
        limit: Annotated[int, Query(ge=1, le=100_000)] = 10_000,
    ) -> dict[str, Any]:
        """The component's last ``limit`` acquisitions (HI, fHI, the RUL median and
        interval, level; time ascending), the component now, its HI forecast to the
        threshold with its band, and its alerts."""
        tail = _raw_tail(request)
        try:
            if not tail.endswith("/history"):  # an id ending in %2Fhistory: the component
                return sdb.component(_component_id(unquote(tail)))
            return sdb.history(_component_id(unquote(tail[:-len("/history")])), limit=limit)
        except NotFound as err:
            raise _err(404, str(err)) from None

    @app.get("/api/v1/components/{component:path}", tags=["components"])
    def get_component(
        component: Annotated[str, PathParam(description="Component id, '/' encoded as %2F")],
        request: Request,
        _tok: Annotated[Token, Depends(authenticated)],
    ) -> dict[str, Any]:
        """One component's state and its number of open alerts."""
        try:
            return sdb.component(_component_id(unquote(_raw_tail(request))))
        except NotFound as err:
            raise _err(404, str(err)) from None

    @app.get("/api/v1/alerts", tags=["alerts"])
    def list_alerts(
        _tok: Annotated[Token, Depends(authenticated)],
        state: Annotated[Literal["open", "acknowledged", "all"], Query()] = "open",
        component: Annotated[str | None, Query()] = None,
        limit: Annotated[int, Query(ge=1, le=1000)] = 100,
        offset: Annotated[int, Query(ge=0, le=2**31 - 1)] = 0,
    ) -> dict[str, Any]:
        """Alerts, highest level then newest first; ``state`` open (default), acknowledged
        or all."""
        if component is not None and "\x00" in component:
            return {"total": 0, "limit": limit, "offset": offset, "items": []}
        total, items = sdb.alerts(state=state, component=component, limit=limit, offset=offset)
        return {"total": total, "limit": limit, "offset": offset, "items": items}

    @app.post("/api/v1/alerts/{alert_id}/ack", tags=["alerts"],
              responses={404: {"description": "No such alert"},
                         409: {"description": "Already acknowledged"}})
    def ack_alert(
        alert_id: Annotated[int, PathParam(ge=1, le=2**53)],
        body: AckBody,
        tok: Annotated[Token, Depends(writer)],
    ) -> dict[str, Any]:
        """Acknowledge an alert: who and why are kept with it (and the token's name)."""
        for v in (body.by, body.reason):
            if "\x00" in v:
                raise _err(422, "'by' and 'reason' must not contain NUL characters")
        try:
            return sdb.ack(alert_id, by=body.by, reason=body.reason, token_name=tok.name)
        except NotFound as err:
            raise _err(404, str(err)) from None
        except ConflictError as err:
            raise _err(409, str(err)) from None

    @app.get("/", include_in_schema=False)
    def dashboard() -> FileResponse:
        return FileResponse(str(STATIC / "index.html"), media_type="text/html")

    app.mount("/static", StaticFiles(directory=str(STATIC)), name="static")
    return app
