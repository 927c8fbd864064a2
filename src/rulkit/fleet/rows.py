"""Rows of fleet tables, read and checked one way everywhere: component ids, numeric columns,
CSV rows.

``rulkit track``, the service's uploads (:mod:`rulkit.fleet.store.acquisitions`) and ``rulkit
fit`` / ``rulkit evaluate`` (:mod:`rulkit.fleet.learned.histories`) take their rows through
these functions, so a row is stored exactly as written or refused, with the same rules in
every command (docs/file-formats.md):

* **Component ids** (:func:`check_component_ids`): 1 to :data:`COMPONENT_ID_MAX_LEN` printable
  characters after stripping surrounding blanks; ``NA``, ``None``, ``null`` are ids like any
  other text, only an empty cell is missing.
* **Numbers** (:func:`numeric_values`): a numeric column holds numbers of a numeric type.
  A boolean (``True`` in a CSV, a Parquet boolean column), text (``'0.5'`` stored as a string
  in Parquet, a typo in a CSV) or a date is refused, naming the column, the row and the value;
  so are NaN and infinities.
* **CSV rows** (:func:`read_csv_rows`): every row has as many fields as the header. A row
  with one extra field was read shifted one column by pandas (``c0,0,0.1,9`` became component
  ``0``, time 0.1, HI 9); here it is refused with its line.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    import pandas as pd

from rulkit.tables import cell_repr, safe_text

COMPONENT_ID_MAX_LEN = 128
"""Longest accepted component id, in characters (ids are names, not payloads)."""

ErrorType = type[Exception]
CSV_BLOCK_BYTES = 1 << 22
"""Bytes of CSV text parsed at a time (the text is never held whole beside the table)."""


def _row_1_based(i: int) -> str:
    return f"row {i + 1}"


@dataclass(frozen=True)
class CodedText:
    """A text column as dictionary codes, as a CSV reader gives it: per row the index of its
    text in ``values`` (distinct texts), -1 for an empty cell. What :func:`read_csv_columns`
    gives for the ``text_columns``, read without one Python string per row."""

    codes: NDArray[np.int32]
    values: list[Any]

    def __len__(self) -> int:
        return int(self.codes.size)


def check_component_ids(comp: pd.Series, error: ErrorType = ValueError) -> pd.Series:
    """Component ids as a categorical of stripped ``str``, or ``error`` at the first bad row
    (:func:`component_codes`: the rules and the refusals)."""
    import pandas as pd

    codes, names = component_codes(comp, error)
    return pd.Series(pd.Categorical.from_codes(codes, categories=pd.Index(names, dtype=object)),
                     index=comp.index)


def component_codes(comp: Any, error: ErrorType = ValueError
                    ) -> tuple[NDArray[np.integer], list[str]]:
    """Component ids as (per row, the index of its id in ``names``; ``names``: the distinct
    stripped ``str`` ids in order of first appearance), or ``error`` at the first bad row.

    Accepted: 1 to :data:`COMPONENT_ID_MAX_LEN` characters after stripping surrounding blanks,
    every one printable (:meth:`str.isprintable`). Refused, naming the 1-based row: a missing
    or empty id, a non-text id (a number in a Parquet column is taken as its text, but bytes
    are refused), text that is not valid Unicode (a lone surrogate), a control or format
    character (ESC, newline, tab, bidi override), and an id longer than the limit. The check
    runs once per distinct id. ``comp``: a pandas Series, a numpy object array (a batch's
    JSON column: one dict lookup per row instead of pandas' factorize) or :class:`CodedText`
    (a CSV's column: the codes renumbered, no string per row).
    """
    values = comp if isinstance(comp, np.ndarray) and comp.dtype == object else None
    uniques: Any
    if isinstance(comp, CodedText):
        codes, uniques = _appearance_codes(comp, error)
    elif values is not None and set(map(type, values.tolist())) == {str}:
        first: dict[str, int] = {}
        codes = np.fromiter((first.setdefault(v, len(first)) for v in values.tolist()),
                            dtype=np.intp, count=values.size)
        uniques = list(first)
    else:
        import pandas as pd

        series = comp if isinstance(comp, pd.Series) else pd.Series(comp, dtype=object)
        missing = series.isna().to_numpy()
        if missing.any():
            i = int(np.flatnonzero(missing)[0])
            raise error(f"row {i + 1}: empty component name")
        codes, uniques = pd.factorize(series, sort=False)
    clean = _plain_ids(uniques)
    if clean is not None:
        return (codes if isinstance(comp, CodedText)  # its int32 codes, not a copy
                else np.asarray(codes, dtype=np.intp)), clean
    clean = []
    for k, v in enumerate(uniques):
        text, reason = _clean_id(v)
        if reason:
            i = int(np.flatnonzero(codes == k)[0])
            raise error(f"row {i + 1}: {reason}")
        clean.append(text)
    # ids equal after stripping share one name (the first appearance's place)
    merged: dict[str, int] = {}
    ucodes = np.fromiter((merged.setdefault(c, len(merged)) for c in clean), dtype=np.intp,
                         count=len(clean))
    return ucodes[codes], list(merged)


def _appearance_codes(comp: CodedText, error: ErrorType
                      ) -> tuple[NDArray[np.integer], list[Any]]:
    """``comp``'s codes renumbered in order of first appearance, with its texts in that order
    (what pandas' factorize gives), or ``error`` at the first empty cell. A CSV reader's
    dictionary is built in order of appearance: then the codes are kept as they are (checked
    with one running maximum: each code is at most one above every code before it)."""
    codes = comp.codes
    if codes.size and int(codes.min()) < 0:
        raise error(f"row {int(np.flatnonzero(codes < 0)[0]) + 1}: empty component name")
    top = np.maximum.accumulate(codes)
    if codes.size == 0 or (codes[0] == 0 and not (np.diff(top) > 1).any()
                           and int(top[-1]) + 1 == len(comp.values)):
        return codes, list(comp.values)
    used, first, inverse = np.unique(codes, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty(order.size, dtype=np.intp)
    rank[order] = np.arange(order.size)
    return rank[inverse.reshape(-1)], [comp.values[k] for k in used[order]]


def _plain_ids(uniques: Any) -> list[str] | None:
    """The ids as they are when every one is accepted unchanged (text of 1 to 128 printable
    ASCII characters without surrounding blanks), checked with a few C-level string
    operations on all of them at once; ``None`` otherwise (then each is checked)."""
    values = list(uniques)
    if not values or not all(type(v) is str for v in values):
        return None
    text = "\x1f".join(values)  # a separator that is not printable
    if text.count("\x1f") != len(values) - 1:  # an id holds it: refused below
        return None
    if not (text.isascii() and text.replace("\x1f", "").isprintable()):
        return None
    if "\x1f " in text or " \x1f" in text or text[0] == " " or text[-1] == " ":
        return None
    lengths = np.fromiter(map(len, values), dtype=np.int64, count=len(values))
    if lengths.min() < 1 or lengths.max() > COMPONENT_ID_MAX_LEN:
        return None
    return values


def _clean_id(v: object) -> tuple[str, str]:
    """``(stripped id, "")`` or ``("", why it is refused)``."""
    if isinstance(v, bytes | bytearray):
        return "", "is binary data, not text"
    text = str(v).strip()
    if not text:
        return "", "empty component name"
    if len(text) > COMPONENT_ID_MAX_LEN:
        return "", (f"component id of {len(text)} characters, longer than the limit of "
                    f"{COMPONENT_ID_MAX_LEN}")
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return "", (f"component id '{safe_text(text.encode('utf-8', 'backslashreplace'), 60)}'"
                    " is not valid Unicode text (a lone surrogate)")
    if not text.isprintable():
        c = next(c for c in text if not c.isprintable())
        return "", (f"component id '{safe_text(text, 60)}' holds the non-printable character "
                    f"{safe_text(c)} (control and format characters are not allowed)")
    return text, ""


def numeric_values(
    col: pd.Series | NDArray[Any],
    name: str,
    *,
    error: ErrorType = ValueError,
    row_label: Callable[[int], str] = _row_1_based,
) -> NDArray[np.float64]:
    """``col`` as finite float64, or ``error`` naming the column, the row and the value.

    Accepted: integer and floating columns (numpy or pandas' nullable ones), and object
    columns whose every cell is an int or float, or a numpy array of integers or floats.
    Refused: booleans, text (also numbers written as text), dates, and NaN / infinities
    (module docstring). A float64 column that is all finite is returned without a copy
    (read-only use)."""
    label = f"column {name!r}, "
    if isinstance(col, np.ndarray) and col.dtype.kind in "iuf":  # a batch's JSON numbers
        return _finite(col.astype(np.float64, copy=False), label, error, row_label)
    import pandas as pd

    if not isinstance(col, pd.Series):
        col = pd.Series(col)
    dtype = col.dtype
    if pd.api.types.is_bool_dtype(dtype):
        raise error(f"{label}{row_label(0)}: {cell_repr(col.iloc[0])} is a boolean, not a "
                    "number (a numeric column holds numbers only)")
    if dtype == np.float64:
        a = col.to_numpy()
    elif isinstance(dtype, np.dtype) and dtype.kind in "iuf":
        a = col.to_numpy(dtype=np.float64)
    elif not isinstance(dtype, np.dtype) and dtype.kind in "iuf":  # nullable Int64, Float64
        a = col.to_numpy(dtype=np.float64, na_value=np.nan)
    elif isinstance(dtype, np.dtype) and dtype.kind == "O":
        a = _object_numbers(col, label, error, row_label)
    elif pd.api.types.is_string_dtype(dtype):
        _refuse_text(col.to_numpy(dtype=object), col.notna().to_numpy(), label, error,
                     row_label)
        raise AssertionError  # unreachable: text is refused
    else:
        raise error(f"{label}{row_label(0)}: {cell_repr(col.iloc[0])} is of type {dtype}, not "
                    "a number (a numeric column holds numbers only)")
    return _finite(a, label, error, row_label)


def _finite(a: NDArray[np.float64], label: str, error: ErrorType,
            row_label: Callable[[int], str]) -> NDArray[np.float64]:
    """``a``, or ``error`` at its first NaN or infinity."""
    nonfinite = ~np.isfinite(a)
    if nonfinite.any():
        i = int(np.flatnonzero(nonfinite)[0])
        what = "NaN (an empty or NaN cell)" if np.isnan(a[i]) else f"{a[i]}"
        raise error(f"{label}{row_label(i)}: {what} is not allowed: every value must be a "
                    f"finite number, no NaN/inf ({int(nonfinite.sum())} non-finite value(s) "
                    "in this column)")
    return a


def _object_numbers(col: pd.Series, label: str, error: ErrorType,
                    row_label: Callable[[int], str]) -> NDArray[np.float64]:
    """An object column of Python / numpy numbers (None = missing) as float64."""
    values = col.to_numpy()
    kinds = np.fromiter((isinstance(v, int | float | np.integer | np.floating)
                         and not isinstance(v, bool | np.bool_) for v in values),
                        dtype=bool, count=len(values))
    missing = col.isna().to_numpy()
    bad = ~kinds & ~missing
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        v = values[i]
        if isinstance(v, str):
            _refuse_text(values, bad, label, error, row_label)
        what = "a boolean" if isinstance(v, bool | np.bool_) else f"of type {type(v).__name__}"
        raise error(f"{label}{row_label(i)}: {cell_repr(v)} is {what}, not a number "
                    f"({int(bad.sum())} such value(s) in this column)")
    out = np.full(len(values), np.nan)
    out[~missing] = values[~missing].astype(np.float64)
    return out


def _refuse_text(values: NDArray[np.object_], text: NDArray[np.bool_], label: str,
                 error: ErrorType, row_label: Callable[[int], str]) -> None:
    """Raise ``error`` at the first text cell that is not a number (a typo in a CSV), or else
    at the first text cell (numbers stored as text)."""
    import pandas as pd

    idx = np.flatnonzero(text)
    num = pd.to_numeric(pd.Series(values[idx], dtype=object), errors="coerce").to_numpy()
    typo = np.flatnonzero(np.isnan(num.astype(np.float64)))
    if typo.size:
        i = int(idx[typo[0]])
        raise error(f"{label}{row_label(i)}: {cell_repr(values[i])} is not a number "
                    f"({typo.size} non-numeric value(s) in this column)")
    i = int(idx[0])
    raise error(f"{label}{row_label(i)}: {cell_repr(values[i])} is text, not a number (a "
                "numeric column holds numbers of a numeric type)")


def read_csv_rows(
    source: str | Path | bytes | memoryview,
    *,
    error: ErrorType = ValueError,
    name: str | None = None,
    text_columns: Sequence[str] = ("component",),
    max_rows: int | None = None,
) -> pd.DataFrame:
    """A CSV file (path, ``.gz`` and other compressions by ending) or CSV bytes as a frame
    (:func:`read_csv_table`: the reading and the refusals)."""
    return arrow_frame(read_csv_table(source, error=error, name=name,
                                      text_columns=text_columns, max_rows=max_rows))


def read_csv_columns(
    source: str | Path | bytes | memoryview,
    *,
    error: ErrorType = ValueError,
    name: str | None = None,
    text_columns: Sequence[str] = ("component",),
    max_rows: int | None = None,
) -> dict[str, Any] | pd.DataFrame:
    """A CSV file or CSV bytes (:func:`read_csv_table`) as numpy columns without pandas when
    every column is plain (:func:`plain_columns`), else as a frame (:func:`arrow_frame`:
    date-times, booleans, text in a numeric column, an all-empty column), so that what is
    refused, and how, is the frame's. Every other column is parsed as float64 first (what
    validation makes of a number: :func:`numeric_values`; no type inference over the rows);
    a column that is not all numbers (date-times, booleans, text) is read as
    :func:`read_csv_table` reads it otherwise. The columns are copied out of the table one
    at a time, each column's Arrow memory released once copied (the table and all its copies
    are never held at once)."""
    import pyarrow as pa

    table = read_csv_table(source, error=error, name=name, text_columns=text_columns,
                           max_rows=max_rows, float_columns=True)
    if not plain_columns(table):
        return arrow_frame(table)
    table = table.unify_dictionaries()
    cols: dict[str, Any] = {}
    for col in table.column_names:
        cols[col] = column_array(table.column(col))
        table = table.drop_columns([col])  # the last reference to the copied column
        pa.default_memory_pool().release_unused()  # its buffers (and the parse's) returned
    return cols


def read_csv_table(
    source: str | Path | bytes | memoryview,
    *,
    error: ErrorType = ValueError,
    name: str | None = None,
    text_columns: Sequence[str] = ("component",),
    max_rows: int | None = None,
    float_columns: bool = False,
) -> Any:
    """A CSV file (path, ``.gz`` and other compressions by ending) or CSV bytes as a pyarrow
    table.

    pyarrow's reader, with every row checked to have as many fields as the header (module
    docstring) and ``text_columns`` read verbatim as text (categorical: one string per
    distinct id); only an empty cell is missing, in every column (``NA`` in a numeric column
    is text, reported by :func:`numeric_values`). Refused, naming ``name`` (the path, or
    ``"CSV body"``): no header, a duplicated column name, a row with too few or too many
    fields (its line number and text), more than ``max_rows`` rows, unparseable bytes.
    ``float_columns``: the columns other than ``text_columns`` are read as float64 when every
    cell of each is a number (else read again with the types inferred)."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    where = name or str(source)
    header = _csv_header(source, error, where)
    if not header:
        raise error(f"{where}: empty file (no header, no rows)")
    seen: dict[str, int] = {}
    for j, c in enumerate(header):
        if c in seen:
            raise error(f"{where}: column {safe_text(c)!r} appears twice in the header "
                        f"(columns {seen[c] + 1} and {j + 1}); rename or drop one")
        seen[c] = j
    bad: list[Any] = []

    def invalid(row: Any) -> str:
        bad.append(row)
        return "skip"

    text = pa.dictionary(pa.int32(), pa.string())
    convert = pacsv.ConvertOptions(
        column_types={c: text for c in text_columns if c in seen},
        null_values=[""], strings_can_be_null=True, quoted_strings_can_be_null=True)
    parse = pacsv.ParseOptions(invalid_row_handler=invalid)
    if float_columns:
        typed = pacsv.ConvertOptions(
            column_types={**convert.column_types, **{
                c: pa.float64() for c in header if c not in text_columns}},
            null_values=[""], strings_can_be_null=True, quoted_strings_can_be_null=True)
        try:
            table = _read_blocks(source, typed, parse)
        except (pa.ArrowInvalid, pa.ArrowTypeError, OSError, UnicodeDecodeError):
            bad.clear()  # a cell that is not a number, or a problem reported below
        else:
            return _checked_table(table, source, error, where, bad, convert, max_rows)
    try:
        try:  # streamed in blocks: the text is not held whole beside the table
            table = _read_blocks(source, convert, parse)
        except pa.ArrowInvalid as err:
            if "conversion error" not in str(err):
                raise
            # a later block holds text in a column the first typed as numbers: read the
            # whole file, typed over all rows, so the cell is named by numeric_values
            bad.clear()
            table = pacsv.read_csv(_csv_input(source), convert_options=convert,
                                   parse_options=parse)
    except (pa.ArrowInvalid, pa.ArrowTypeError, OSError, UnicodeDecodeError) as err:
        raise error(f"{where}: cannot be read as CSV: {safe_text(err, 300)}") from None
    return _checked_table(table, source, error, where, bad, convert, max_rows)


def _read_blocks(source: str | Path | bytes | memoryview, convert: Any, parse: Any) -> Any:
    """The CSV as a pyarrow table, streamed in blocks of :data:`CSV_BLOCK_BYTES` (the text is
    not held whole beside the table), its dictionaries unified. A large plain file is parsed
    in two halves at once where that gives what one pass gives
    (:func:`rulkit.fleet.csv_halves.read`); else in one pass on this thread (pyarrow's own
    threads parsed no faster and took more CPU)."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    from rulkit.fleet import csv_halves

    if isinstance(source, str | Path) and not str(source).endswith(_COMPRESSED):
        halves = csv_halves.read(Path(source), convert, CSV_BLOCK_BYTES)
        if halves is not None:
            return pa.Table.from_batches(halves).unify_dictionaries()
    with _stream_input(source) as inp:
        reader = pacsv.open_csv(inp, convert_options=convert, parse_options=parse,
                                read_options=pacsv.ReadOptions(block_size=CSV_BLOCK_BYTES,
                                                               use_threads=False))
        batches = list(reader)
    return pa.Table.from_batches(batches, schema=reader.schema).unify_dictionaries()


def _checked_table(table: Any, source: str | Path | bytes | memoryview, error: ErrorType,
                   where: str, bad: list[Any], convert: Any, max_rows: int | None) -> Any:
    """``table``, or ``error`` at its first row of another field count than the header's
    (``bad``: the rows the reader skipped), above ``max_rows`` rows, or without rows."""
    if bad:
        _raise_bad_row(source, error, where, len(bad), convert)
    if max_rows is not None and table.num_rows > max_rows:
        raise error(f"{where}: {table.num_rows} rows, at most {max_rows} per batch")
    if table.num_rows == 0:
        raise error(f"{where}: no data rows (header only)")
    return table


def plain_columns(table: Any) -> bool:
    """Whether every column of a pyarrow table is of an integer or floating type or text
    dictionary-encoded with int32 codes (as :func:`read_csv_table` reads ``text_columns``),
    and no integer or text column has empty cells: what :func:`column_array` takes."""
    import pyarrow.types as pt

    return all(pt.is_floating(col.type) or (col.null_count == 0 and (
        pt.is_integer(col.type) or (pt.is_dictionary(col.type) and pt.is_string(
            col.type.value_type) and pt.is_int32(col.type.index_type))))
        for col in table.columns)


def column_array(col: Any) -> Any:
    """A plain pyarrow column (:func:`plain_columns`, its chunks' dictionaries unified) as a
    numpy array of its type (a copy; NaN for an empty cell of a floating column) or, for
    text, :class:`CodedText`."""
    import pyarrow.types as pt

    if pt.is_dictionary(col.type):
        values = col.chunks[0].dictionary.to_pylist() if col.num_chunks else []
        return CodedText(codes=_joined([c.indices for c in col.chunks], np.dtype(np.int32)),
                         values=values)
    return _joined(col.chunks, np.dtype(col.type.to_pandas_dtype()))


def _joined(chunks: list[Any], dtype: np.dtype) -> NDArray[Any]:
    """Primitive Arrow arrays joined into one numpy array of ``dtype`` (their type's) from
    their buffers, an empty cell NaN (pyarrow's ``to_numpy`` imports pandas when installed)."""
    out = np.empty(sum(len(c) for c in chunks), dtype=dtype)
    i = 0
    for c in chunks:
        n = len(c)
        if n == 0:  # an empty chunk may have no data buffer
            continue
        validity, data = c.buffers()[:2]
        out[i:i + n] = np.frombuffer(data, dtype=dtype, count=n, offset=c.offset * dtype.itemsize)
        if c.null_count:
            bits = np.unpackbits(np.frombuffer(validity, dtype=np.uint8), bitorder="little")
            out[i:i + n][~bits[c.offset:c.offset + n].astype(bool)] = np.nan
        i += n
    return out


def arrow_frame(table: Any) -> pd.DataFrame:
    """A pyarrow table as a frame, the table consumed: each column converted on its own and
    its Arrow buffers freed as it goes (``self_destruct``), float columns kept without a copy
    (``split_blocks``), and what Arrow's memory pool holds unused afterwards (the CSV reader's
    parse buffers) returned to the system."""
    import pyarrow as pa

    frame = table.to_pandas(self_destruct=True, split_blocks=True)
    del table
    pa.default_memory_pool().release_unused()
    return frame


def _csv_input(source: str | Path | bytes | memoryview) -> Any:
    import pyarrow as pa

    if isinstance(source, bytes | memoryview):
        return pa.BufferReader(pa.py_buffer(source))  # no copy of the bytes
    return str(source)


_COMPRESSED = (".gz", ".bz2", ".lz4", ".zst")
"""The endings by which pyarrow reads a path as compressed."""


def _stream_input(source: str | Path | bytes | memoryview) -> Any:
    """The streaming reader's input, as a context: a plain file opened by Python, read as the
    reader asks for blocks (given the path, pyarrow reads ahead of the parse: on a 71 MB file
    the read's peak was 40 to 45 MB higher, ``benchmarks/profile_track.py``); a compressed
    path or bytes as :func:`_csv_input` gives them."""
    from contextlib import nullcontext

    if isinstance(source, str | Path) and not str(source).endswith(_COMPRESSED):
        return open(source, "rb")  # the caller's with closes it
    return nullcontext(_csv_input(source))


def _csv_header(source: str | Path | bytes | memoryview, error: ErrorType, where: str) -> list[str]:
    """The names of the first line, verbatim (an empty list for an empty input)."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    try:
        with _stream_input(source) as inp:
            reader = pacsv.open_csv(
                inp, read_options=pacsv.ReadOptions(block_size=1 << 16, use_threads=False),
                parse_options=pacsv.ParseOptions(invalid_row_handler=lambda row: "skip"),
                convert_options=pacsv.ConvertOptions(column_types={}, null_values=[""]))
    except pa.ArrowInvalid as err:
        if "Empty CSV file" in str(err):
            return []
        raise error(f"{where}: cannot be read as CSV: {safe_text(err, 300)}") from None
    except (OSError, UnicodeDecodeError) as err:
        raise error(f"{where}: cannot be read as CSV: {safe_text(err, 300)}") from None
    return [str(c) for c in reader.schema.names]


def _raise_bad_row(source: str | Path | bytes | memoryview, error: ErrorType, where: str,
                   n_bad: int, convert: Any) -> None:
    """Read again on one thread (which numbers the lines) and raise ``error`` at the first row
    whose field count differs from the header's."""
    import pyarrow.csv as pacsv

    first: list[Any] = []

    def invalid(row: Any) -> str:
        if not first:
            first.append(row)
        return "skip"

    pacsv.read_csv(_csv_input(source), read_options=pacsv.ReadOptions(use_threads=False),
                   convert_options=convert,
                   parse_options=pacsv.ParseOptions(invalid_row_handler=invalid))
    row = first[0]
    line = f"line {row.number}" if row.number is not None else "a line"
    raise error(f"{where}: {line} (data row {row.number - 1 if row.number else '?'}) has "
                f"{row.actual_columns} fields, the header {row.expected_columns}: "
                f"{safe_text(row.text, 120)!r} ({n_bad} such row(s); nothing is read from a "
                "file whose rows do not match its header)")


def previous_per_component(codes: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Per row, ``t`` of the same component's previous row in file order (NaN for its first);
    ``codes`` the rows' component codes. One stable sort by component, no per-component
    work."""
    t = np.asarray(t, dtype=np.float64)
    prev = np.full_like(t, np.nan)
    if t.size < 2:
        return prev
    order = np.argsort(codes, kind="stable")
    c_sorted = np.asarray(codes)[order]
    prev_sorted = np.empty_like(t)
    prev_sorted[0] = np.nan
    prev_sorted[1:] = t[order[:-1]]
    prev_sorted[1:][c_sorted[1:] != c_sorted[:-1]] = np.nan
    prev[order] = prev_sorted
    return prev
