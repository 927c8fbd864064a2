"""``rulkit status`` at fleet scale: read the ``components`` table with :mod:`sqlite3` and print
it as a table, CSV or JSON without pandas or pyarrow.

docs/systems/embedded-rul.md §4 (the component state file). The command used to read through
:meth:`rulkit.fleet.store.sqlite.ComponentStore.status` (pandas) and print with pyarrow's CSV writer
and pandas' JSON writer; importing those alone took ~0.4 s of a one-second budget for 10^5
components. This module gives the same bytes (tested against that implementation,
tests/fleet/store/test_status_view.py):

* **Same rows, same order.** Worst first: alert level, then filtered HI, descending, then the
  component id (code-point order). Only a table rulkit can have written takes this path: every
  id text, every number column of its SQL type, every level 0, 1 or 2
  (:func:`read_status` returns ``None`` otherwise, and the caller falls back to the pandas
  path, which names the bad row or coerces as before).
* **Same text.** Floats in CSV as Arrow writes them (shortest round-trip digits, positional
  for decimal exponents -6 to 9, ``1e+10``/``1e-7`` otherwise, no ``.0``; :func:`arrow_float`),
  in JSON as pandas' ujson writes them with ``double_precision=15`` (15 decimals by its own
  rounding, trailing zeros cut, ``%.15g`` beyond 1e16 and below 1e-15, non-finite as
  ``null``; :func:`_ujson_floats`), strings quoted as Arrow and ujson quote them.
* **Read-only.** The database is opened as :class:`~rulkit.fleet.store.sqlite.ComponentStore`
  opens it with ``readonly=True``
  (:func:`~rulkit.fleet.store.database_file.read_verified`: through SQLite, ``query_only``)
  and read in one read transaction.
"""

from __future__ import annotations

import json
import sqlite3
from operator import itemgetter
from pathlib import Path
from typing import Any

import numpy as np

from rulkit.fleet.store.database_file import (
    _config_from_meta,
    _degradation_from_meta,
    _read_meta,
    read_verified,
    store_error,
)
from rulkit.fleet.tracking.tracker_chain import LEVEL_NAMES

STATUS_COLUMNS = ("component", "level", "hi", "fhi", "rul", "rul_low", "rul_high", "valid",
                  "dhi", "drul", "d2rul", "n", "t")
"""The columns of ``rulkit status --format csv|json``, in order (``rul`` is the filtered
RUL, the table's ``frul``)."""
_SQL_COLUMNS = tuple("frul" if c == "rul" else c for c in STATUS_COLUMNS)
FLOAT_COLUMNS = ("hi", "fhi", "rul", "rul_low", "rul_high", "dhi", "drul", "d2rul", "t")
INT_COLUMNS = ("level", "valid", "n")


