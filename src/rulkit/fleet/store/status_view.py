"""``rulkit status`` at fleet scale: read the ``components`` table with :mod:`sqlite3` and print
it as a table, CSV or JSON without pandas.

docs/systems/embedded-rul.md §6-7: one row per component with its alert level, the RUL of the
estimator in force (median and interval, the data's time unit, the due date on the calendar),
whether it has failed or is stale, its last HI and acquisition. :func:`status_columns` derives
the printed columns from the stored ones; :func:`read_status` reads those with :mod:`sqlite3`
(the same read-only opening as :class:`~rulkit.fleet.store.sqlite.ComponentStore` with
``readonly=True``, one read transaction), and the pandas path of ``rulkit status`` (a table
rulkit cannot have written: it names the bad row) feeds the same function, so both print the
same bytes (tested, tests/fleet/store/test_status_view.py):

* **Order.** Worst first: alert level descending, then RUL median ascending (not estimated
  yet as 1e308: after every finite RUL), then the component id (code-point order); or by RUL
  or due date (``sort``); the API's orders.
* **Text.** Floats in CSV as Arrow writes them (shortest round-trip digits, positional for
  decimal exponents -6 to 9, ``1e+10``/``1e-7`` otherwise, no ``.0``, ``inf``; a missing
  value empty); in JSON as orjson writes them (the shortest text that reads back as the same
  float64, ``1.0``, ``1e-7``, ``1e16``; non-finite and missing as ``null``), the text ASCII
  (:func:`format_json`). Date-times as ISO 8601 UTC (``2024-05-01T12:00:00Z``).
* **Read-only.** The database is opened as :class:`~rulkit.fleet.store.sqlite.ComponentStore`
  opens it with ``readonly=True``
  (:func:`~rulkit.fleet.store.database_file.read_verified`: through SQLite, ``query_only``)
  and read in one read transaction.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from dataclasses import dataclass, field
from operator import itemgetter
from pathlib import Path
from typing import Any

import numpy as np

from rulkit.fleet.monitoring.estimators import Estimator, estimator_in_force
from rulkit.fleet.monitoring.rules import due_time, stale, unit_seconds
from rulkit.fleet.store.database_file import (
    StoreError,
    _config_from_meta,
    _degradation_from_meta,
    _read_meta,
    read_verified,
    store_error,
)
from rulkit.fleet.store.prognosis import read_monitoring
from rulkit.fleet.tracking.tracker_chain import LEVEL_NAMES

STORED_COLUMNS = ("component", "level", "hi", "n", "t", "rul_median", "rul_low", "rul_high",
                  "failed_at", "seen")
"""The ``components`` columns ``rulkit status`` reads."""
NULLABLE = ("rul_median", "failed_at", "seen")
STATUS_COLUMNS = ("component", "level", "failed", "stale", "rul", "rul_low", "rul_high",
                  "time_unit", "due", "hi", "n", "t", "last_seen", "estimator")
"""The columns of ``rulkit status --format csv|json``, in order: ``rul`` the median (missing
while not estimated), ``rul_low``/``rul_high`` its interval (``inf``: the quantile lies in the
never-failing mass; JSON ``null``), ``due`` the calendar date-time the median runs out,
``last_seen`` the calendar date-time of the last acquisition, ``estimator`` what gave the
RUL."""
FLOAT_COLUMNS = ("rul", "rul_low", "rul_high", "hi", "t")
BOOL_COLUMNS = ("failed", "stale")
TEXT_COLUMNS = ("time_unit", "due", "last_seen", "estimator")
SORTS = ("worst", "rul", "due")


@dataclass(frozen=True)
class StatusInfo:
    """What the table prints around the rows: the database's estimator, the counts per level
    (and of stale components) over all components, the calendar time ``now`` staleness is
    judged at, and the fitted model's warnings."""

    estimator: Estimator
    n_all: int
    counts: dict[str, int] = field(default_factory=dict)
    now: float = 0.0


