"""Binary COPY data made by numpy (src/rulkit/fleet/store/pg_copy.py) against psycopg's own
``write_row`` of the same rows (those :func:`component_rows` makes of the same arrays, and
rows with text and bytea of any length): PostgreSQL stores the same values, bit for bit,
NULL for NULL."""

import numpy as np
import pytest

from rulkit.fleet.store.pg_copy import binary_rows, binary_tuples
from rulkit.fleet.store.postgres import _connect_pg
from rulkit.fleet.store.tracker_rows import component_rows

COLUMNS = ("t", "n", "valid", "level", "rul_median", "hits", "seen")
TYPES = ("float8", "int8", "bool", "int2", "float8", "int8", "float8")
NULLABLE = ("rul_median", "hits", "seen")


def _values(rng, b):
    v = rng.normal(0, 1e3, (b, len(COLUMNS)))
    v[:, 1] = rng.integers(-2**40, 2**40, b)
    v[:, 2] = rng.integers(0, 3, b)  # 2 is a true bool too
    v[:, 3] = rng.integers(-3, 3, b)
    v[:, 5] = np.where(rng.random(b) < 0.3, np.nan, rng.integers(0, 9, b))
    v[rng.random(b) < 0.3, 4] = np.nan
    v[rng.random(b) < 0.3, 6] = np.nan
    v[:3, 0] = [-0.0, np.inf, np.nan]  # a NaN that is not NULL: the column has no NULL
    v[3, 4] = -np.inf
    return v


def _both(conn, spec, cols, types, theirs_rows, ours_data):
    """Each way into a table of its own; both tables as PostgreSQL's binary COPY gives them."""
    out = []
    for table in ("theirs", "ours"):
        conn.execute(f"CREATE TABLE {table} (i serial, {spec})")
    conn.copy_binary("theirs", cols, types, theirs_rows)
    conn.copy_data("ours", cols, ours_data)
    for table in ("theirs", "ours"):
        with conn.raw.cursor() as cur:
            with cur.copy(f"COPY (SELECT {', '.join(cols)} FROM {table} ORDER BY i) "
                          "TO STDOUT (FORMAT BINARY)") as copy:
                out.append(b"".join(bytes(block) for block in copy))
    return out


def test_binary_tuples_store_what_psycopgs_rows_store(pg_server):
    rng = np.random.default_rng(5)
    rows = [(f"u{i}-é𝄞" * (i % 4), float(rng.normal()), float(-0.0 if i % 5 else np.nan),
             int(rng.integers(-2**62, 2**62)), int(rng.integers(0, 3)),
             rng.bytes(int(rng.integers(0, 40)) if i != 7 else 100_000))
            for i in range(200)]
    cols = ("k", "a", "b", "n", "s", "data")
    types = ["text", "float8", "float8", "int8", "int2", "bytea"]
    conn = _connect_pg(pg_server.create_schema(), 10)
    try:
        spec = ", ".join(f"{c} {t}" for c, t in zip(cols, types, strict=True))
        out = _both(conn, spec, cols, types, rows, binary_tuples(rows, types))
        assert conn.execute("SELECT length(data) FROM ours WHERE i = 8").fetchone()[0] == 100_000
    finally:
        conn.close()
    assert out[0] == out[1]
    assert binary_tuples([], types) == binary_tuples([], ["text"])  # header and trailer


@pytest.mark.parametrize("key_last", [False, True])
def test_binary_rows_store_what_psycopgs_rows_store(pg_server, key_last):
    rng = np.random.default_rng(3)
    b = 300
    values = _values(rng, b)
    names = [f"c{i}-é€𝄞" if i % 7 == 0 else f"unit {i}" for i in range(b)]
    names[5] = ""
    cols = (*COLUMNS, "component") if key_last else ("component", *COLUMNS)
    types = [*TYPES, "text"] if key_last else ["text", *TYPES]
    conn = _connect_pg(pg_server.create_schema(), 10)
    try:
        spec = ", ".join(f"{c} {t}" for c, t in zip(cols, types, strict=True))
        out = _both(conn, spec, cols, types,
                    component_rows(names, values, COLUMNS, NULLABLE, key_last=key_last),
                    binary_rows(names, values, COLUMNS, TYPES,
                                [c in NULLABLE for c in COLUMNS], key_last))
        n_null = conn.execute("SELECT count(*) FROM ours WHERE hits IS NULL").fetchone()[0]
    finally:
        conn.close()
    assert out[0] == out[1]
    assert n_null == int(np.isnan(values[:, 5]).sum()) > 0


def test_a_nan_where_an_integer_is_required_is_refused():
    values = np.array([[1.0, np.nan]])
    with pytest.raises(ValueError, match="column n: NaN where an integer is required"):
        binary_rows(["a"], values, ("t", "n"), ("float8", "int8"), (False, False))
    with pytest.raises(ValueError, match="out of the range of int2"):
        binary_rows(["a"], np.array([[1.0, 4e4]]), ("t", "level"), ("float8", "int2"),
                    (False, False))
