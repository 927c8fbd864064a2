"""The history table's packed layout: one row per component and write chunk, its acquisitions'
values packed as little-endian float64 (docs/systems/embedded-rul.md §4).

A row of ``history`` is ``(component, t_first, t_last, n, ingest, data)``, primary key
``(component, t_first)``: ``n`` consecutive acquisitions of one component written by one
ingestion (at most :data:`MAX_CHUNK`). ``data`` (a BLOB on SQLite, BYTEA on PostgreSQL) is an
8-byte header (:data:`HEADER`: ``b"RKH"``, the layout version 1, the field count as a 32-bit
little-endian integer) followed by ``n`` records of :data:`PACKED_FIELDS`, each a
little-endian float64, record after record (``valid`` and ``level`` as 0.0/1.0 and 0.0, 1.0,
2.0; ``rul_median`` NaN where there is no estimate).

Why this layout: one SQL row per acquisition made the bare writes alone (15 bound values per
acquisition) cost more than the whole goal of ``rulkit track`` and of the service's ingest;
a chunk binds 6 values per component and ingestion, whatever its length. Records rather than
one array per column, so that the blobs of many chunks joined end to end are one array:
:func:`decode` reads any number of chunks with one ``np.frombuffer`` and no loop over them.
The header makes a later layout (another field list, another version) detectable per row;
:func:`decode` refuses a blob whose header or length is not this layout's.

Readers find the chunks overlapping a time range by ``t_last >= t0 AND t_first <= t1`` on the
key's ``component`` prefix; the last ``limit`` acquisitions by the chunks' ``n`` newest first
(:func:`read_last`). A database written with one row per acquisition is converted inside the
caller's write transaction by :func:`convert_row_history`
(:func:`rulkit.fleet.store.schema.migrate`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

PACKED_FIELDS = ("t", "hi", "fhi", "dhi", "rul", "frul", "drul", "d2rul", "valid", "level",
                 "rul_low", "rul_high", "rul_median")
"""The fields of one acquisition's record, in order: the history's fields of
:data:`rulkit.fleet.store.tracker_rows.HISTORY_FIELDS`, then ``rul_median`` (this module
imports no pandas: ``rulkit status`` reads the schema)."""
WIDTH = len(PACKED_FIELDS)
HEADER = b"RKH\x01" + WIDTH.to_bytes(4, "little")
"""Every blob's first 8 bytes: magic, layout version 1, field count."""
_HEADER_WORD = int(np.frombuffer(HEADER, dtype="<u8")[0])
MAX_CHUNK = 4096
"""Acquisitions per chunk at most (a component's longer run in one ingestion is split): bounds
what a read of a component's last rows decodes beyond them."""
COLUMNS = ("component", "t_first", "t_last", "n", "ingest", "data")
"""The history table's columns, in order."""
_F = {f: j for j, f in enumerate(PACKED_FIELDS)}


class LayoutError(ValueError):
    """A stored chunk that is not of this layout (header, length or count)."""


def records(columns: dict[str, Any], m: int) -> np.ndarray:
    """An ``(m, WIDTH)`` float64 array of records from ``columns`` (every field of
    :data:`PACKED_FIELDS`, arrays of length ``m``)."""
    out = np.empty((m, WIDTH), dtype="<f8")
    for j, f in enumerate(PACKED_FIELDS):
        out[:, j] = columns[f]
    return out