def estimator_of_meta(path: Path, meta: dict[str, str]) -> Estimator:
    """The estimator in force of a database from its ``meta`` (StoreError when unreadable)."""
    cfg, _ = _config_from_meta(path, meta)
    model = _degradation_from_meta(path, meta)
    try:
        rules, trend = read_monitoring(meta)
    except (ValueError, TypeError, KeyError) as err:
        raise StoreError(f"{path}: unreadable monitoring rules in table meta: {err}") from err
    return estimator_in_force(rules, cfg, model, trend)


def read_status(path: str | Path, *, now: float, sort: str = "worst", timeout: float = 30.0
                ) -> tuple[StatusInfo, dict[str, Any]] | None:
    """``(info, columns)`` of the database at ``path`` (:func:`status_columns`), or ``None``
    when a row is not as rulkit writes it (a text among numbers, a NULL where rulkit never
    writes one, an unknown level): the caller then reads through
    :meth:`~rulkit.fleet.store.sqlite.ComponentStore.status`, which names the row.

    Raises ``FileNotFoundError`` (no database) and :class:`StoreError` as
    ``ComponentStore(path, readonly=True)`` does.
    """
    path = Path(path)
    est_box: list[Any] = []

    def read(conn: sqlite3.Connection) -> list[dict[str, Any]] | None:
        meta = _read_meta(conn)
        est_box[:] = [estimator_of_meta(path, meta)]
        try:
            have = {r[1] for r in conn.execute("PRAGMA table_info(components)").fetchall()}
            if not set(STORED_COLUMNS) <= have:
                raise StoreError(f"{path}: written by an older rulkit (no one-RUL columns); "
                                 "`rulkit track` or `rulkit serve` on it upgrades it in place")
            # no memory map: it saved no CPU, warm or cold (bench_scale.py --mmap), and a
            # mapped file's I/O error is a signal that ends the process, not an exception
            conn.execute("BEGIN DEFERRED")
            cur = conn.execute(f"SELECT {', '.join(STORED_COLUMNS)} FROM components")
            chunks = []
            while rows := cur.fetchmany(READ_ROWS):  # each chunk's objects freed for the next
                chunk = _typed(np.fromiter(rows, dtype=_OBJECT_RECORD, count=len(rows)))
                if chunk is None:
                    return None
                chunks.append(chunk)
            conn.execute("COMMIT")
        except sqlite3.Error as err:
            raise store_error(path, err, timeout) from err
        return chunks

    chunks = read_verified(path, timeout, read)
    if chunks is None:
        return None
    est = est_box[0]
    if not chunks:
        return status_columns({c: [] for c in STORED_COLUMNS}, est, now, sort)
    stored = {c: [v for ch in chunks for v in ch[c]] if c == "component"
              else np.concatenate([ch[c] for ch in chunks]) for c in STORED_COLUMNS}
    return status_columns(stored, est, now, sort)


READ_ROWS = 8192
"""Rows fetched and converted at a time by :func:`read_status`."""
_OBJECT_RECORD = np.dtype([(c, object) for c in STORED_COLUMNS])


def _typed(rows: np.ndarray) -> dict[str, Any] | None:
    """The stored columns of a chunk of rows (a record array of objects, one field per
    column; the fields are copied into it in one C loop, faster than ``zip(*rows)``) with
    their numbers as arrays (None as NaN), or None when a value is not of the type rulkit
    writes (what the pandas path accepts unchanged)."""
    typed: dict[str, Any] = {"component": rows["component"].tolist()}
    if set(map(type, typed["component"])) != {str}:
        return None
    for c in STORED_COLUMNS[1:]:
        values = rows[c]
        kinds = set(map(type, values))
        if c in NULLABLE:
            if not kinds <= {float, type(None)}:
                return None
            if type(None) in kinds:
                values = values.copy()
                values[values == None] = np.nan  # noqa: E711 (elementwise)
            typed[c] = values.astype(np.float64)
        elif kinds != ({int} if c in ("level", "n") else {float}):
            return None
        else:
            typed[c] = values.astype(np.int64 if c in ("level", "n") else np.float64)
    if not np.isin(typed["level"], list(LEVEL_NAMES)).all():
        return None
    return typed


