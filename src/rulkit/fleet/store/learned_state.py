"""The learned model inside the component database, on SQLite and PostgreSQL alike (used by
:mod:`rulkit.fleet.store.sqlite` and :mod:`rulkit.fleet.store.postgres`).

``rulkit fit`` stores a :class:`~rulkit.fleet.learned.degradation.DegradationModel` in the
``meta`` table (key ``degradation_model``) and each component's model state (the Kalman
posterior of docs/fleet-models.md eq. (2): 7 numbers and the acquisition count) in table
``model_state``; ``rulkit track`` then writes, per acquisition, the model's RUL median and
90 % interval into the history (columns ``rul_median``, ``rul_low``, ``rul_high``). Schema
changes are additive: an older database gains the column and the table when a model is first
stored (:func:`install_model`), in the same transaction.
"""

from __future__ import annotations

import json
import sqlite3
from typing import Any

import numpy as np
import pandas as pd

from rulkit.fleet.learned.degradation import (
    DegradationModel,
    UnitState,
    final_states,
    update_state,
)
from rulkit.fleet.learned.histories import Histories
from rulkit.fleet.store.schema import migrate

STATE_COLS = ("m_z", "m_b", "p_zz", "p_zb", "p_bb", "t", "hi", "n")
LEVELS = (0.5, 0.05, 0.95)


def _migrate(conn: sqlite3.Connection) -> None:
    """Additive migration (history column ``rul_median``, table ``model_state``)."""
    migrate(conn, getattr(conn, "dialect", "sqlite"))


def _write(conn: sqlite3.Connection, names: list[str], st: UnitState) -> None:
    cols = st.columns()
    rows = zip(names, *(np.asarray(cols[c]).tolist() for c in STATE_COLS), strict=True)
    ph = ", ".join("?" * (len(STATE_COLS) + 1))
    update = ", ".join(f"{c} = excluded.{c}" for c in STATE_COLS)
    conn.executemany(f"INSERT INTO model_state (component, {', '.join(STATE_COLS)}) "
                     f"VALUES ({ph}) ON CONFLICT (component) DO UPDATE SET {update}", rows)


def install_model(conn: sqlite3.Connection, model: DegradationModel) -> int:
    """Inside the caller's transaction: migrate, store the model, rebuild every component's
    state from its stored history (t, hi). Returns the number of components rebuilt."""
    _migrate(conn)
    conn.execute("INSERT INTO meta VALUES ('degradation_model', ?) ON CONFLICT (key) DO "
                 "UPDATE SET value = excluded.value", (json.dumps(model.to_dict()),))
    conn.execute("DELETE FROM model_state")
    rows = conn.execute("SELECT component, t, hi FROM history ORDER BY component, t").fetchall()
    if not rows:
        return 0
    df = pd.DataFrame(rows, columns=["component", "t", "hi"])
    codes, names = pd.factorize(df["component"], sort=False)
    counts = np.bincount(codes)
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    hist = Histories(unit=codes.astype(np.int64), t=df["t"].to_numpy(np.float64),
                     hi=df["hi"].to_numpy(np.float64), names=np.asarray(names, dtype=object),
                     start=start, failed=np.zeros(len(names), dtype=bool), source="history")
    _write(conn, [str(n) for n in names], final_states(model, hist))
    return len(names)


class LearnedPass:
    """The learned model's state of a batch's components during one ingestion."""

    def __init__(self, conn: sqlite3.Connection, model: DegradationModel,
                 names: list[str]) -> None:
        self.conn, self.model, self.names = conn, model, names
        _migrate(conn)
        self.state = UnitState.empty(model, len(names))
        pos = {n: i for i, n in enumerate(names)}
        for i0 in range(0, len(names), 500):
            chunk = names[i0:i0 + 500]
            q = (f"SELECT component, {', '.join(STATE_COLS)} FROM model_state "
                 f"WHERE component IN ({','.join('?' * len(chunk))})")
            for row in conn.execute(q, chunk):
                i = pos[row[0]]
                v = dict(zip(STATE_COLS, row[1:], strict=True))
                self.state.m[i] = (v["m_z"], v["m_b"])
                self.state.p[i] = (v["p_zz"], v["p_zb"], v["p_bb"])
                self.state.t[i], self.state.hi[i], self.state.n[i] = v["t"], v["hi"], v["n"]

    def step(self, ci: np.ndarray, t: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, ...]:
        """Assimilate one acquisition per component (NaN = none); quantiles of ``ci``."""
        self.state = update_state(self.state, self.model, t, hi)
        sub = UnitState(m=self.state.m[ci], p=self.state.p[ci], t=self.state.t[ci],
                        hi=self.state.hi[ci], n=self.state.n[ci])
        return self.model.rul_quantiles(sub, LEVELS)

    def finish(self) -> tuple[np.ndarray, ...]:
        """Write the states; the final quantiles of every component of the batch."""
        _write(self.conn, self.names, self.state)
        return self.model.rul_quantiles(self.state, LEVELS)


def learned_model_of(meta: dict[str, Any]) -> DegradationModel | None:
    d = meta.get("degradation_model")
    return None if d is None else DegradationModel.from_dict(d)
