"""Request bodies of the service, read with bounded memory and time (docs/service.md).

* :func:`read_body` streams a body and stops at :data:`MAX_BODY` bytes (413) without holding
  more, and gives up on a client that sends nothing for :data:`BODY_TIMEOUT` seconds (408).
* :func:`batch_frame` turns a body into the acquisition columns of the store's one ingestion path:
  CSV and Parquet through :func:`rulkit.fleet.store.acquisitions.read_acquisitions` (the reader
  of ``rulkit track``: field counts per row, Parquet row counts from the metadata before
  decoding), JSON here: rows are counted before they are decoded (:data:`MAX_ROWS`), nesting
  deeper than the batch's own is refused (422, never a recursion error), and every value
  keeps its JSON type (``true`` is not a number).
"""

from __future__ import annotations

import asyncio
import json
from typing import Any

import numpy as np
import pandas as pd
from fastapi import HTTPException, Request

from rulkit.fleet.store.acquisitions import Columns, IngestError, read_acquisitions

MAX_BODY = 64 * 1024 * 1024
"""Bytes of one upload."""
MAX_ROWS = 1_000_000
"""Acquisitions in one batch."""
BODY_TIMEOUT = 30.0
"""Seconds a client may go without sending any of its body."""
CSV_TYPES = ("text/csv", "text/plain")
PARQUET_TYPES = ("application/vnd.apache.parquet", "application/x-parquet",
                 "application/octet-stream")


def http_error(status: int, detail: str, headers: dict[str, str] | None = None
               ) -> HTTPException:
    """An error response ``{"detail": ...}`` with ``status``."""
    return HTTPException(status_code=status, detail=detail, headers=headers)


async def read_body(request: Request, max_bytes: int = MAX_BODY,
                    timeout: float = BODY_TIMEOUT) -> bytearray:
    """The request body, streamed into one buffer (no second copy): 413 as soon as it
    exceeds ``max_bytes`` (also when a ``Content-Length`` says so up front), 408 when no data
    arrives for ``timeout`` s."""
    size = request.headers.get("content-length")
    if size is not None and size.isdigit() and int(size) > max_bytes:
        raise http_error(413, f"body larger than {max_bytes} bytes")
    buf = bytearray()
    stream = request.stream().__aiter__()
    while True:
        try:
            chunk = await asyncio.wait_for(stream.__anext__(), timeout)
        except StopAsyncIteration:
            break
        except TimeoutError:
            raise http_error(408, f"no body data for {timeout:g} s") from None
        if len(buf) + len(chunk) > max_bytes:
            raise http_error(413, f"body larger than {max_bytes} bytes")
        buf += chunk
    return buf


def batch_frame(body: bytes | bytearray, ctype: str) -> pd.DataFrame | Columns:
    """The batch in ``body`` (content type ``ctype``) as columns component, time and hi (or
    the CI columns): a frame for CSV and Parquet, arrays for JSON; 413 / 415 / 422 for what
    cannot be taken (module docstring)."""
    try:
        if ctype in CSV_TYPES:
            return read_acquisitions(memoryview(body), "csv", max_rows=MAX_ROWS,
                                     name="CSV body")
        if ctype in PARQUET_TYPES:
            return read_acquisitions(memoryview(body), "parquet", max_rows=MAX_ROWS,
                                     name="Parquet body")
    except IngestError as err:
        raise http_error(413 if "per batch" in str(err) else 422, str(err)) from None
    if ctype in ("application/json", ""):
        return _json_frame(body)
    raise http_error(415, f"unsupported content type {ctype!r}: use application/json, "
                          "text/csv or application/vnd.apache.parquet")


def _json_frame(body: bytes | bytearray) -> Columns:
    if body.count(b"{") > MAX_ROWS + 1:  # rows counted before they are decoded
        raise http_error(413, f"body: more than {MAX_ROWS} rows per batch")
    try:
        obj = json.loads(body)
    except RecursionError:
        raise http_error(422, "body: JSON nested too deeply (a batch is "
                              '{"rows": [{...}, ...]})') from None
    except (ValueError, UnicodeDecodeError) as err:
        raise http_error(422, f"body: not valid JSON ({err})") from None
    rows = obj.get("rows") if isinstance(obj, dict) else None
    if not isinstance(rows, list):
        raise http_error(422, 'body: expected a JSON object {"rows": [...]}')
    if len(rows) > MAX_ROWS:
        raise http_error(413, f"body: {len(rows)} rows, at most {MAX_ROWS} per batch")
    if not rows:
        return {}
    return _rows_columns(rows)


def _rows_columns(rows: list[Any]) -> Columns:
    """Columns from JSON rows (objects of component and numbers; a missing key is NaN, named by
    the store's validation): one list per key, type-checked as a set of types, then one
    array per column (no pandas Series or frame: the store's validation takes arrays)."""
    keys: dict[str, None] = {}
    for i, r in enumerate(rows):
        if not isinstance(r, dict):
            raise http_error(422, f"row {i + 1}: expected an object with component, time, hi")
        keys.update(dict.fromkeys(r))
    cols: dict[str, Any] = {}
    for k in keys:
        vals = [r.get(k) for r in rows]
        types = set(map(type, vals))
        if k == "component":
            if types != {str}:
                bad = next(i for i, v in enumerate(vals) if not isinstance(v, str))
                raise http_error(422, f"row {bad + 1}: 'component' must be a string, got "
                                      f"{type(vals[bad]).__name__}")
            comp = np.empty(len(vals), dtype=object)  # not inferred as (UTF-8) strings
            comp[:] = vals
            cols[k] = comp
            continue
        if not types <= _NUMBER_TYPES:
            bad = next(i for i, v in enumerate(vals) if type(v) not in _NUMBER_TYPES)
            raise http_error(422, f"row {bad + 1}: {k!r} must be a number, got "
                                  f"{type(vals[bad]).__name__}")
        try:
            cols[k] = np.array(vals, dtype=np.float64)  # None -> NaN
        except OverflowError:
            raise http_error(422, "a number is too large for float64") from None
    return cols


_NUMBER_TYPES = frozenset((int, float, type(None)))
