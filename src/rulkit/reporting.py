"""Markdown tables and number formatting for the reproductions' ``report.md`` files.

One writer for every system, so the reports agree on how a missing value, an infinite RUL or a
boolean prints (no ``tabulate`` dependency; pandas' own ``to_markdown`` needs it):

- a float prints with a format spec chosen per report (``".4g"`` by default; a table whose
  values are compared with a paper's may ask for more digits),
- NaN (no value: a statistic over an empty set, a paper value the paper does not give) prints as
  an empty cell,
- ``inf`` / ``-inf`` (e.g. a RUL beyond the horizon) print as ``inf`` / ``-inf``,
- anything else (integers, booleans, strings) prints with ``str``.

Example::

    >>> import pandas as pd
    >>> print(markdown_table(pd.DataFrame({"method": ["pf"], "rmse": [0.12345], "p": [None]})))
    | method | rmse | p |
    |---|---|---|
    | pf | 0.1235 |  |
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from numbers import Real
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["NAN_TEXT", "format_float", "format_value", "markdown_table"]

#: How a NaN (missing value) prints in every report table.
NAN_TEXT = ""


def format_float(v: float, spec: str = ".4g") -> str:
    """``v`` with the format ``spec``; NaN as :data:`NAN_TEXT`, infinities as ``inf``/``-inf``."""
    if math.isnan(v):
        return NAN_TEXT
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return format(v, spec)


def format_value(v: object, spec: str = ".4g") -> str:
    """One table cell: floats through :func:`format_float`, ``None`` as NaN, others ``str``."""
    if v is None:
        return NAN_TEXT
    if isinstance(v, bool | np.bool_):
        return str(bool(v))
    if isinstance(v, float | np.floating):
        return format_float(float(v), spec)
    if isinstance(v, Real) and not isinstance(v, int | np.integer):
        return format_float(float(v), spec)
    return str(v)


def markdown_rows(header: Iterable[object], rows: Iterable[Iterable[object]],
                  spec: str = ".4g") -> str:
    """A markdown table from a header and rows of cells (see :func:`format_value`)."""
    cols = [str(c) for c in header]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for row in rows:
        cells = [format_value(v, spec) for v in row]
        if len(cells) != len(cols):
            raise ValueError(f"a row has {len(cells)} cells, the header {len(cols)}: {cells}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def markdown_table(df: pd.DataFrame, spec: str = ".4g") -> str:
    """A DataFrame (its columns, not its index) as a markdown table.

    Each cell keeps its column's type (an integer column prints as integers even beside float
    columns); floats print with ``spec``, NaN as an empty cell, infinities as ``inf``."""
    return markdown_rows(df.columns, df.itertuples(index=False, name=None), spec)
