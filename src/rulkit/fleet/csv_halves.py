"""A large plain CSV file parsed in two halves at once, the second on a thread of its own, for
:func:`rulkit.fleet.rows.read_csv_table` (docs/file-formats.md; docs/service-load.md, "Track's
wall time").

pyarrow's streaming reader parses on the thread that asks for the blocks. The file is cut
after the first newline past its middle; each half is streamed by its own reader (pyarrow
releases the interpreter's lock while it parses), the second given the first's column names
and types, and their record batches are joined in file order: the same rows, cells and
dictionary order as one reader gives, in about half the time on two cores. The second half
is read by pyarrow's own file (no Python call per block on that thread, no Python buffer
kept in its heap: read by Python, the halves held some 30 MB more).

A newline ends a row only where no value is quoted, so the halves are given back only when
no byte of the file is a quote character and neither half had a row of another field count
than the header, raised an error or was typed otherwise than the first; else :func:`read`
returns ``None`` and the caller reads the file in one pass (whose refusals and messages are
the ones that count).
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

MIN_BYTES = 16 << 20
"""Files smaller than this are read in one pass (a thread is not worth its start)."""

_SCAN_BYTES = 1 << 20
"""Bytes read at a time while the second half is searched for a quote character."""


class _Range:
    """Bytes ``0`` to ``end`` of the file at ``path``, read as pyarrow asks for them;
    :attr:`quoted` whether any of them was a quote character."""

    def __init__(self, path: Path, end: int) -> None:
        self._file = open(path, "rb", buffering=0)  # closed by close()
        self._left = end
        self.quoted = False
        self.closed = False

    def read(self, n: int = -1) -> bytes:
        n = self._left if n is None or n < 0 else min(n, self._left)
        data = self._file.read(n) or b""
        self._left -= len(data)
        self.quoted = self.quoted or b'"' in data
        return data

    def readable(self) -> bool:
        return True

    def close(self) -> None:
        self._file.close()
        self.closed = True


def _cut(path: Path) -> tuple[int, int] | None:
    """Where the second half starts (after the first newline past the middle) and the
    file's size; ``None`` for a file too small, or without a newline past its first line
    and within :data:`_SCAN_BYTES` of its middle."""
    size = path.stat().st_size
    if size < MIN_BYTES:
        return None
    with open(path, "rb") as f:  # each line read bounded: a file may hold no newline
        first = f.readline(size // 2 + 1)
        f.seek(size // 2)
        rest = f.readline(_SCAN_BYTES)
    cut = size // 2 + len(rest)
    if not first.endswith(b"\n") or not first.strip() or len(first) > size // 2 or (
            not rest.endswith(b"\n") or cut >= size):
        return None
    return cut, size


def _quoted(path: Path, start: int) -> bool:
    """Whether the file at ``path`` holds a quote character from byte ``start`` on."""
    buf = bytearray(_SCAN_BYTES)
    with open(path, "rb", buffering=0) as f:
        f.seek(start)
        while n := f.readinto(buf):
            if buf.find(b'"', 0, n) >= 0:
                return True
    return False


def read(path: Path, convert: Any, block_size: int) -> list[Any] | None:
    """The record batches of the plain CSV file at ``path`` (header first), parsed in two
    halves on two threads with ``convert`` (pyarrow's ``ConvertOptions``) and the default
    parse options, streamed in blocks of ``block_size`` bytes; ``None`` where the halves
    cannot be trusted to give what one reader gives (module docstring)."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    where = _cut(path)
    if where is None:
        return None
    cut, _ = where
    bad: list[Any] = []
    failed: list[BaseException] = []
    second: list[Any] = []

    def invalid(row: Any) -> str:
        bad.append(row)
        return "skip"

    def reader(source: Any, schema: Any = None) -> Any:
        typed = convert if schema is None else pacsv.ConvertOptions(
            column_types=dict(zip(schema.names, schema.types, strict=True)),
            null_values=convert.null_values, strings_can_be_null=convert.strings_can_be_null,
            quoted_strings_can_be_null=convert.quoted_strings_can_be_null)
        return pacsv.open_csv(source, convert_options=typed,
                              read_options=pacsv.ReadOptions(
                                  block_size=block_size, use_threads=False,
                                  column_names=None if schema is None else schema.names),
                              parse_options=pacsv.ParseOptions(invalid_row_handler=invalid))

    def parse_second(schema: Any) -> None:
        try:
            with pa.OSFile(str(path)) as f:
                f.seek(cut)
                rd = reader(f, schema)
                second.extend(rd)
            if not rd.schema.equals(schema):
                failed.append(ValueError("the second half was typed otherwise"))
        except BaseException as err:  # the one pass reports it
            failed.append(err)

    head = _Range(path, cut)
    try:
        try:
            first_reader = reader(pa.PythonFile(head, mode="r"))
        except (pa.ArrowInvalid, pa.ArrowTypeError, OSError, UnicodeDecodeError):
            return None
        worker = threading.Thread(target=parse_second, args=(first_reader.schema,),
                                  name="rulkit-csv")
        worker.start()
        quoted = True
        try:
            first = list(first_reader)
            quoted = _quoted(path, cut)
        except (pa.ArrowInvalid, pa.ArrowTypeError, OSError, UnicodeDecodeError) as err:
            failed.append(err)
        finally:
            worker.join()
    finally:
        head.close()
    if failed or bad or head.quoted or quoted:
        return None
    return [*first, *second]
