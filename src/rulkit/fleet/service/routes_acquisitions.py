"""The ingest route ``POST /api/v1/acquisitions`` (docs/service.md): a batch as JSON, CSV or
Parquet, whose documented rows require ``hi`` or exactly the CI columns of the database's HI
model."""

import time
from typing import Any

from fastapi import APIRouter, HTTPException, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import Response

from rulkit.fleet.service.auth import BEARER, bearer_token, refusal, write_token
from rulkit.fleet.service.bodies import batch_frame, http_error, read_body
from rulkit.fleet.service.db import ServiceDB, TokenRefused
from rulkit.fleet.service.metrics import Metrics
from rulkit.fleet.service.responses import OrjsonResponse, error_responses
from rulkit.fleet.store.acquisitions import ConflictError, IngestError
from rulkit.fleet.store.database_file import StoreError
from rulkit.fleet.tracking.health_index import HealthIndexModel


def row_schema(hi_model: HealthIndexModel | None) -> dict[str, Any]:
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


def acquisitions_body(hi_model: HealthIndexModel | None) -> dict[str, Any]:
    """The OpenAPI request body of a batch for this database."""
    row = row_schema(hi_model)
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


async def post_acquisitions(request: Request) -> Response:
    """Ingest a batch: validated completely, applied in one transaction.

    Rows already stored (same component, time and HI) are skipped and counted in
    ``duplicates``; the response lists the new alerts. The token (a write token) is checked
    before the body on SQLite. On PostgreSQL it is checked inside the group commit's
    transaction (:meth:`ServiceDB.ingest`), and before the body too unless it passed that
    check before (:meth:`ServiceDB.known_writer`): a token never seen, or refused since, is
    refused before its body is read or anything is queued for the writer; a body that fails
    has its token checked first. A bad token gets its 401 or 403 either way."""
    sdb: ServiceDB = request.app.state.db
    token: str | None = None  # checked by the ingest
    if sdb.watch is not None:  # SQLite: a few microseconds on the event loop
        source = f"api:{(await write_token(request)).name}"
    else:
        source, token = "api:", await bearer_token(request)
        if not sdb.known_writer(token):
            try:
                await run_in_threadpool(sdb.writer_token, token)
            except TokenRefused as err:
                raise refusal(err) from None
    metrics: Metrics = request.app.state.metrics
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    t0 = time.perf_counter()
    try:
        body = [await _read_body(request, sdb, token)]  # freed by _ingest_body once decoded
        out = await run_in_threadpool(_ingest_body, sdb, body, ctype, source, token)
    except TokenRefused as err:
        raise refusal(err) from None
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
    return OrjsonResponse(out)


async def _read_body(request: Request, sdb: ServiceDB, token: str | None) -> bytearray:
    """The body (:func:`read_body`); when it fails (413, 408), ``token`` (not yet checked)
    is checked first (:meth:`ServiceDB.writer_token`)."""
    try:
        return await read_body(request)
    except BaseException:
        if token is not None:
            await run_in_threadpool(sdb.writer_token, token)
        raise


def _ingest_body(sdb: ServiceDB, body: list[bytearray], ctype: str, source: str,
                 token: str | None) -> dict[str, Any]:
    """The batch of the body in ``body`` (:func:`batch_frame`) ingested
    (:meth:`ServiceDB.ingest`, which checks ``token`` if given): one hand-off to a worker
    thread for both. The body is taken out of the list, so only its columns are held while
    the batch waits for its commit. A body that cannot be read has ``token`` checked
    first."""
    try:
        df = batch_frame(body.pop(), ctype)
    except BaseException:
        if token is not None:
            sdb.writer_token(token)
        raise
    return sdb.ingest(df, source, token=token)


def acquisitions_router(hi_model: HealthIndexModel | None) -> APIRouter:
    """The ingest route, its request body documented for a database of ``hi_model``."""
    router = APIRouter()
    router.add_api_route(
        "/api/v1/acquisitions", post_acquisitions, methods=["POST"], tags=["acquisitions"],
        openapi_extra={"requestBody": acquisitions_body(hi_model),
                       "security": [{BEARER.scheme_name: []}]},
        response_model=dict[str, Any], response_class=OrjsonResponse,
        responses=error_responses(401, 403, 408, 409, 413, 415, 422, 503))
    return router
