"""What the service's routes answer with (docs/service.md): the orjson response of the reads
and the error bodies every route documents in the OpenAPI schema."""

from typing import Any

import orjson
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field


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


ERROR_TEXT = {401: "Missing, invalid or revoked token", 403: "Read-only token on a write",
              404: "No such component or alert", 408: "The body did not arrive in time",
              409: "Contradicts stored data; nothing written", 413: "Batch too large",
              415: "Unsupported content type", 422: "Invalid request; nothing written",
              503: "Database busy or unavailable; retry (Retry-After)"}
"""The OpenAPI description of each error status a route can answer."""


def error_responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    """The OpenAPI ``responses`` of a route that can answer each of ``codes``."""
    return {c: {"model": ErrorBody, "description": ERROR_TEXT[c]} for c in codes}