def _floats(values: Any) -> np.ndarray:
    """A float64 array of ``values`` (None as NaN)."""
    a = np.asarray(values, dtype=object) if isinstance(values, list) else np.asarray(values)
    if a.dtype == object:
        a = np.where(a == None, np.nan, a)  # noqa: E711 (elementwise)
    return np.asarray(a, dtype=np.float64)


def iso_times(seconds: np.ndarray) -> list[str | None]:
    """Seconds since 1970 as ISO 8601 UTC date-times to the second (None where NaN)."""
    s = np.asarray(seconds, dtype=np.float64)
    ok = np.isfinite(s) & (np.abs(s) < 1e13)
    # each distinct second written once (the components of one batch share their last-seen
    # time), then taken for every row
    distinct, where = np.unique(np.where(ok, np.round(s), 0), return_inverse=True)
    texts = np.datetime_as_string(distinct.astype("datetime64[s]"), unit="s", timezone="UTC")
    out: list[str | None] = texts.astype(object)[where.reshape(-1)].tolist()
    for i in np.flatnonzero(~ok).tolist():
        out[i] = None
    return out


def status_columns(stored: dict[str, Any], est: Estimator, now: float, sort: str = "worst"
                   ) -> tuple[StatusInfo, dict[str, Any]]:
    """The printed columns (:data:`STATUS_COLUMNS`) and :class:`StatusInfo` from the stored
    ones (:data:`STORED_COLUMNS`; lists or arrays, None/NaN where missing), sorted by
    ``sort`` (:data:`SORTS`)."""
    if sort not in SORTS:
        raise ValueError(f"sort: expected one of {SORTS}, got {sort!r}")
    comp = stored["component"]
    if not isinstance(comp, list) or set(map(type, comp)) - {str}:
        comp = [str(c) for c in comp]
    n = len(comp)
    a = {c: _floats(stored[c]) for c in ("hi", "t", "rul_median", "rul_low", "rul_high",
                                          "failed_at", "seen")}
    level = np.asarray(stored["level"], dtype=np.int64).reshape(n)
    unit = est.time_unit
    is_stale = stale(a["seen"], now, est.rules)
    failed = np.isfinite(a["failed_at"])
    due = np.where(failed, np.nan, due_time(a["seen"], a["rul_median"], unit))  # failed: none
    counts = {name: int((level == k).sum()) for k, name in sorted(LEVEL_NAMES.items())}
    counts["stale"] = int(is_stale.sum())
    rank = np.empty(n, dtype=np.int64)
    rank[sorted(range(n), key=comp.__getitem__)] = np.arange(n)
    order = np.lexsort(_sort_keys(sort, rank, level, a["rul_median"], a["seen"], unit))
    cols: dict[str, Any] = {
        "component": list(itemgetter(*order.tolist())(comp)) if n > 1 else comp,
        "level": level[order], "failed": failed[order],
        "stale": is_stale[order], "rul": a["rul_median"][order], "rul_low": a["rul_low"][order],
        "rul_high": a["rul_high"][order], "time_unit": [unit] * n,
        "due": iso_times(due[order]), "hi": a["hi"][order],
        "n": np.asarray(stored["n"], dtype=np.int64).reshape(n)[order], "t": a["t"][order],
        "last_seen": iso_times(a["seen"][order]), "estimator": [est.label] * n}
    return StatusInfo(estimator=est, n_all=n, counts=counts, now=now), cols


