"""The service's own routes (docs/service.md): liveness, readiness and the Prometheus
metrics, none of them behind a token."""

from typing import Annotated, Any

from fastapi import APIRouter, Depends
from fastapi.responses import PlainTextResponse

from rulkit import __version__
from rulkit.fleet.service.auth import DB, service_metrics
from rulkit.fleet.service.metrics import CONTENT_TYPE, Metrics
from rulkit.fleet.service.responses import error_responses

router = APIRouter()


@router.get("/healthz", tags=["service"])
async def healthz() -> dict[str, Any]:
    """Liveness: the process answers (no auth, no database access; on the event loop, so it
    answers while every worker thread is busy)."""
    return {"status": "ok", "version": __version__}


@router.get("/readyz", tags=["service"], responses=error_responses(503))
def readyz(sdb: DB) -> dict[str, Any]:
    """Readiness: the database answers (no auth); 503 while it does not."""
    with sdb.store() as s:
        s._conn.execute("SELECT 1").fetchone()
    return {"status": "ok", "backend": sdb.dialect, "version": __version__}


@router.get("/metrics", tags=["service"], response_class=PlainTextResponse)
def prometheus(metrics: Annotated[Metrics, Depends(service_metrics)]) -> PlainTextResponse:
    """Counters and latency histograms in the Prometheus text format (no auth)."""
    return PlainTextResponse(metrics.render(), media_type=CONTENT_TYPE)
