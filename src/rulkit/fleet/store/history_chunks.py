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

from dataclasses import dataclass
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


@dataclass(frozen=True)
class Chunks:
    """History chunks laid out as their blobs, end to end in one buffer: chunk ``i`` of
    ``n[i]`` acquisitions belongs to component ``owner[i]`` (an index into the caller's
    names); ``words[start[i]]`` is its header and its records follow (:func:`layout`)."""

    owner: np.ndarray
    n: np.ndarray
    words: np.ndarray
    start: np.ndarray

    def rows(self, names: Any, ingest: Any) -> list[tuple]:
        """The history rows ``(component, t_first, t_last, n, ingest, data)``: component
        ``names[owner]``, written by ingestion ``ingest[owner]`` (or one ``ingest`` for all);
        each blob a view of the buffer (SQLite and psycopg bind a memoryview as a blob)."""
        owner, n, start = self.owner, self.n, self.start
        first = start + 1 + _F["t"]
        t_first = self.words[first].tolist()
        t_last = self.words[first + (n - 1) * WIDTH].tolist()
        comp = np.asarray(names, dtype=object)[owner].tolist()
        ing = (np.asarray(ingest)[owner].tolist() if np.ndim(ingest)
               else [int(ingest)] * owner.size)
        return list(zip(comp, t_first, t_last, n.tolist(), ing, self.blobs(), strict=True))

    def blobs(self) -> list[memoryview]:
        """Each chunk's blob (its header and records), a view of the buffer."""
        raw = self.words.data.cast("B")
        return [raw[8 * s:8 * (s + 1 + WIDTH * m)]
                for s, m in zip(self.start.tolist(), self.n.tolist(), strict=True)]


def layout(seg: np.ndarray, max_chunk: int = MAX_CHUNK) -> Chunks:
    """The chunks of components whose records are ``seg[i]:seg[i + 1]`` (a component's run
    split into chunks of at most ``max_chunk``, each chunk's first record at a multiple of
    ``max_chunk`` of its component's), headers in place, the records' words not yet
    written."""
    seg = np.asarray(seg, dtype=np.int64)
    counts = np.diff(seg)
    pieces = -(-counts // max_chunk)
    owner = np.repeat(np.arange(counts.size), pieces)
    within = np.arange(owner.size) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    n = np.minimum(counts[owner] - within * max_chunk, max_chunk)
    per = 1 + WIDTH * n
    start = np.cumsum(per) - per  # each chunk's first word
    words = np.empty(int(per.sum()), dtype="<f8")
    words.view("<u8")[start] = _HEADER_WORD
    return Chunks(owner, n, words, start)


def chunk_rows(names: Any, seg: np.ndarray, rec: np.ndarray, ingest: Any,
               max_chunk: int = MAX_CHUNK) -> list[tuple]:
    """The history rows of records ``rec`` (time order within each component): component
    ``names[i]`` owns ``rec[seg[i]:seg[i + 1]]``, written by ingestion ``ingest[i]`` (or one
    ``ingest`` for all), split into chunks of at most ``max_chunk``."""
    seg = np.asarray(seg, dtype=np.int64)
    chunks = layout(seg, max_chunk)
    _fill(chunks, np.ascontiguousarray(rec[seg[0]:seg[-1]], dtype="<f8"))
    return chunks.rows(names, ingest)


def _fill(chunks: Chunks, rec: np.ndarray) -> None:
    """Write the records ``rec`` (every chunk's, end to end) beside the headers, in one
    operation (the records are copied once)."""
    body = np.ones(chunks.words.size, dtype=bool)
    body[chunks.start] = False
    chunks.words[body] = rec.reshape(-1)


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
    packed = layout(np.concatenate([[0], np.cumsum(n)]), int(n.max(initial=1)))  # a chunk each
    _fill(packed, np.ascontiguousarray(rec, dtype="<f8"))
    conn.executemany("UPDATE history SET data = ? WHERE component = ? AND t_first = ?",
                     [(blob, c[0], c[1]) for c, blob in
                      zip(chunks, packed.blobs(), strict=True)])


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
           "Chunks", "LayoutError", "chunk_rows", "convert_row_history", "count", "decode",
           "field", "is_row_history", "layout", "read_all", "read_components", "read_last",
           "read_range", "records", "rewrite", "write_chunks"]