def _sort_keys(sort: str, rank: np.ndarray, level: np.ndarray, median: np.ndarray,
               seen: np.ndarray, unit: str) -> list[np.ndarray]:
    """:func:`numpy.lexsort` keys (last = primary) of the orders of the API
    (:data:`rulkit.fleet.service.fleet_view.ORDERS`): an unknown value sorts as 1e308."""
    def known(x: np.ndarray) -> np.ndarray:
        return np.where(np.isnan(x), 1e308, x)

    if sort == "worst":
        return [rank, known(median), -level]
    if sort == "rul":
        return [rank, known(median)]
    scale = unit_seconds(unit)
    if scale is None:  # no calendar: the id decides
        return [rank]
    with np.errstate(invalid="ignore"):
        return [rank, known(seen + median * scale)]


def limited(cols: dict[str, Any], limit: int) -> dict[str, Any]:
    """The first ``limit`` rows (all for 0)."""
    return {c: v[:limit] for c, v in cols.items()} if limit else cols


# --------------------------------------------------------------------------- Arrow arrays
# Built from buffers: pyarrow.array and pyarrow.scalar look for pandas objects and import
# pandas (~0.3 s) on their first call, which this module exists to avoid.
def _num(a: np.ndarray, typ: Any) -> Any:
    import pyarrow as pa

    a = np.ascontiguousarray(a)
    return pa.Array.from_buffers(typ, len(a), [None, pa.py_buffer(a)])


def _bools(a: np.ndarray) -> Any:
    import pyarrow as pa

    bits = np.packbits(np.asarray(a, dtype=bool), bitorder="little")
    return pa.Array.from_buffers(pa.bool_(), len(a), [None, pa.py_buffer(bits)])


def _strs(values: list[str]) -> Any:
    """A ``large_string`` array of ``values``."""
    import pyarrow as pa

    text = "".join(values)
    raw = text.encode("utf-8")
    if len(raw) == len(text):  # ASCII: bytes = characters
        lens = np.fromiter(map(len, values), dtype=np.int64, count=len(values))
    else:
        lens = np.fromiter((len(v.encode("utf-8")) for v in values), dtype=np.int64,
                           count=len(values))
    off = np.zeros(len(values) + 1, dtype=np.int64)
    np.cumsum(lens, out=off[1:])
    return pa.Array.from_buffers(pa.large_string(), len(values),
                                 [None, pa.py_buffer(off), pa.py_buffer(raw)])


def _const(s: str, n: int) -> Any:
    """``n`` times the string ``s`` (a ``large_string`` array)."""
    import pyarrow as pa

    raw = s.encode("utf-8")
    off = np.arange(n + 1, dtype=np.int64) * len(raw)
    return pa.Array.from_buffers(pa.large_string(), n,
                                 [None, pa.py_buffer(off), pa.py_buffer(raw * n)])


def _levels(level: np.ndarray) -> Any:
    """The level names of ``level`` (a ``large_string`` array; no pyarrow.compute, whose
    import alone costs a tenth of a second)."""
    return _strs([LEVEL_NAMES[k] for k in np.asarray(level, dtype=np.int64).tolist()])


# --------------------------------------------------------------------------- CSV
def printable_id(component: str) -> str:
    """A component id as the CSV prints it: unchanged when printable (every id rulkit
    ingests is), else through :func:`rulkit.tables.safe_text` (a hand-made database's ESC
    or newline must not reach a terminal)."""
    if component.isprintable():
        return component
    from rulkit.tables import safe_text

    return safe_text(component)


def _with_nulls(arr: Any, missing: np.ndarray) -> Any:
    """``arr`` with the rows ``missing`` null (a validity bitmap on its buffers)."""
    import pyarrow as pa

    if not missing.any():
        return arr
    bits = np.packbits(~missing, bitorder="little")
    return pa.Array.from_buffers(arr.type, len(arr), [pa.py_buffer(bits), *arr.buffers()[1:]])


