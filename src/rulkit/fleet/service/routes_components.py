"""The read routes of components (docs/service.md): the summary, the pages of components, one
component and its history (by path, or by query for ids a browser would rewrite)."""

from typing import Annotated, Any, Literal
from urllib.parse import unquote

from fastapi import APIRouter, Query, Request
from fastapi import Path as PathParam
from fastapi.responses import Response

from rulkit.fleet.service.auth import DB, ReadToken
from rulkit.fleet.service.bodies import http_error
from rulkit.fleet.service.db import NotFound, ServiceDB
from rulkit.fleet.service.fleet_view import CursorError
from rulkit.fleet.service.responses import OrjsonResponse, error_responses

router = APIRouter()

PREFIX = "/api/v1/components/"


def component_id(component: str) -> str:
    """``component`` as a stored id could be (404 for one holding a NUL character)."""
    if "\x00" in component:
        raise http_error(404, "no such component")
    return component


def raw_tail(request: Request) -> str:
    """The percent-encoded path after /api/v1/components/ (ids may hold "/" as %2F)."""
    raw = request.scope.get("raw_path") or request.url.path.encode()
    return raw.decode("latin-1").split("?", 1)[0][len(PREFIX):]


@router.get("/api/v1/summary", tags=["components"], response_model=dict[str, Any],
            response_class=OrjsonResponse, responses=error_responses(401, 503))
def get_summary(_tok: ReadToken, sdb: DB) -> Response:
    """Counts per level and of stale components, what gives the RUL (estimator, time
    unit, interval), the alert rules and the fitted model's warnings."""
    return OrjsonResponse(sdb.summary())


@router.get("/api/v1/components", tags=["components"], response_model=dict[str, Any],
            response_class=OrjsonResponse, responses=error_responses(401, 422, 503))
def list_components(
    _tok: ReadToken,
    sdb: DB,
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
        return OrjsonResponse(page_body(sdb, limit=limit, offset=offset, level=level,
                                        sort=sort, after=after))
    except CursorError as err:
        raise http_error(422, str(err)) from None


def page_body(sdb: ServiceDB, *, limit: int, offset: int, level: str | None, sort: str,
              after: str | None, now: float | None = None) -> dict[str, Any]:
    """A page's body: the total, the page's own parameters, its items and the next cursor
    (:meth:`~rulkit.fleet.service.db.ServiceDB.components`; staleness judged at ``now``,
    default the clock)."""
    total, items, nxt = sdb.components(limit=limit, offset=offset, level=level, sort=sort,
                                       after=after, now=now)
    return {"total": total, "limit": limit, "offset": offset, "sort": sort, "items": items,
            "next": nxt}


@router.get("/api/v1/components/{component:path}/history", tags=["components"],
            response_model=dict[str, Any],
            response_class=OrjsonResponse, responses=error_responses(401, 404, 422, 503))
def component_history(
    component: Annotated[str, PathParam(description="Component id, '/' encoded as %2F")],
    request: Request,
    _tok: ReadToken,
    sdb: DB,
    limit: Annotated[int, Query(ge=1, le=100_000)] = 10_000,
) -> Response:
    """The component's last ``limit`` acquisitions (HI, fHI, the RUL median and
    interval, level; time ascending), the component now, its HI forecast to the
    threshold with its band, and its alerts."""
    tail = raw_tail(request)
    try:
        if not tail.endswith("/history"):  # an id ending in %2Fhistory: the component
            return OrjsonResponse(sdb.component(component_id(unquote(tail))))
        return OrjsonResponse(sdb.history(component_id(unquote(tail[:-len("/history")])),
                                          limit=limit))
    except NotFound as err:
        raise http_error(404, str(err)) from None


@router.get("/api/v1/components/{component:path}", tags=["components"],
            response_model=dict[str, Any],
            response_class=OrjsonResponse, responses=error_responses(401, 404, 422, 503))
def get_component(
    component: Annotated[str, PathParam(description="Component id, '/' encoded as %2F")],
    request: Request,
    _tok: ReadToken,
    sdb: DB,
) -> Response:
    """One component's state and its number of open alerts."""
    try:
        return OrjsonResponse(sdb.component(component_id(unquote(raw_tail(request)))))
    except NotFound as err:
        raise http_error(404, str(err)) from None


@router.get("/api/v1/history", tags=["components"], response_model=dict[str, Any],
            response_class=OrjsonResponse, responses=error_responses(401, 404, 422, 503))
def history_by_query(
    component: Annotated[str, Query(min_length=1, max_length=512,
                                    description="Component id (any, also '.' or '..')")],
    _tok: ReadToken,
    sdb: DB,
    limit: Annotated[int, Query(ge=1, le=100_000)] = 10_000,
) -> Response:
    """As ``GET /api/v1/components/{id}/history``, the id in the query: browsers rewrite
    the path segments ``.`` and ``..`` (also percent-encoded), so a component named so
    is only reachable this way."""
    try:
        return OrjsonResponse(sdb.history(component_id(component), limit=limit))
    except NotFound as err:
        raise http_error(404, str(err)) from None
