"""Fixtures of the store tests: a database's history rewritten in the layout of an older
rulkit (one row per acquisition), to test its conversion."""

import pytest

from rulkit.fleet.store.schema import table_columns

OLD_FIELDS = ("t", "hi", "fhi", "dhi", "rul", "frul", "drul", "d2rul", "valid", "level",
              "rul_low", "rul_high")


def write_row_history(conn, frame, dialect="sqlite", median=True):
    """Inside the caller's transaction on ``conn``: replace table ``history`` by the table of
    one row per acquisition that rulkit wrote before the packed layout (its DDL of then),
    holding the rows of ``frame`` (a ``ComponentStore.history()`` frame); without its
    ``rul_median`` column when ``median`` is false."""
    real = "REAL" if dialect == "sqlite" else "DOUBLE PRECISION"
    types = {"valid": "INTEGER" if dialect == "sqlite" else "BOOLEAN",
             "level": "INTEGER" if dialect == "sqlite" else "SMALLINT"}
    key = "TEXT" if dialect == "sqlite" else 'TEXT COLLATE "C"'
    cols = [f"component {key} NOT NULL"]
    cols += [f"{f} {types.get(f, real)} NOT NULL" for f in OLD_FIELDS]
    cols += ["ingest " + ("INTEGER" if dialect == "sqlite" else "BIGINT") + " NOT NULL"]
    cols += [f"rul_median {real}"] if median else []
    tail = " WITHOUT ROWID" if dialect == "sqlite" else ""
    conn.execute("DROP TABLE history")
    conn.execute(f"CREATE TABLE history ({', '.join(cols)}, PRIMARY KEY (component, t))"
                 f"{tail}")
    names = ["component", *OLD_FIELDS, "ingest", *(["rul_median"] if median else [])]
    rows = []
    for r in frame[names].itertuples(index=False):
        row = [v.item() if hasattr(v, "item") else v for v in r]
        row[OLD_FIELDS.index("valid") + 1] = (bool(row[OLD_FIELDS.index("valid") + 1])
                                              if dialect != "sqlite"
                                              else int(row[OLD_FIELDS.index("valid") + 1]))
        if median and row[-1] != row[-1]:
            row[-1] = None  # NULL, as the old store wrote a missing RUL
        rows.append(tuple(row))
    conn.executemany(f"INSERT INTO history ({', '.join(names)}) VALUES "
                     f"({', '.join('?' * len(names))})", rows)
    assert "data" not in table_columns(conn, "history")


@pytest.fixture(name="row_history")
def row_history_fixture():
    """:func:`write_row_history`."""
    return write_row_history