def _text(values: list[str | None]) -> Any:
    """A ``large_string`` array, None as null (one value in every row written once)."""
    n = len(values)
    if n and values.count(values[0]) == n:
        return _with_nulls(_const(values[0] or "", n), np.full(n, values[0] is None))
    if None not in values:
        return _strs(values)  # type: ignore[arg-type]
    missing = np.fromiter((v is None for v in values), dtype=bool, count=n)
    return _with_nulls(_strs([v or "" for v in values]), missing)


def format_csv(cols: dict[str, Any]) -> bytes:
    """The CSV bytes of ``rulkit status --format csv`` (:data:`STATUS_COLUMNS`): pyarrow's
    CSV writer with ``quoting_style="needed"`` (strings quoted, shortest round-trip floats,
    booleans ``true``/``false``, a missing value empty), on arrays built without pandas."""
    import io

    import pyarrow as pa
    import pyarrow.csv as pacsv

    ids = cols["component"]
    if not "".join(ids).isprintable():
        ids = [printable_id(c) for c in ids]
    arrays = [_strs(ids), _levels(cols["level"])]
    for c in STATUS_COLUMNS[2:]:
        if c in BOOL_COLUMNS:
            arrays.append(_bools(cols[c]))
        elif c == "n":
            arrays.append(_num(cols[c].astype(np.int64), pa.int64()))
        elif c in TEXT_COLUMNS:
            arrays.append(_text(cols[c]))
        else:
            v = np.asarray(cols[c], dtype=np.float64)
            arrays.append(_with_nulls(_num(v, pa.float64()), np.isnan(v)))
    buf = io.BytesIO()
    pacsv.write_csv(pa.Table.from_arrays(arrays, names=list(STATUS_COLUMNS)), buf,
                    pacsv.WriteOptions(quoting_style="needed"))
    return buf.getvalue()


# --------------------------------------------------------------------------- JSON
def _ascii_json(text: bytes) -> bytes:
    """UTF-8 JSON with every non-ASCII character as a ``\\uXXXX`` escape (a surrogate pair
    beyond U+FFFF), so no byte of an id reaches a terminal raw; outside strings JSON text is
    ASCII, so escaping every such character keeps the text's meaning."""
    if text.isascii():
        return text

    def esc(ch: str) -> str:
        c = ord(ch)
        if c < 0x10000:
            return f"\\u{c:04x}"
        c -= 0x10000
        return f"\\u{0xD800 + (c >> 10):04x}\\u{0xDC00 + (c & 0x3FF):04x}"

    return "".join(esc(ch) if ord(ch) > 0x7F else ch for ch in text.decode()).encode()


def _json_texts(values: Any) -> tuple[np.ndarray, np.ndarray]:
    """Each value of a column as orjson writes it inside a record, as ``(bytes, lengths)``
    (:func:`split_texts`): a column's list through one :func:`orjson.dumps` cut at its commas
    when that gives one text per value (numbers, booleans, null and strings without commas),
    else one :func:`orjson.dumps` per value."""
    import orjson

    if isinstance(values, np.ndarray):  # NaN and inf stay floats: orjson writes them as null
        values = values.tolist()
    text = orjson.dumps(values)[1:-1]
    if text.count(b",") != len(values) - 1:  # a comma inside a string
        return split_texts(b"\x00".join(map(orjson.dumps, values)), 0)  # JSON holds no NUL
    return split_texts(text, ord(","))


def split_texts(text: bytes, sep: int) -> tuple[np.ndarray, np.ndarray]:
    """The texts joined by the byte ``sep`` in ``text`` as ``(bytes, lengths)``: their bytes
    one after another (a uint8 array, the separators dropped) and the length of each."""
    raw = np.frombuffer(text, dtype=np.uint8)
    cuts = np.flatnonzero(raw == sep)
    lens = np.diff(cuts, prepend=-1, append=raw.size) - 1
    return np.delete(raw, cuts), lens


