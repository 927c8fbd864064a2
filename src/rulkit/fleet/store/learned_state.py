"""The learned model inside the component database (used by :mod:`rulkit.fleet.store.sqlite`).

``rulkit fit`` stores a fitted candidate (:mod:`rulkit.fleet.learned.candidates`, with its type
tag) in the ``meta`` table (key ``degradation_model``), its time axis (key ``time_axis``) and
each component's model state in table ``model_state``: the candidate's own state columns
(``model.state_columns``: 7 numbers and the count for the Gaussian growth models, the onset
mixture's weights and Gaussians, a baseline's forgotten sums) and ``t0``, the component's age
origin in the database's time (0 when the time column is the age; its first acquisition, or its
``installed`` time). ``rulkit track`` then writes, per acquisition, the model's RUL median and
90 % interval into the history (columns ``rul_median``, ``rul_low``, ``rul_high``), computed at
the component's age t - t0. Schema changes are additive: an older database gains the column,
and ``model_state`` is rebuilt for the stored model's columns, when a model is stored
(:func:`install_model`), in the same transaction.
"""

from __future__ import annotations

import json
import sqlite3
from typing import Any

import numpy as np
import pandas as pd

from rulkit.fleet.learned.candidates import FleetModel, model_from_dict, model_to_dict
from rulkit.fleet.learned.histories import Histories
from rulkit.fleet.time_axis import TimeAxis

LEVELS = (0.5, 0.05, 0.95)


def _migrate(conn: sqlite3.Connection, model: FleetModel) -> None:
    cols = [r[1] for r in conn.execute("PRAGMA table_info(history)")]
    if "rul_median" not in cols:
        conn.execute("ALTER TABLE history ADD COLUMN rul_median REAL")
    have = [r[1] for r in conn.execute("PRAGMA table_info(model_state)")]
    want = ["component", "t0", *model.state_columns]
    if have != want:
        conn.execute("DROP TABLE IF EXISTS model_state")
        body = ", ".join(f"{c} {'INTEGER' if c == 'n' else 'REAL'} NOT NULL"
                         for c in want[1:])
        conn.execute(f"CREATE TABLE model_state (component TEXT PRIMARY KEY, {body})")


def _write(conn: sqlite3.Connection, model: FleetModel, names: list[str], t0: np.ndarray,
           st: Any) -> None:
    cols = st.columns()
    names_c = ("t0", *model.state_columns)
    values = [np.asarray(t0).tolist()] + [np.asarray(cols[c]).tolist()
                                          for c in model.state_columns]
    rows = zip(names, *values, strict=True)
    ph = ", ".join("?" * (len(names_c) + 1))
    conn.executemany(f"INSERT OR REPLACE INTO model_state (component, {', '.join(names_c)}) "
                     f"VALUES ({ph})", rows)


def model_axis(model: FleetModel) -> TimeAxis:
    """The time axis a model was fitted on."""
    return TimeAxis.from_dict(model.time_axis)


def install_model(conn: sqlite3.Connection, model: FleetModel) -> int:
    """Inside the caller's transaction: migrate, store the model and its time axis, rebuild
    every component's state from its stored history (t, hi). Returns the number of components
    rebuilt. A model whose ages count from an ``installed`` column cannot be replayed over a
    history that has none (``ValueError``)."""
    axis = model_axis(model)
    df = pd.read_sql_query("SELECT component, t, hi FROM history ORDER BY component, t", conn)
    if not df.empty and axis.origin == "installed":
        raise ValueError("the model counts ages from an 'installed' column, which the stored "
                         "history does not hold; fit it into a new database")
    _migrate(conn, model)
    conn.execute("INSERT OR REPLACE INTO meta VALUES ('degradation_model', ?)",
                 (json.dumps(model_to_dict(model)),))
    conn.execute("INSERT OR REPLACE INTO meta VALUES ('time_axis', ?)",
                 (json.dumps(axis.to_dict()),))
    conn.execute("DELETE FROM model_state")
    if df.empty:
        return 0
    codes, names = pd.factorize(df["component"], sort=False)
    counts = np.bincount(codes)
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    t = df["t"].to_numpy(np.float64)
    t0 = t[start[:-1]] if axis.origin == "first" else np.zeros(len(names))
    hist = Histories(unit=codes.astype(np.int64), t=t - t0[codes],
                     hi=df["hi"].to_numpy(np.float64), names=np.asarray(names, dtype=object),
                     start=start, failed=np.zeros(len(names), dtype=bool), source="history")
    last = start[1:] - 1
    _write(conn, model, [str(n) for n in names], t0, model.replay(hist).take(last))
    return len(names)


class LearnedPass:
    """The learned model's state of a batch's components during one ingestion.

    ``installed``: each component's install time in the database's time (the batch's
    ``installed`` column), for a model whose ages count from it."""

    def __init__(self, conn: sqlite3.Connection, model: FleetModel, names: list[str],
                 installed: dict[str, float] | None = None) -> None:
        self.conn, self.model, self.names = conn, model, names
        self.axis = model_axis(model)
        _migrate(conn, model)
        cols = ("t0", *model.state_columns)
        found: dict[str, tuple] = {}
        for i0 in range(0, len(names), 500):
            chunk = names[i0:i0 + 500]
            q = (f"SELECT component, {', '.join(cols)} FROM model_state "
                 f"WHERE component IN ({','.join('?' * len(chunk))})")
            for row in conn.execute(q, chunk):
                found[row[0]] = row[1:]
        state = model.empty_state(len(names))
        stored = np.array([n in found for n in names])
        self.t0 = np.full(len(names), np.nan if self.axis.origin != "time" else 0.0)
        if self.axis.origin == "installed":
            self.t0 = np.array([(installed or {}).get(n, np.nan) for n in names])
        if stored.any():
            rows = [found[n] for n in names if n in found]
            c = {k: np.array([r[j] for r in rows]) for j, k in enumerate(cols)}
            got = model.state_from_columns(c)
            idx = np.flatnonzero(stored)
            self.t0[idx] = c["t0"]
            state = _assign(state, idx, got)
        self.state = state

    def step(self, ci: np.ndarray, t: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, ...]:
        """Assimilate one acquisition per component (NaN = none; ``t`` in the database's time);
        the quantiles of the components ``ci``."""
        new = np.isfinite(t) & np.isnan(self.t0)
        if new.any():  # age since the first acquisition: this one
            self.t0 = np.where(new, t, self.t0)
        self.state = self.model.update(self.state, t - self.t0, hi)
        return self.model.rul_quantiles(self.state.take(ci), LEVELS)

    def finish(self) -> tuple[np.ndarray, ...]:
        """Write the states; the final quantiles of every component of the batch."""
        _write(self.conn, self.model, self.names, self.t0, self.state)
        return self.model.rul_quantiles(self.state, LEVELS)


def _assign(state: Any, idx: np.ndarray, got: Any) -> Any:
    """``state`` with the units ``idx`` replaced by ``got`` (same type, struct of arrays)."""
    for name, arr in vars(state).items():
        arr[idx] = getattr(got, name)
    return state


def learned_model_of(meta: dict[str, Any]) -> FleetModel | None:
    """The learned model of a parsed ``meta`` table (None if there is none)."""
    d = meta.get("degradation_model")
    return None if d is None else model_from_dict(d)
