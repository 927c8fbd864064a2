"""The fitted model inside the component database (used by :mod:`rulkit.fleet.store.prognosis`).

``rulkit fit`` stores a :class:`~rulkit.fleet.learned.degradation.DegradationModel` in the
``meta`` table (key ``degradation_model``) and each component's model state (the Kalman
posterior of docs/fleet-models.md eq. (2): 7 numbers and the acquisition count) in table
``model_state`` (:func:`store_model`); every ingestion then advances the states of its
components (:class:`LearnedPass`), and the model's RUL median and interval are the RUL of the
store while the model is in force (docs/systems/embedded-rul.md §6). The table is added to an
older database when a model is first stored, in the same transaction.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from rulkit.fleet.learned.degradation import (
    DegradationModel,
    UnitState,
    filtered_states,
    update_state,
)
from rulkit.fleet.learned.histories import Histories
from rulkit.fleet.monitoring.rules import MonitoringRules
from rulkit.fleet.store.database_file import rows_of_components

STATE_COLS = ("m_z", "m_b", "p_zz", "p_zb", "p_bb", "t", "hi", "n")
LEVELS = MonitoringRules().levels
"""The RUL quantiles the store keeps by default: the median, 5 % and 95 %."""
_TABLE = """CREATE TABLE IF NOT EXISTS model_state (
    component TEXT PRIMARY KEY, m_z REAL NOT NULL, m_b REAL NOT NULL, p_zz REAL NOT NULL,
    p_zb REAL NOT NULL, p_bb REAL NOT NULL, t REAL NOT NULL, hi REAL NOT NULL,
    n INTEGER NOT NULL
)"""


def ensure_model_state(conn: Any) -> None:
    """Create the ``model_state`` table if missing (inside the caller's transaction)."""
    conn.execute(_TABLE)


def store_model(conn: Any, model: DegradationModel) -> None:
    """Inside the caller's transaction: the model in ``meta``, the states table emptied (the
    caller replays them)."""
    ensure_model_state(conn)
    conn.execute("DELETE FROM meta WHERE key = 'degradation_model'")
    conn.execute("INSERT INTO meta VALUES ('degradation_model', ?)",
                 (json.dumps(model.to_dict()),))
    conn.execute("DELETE FROM model_state")


def _take(st: UnitState, idx: np.ndarray) -> UnitState:
    return UnitState(m=st.m[idx], p=st.p[idx], t=st.t[idx], hi=st.hi[idx], n=st.n[idx])


class LearnedPass:
    """The fitted model's states of a batch's components ``names`` during one ingestion."""

    def __init__(self, conn: Any, model: DegradationModel, names: list[str]) -> None:
        self.conn, self.model, self.names = conn, model, names
        ensure_model_state(conn)
        self.state = UnitState.empty(model, len(names))
        self.fresh = False
        for i, row in rows_of_components(conn, "model_state", STATE_COLS, names):
            v = dict(zip(STATE_COLS, row, strict=True))
            self.state.m[i] = (v["m_z"], v["m_b"])
            self.state.p[i] = (v["p_zz"], v["p_zb"], v["p_bb"])
            self.state.t[i], self.state.hi[i], self.state.n[i] = v["t"], v["hi"], v["n"]

    def reset(self) -> None:
        """Every component back to the prior (a replay from its first acquisition)."""
        self.state = UnitState.empty(self.model, len(self.names))
        self.fresh = True

    def run(self, comps: np.ndarray, seg: np.ndarray, t: np.ndarray, hi: np.ndarray,
            levels: tuple[float, ...]) -> tuple[np.ndarray, ...]:
        """Assimilate the rows ``seg[c]:seg[c + 1]`` of each component ``comps[c]`` in order;
        the RUL quantiles ``levels`` after each row."""
        counts = np.diff(seg)
        if self.fresh and counts.size and counts.min() > 0:  # a replay: one compiled pass
            hist = Histories(unit=np.repeat(np.arange(counts.size), counts), t=t, hi=hi,
                             names=np.asarray(comps, dtype=object), start=seg,
                             failed=np.zeros(counts.size, dtype=bool), source="history")
            rows = filtered_states(self.model, hist)
            last = seg[1:] - 1
            for f in ("m", "p", "t", "hi", "n"):
                getattr(self.state, f)[comps] = getattr(rows, f)[last]
            self.fresh = False
            return self.model.rul_quantiles(rows, levels)
        sub = _take(self.state, comps)
        out = [np.empty(t.size) for _ in levels]
        for r in range(int(counts.max(initial=0))):
            have = np.flatnonzero(counts > r)
            idx = seg[have] + r
            t_r, h_r = np.full(counts.size, np.nan), np.full(counts.size, np.nan)
            t_r[have], h_r[have] = t[idx], hi[idx]
            sub = update_state(sub, self.model, t_r, h_r)
            for k, q in enumerate(self.model.rul_quantiles(_take(sub, have), levels)):
                out[k][idx] = q
        for f in ("m", "p", "t", "hi", "n"):
            getattr(self.state, f)[comps] = getattr(sub, f)
        self.fresh = False
        return tuple(out)

    def finish(self) -> None:
        """Write the states of the batch's components."""
        cols = self.state.columns()
        have = self.state.n > 0
        rows = zip([n for n, h in zip(self.names, have, strict=True) if h],
                   *(np.asarray(cols[c])[have].tolist() for c in STATE_COLS), strict=True)
        ph = ", ".join("?" * (len(STATE_COLS) + 1))
        updates = ", ".join(f"{c} = excluded.{c}" for c in STATE_COLS)
        self.conn.executemany(
            f"INSERT INTO model_state (component, {', '.join(STATE_COLS)}) VALUES ({ph}) "
            f"ON CONFLICT (component) DO UPDATE SET {updates}", rows)


def model_states(conn: Any, model: DegradationModel, names: list[str]) -> UnitState:
    """The stored model states of ``names`` (the prior for a component without one)."""
    return LearnedPass(conn, model, names).state


__all__ = ["LEVELS", "STATE_COLS", "LearnedPass", "ensure_model_state", "model_states",
           "store_model"]
