"""Shared pieces of the user-file readers: reading a CSV/Parquet table, coercing columns to
float64 with row-level messages, and suggesting the intended name of a misnamed column.

Used by :mod:`rulkit.systems.reaction_wheel.telemetry` (reaction-wheel telemetry),
:mod:`rulkit.systems.motor_damping.pullup`
(motor pull-up tests) and :mod:`rulkit.fleet.store.sqlite` (``rulkit track`` acquisitions).
Each reader passes its own exception class (``error=``, a ``ValueError`` subclass), so callers
keep catching the reader's error; the helpers only decide *what* is wrong and say it in one
consistent form (CONTRIBUTING.md, "Habits": bad input gets a specific error, which file, column,
row, and what was expected):

* file level, prefixed by the path: ``<path>: file not found (no such file or directory)``,
  ``<path>: is a directory, ...``, ``<path>: empty file (no header, no rows; expected a header
  with columns [...])``, ``<path>: no data rows (header only)``, ``<path>: unknown file type
  '.xlsx'; expected .csv, .parquet or .pq``, ``<path>: cannot be read as CSV: <parser error>``;
* cell level, prefixed by the source: ``column 'x', row 6: 'noon' is not a number (1
  non-numeric value(s) in this column)`` and ``column 'x', row 18: NaN (an empty or NaN cell)
  is not allowed: every value must be a finite number, no NaN/inf (2 non-finite value(s) in
  this column)``. How a row is named (0- or 1-based, with the CSV file line, with the
  component) is the reader's choice, passed as ``row_label``.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Hashable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "CSV_SUFFIXES",
    "PARQUET_SUFFIXES",
    "TableWriter",
    "cell_repr",
    "did_you_mean",
    "match_columns",
    "numeric_columns",
    "read_table",
    "read_table_chunks",
    "safe_text",
    "suggest_column",
    "table_format",
    "text_table",
    "time_seconds",
]

#: Default file name endings read as CSV and as Parquet (matched case-insensitively).
CSV_SUFFIXES: tuple[str, ...] = (".csv",)
PARQUET_SUFFIXES: tuple[str, ...] = (".parquet", ".pq")

ErrorType = type[Exception]
_COMPRESSION = (".gz", ".bz2", ".xz", ".zip", ".zst")  # shown with the ending before them


def _accepted(suffixes: Sequence[str]) -> str:
    """``.csv, .parquet or .pq`` from a list of endings."""
    s = list(suffixes)
    return s[0] if len(s) == 1 else f"{', '.join(s[:-1])} or {s[-1]}"


def table_format(
    path: str | Path,
    *,
    error: ErrorType = ValueError,
    csv_suffixes: Sequence[str] = CSV_SUFFIXES,
    parquet_suffixes: Sequence[str] = PARQUET_SUFFIXES,
) -> str:
    """``"csv"`` or ``"parquet"`` from the file name's ending (case-insensitive; multi-part
    endings such as ``.csv.gz`` are allowed); any other ending raises ``error`` naming the
    ending found and the accepted ones."""
    p = Path(path)
    name = p.name.lower()
    if name.endswith(tuple(s.lower() for s in parquet_suffixes)):
        return "parquet"
    if name.endswith(tuple(s.lower() for s in csv_suffixes)):
        return "csv"
    compressed = len(p.suffixes) > 1 and p.suffix.lower() in _COMPRESSION
    found = "".join(p.suffixes[-2:]) if compressed else p.suffix
    raise error(
        f"{p}: unknown file type {found.lower()!r}; expected "
        f"{_accepted([*csv_suffixes, *parquet_suffixes])}"
    )


def read_table(
    path: str | Path,
    *,
    error: ErrorType = ValueError,
    csv_suffixes: Sequence[str] = CSV_SUFFIXES,
    parquet_suffixes: Sequence[str] = PARQUET_SUFFIXES,
    expected_columns: Sequence[str] | None = None,
    csv_dtype: Mapping[str, Any] | None = None,
    allow_no_rows: bool = False,
    text_columns: Sequence[str] = (),
) -> Any:
    """Read a CSV or Parquet file into a ``pandas.DataFrame``; every problem raises ``error``.

    The format is chosen by the file name's ending (:func:`table_format`; ``csv_suffixes`` /
    ``parquet_suffixes``). Refused, each with the path first: a missing path, a directory, an
    empty file (0 bytes, or a CSV without even a header line; ``expected_columns`` is then
    named in the message), a header without data rows (unless ``allow_no_rows``), an unknown
    ending, and a file the CSV / Parquet parser rejects (its message is quoted).
    ``csv_dtype`` is passed to :func:`pandas.read_csv` as ``dtype`` (e.g. keep an identifier
    column as text). ``text_columns`` are read from a CSV verbatim: pandas' missing-value
    strings (``NA``, ``None``, ``null``, ``nan``, ...) stay text in them, as they do in a
    Parquet string column (only an empty cell is missing); the other columns keep pandas'
    missing-value strings. A duplicated column name is refused (pandas would rename the CSV
    copy ``x.1`` silently). The frame's ``attrs`` get ``"source"`` (the path as given) and
    ``"format"`` (``"csv"`` or ``"parquet"``) so a caller can, e.g., report CSV file lines.
    """
    import pandas as pd

    p, fmt, empty = _usable_path(path, error, csv_suffixes, parquet_suffixes, expected_columns)
    with _parser_errors(p, fmt, empty, error):
        if fmt == "csv":
            kw: dict[str, Any] = {}
            header_cols = _csv_header(p)
            _check_unique_columns(p, header_cols, error)
            if text_columns:
                from pandas._libs.parsers import STR_NA_VALUES

                kw = {"keep_default_na": False,
                      "na_values": {c: sorted(STR_NA_VALUES) for c in header_cols
                                    if c not in text_columns}}
                kw["na_values"].update({c: [""] for c in text_columns if c in header_cols})
            df = pd.read_csv(p, dtype=dict(csv_dtype) if csv_dtype else None, **kw)
        else:
            df = pd.read_parquet(p)
    _check_unique_columns(p, [str(c) for c in df.columns], error)
    if len(df) == 0 and not allow_no_rows:
        raise error(f"{p}: no data rows (header only)")
    df.attrs["source"] = str(path)
    df.attrs["format"] = fmt
    return df


def _usable_path(
    path: str | Path, error: ErrorType, csv_suffixes: Sequence[str],
    parquet_suffixes: Sequence[str], expected_columns: Sequence[str] | None,
) -> tuple[Path, str, str]:
    """(path, format, the empty-file message) of a file that exists, is not a directory, has
    a known ending and is not 0 bytes; else ``error``."""
    p = Path(path)
    if not p.exists():
        raise error(f"{p}: file not found (no such file or directory)")
    if p.is_dir():
        raise error(f"{p}: is a directory, expected a CSV or Parquet file")
    fmt = table_format(p, error=error, csv_suffixes=csv_suffixes,
                       parquet_suffixes=parquet_suffixes)
    header = (f"; expected a header with columns {list(expected_columns)}"
              if expected_columns else "")
    empty = f"{p}: empty file (no header, no rows{header})"
    if p.stat().st_size == 0:
        raise error(empty)
    return p, fmt, empty


@contextmanager
def _parser_errors(p: Path, fmt: str, empty: str, error: ErrorType,
                   where: Callable[[], str] = lambda: "") -> Iterator[None]:
    """Turn what pandas / pyarrow raise while reading ``p`` into ``error``: an empty file
    (only blank lines) into ``empty``, any other parser error into ``"<p>: cannot be read as
    CSV<where()>: <their message>"``."""
    import pandas as pd

    try:
        yield
    except pd.errors.EmptyDataError as err:
        raise error(empty) from err
    except error:
        raise
    except Exception as err:  # parser errors of pandas / pyarrow, unreadable file
        raise error(f"{p}: cannot be read as {'CSV' if fmt == 'csv' else 'Parquet'}{where()}: "
                    f"{safe_text(str(err), 300)}") from err