def read_status(path: str | Path, timeout: float = 30.0) -> tuple[int, dict[str, Any]] | None:
    """``(number of components, columns)`` of the database at ``path``, worst first:
    ``component`` a list of str, the others numpy arrays (float64; int64 for ``level``,
    ``valid`` and ``n``), keyed by :data:`STATUS_COLUMNS`; ``None`` when a row is not as
    rulkit writes it (a text or NULL among numbers, an
    unknown level): the caller then reads through
    :meth:`~rulkit.fleet.store.sqlite.ComponentStore.status`, which names the row.

    Raises ``FileNotFoundError`` (no database) and :class:`StoreError` as
    ``ComponentStore(path, readonly=True)`` does.
    """
    path = Path(path)

    def read(conn: sqlite3.Connection) -> list[tuple]:
        meta = _read_meta(conn)
        _config_from_meta(path, meta)  # unreadable settings: the same error as the store's
        _degradation_from_meta(path, meta)
        try:
            conn.execute("PRAGMA mmap_size = 1073741824")  # reads pages in place, no copies
            conn.execute("BEGIN DEFERRED")
            rows = conn.execute(
                f"SELECT {', '.join(_SQL_COLUMNS)} FROM components").fetchall()
            conn.execute("COMMIT")
        except sqlite3.Error as err:
            raise store_error(path, err, timeout) from err
        return rows

    rows = read_verified(path, timeout, read)
    n = len(rows)
    if n == 0:
        return 0, {c: [] if c == "component" else np.zeros(
            0, dtype=np.float64 if c in FLOAT_COLUMNS else np.int64) for c in STATUS_COLUMNS}
    # one object per value already exists; a column-major copy of the references is the
    # cheapest way to columns (zip(*rows) builds 13 tuples: ~2x slower)
    by_col = np.array(rows, dtype=object).T.copy()
    del rows
    lists = dict(zip(STATUS_COLUMNS, (c.tolist() for c in by_col), strict=True))
    if not _canonical(lists):
        return None
    arrays = {c: by_col[j].astype(np.float64 if c in FLOAT_COLUMNS else np.int64)
              for j, c in enumerate(STATUS_COLUMNS) if j > 0}
    del by_col
    # worst first: level, then fHI, descending; ties by id (stable as pandas' sort_values)
    comp = lists["component"]
    rank = np.empty(n, dtype=np.int64)
    rank[sorted(range(n), key=comp.__getitem__)] = np.arange(n)
    order = np.lexsort((rank, -arrays["fhi"], -arrays["level"]))
    out: dict[str, Any] = {"component": list(itemgetter(*order.tolist())(comp)) if n > 1
                           else comp}
    out.update({c: a[order] for c, a in arrays.items()})
    return n, out


def _canonical(cols: dict[str, list]) -> bool:
    """Every value of the type rulkit writes (what the pandas path accepts unchanged)."""
    if set(map(type, cols["component"])) != {str}:
        return False
    for c in FLOAT_COLUMNS:
        if set(map(type, cols[c])) != {float}:
            return False
    for c in INT_COLUMNS:
        if set(map(type, cols[c])) != {int}:
            return False
    return set(cols["level"]) <= set(LEVEL_NAMES)


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
    import pyarrow.compute as pc

    names = _strs([LEVEL_NAMES[k] for k in range(len(LEVEL_NAMES))])
    return pc.take(names, _num(level.astype(np.int64), _pa_type("int64")))


def _pa_type(name: str) -> Any:
    import pyarrow as pa

    return getattr(pa, name)()


# --------------------------------------------------------------------------- CSV
def printable_id(component: str) -> str:
    """A component id as the CSV prints it: unchanged when printable (every id rulkit
    ingests is), else through :func:`rulkit.tables.safe_text` (a hand-made database's ESC
    or newline must not reach a terminal)."""
    if component.isprintable():
        return component
    from rulkit.tables import safe_text

    return safe_text(component)


def format_csv(cols: dict[str, Any]) -> bytes:
    """The CSV bytes of ``rulkit status --format csv``: pyarrow's CSV writer with
    ``quoting_style="needed"`` (strings quoted, shortest round-trip floats, booleans
    ``true``/``false``), as before, on arrays built without pandas."""
    import io

    import pyarrow as pa
    import pyarrow.csv as pacsv

    arrays = [_strs([printable_id(c) for c in cols["component"]]), _levels(cols["level"])]
    for c in STATUS_COLUMNS[2:]:
        if c == "valid":
            arrays.append(_bools(cols[c] != 0))
        elif c == "n":
            arrays.append(_num(cols[c].astype(np.int64), pa.int64()))
        else:
            arrays.append(_num(cols[c].astype(np.float64), pa.float64()))
    buf = io.BytesIO()
    pacsv.write_csv(pa.Table.from_arrays(arrays, names=list(STATUS_COLUMNS)), buf,
                    pacsv.WriteOptions(quoting_style="needed"))
    return buf.getvalue()


# --------------------------------------------------------------------------- JSON (ujson's text)
def _json_str(s: str) -> str:
    """``s`` as pandas' JSON writer quotes it: ASCII only, ``/`` as ``\\/``, DEL raw."""
    if "\x7f" in s:
        return ('"' + "\x7f".join(json.dumps(p)[1:-1] for p in s.split("\x7f"))
                .replace("/", "\\/") + '"')
    return json.dumps(s).replace("/", "\\/")


