"""The dependencies of the service's routes (docs/service.md): the app's database and
metrics, and the bearer token (any valid token for reads, a write token for writes).

Each is a coroutine: FastAPI runs a plain function dependency in its thread pool, a hand-off
to a worker thread and back per dependency and request, which cost more CPU than the rest of
the framework's share of a request. The token's database lookup
(:meth:`~rulkit.fleet.service.db.ServiceDB.check_token`) runs on the event loop on SQLite
(a few microseconds on the connection of :mod:`.commit_watch`, which never waits for a
writer) and in a worker thread on PostgreSQL (a round trip to its server, and a wait for a
pooled connection). The ingest route on PostgreSQL checks its token inside the group
commit's transaction instead (:meth:`~rulkit.fleet.service.db.ServiceDB.ingest`): one query
for a group's batches, no hand-off of its own.
"""

from typing import Annotated

from fastapi import Depends, HTTPException, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from rulkit.fleet.service.bodies import http_error
from rulkit.fleet.service.db import (
    ServiceDB,
    Token,
    TokenRefused,
    plausible_token,
)
from rulkit.fleet.service.metrics import Metrics

BEARER = HTTPBearer(auto_error=False, description="A token from `rulkit token create`.")
"""The OpenAPI security scheme of ``/api/v1``."""


async def service_db(request: Request) -> ServiceDB:
    """The database the app serves (``app.state.db``, set by ``create_app``)."""
    sdb: ServiceDB = request.app.state.db
    return sdb


async def service_metrics(request: Request) -> Metrics:
    """The app's counters and histograms (``app.state.metrics``)."""
    metrics: Metrics = request.app.state.metrics
    return metrics


async def authenticated(
    creds: Annotated[HTTPAuthorizationCredentials | None, Depends(BEARER)],
    sdb: Annotated[ServiceDB, Depends(service_db)],
) -> Token:
    """The request's valid token (401 when it has none, or one unknown or revoked)."""
    return await _valid(creds, sdb)


async def _valid(creds: HTTPAuthorizationCredentials | None, sdb: ServiceDB) -> Token:
    token = _credential(creds)
    if sdb.watch is not None:
        tok = sdb.check_token(token)
    else:
        tok = await run_in_threadpool(sdb.check_token, token)
    if tok is None:
        raise refusal(TokenRefused(401))
    return tok


def _credential(creds: HTTPAuthorizationCredentials | None) -> str:
    """The bearer token of the request's credentials (401 when there is none, or one that
    cannot be a token)."""
    if creds is None or creds.scheme.lower() != "bearer":
        raise http_error(401, "missing bearer token", {"WWW-Authenticate": "Bearer"})
    if not plausible_token(creds.credentials):
        raise refusal(TokenRefused(401))
    return creds.credentials


async def bearer_token(request: Request) -> str:
    """The request's bearer token, not yet checked (401 when it has none): the ingest route
    on PostgreSQL has it checked in the group's transaction."""
    return _credential(await BEARER(request))


def refusal(err: TokenRefused) -> HTTPException:
    """The response of a refused token: 401 (with ``WWW-Authenticate``) or 403."""
    return http_error(err.status, str(err),
                      {"WWW-Authenticate": "Bearer"} if err.status == 401 else None)


async def writer(tok: Annotated[Token, Depends(authenticated)]) -> Token:
    """The request's write token (403 for a read-only token)."""
    return _writes(tok)


async def write_token(request: Request) -> Token:
    """The request's write token, as :func:`writer` gives it (the same 401 and 403), read
    without FastAPI's resolution of the four dependencies behind it: the ingest route calls
    it, once per batch, and declares the security scheme in its OpenAPI operation."""
    return _writes(await _valid(await BEARER(request), request.app.state.db))


def _writes(tok: Token) -> Token:
    if not tok.can_write:
        raise refusal(TokenRefused(403))
    return tok


ReadToken = Annotated[Token, Depends(authenticated)]
"""A route parameter: any valid token."""
WriteToken = Annotated[Token, Depends(writer)]
"""A route parameter: a write token."""
DB = Annotated[ServiceDB, Depends(service_db)]
"""A route parameter: the app's database."""
