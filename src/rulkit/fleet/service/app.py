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

The routes live in one module per group, each registered here: :mod:`.routes_service`,
:mod:`.routes_acquisitions`, :mod:`.routes_components`, :mod:`.routes_alerts`; their
dependencies (database, metrics, tokens) in :mod:`.auth`, their responses in
:mod:`.responses`. The pages and histories a route would answer with a 200 are answered
before FastAPI's routing by :mod:`.lean_reads`, the same body at a fraction of the CPU.
"""


import logging
import sqlite3
from importlib import resources
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.responses import FileResponse, JSONResponse
from fastapi.staticfiles import StaticFiles

from rulkit import __version__
from rulkit.fleet.service import routes_alerts, routes_components, routes_service
from rulkit.fleet.service.access_log import AccessLog
from rulkit.fleet.service.db import ServiceDB
from rulkit.fleet.service.lean_reads import LeanReads
from rulkit.fleet.service.metrics import Metrics
from rulkit.fleet.service.routes_acquisitions import acquisitions_router
from rulkit.fleet.store.database_file import StoreError

log = logging.getLogger("rulkit.service")

STATIC = resources.files("rulkit.fleet.service") / "static"


def _busy(request: Request, exc: Exception) -> JSONResponse:
    """503 with Retry-After for a busy or unavailable database (counted in the metrics)."""
    log.warning("database busy or unavailable: %s", type(exc).__name__)
    request.app.state.metrics.inc("rulkit_errors_total", "database")
    return JSONResponse({"detail": "database busy or unavailable, retry"}, status_code=503,
                        headers={"Retry-After": "1"})


def _add_busy_handlers(app: FastAPI) -> None:
    app.add_exception_handler(StoreError, _busy)  # StoreBusyError, or a broken database
    app.add_exception_handler(sqlite3.OperationalError, _busy)
    app.add_exception_handler(ConnectionError, _busy)
    try:
        import psycopg

        app.add_exception_handler(psycopg.OperationalError, _busy)
    except ImportError:  # pragma: no cover
        pass


def create_app(db: str | Path | ServiceDB, *, pool_size: int = 8,
               lean_reads: bool = True) -> FastAPI:
    """The service app over ``db`` (a path, URL, or an open :class:`ServiceDB`); with
    ``lean_reads`` (the default) the pages and histories that the FastAPI routes would answer
    with a 200 are answered by :class:`~rulkit.fleet.service.lean_reads.LeanReads`."""
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
    if lean_reads:
        app.add_middleware(LeanReads)  # inside the access log (added after it: outermost)
    app.add_middleware(AccessLog, metrics=metrics)
    _add_busy_handlers(app)
    app.include_router(routes_service.router)
    app.include_router(acquisitions_router(hi_model))
    app.include_router(routes_components.router)
    app.include_router(routes_alerts.router)

    @app.get("/", include_in_schema=False)
    def dashboard() -> FileResponse:
        return FileResponse(str(STATIC / "index.html"), media_type="text/html")

    app.mount("/static", StaticFiles(directory=str(STATIC)), name="static")
    return app