def _csv_header(p: Path) -> list[str]:
    """The names in a CSV file's first line, verbatim."""
    import pandas as pd

    raw = pd.read_csv(p, nrows=1, header=None, dtype=str, keep_default_na=False)
    return [str(c) for c in raw.iloc[0].tolist()] if len(raw) else []


def read_table_chunks(
    path: str | Path,
    columns: Sequence[str],
    *,
    chunk_rows: int = 200_000,
    error: ErrorType = ValueError,
    csv_suffixes: Sequence[str] = CSV_SUFFIXES,
    parquet_suffixes: Sequence[str] = PARQUET_SUFFIXES,
) -> Iterator[Any]:
    """Read a CSV or Parquet file ``chunk_rows`` rows at a time (memory bounded by the chunk,
    not the file): yields ``pandas.DataFrame`` chunks holding those of ``columns`` the file
    has (other columns are not read), with ``attrs`` ``"source"``, ``"format"``, ``"row0"``
    (the file row of the chunk's first row, 0-based over the data rows) and ``"header"`` (all
    column names of the file). The file-level refusals of :func:`read_table` apply (missing,
    directory, empty, unknown ending, duplicated column name, parser errors, header only);
    a parser error in a later chunk is raised when that chunk is reached. Each chunk's types
    are inferred on their own, so a bad cell is reported by the caller's column checks with
    ``row0`` added.
    """
    import pandas as pd

    if chunk_rows < 1:
        raise ValueError(f"chunk_rows: expected >= 1, got {chunk_rows}")
    p, fmt, empty = _usable_path(path, error, csv_suffixes, parquet_suffixes, columns)
    row0 = 0
    with _parser_errors(p, fmt, empty, error, lambda: f" (after data row {row0})"):
        if fmt == "csv":
            header = _csv_header(p)
            _check_unique_columns(p, header, error)
            # none of the columns: read the first one anyway, so the rows still count
            wanted = [c for c in columns if c in header] or header[:1]
            batches: Iterator[Any] = iter(pd.read_csv(p, usecols=wanted, chunksize=chunk_rows))
        else:
            import pyarrow.parquet as pq

            pf = pq.ParquetFile(p)
            header = [str(c) for c in pf.schema_arrow.names]
            _check_unique_columns(p, header, error)
            wanted = [c for c in columns if c in header]
            batches = (b.to_pandas() for b in pf.iter_batches(batch_size=chunk_rows,
                                                              columns=wanted))
        while True:
            try:
                df = next(batches)
            except StopIteration:
                break
            df.attrs.update(source=str(path), format=fmt, row0=row0, header=header)
            row0 += len(df)
            yield df
    if row0 == 0:
        raise error(f"{p}: no data rows (header only)")