def chunk_rows(names: Any, seg: np.ndarray, rec: np.ndarray, ingest: Any,
               max_chunk: int = MAX_CHUNK) -> list[tuple]:
    """The history rows of records ``rec`` (time order within each component): component
    ``names[i]`` owns ``rec[seg[i]:seg[i + 1]]``, written by ingestion ``ingest[i]`` (or one
    ``ingest`` for all), split into chunks of at most ``max_chunk``."""
    seg = np.asarray(seg, dtype=np.int64)
    counts = np.diff(seg)
    pieces = -(-counts // max_chunk)
    owner = np.repeat(np.arange(counts.size), pieces)
    within = np.arange(owner.size) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    p0 = seg[owner] + within * max_chunk
    p1 = np.minimum(p0 + max_chunk, seg[owner + 1])
    blobs = _blobs(rec, p0, p1)
    comp = np.asarray(names, dtype=object)[owner].tolist()
    ing = (np.asarray(ingest)[owner].tolist() if np.ndim(ingest)
           else [int(ingest)] * owner.size)
    t = rec[:, _F["t"]]
    return list(zip(comp, t[p0].tolist(), t[p1 - 1].tolist(), (p1 - p0).tolist(), ing, blobs,
                    strict=True))


def _blobs(rec: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> list[memoryview]:
    """The blob of each chunk ``rec[p0[i]:p1[i]]`` (the header, then its records; the chunks
    consecutive: ``p0[i + 1] == p1[i]``), as views of one buffer: the records are copied
    once, in one operation, into place beside their headers (no bytes object per chunk;
    SQLite and psycopg bind a memoryview as a blob)."""
    p0 = np.asarray(p0, dtype=np.int64)
    p1 = np.asarray(p1, dtype=np.int64)
    if not np.array_equal(p0[1:], p1[:-1]):
        raise ValueError("history chunks: expected consecutive record ranges")
    per = 1 + WIDTH * (p1 - p0)
    start = np.cumsum(per) - per  # each chunk's first word
    words = np.empty(int(per.sum()), dtype="<f8")
    body = np.ones(words.size, dtype=bool)
    body[start] = False
    flat = np.ascontiguousarray(rec, dtype="<f8").reshape(-1)
    if p0.size:
        words[body] = flat[int(p0[0]) * WIDTH:int(p1[-1]) * WIDTH]
    del body
    words.view("<u8")[start] = _HEADER_WORD
    raw = words.data.cast("B")
    return [raw[8 * s:8 * (s + m)] for s, m in zip(start.tolist(), per.tolist(), strict=True)]


def decode(blobs: list[Any], n: Any) -> np.ndarray:
    """The records of chunks ``blobs`` (bytes or memoryview) of ``n`` acquisitions each, end
    to end: an ``(sum(n), WIDTH)`` float64 array. :class:`LayoutError` when a blob's header or
    length is not this layout's."""
    n = np.asarray(n, dtype=np.int64)
    if not blobs:
        return np.empty((0, WIDTH))
    joined = b"".join(blobs) if len(blobs) > 1 else bytes(blobs[0])
    per = 1 + WIDTH * n
    if len(joined) != 8 * int(per.sum()):
        raise LayoutError(f"history chunks hold {len(joined)} bytes, not the "
                          f"{int(per.sum()) * 8} of {int(n.sum())} acquisitions "
                          f"x {WIDTH} float64 and a header each")
    words = np.frombuffer(joined, dtype="<f8")
    heads = np.cumsum(per) - per
    if (words.view("<u8")[heads] != _HEADER_WORD).any():
        raise LayoutError("a history chunk's header is not rulkit's packed layout 1 "
                          f"({HEADER!r}); written by another version?")
    keep = np.ones(words.size, dtype=bool)
    keep[heads] = False
    return words[keep].reshape(-1, WIDTH)


def field(rec: np.ndarray, name: str) -> np.ndarray:
    """Column ``name`` of records ``rec``."""
    return rec[:, _F[name]]


def write_chunks(conn: Any, rows: list[tuple], table: str = "history") -> None:
    """INSERT history rows ``(component, t_first, t_last, n, ingest, data)`` into ``table``
    (a DB-API connection in qmark style)."""
    conn.executemany(f"INSERT INTO {table} ({', '.join(COLUMNS)}) VALUES "
                     f"({', '.join('?' * len(COLUMNS))})", rows)


def _decoded(rows: list[tuple]) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(component per chunk, n per chunk, records) of fetched rows
    ``(component, n, data)``."""
    comp = [str(r[0]) for r in rows]
    n = np.array([r[1] for r in rows], dtype=np.int64)
    return comp, n, decode([r[2] for r in rows], n)


def read_all(conn: Any, component: str | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(component per acquisition, ingest per acquisition, records) of the whole history or
    of one ``component``, ordered by component and time."""
    where, params = ("", ()) if component is None else (" WHERE component = ?", (component,))
    rows = conn.execute(f"SELECT component, n, data, ingest FROM history{where} "
                        "ORDER BY component, t_first", params).fetchall()
    comp, n, rec = _decoded(rows)
    ingest = np.repeat(np.array([r[3] for r in rows], dtype=np.int64), n)
    return np.repeat(np.array(comp, dtype=object), n), ingest, rec


def read_components(conn: Any, names: list[str]
                    ) -> tuple[list[tuple[str, float, int]], np.ndarray]:
    """Every chunk of ``names`` ordered by component and time: ((component, t_first, n) per
    chunk, their records end to end)."""
    ph = ",".join("?" * len(names))
    rows = conn.execute(f"SELECT component, n, data, t_first FROM history WHERE component IN "
                        f"({ph}) ORDER BY component, t_first", names).fetchall()
    comp, n, rec = _decoded(rows)
    return [(c, float(r[3]), int(k)) for c, r, k in zip(comp, rows, n, strict=True)], rec


def read_range(conn: Any, component: str, t0: float, t1: float) -> np.ndarray:
    """The records of ``component`` with ``t0 <= t <= t1``, time order (the chunks whose
    [t_first, t_last] overlap the range)."""
    rows = conn.execute("SELECT component, n, data FROM history WHERE component = ? AND "
                        "t_last >= ? AND t_first <= ? ORDER BY t_first",
                        (component, t0, t1)).fetchall()
    rec = _decoded(rows)[2]
    t = rec[:, _F["t"]]
    return rec[(t >= t0) & (t <= t1)]


def read_last(conn: Any, component: str, limit: int) -> np.ndarray:
    """The last ``limit`` records of ``component``, time ascending: the newest chunks' counts
    first (no blob read), then the blobs of just the chunks that hold them."""
    if limit <= 0:
        return np.empty((0, WIDTH))
    heads = conn.execute("SELECT t_first, n FROM history WHERE component = ? "
                         "ORDER BY t_first DESC LIMIT ?", (component, limit)).fetchall()
    if not heads:
        return np.empty((0, WIDTH))
    total = np.cumsum([int(r[1]) for r in heads])
    k = int(np.searchsorted(total, limit))  # the oldest chunk needed
    cut = float(heads[min(k, len(heads) - 1)][0])
    rows = conn.execute("SELECT component, n, data FROM history WHERE component = ? AND "
                        "t_first >= ? ORDER BY t_first", (component, cut)).fetchall()
    return _decoded(rows)[2][-limit:]


def rewrite(conn: Any, chunks: list[tuple[str, float, int]], rec: np.ndarray) -> None:
    """Replace the data of ``chunks`` ((component, t_first, n) each, as
    :func:`read_components` gives them) by ``rec``, their records end to end."""
    n = np.array([c[2] for c in chunks], dtype=np.int64)
    seg = np.concatenate([[0], np.cumsum(n)])
    conn.executemany("UPDATE history SET data = ? WHERE component = ? AND t_first = ?",
                     [(blob, c[0], c[1]) for c, blob in
                      zip(chunks, _blobs(rec, seg[:-1], seg[1:]), strict=True)])


def count(conn: Any) -> int:
    """The number of acquisitions in the history."""
    return int(conn.execute("SELECT COALESCE(SUM(n), 0) FROM history").fetchone()[0])


# ------------------------------------------------------------------ one row per acquisition
CONVERT_ROWS = 100_000
"""Acquisitions read per step of :func:`convert_row_history` (bounds its memory)."""


def is_row_history(columns: list[str]) -> bool:
    """Whether a history table of ``columns`` is the layout of one row per acquisition."""
    return bool(columns) and "t" in columns and "data" not in columns


def convert_row_history(conn: Any, columns: list[str], create: list[str]) -> int:
    """Inside the caller's write transaction: the table ``history`` of one row per acquisition
    (columns ``columns``) rewritten as chunks into a new table ``history_packed`` made by the
    statements ``create``, which then replaces it. Consecutive rows of one component and one
    ingestion become one chunk; a missing ``rul_median`` is NaN. Returns the acquisitions
    converted."""
    for stmt in create:
        conn.execute(stmt)
    sel = ", ".join(f if f in columns else "NULL" for f in PACKED_FIELDS)
    after: tuple[Any, ...] = ()
    total = 0
    while True:
        where = " WHERE (component, t) > (?, ?)" if after else ""
        rows = conn.execute(f"SELECT component, ingest, {sel} FROM history{where} ORDER BY "
                            f"component, t LIMIT {CONVERT_ROWS}", after).fetchall()
        if not rows:
            break
        comp = np.array([r[0] for r in rows], dtype=object)
        ingest = np.array([r[1] for r in rows], dtype=np.int64)
        rec = np.array([r[2:] for r in rows], dtype=np.float64)  # None -> NaN
        new = np.flatnonzero((comp[1:] != comp[:-1]) | (ingest[1:] != ingest[:-1])) + 1
        seg = np.concatenate([[0], new, [len(rows)]])
        write_chunks(conn, chunk_rows(comp[seg[:-1]], seg, rec, ingest[seg[:-1]]),
                     "history_packed")
        total += len(rows)
        after = (rows[-1][0], rows[-1][2])
    conn.execute("DROP TABLE history")
    conn.execute("ALTER TABLE history_packed RENAME TO history")
    return total


__all__ = ["COLUMNS", "CONVERT_ROWS", "HEADER", "MAX_CHUNK", "PACKED_FIELDS", "WIDTH",
           "LayoutError", "chunk_rows", "convert_row_history", "count", "decode", "field",
           "is_row_history", "read_all", "read_components", "read_last", "read_range",
           "records", "rewrite", "write_chunks"]