def place_texts(out: np.ndarray, raw: np.ndarray, lens: np.ndarray, first: Any) -> None:
    """Copy one text per row of the byte matrix ``out`` (``raw`` and ``lens`` as
    :func:`split_texts` gives them) to that row from column ``first`` (one for all rows, or
    one per row): every character's place computed at once, no Python per text."""
    rows, width = out.shape
    begin = np.arange(rows, dtype=np.int64) * width + first - (np.cumsum(lens) - lens)
    out.reshape(-1)[np.repeat(begin, lens) + np.arange(raw.size)] = raw


CHUNK_ROWS = 4096
"""Rows per chunk of the JSON and table writers: their byte matrices stay a few MB, reused
chunk after chunk, whatever the number of components."""


def format_json(cols: dict[str, Any]) -> Iterator[bytes]:
    """The JSON text of ``rulkit status --format json``: an array of records of
    :data:`STATUS_COLUMNS`, the bytes :func:`orjson.dumps` writes for a list of dicts,
    without the final newline, in chunks of :data:`CHUNK_ROWS` records.

    Floats are the shortest text that reads back as the same float64 (``json.loads`` gives
    the stored value bit for bit); NaN and infinities ``null``; date-times ISO 8601 UTC
    strings (``2024-05-01T12:00:00Z``) or ``null``; booleans ``true``/``false``; ASCII only
    (:func:`_ascii_json`).

    Written by columns, no dict per row: a byte matrix of NUL (a row per record) gets the
    keys and the columns with one value in every row as blocks, and each other column's
    texts (:func:`_json_texts`) at their block (:func:`place_texts`); the NUL left between
    them is dropped in one pass (JSON text holds no NUL byte: orjson escapes it)."""
    n = len(cols["component"])
    if n == 0:
        yield b"[]"
        return
    blocks = _json_blocks(cols, n)
    widths = [len(b) if isinstance(b, bytes) else int(b[1].max()) for b in blocks]
    # each column's texts by chunk of rows: where a chunk's texts begin and end
    bounds: list[Any] = [None if isinstance(b, bytes)
                         else np.concatenate([[0], np.cumsum(b[1])]) for b in blocks]
    for r0 in range(0, n, CHUNK_ROWS):
        r1 = min(r0 + CHUNK_ROWS, n)
        out = np.zeros((r1 - r0, sum(widths)), dtype=np.uint8)
        at = 0
        for block, width, ends in zip(blocks, widths, bounds, strict=True):
            if isinstance(block, bytes):
                out[:, at:at + width] = np.frombuffer(block, dtype=np.uint8)
            else:
                raw, lens = block
                place_texts(out, raw[ends[r0]:ends[r1]], lens[r0:r1], at)
            at += width
        if r1 == n:
            out[-1, -1] = ord("]")  # the last record's comma
        yield _ascii_json((b"[" if r0 == 0 else b"") + out[out != 0].tobytes())


def _json_blocks(cols: dict[str, Any], n: int) -> list[Any]:
    """The blocks of a record of :func:`format_json`, in order: literal bytes (keys, the
    columns with one value in every row), or a column's texts as ``(bytes, lengths)``."""
    import orjson

    blocks: list[Any] = []
    between = b"{"  # the literal text before the next column of texts
    for k, c in enumerate(STATUS_COLUMNS):
        v = cols[c]
        between += (b"," if k else b"") + orjson.dumps(c) + b":"
        if c == "level":
            names = {i: orjson.dumps(name) for i, name in LEVEL_NAMES.items()}
            texts = split_texts(b"\x00".join(
                [names[i] for i in np.asarray(v, dtype=np.int64).tolist()]), 0)
        elif c in BOOL_COLUMNS:
            texts = split_texts(b",".join(np.where(np.asarray(v, dtype=bool), b"true", b"false")
                                          .tolist()), ord(","))
        elif not isinstance(v, np.ndarray) and v.count(v[0]) == n:  # one value in every row
            between += orjson.dumps(v[0])
            continue
        else:
            texts = _json_texts(v)
        blocks += [between, texts]
        between = b""
    return [*blocks, between + b"},"]