class TableWriter:
    """Write a table chunk by chunk (frames with the same columns) to a CSV or Parquet file,
    without holding it in memory: ``with TableWriter(path) as w: w.write(df)``.

    The format is ``fmt`` (``"csv"`` / ``"parquet"``) or, when ``None``, the path's ending
    (:func:`table_format`). CSV: a plain header line, then rows by pyarrow's CSV writer
    (numbers in shortest round-trip form, booleans ``true``/``false``, which
    :func:`pandas.read_csv` reads back as booleans). The file is created at the first
    ``write``; nothing is created when nothing is written.
    """

    def __init__(self, path: str | Path, fmt: str | None = None) -> None:
        self.path = Path(path)
        self.fmt = fmt or table_format(self.path)
        if self.fmt not in ("csv", "parquet"):
            raise ValueError(f"fmt: expected 'csv' or 'parquet', got {fmt!r}")
        self._writer: Any = None
        self._file: Any = None

    def write(self, df: Any) -> None:
        """Append the rows of ``df`` (a ``pandas.DataFrame``; its index is not written)."""
        import pyarrow as pa

        table = pa.Table.from_pandas(df, preserve_index=False)
        if self._writer is None:
            if self.fmt == "csv":
                import pyarrow.csv as pcsv

                self._file = open(self.path, "wb")  # closed in close()
                self._file.write((",".join(table.schema.names) + "\n").encode())
                self._writer = pcsv.CSVWriter(
                    self._file, table.schema,
                    write_options=pcsv.WriteOptions(include_header=False))
            else:
                import pyarrow.parquet as pq

                self._writer = pq.ParquetWriter(self.path, table.schema)
        self._writer.write_table(table)

    def close(self) -> None:
        """Finish the file (idempotent)."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> TableWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _check_unique_columns(path: Path, cols: Sequence[str], error: ErrorType) -> None:
    """Refuse a header that names a column twice (which copy would be meant is a guess)."""
    seen: dict[str, int] = {}
    for j, c in enumerate(cols):
        if c in seen:
            raise error(f"{path}: column {safe_text(c)!r} appears twice in the header (columns "
                        f"{seen[c] + 1} and {j + 1}); rename or drop one")
        seen[c] = j


def safe_text(s: object, limit: int = 200) -> str:
    """``str(s)`` safe to print on a terminal: every non-printable character (control
    characters such as ESC, newline, tab, carriage return; Unicode format characters such as
    bidirectional overrides; see :meth:`str.isprintable`) is replaced by its Python escape
    (``\\x1b``, ``\\n``, ``\\u202e``), and text longer than ``limit`` characters is cut with a
    note of its length. Used for every user-supplied string we echo (component ids, column
    names, cell values)."""
    text = str(s)
    if not text.isprintable():
        text = "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii")
                       for c in text)
    if len(text) > limit:
        text = f"{text[:limit]}... ({len(text)} characters)"
    return text


def time_seconds(
    col: Any,
    name: str,
    *,
    error: ErrorType = ValueError,
    source: str = "",
    row_label: Callable[[int], str] | None = None,
    since_first: bool = False,
) -> NDArray[np.float64] | None:
    """A date-time column as float64 seconds since 1970-01-01T00:00:00Z (``since_first``:
    since the column's first value, computed in integer nanoseconds, so sub-microsecond steps
    survive: seconds since the epoch are rounded to 2.4e-7 s in float64), or ``None`` when
    ``col`` holds no date-times (then the caller reads it as numbers).

    Date-times are: a ``datetime64`` column (Parquet timestamps, naive ones taken as UTC,
    time-zone aware ones converted to UTC), a ``timedelta64`` column (seconds of the duration)
    and a text column whose every cell is an ISO 8601 date-time (``2024-05-01T12:00:00``,
    ``2024-05-01 12:00:00+02:00``; naive ones taken as UTC), as CSV gives them. Without this a
    Parquet timestamp read as a number is nanoseconds taken as seconds. A missing date-time
    (``NaT``) raises ``error`` naming the column and row.
    """
    import pandas as pd

    label = row_label or _row_1_based
    prefix = f"{source}: " if source else ""
    s = pd.Series(col).reset_index(drop=True)
    if isinstance(s.dtype, pd.DatetimeTZDtype) or pd.api.types.is_datetime64_dtype(s.dtype):
        ts = pd.to_datetime(s, utc=True)
    elif pd.api.types.is_timedelta64_dtype(s.dtype):
        ts = None
        secs = ((s - s.iloc[0]) if since_first else s).dt.total_seconds().to_numpy(
            dtype=np.float64)
        bad = ~np.isfinite(secs)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise error(f"{prefix}column {name!r}, {label(i)}: missing duration (NaT)")
        return secs
    elif s.dtype == object or pd.api.types.is_string_dtype(s.dtype):
        txt = s.dropna()
        if len(txt) == 0 or not txt.map(lambda v: isinstance(v, str)).all():
            return None
        if pd.to_numeric(txt, errors="coerce").notna().any():
            return None  # numbers (perhaps with a typo): the numeric reader explains
        if not txt.str.match(r"^\s*\d{4}-\d{2}-\d{2}([T ]\d{2}:\d{2}(:\d{2}(\.\d+)?)?)?"
                             r"\s*(Z|[+-]\d{2}:?\d{2})?\s*$").all():
            return None
        try:
            ts = pd.to_datetime(s, utc=True, format="ISO8601")
        except (ValueError, OverflowError):
            return None
    else:
        return None
    bad = ts.isna().to_numpy()
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise error(f"{prefix}column {name!r}, {label(i)}: missing date-time (NaT or empty)")
    origin = ts.iloc[0] if since_first else pd.Timestamp("1970-01-01", tz="UTC")
    return np.asarray((ts - origin) / pd.Timedelta(seconds=1), dtype=np.float64)


def cell_repr(v: object) -> str:
    """repr of a cell value without numpy type wrappers (``'1,0'``, ``12.0``, not
    ``np.float64(12.0)``), for messages."""
    if isinstance(v, np.generic):
        v = v.item()
    return safe_text(repr(v))


def _row_1_based(i: int) -> str:
    return f"row {i + 1}"


def numeric_columns(
    df: Any,
    names: Sequence[str] | Mapping[str, Hashable],
    *,
    error: ErrorType = ValueError,
    source: str = "",
    row_label: Callable[[int], str] = _row_1_based,
    missing_ok: Iterable[str] = (),
) -> dict[str, NDArray[np.float64]]:
    """Coerce columns of ``df`` to finite float64 arrays, or raise ``error`` at the first bad cell.
    In the columns named in ``missing_ok`` an empty (NaN) cell is allowed and stays NaN (a
    missing measurement); +-inf is refused there too.

    ``names`` lists the columns, in the order they are checked; a mapping ``{name: key}``
    names a column in the messages by ``name`` while reading ``df[key]`` (e.g. a
    case-insensitive match). Returns ``{name: array}`` (fresh float64 arrays, positional, the
    frame's index ignored).

    For each column in turn: a true/false cell (a boolean column, as a CSV of ``True`` /
    ``False`` or a Parquet boolean column reads, or a boolean inside a mixed column) raises
    ``"<source>: column 'x', <row_label(i)>: True is a boolean (true/false), not a number"``
    (pandas would read it as 1.0 / 0.0); a cell that is not a number (after
    :func:`pandas.to_numeric`) raises ``"<source>: column 'x', <row_label(i)>: 'abc' is not a
    number (k non-numeric value(s) in this column)"``; then a NaN / +-inf (an empty cell reads
    as NaN) raises ``"<source>: column 'x', <row_label(i)>: NaN (an empty or NaN cell) is not
    allowed: every value must be a finite number, no NaN/inf (k non-finite value(s) in this
    column)"``.
    ``i`` is the 0-based position of the first offending row; ``row_label`` turns it into the
    reader's row wording (default ``row {i + 1}``, 1-based over the data rows).
    """
    import pandas as pd

    items = list(names.items()) if isinstance(names, Mapping) else [(n, n) for n in names]
    prefix = f"{source}: " if source else ""
    allowed = set(missing_ok)
    out: dict[str, NDArray[np.float64]] = {}
    for name, key in items:
        col = df[key]
        _refuse_booleans(col, name, error, prefix, row_label)
        num = pd.to_numeric(col, errors="coerce")
        bad = (num.isna() & col.notna()).to_numpy()
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise error(
                f"{prefix}column {name!r}, {row_label(i)}: {cell_repr(col.iloc[i])} is not a "
                f"number ({int(bad.sum())} non-numeric value(s) in this column)"
            )
        a = np.array(num.to_numpy(dtype=np.float64), dtype=np.float64, copy=True)
        nonfinite = np.isinf(a) if name in allowed else ~np.isfinite(a)
        if nonfinite.any():
            i = int(np.flatnonzero(nonfinite)[0])
            what = "NaN (an empty or NaN cell)" if np.isnan(a[i]) else f"{a[i]}"
            raise error(
                f"{prefix}column {name!r}, {row_label(i)}: {what} is not allowed: every value "
                f"must be a finite number, no NaN/inf ({int(nonfinite.sum())} non-finite "
                f"value(s) in this column)"
            )
        out[name] = a
    return out


def _refuse_booleans(col: Any, name: str, error: ErrorType, prefix: str,
                     row_label: Callable[[int], str]) -> None:
    """Raise ``error`` at the first true/false cell of ``col`` (numeric_columns)."""
    import pandas as pd

    if pd.api.types.is_bool_dtype(col.dtype):
        is_bool = col.notna().to_numpy()
    elif col.dtype == object:
        is_bool = col.map(lambda v: isinstance(v, bool | np.bool_)).to_numpy(dtype=bool)
    else:
        return
    if is_bool.any():
        i = int(np.flatnonzero(is_bool)[0])
        raise error(f"{prefix}column {name!r}, {row_label(i)}: {cell_repr(col.iloc[i])} is a "
                    f"boolean (true/false), not a number ({int(is_bool.sum())} boolean "
                    "value(s) in this column)")


def match_columns(
    present: Iterable[Hashable],
    wanted: Sequence[str],
    *,
    error: ErrorType = ValueError,
    source: str = "",
) -> dict[str, Hashable]:
    """``{name: column}`` for each name of ``wanted`` found in ``present``, matched with case
    and surrounding blanks ignored; names not found are left out (the caller says what is
    missing).

    Two present columns that match the same wanted name (``speed`` and ``SPEED``) raise
    ``error`` naming both: which one was meant is a guess, and taking either would silently
    drop the other."""
    prefix = f"{source}: " if source else ""
    found: dict[str, list[Hashable]] = {}
    for c in present:
        found.setdefault(str(c).strip().casefold(), []).append(c)
    out: dict[str, Hashable] = {}
    for name in wanted:
        hits = found.get(name.strip().casefold(), [])
        if len(hits) > 1:
            listed = " and ".join(repr(safe_text(h)) for h in hits)
            raise error(f"{prefix}columns {listed} differ only in case or blanks and both read "
                        f"as {name!r}; keep one of them")
        if hits:
            out[name] = hits[0]
    return out


def suggest_column(
    name: str, present: Iterable[Hashable], aliases: Iterable[str] = ()
) -> list[str]:
    """Columns of ``present`` that are probably ``name`` under another spelling, best first.

    First the present columns equal (case and surrounding blanks ignored) to ``name`` itself
    or to one of ``aliases`` (known other names, e.g. ``"rpm"`` for ``"speed_rad_s"``), then up
    to 3 close spellings by :func:`difflib.get_close_matches` (ratio >= 0.5, compared in lower
    case). Empty when nothing is close.
    """
    cols = [str(c) for c in present]
    low: dict[str, str] = {}
    for c in cols:
        low.setdefault(c.lower().strip(), c)
    hits = [low[a] for a in (name.lower(), *(a.lower() for a in aliases))
            if a in low and low[a] != name]
    close = difflib.get_close_matches(name.lower(), list(low), n=3, cutoff=0.5)
    hits += [low[c] for c in close if low[c] not in hits and low[c] != name]
    return list(dict.fromkeys(hits))


def did_you_mean(name: str, present: Iterable[Hashable], aliases: Iterable[str] = ()) -> str:
    """``"; did you mean 'a' or 'b'? (rename it to 'name')"`` from :func:`suggest_column`, or
    ``""`` when no present column is close to ``name``."""
    hits = suggest_column(name, present, aliases)
    if not hits:
        return ""
    return f"; did you mean {' or '.join(repr(h) for h in hits)}? (rename it to {name!r})"


def text_table(columns: Mapping[str, Sequence[str]], left: Sequence[str] = ()) -> str:
    """Plain aligned text table (header, rule, rows; one line each, ending in a newline) of
    already formatted, terminal-safe cells. Columns in ``left`` are left-aligned, the others
    right-aligned. Linear in the number of cells (rich's tables took 8.6 s for 10^4 rows)."""
    names = list(columns)
    widths = [max([len(n), *(len(c) for c in columns[n])]) for n in names]
    just = [str.ljust if n in left else str.rjust for n in names]
    lines = ["  ".join(j(n, w) for n, w, j in zip(names, widths, just, strict=True)).rstrip(),
             "  ".join("-" * w for w in widths)]
    cells = [columns[n] for n in names]
    for row in zip(*cells, strict=True):
        lines.append("  ".join(j(c, w) for c, w, j in zip(row, widths, just, strict=True))
                     .rstrip())
    return "\n".join(lines) + "\n"