def _ujson_floats(a: np.ndarray) -> Any:
    """Each value as pandas' ``to_json(double_precision=15)`` writes it (its vendored
    ultrajson), as a ``large_string`` array: |x| in [1e-15, 1e16 - 1] as the integer part,
    ``.`` and 15 decimals rounded its way (``(x - whole) * 1e15``, a tie rounded up when the
    truncated decimals are odd or zero) with trailing zeros cut (``.0`` kept); otherwise
    ``%.15g``; NaN and infinities ``null``; -0.0 as ``0.0``."""
    import pyarrow as pa
    import pyarrow.compute as pc

    a = np.asarray(a, dtype=np.float64)
    n = len(a)
    v = np.abs(a)
    finite = np.isfinite(v)
    plain = finite & (v <= 1e16 - 1) & ~((v != 0.0) & (v < 1e-15))
    v = np.where(plain, v, 0.0)
    whole = v.astype(np.uint64)
    tmp = (v - whole.astype(np.float64)) * 1e15
    frac = tmp.astype(np.uint64)
    diff = tmp - frac.astype(np.float64)
    frac += ((diff > 0.5) | ((diff == 0.5) & ((frac == 0) | (frac & 1 == 1)))).astype(np.uint64)
    roll = frac >= 10**15
    frac[roll] = 0
    whole[roll] += 1
    s = pa.large_string()
    digits = pc.utf8_rtrim(pc.utf8_lpad(pc.cast(_num(frac, pa.uint64()), s), 15, "0"), "0")
    neg = (a < 0) & plain
    sign_off = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(neg, out=sign_off[1:])
    sign = pa.Array.from_buffers(s, n, [None, pa.py_buffer(sign_off),
                                        pa.py_buffer(b"-" * int(sign_off[-1]))])
    out = pc.binary_join_element_wise(
        sign, pc.cast(_num(whole, pa.uint64()), s), _const(".", n),
        pc.utf8_rpad(digits, 1, "0"), _const("", n))  # no decimals: ".0"
    if not plain.all():
        idx = np.flatnonzero(~plain).tolist()
        out = pc.replace_with_mask(out, _bools(~plain), _strs(
            [format(a[i], ".15g") if finite[i] else "null" for i in idx]))
    return out


def format_json(cols: dict[str, Any]) -> list[bytes]:
    """The JSON text of ``rulkit status --format json`` (what pandas'
    ``to_json(orient="records", double_precision=15)`` wrote), without the final newline, as
    byte chunks to write one after the other (no copy of the whole text to join them)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    comps = cols["component"]
    n = len(comps)
    if n == 0:
        return [b"[]"]
    text = "".join(comps)
    if text.isascii() and text.isprintable() and not any(c in text for c in '"\\/'):
        parts: list[Any] = ['{"component":"', _strs(comps), '","level":"']
    else:
        parts = ['{"component":', _strs([_json_str(c) for c in comps]), ',"level":"']
    parts += [_levels(cols["level"]), '"']
    for c in STATUS_COLUMNS[2:]:
        parts.append(f',"{c}":')
        if c == "valid":
            parts.append(pc.if_else(_bools(cols[c] != 0), _const("true", n), _const("false", n)))
        elif c == "n":
            parts.append(pc.cast(_num(cols[c].astype(np.int64), pa.int64()), pa.large_string()))
        else:
            parts.append(_ujson_floats(cols[c]))
    parts.append("},")
    merged: list[Any] = []
    for p in parts:  # adjacent literals as one constant column
        if isinstance(p, str) and merged and isinstance(merged[-1], str):
            merged[-1] += p
        else:
            merged.append(p)
    rows = pc.binary_join_element_wise(
        *[_const(p, n) if isinstance(p, str) else p for p in merged], _const("", n))
    off = np.frombuffer(rows.buffers()[1], dtype=np.int64)[rows.offset:rows.offset + n + 1]
    body = memoryview(rows.buffers()[2])[int(off[0]):int(off[-1]) - 1]  # without the last ","
    return [b"[", bytes(body), b"]"]
