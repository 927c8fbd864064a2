"""The alert routes (docs/service.md): the list of alerts and their acknowledgement (a write
token; who and why are kept with the alert)."""

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query
from fastapi import Path as PathParam
from fastapi.responses import Response
from pydantic import BaseModel, Field

from rulkit.fleet.service.auth import DB, ReadToken, WriteToken
from rulkit.fleet.service.bodies import http_error
from rulkit.fleet.service.db import NotFound
from rulkit.fleet.service.responses import OrjsonResponse, error_responses
from rulkit.fleet.store.acquisitions import ConflictError

router = APIRouter()


# No docstring: pydantic would publish it as the schema's description.
class AckBody(BaseModel):  # noqa: D101
    by: str = Field(min_length=1, max_length=200, description="Who acknowledges the alert.")
    reason: str = Field(min_length=1, max_length=2000, description="Why (kept with the alert).")


@router.get("/api/v1/alerts", tags=["alerts"], response_model=dict[str, Any],
            response_class=OrjsonResponse, responses=error_responses(401, 422, 503))
def list_alerts(
    _tok: ReadToken,
    sdb: DB,
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


@router.post("/api/v1/alerts/{alert_id}/ack", tags=["alerts"],
             responses=error_responses(401, 403, 404, 409, 422, 503))
def ack_alert(
    alert_id: Annotated[int, PathParam(ge=1, le=2**53)],
    body: AckBody,
    tok: WriteToken,
    sdb: DB,
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
