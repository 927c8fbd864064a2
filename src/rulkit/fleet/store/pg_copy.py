"""PostgreSQL's binary ``COPY`` data of a table of rows made from arrays, built by numpy
(docs/systems/embedded-rul.md §4: the component rows of a batch, written by the PostgreSQL
store through its staging table).

:func:`binary_rows` gives the bytes psycopg's own ``write_row`` sends for the same rows (the
format's header, one tuple per row: its field count, then each field's length and its
bytes in network order, ``-1`` and no bytes for NULL; the trailer), from one text key per
row and a float64 array of the other columns, without a Python object per value: every
column is one array operation, and the rows are cut out of one byte matrix at once.
:func:`binary_tuples` does the same for rows of Python values with variable-length
columns (text, bytea) of any length: the fixed-size fields between them made by numpy,
each row joined from its pieces.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import chain
from typing import Any

import numpy as np

HEADER = b"PGCOPY\n\xff\r\n\x00" + bytes(8)
"""The binary format's signature, its flags (none) and its header extension's length (0)."""
TRAILER = b"\xff\xff"
"""The field count -1 that ends the data."""
_FIXED = {"float8": ">f8", "int8": ">i8", "int2": ">i2", "bool": "u1"}
"""The network-order layout of each fixed-size type a column may have."""


def binary_rows(keys: Sequence[str], values: np.ndarray, columns: Sequence[str],
                types: Sequence[str], nullable: Sequence[bool], key_last: bool = False
                ) -> bytes:
    """The rows ``[key, *row]`` (``[*row, key]`` with ``key_last``) of ``keys`` (text) and
    ``values`` (one float64 row per key, a column per name of ``columns``, of the type of
    ``types``: ``float8``, ``int8``, ``int2`` or ``bool``) as binary ``COPY`` data, header
    and trailer included. A NaN is NULL in a column that is ``nullable``; in another it is
    NaN in a ``float8`` column and refused (``ValueError``) in an integer or boolean one.
    Integers are the values truncated toward zero (refused out of their type's range),
    booleans whether they are non-zero: the values
    :func:`~rulkit.fleet.store.tracker_rows.component_rows` gives the same columns."""
    b, k = values.shape
    if not (len(keys) == b and len(columns) == len(types) == len(nullable) == k):
        raise ValueError(f"{len(keys)} keys, {len(columns)} columns, {len(types)} types "
                         f"and {len(nullable)} null flags for {b} rows of {k} values")
    null = np.isnan(values) & np.asarray(nullable, bool)
    sizes = np.array([np.dtype(_FIXED[t]).itemsize for t in types], np.int64)
    starts = np.concatenate([[0], np.cumsum(4 + sizes)[:-1]])  # each field's offset
    fields = np.empty((b, int((4 + sizes).sum())), np.uint8)
    keep = np.ones(fields.shape, bool)
    lengths = np.where(null, -1, sizes).astype(">i4")
    fields[:, starts[:, None] + np.arange(4)] = lengths.view(np.uint8).reshape(b, k, 4)
    for typ in dict.fromkeys(types):  # the columns of each type in one operation
        idx = [j for j, t in enumerate(types) if t == typ]
        vals = np.ascontiguousarray(_typed(values[:, idx], [columns[j] for j in idx], typ,
                                           [bool(nullable[j]) for j in idx]))
        pos = starts[idx][:, None] + 4 + np.arange(vals.dtype.itemsize)
        fields[:, pos] = vals.view(np.uint8).reshape(b, len(idx), -1)
        keep[:, pos] = ~null[:, idx][:, :, None]
    count = np.empty((b, 2), np.uint8)
    count[:] = np.frombuffer(np.array(k + 1, ">i2").tobytes(), np.uint8)
    parts = [(count, np.ones((b, 2), bool)), (fields, keep)]
    parts.insert(len(parts) if key_last else 1, _text(keys))
    data = np.hstack([p[0] for p in parts])
    return HEADER + data[np.hstack([p[1] for p in parts])].tobytes() + TRAILER


def _typed(v: np.ndarray, names: list[str], typ: str, nullable: list[bool]) -> np.ndarray:
    """Columns ``v`` (float64, a column per name of ``names``) as values of ``typ`` in
    network order (a NULL's value is there, and not sent)."""
    if typ == "float8":
        return v.astype(">f8")
    bad = np.isnan(v).any(axis=0) & ~np.asarray(nullable, bool)
    if bad.any():
        raise ValueError(f"column {names[int(np.argmax(bad))]}: NaN where an integer is "
                         "required")
    if typ == "bool":
        return (np.nan_to_num(v) != 0).astype("u1")
    ints = np.nan_to_num(v).astype(np.int64)
    info = np.iinfo(_FIXED[typ])
    if ints.size and (ints.min() < info.min or ints.max() > info.max):
        raise ValueError(f"column {names[0] if len(names) == 1 else names}: a value out "
                         f"of the range of {typ}")
    return ints.astype(_FIXED[typ])


def _column(v: np.ndarray, typ: str) -> np.ndarray:
    """One column without NULL (float64, or int64 for the integer types) as fields: a
    byte matrix of each row's length, then its value."""
    vals = _typed(v[:, None].astype(np.float64) if typ == "bool" else v[:, None], [""], typ,
                  [False])
    size = vals.dtype.itemsize
    length = np.full(v.size, size, ">i4")
    return np.hstack([length.view(np.uint8).reshape(-1, 4),
                      vals.view(np.uint8).reshape(-1, size)])


def _text(keys: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """The text fields of ``keys`` (UTF-8): their lengths, then their bytes, padded to the
    longest in the matrix and not sent."""
    enc = [s.encode("utf-8") for s in keys]
    lengths = np.fromiter(map(len, enc), np.int64, len(enc))
    width = int(lengths.max(initial=0))
    raw = np.array(enc, dtype=f"S{max(width, 1)}").view(np.uint8).reshape(len(enc), -1)
    mat = np.hstack([lengths.astype(">i4").view(np.uint8).reshape(-1, 4), raw[:, :width]])
    keep = np.ones(mat.shape, bool)
    keep[:, 4:] = np.arange(width) < lengths[:, None]
    return mat, keep


def binary_tuples(rows: Sequence[Sequence[Any]], types: Sequence[str]) -> bytes:
    """``rows`` (tuples of Python values, no NULL) of columns of ``types`` (``text``,
    ``bytea`` or a fixed-size type of :func:`binary_rows`: ``float8`` from floats, ``int8``
    and ``int2`` from ints, exactly) as binary ``COPY`` data, header and trailer included:
    the bytes psycopg's ``write_row`` sends for them."""
    cols = list(zip(*rows, strict=True)) if rows else [() for _ in types]
    b = len(rows)
    count = np.empty((b, 2), np.uint8)
    count[:] = np.frombuffer(np.array(len(types), ">i2").tobytes(), np.uint8)
    pieces: list[list[bytes] | tuple[bytes, ...]] = []  # per column group, one per row
    run = [count]  # fixed-size bytes since the last variable-length value
    for col, typ in zip(cols, types, strict=True):
        if typ in _FIXED:
            vals = np.asarray(col, np.float64 if typ == "float8" else np.int64)
            run.append(_column(vals, typ))
            continue
        data = tuple(v.encode("utf-8") if typ == "text" else bytes(v) for v in col)
        run.append(np.fromiter(map(len, data), ">i4", b).view(np.uint8).reshape(b, 4))
        pieces += [_split(np.hstack(run)), data]
        run = []
    if run:
        pieces.append(_split(np.hstack(run)))
    return HEADER + b"".join(chain.from_iterable(zip(*pieces, strict=True))) + TRAILER


def _split(mat: np.ndarray) -> list[bytes]:
    """The bytes of each row of the byte matrix ``mat``."""
    buf, w = mat.tobytes(), mat.shape[1]
    return [buf[i:i + w] for i in range(0, len(buf), w)]


__all__ = ["HEADER", "TRAILER", "binary_rows", "binary_tuples"]
