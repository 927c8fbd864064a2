"""The fitted model inside the component database (used by :mod:`rulkit.fleet.store.prognosis`).

``rulkit fit`` stores a fitted candidate (:mod:`rulkit.fleet.learned.candidates`, with its type
tag) in the ``meta`` table (key ``degradation_model``), its time axis (key ``time_axis``) and
each component's model state in table ``model_state`` (:func:`store_model`): the candidate's own
state columns (``model.state_columns``: the Gaussian (level, rate) posterior and the count for
the growth models of docs/fleet-models.md eq. (2), (8), the onset mixture's weights and
Gaussians, a baseline's forgotten sums) and ``t0``, the component's age origin in the
database's time (0 when the time column is the age; its first acquisition, or its ``installed``
time). Every ingestion then advances the states of its components at their ages t - t0
(:class:`LearnedPass`), and the model's RUL median and interval are the RUL of the store while
the model is in force (docs/systems/embedded-rul.md §6). The table is (re)made for the stored
model's columns when a model is stored, in the same transaction.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from rulkit.fleet.learned.candidates import FleetModel, model_to_dict
from rulkit.fleet.learned.histories import Histories
from rulkit.fleet.monitoring.rules import MonitoringRules
from rulkit.fleet.store.database_file import rows_of_components
from rulkit.fleet.store.schema import model_state_table
from rulkit.fleet.time_axis import TimeAxis

LEVELS = MonitoringRules().levels
"""The RUL quantiles the store keeps by default: the median, 5 % and 95 %."""


def model_axis(model: FleetModel) -> TimeAxis:
    """The time axis a model was fitted on."""
    return TimeAxis.from_dict(model.time_axis)


def _columns(model: FleetModel) -> tuple[str, ...]:
    return ("t0", *model.state_columns)


def ensure_model_state(conn: Any, model: FleetModel) -> None:
    """Create the ``model_state`` table for ``model``'s columns, or make it again (empty)
    when it holds another model's (inside the caller's transaction)."""
    have = [str(r[1]) for r in conn.execute("PRAGMA table_info(model_state)").fetchall()]
    want = ["component", *_columns(model)]
    if have == want:
        return
    conn.execute("DROP TABLE IF EXISTS model_state")
    for stmt in model_state_table(_columns(model)).create("sqlite"):
        conn.execute(stmt)


def store_model(conn: Any, model: FleetModel) -> None:
    """Inside the caller's transaction: the model and its time axis in ``meta``, the states
    table emptied (the caller replays them)."""
    ensure_model_state(conn, model)
    conn.execute("DELETE FROM meta WHERE key IN ('degradation_model', 'time_axis')")
    conn.execute("INSERT INTO meta VALUES ('degradation_model', ?)",
                 (json.dumps(model_to_dict(model)),))
    conn.execute("INSERT INTO meta VALUES ('time_axis', ?)",
                 (json.dumps(model_axis(model).to_dict()),))
    conn.execute("DELETE FROM model_state")


def _assign(state: Any, idx: np.ndarray, got: Any) -> None:
    """Units ``idx`` of ``state`` replaced by ``got`` (same type, struct of arrays)."""
    for name, arr in vars(state).items():
        arr[idx] = getattr(got, name)


class LearnedPass:
    """The fitted model's states of a batch's components ``names`` during one ingestion.

    ``installed``: each component's install time in the database's time (the batch's
    ``installed`` column), for a model whose ages count from it."""

    def __init__(self, conn: Any, model: FleetModel, names: list[str],
                 installed: dict[str, float] | None = None) -> None:
        self.conn, self.model, self.names = conn, model, names
        self.axis = model_axis(model)
        self.installed = installed or {}
        ensure_model_state(conn, model)
        self.reset()
        self.fresh = False
        cols = _columns(model)
        found = dict(rows_of_components(conn, "model_state", cols, names))
        if found:
            idx = np.array(sorted(found))
            c = {k: np.array([found[i][j] for i in idx]) for j, k in enumerate(cols)}
            _assign(self.state, idx, model.state_from_columns(c))
            self.t0[idx] = c["t0"]

    def reset(self) -> None:
        """Every component back to the prior (a replay from its first acquisition)."""
        self.state = self.model.empty_state(len(self.names))
        if self.axis.origin == "time":
            self.t0 = np.zeros(len(self.names))
        else:  # the first acquisition (or the batch's installed time) sets it
            self.t0 = np.array([self.installed.get(n, np.nan) for n in self.names])
        self.fresh = True

    def run(self, comps: np.ndarray, seg: np.ndarray, t: np.ndarray, hi: np.ndarray,
            levels: tuple[float, ...]) -> tuple[np.ndarray, ...]:
        """Assimilate the rows ``seg[c]:seg[c + 1]`` of each component ``comps[c]`` in order
        (``t`` in the database's time; the model sees ages t - t0); the RUL quantiles
        ``levels`` after each row."""
        counts = np.diff(seg)
        new = np.isnan(self.t0[comps]) & (counts > 0)
        self.t0[comps[new]] = t[seg[:-1][new]]  # age since the first acquisition: this one
        age = t - np.repeat(self.t0[comps], counts)
        if self.fresh and counts.size and counts.min() > 0:  # a replay: one compiled pass
            hist = Histories(unit=np.repeat(np.arange(counts.size), counts), t=age, hi=hi,
                             names=np.asarray(comps, dtype=object), start=seg,
                             failed=np.zeros(counts.size, dtype=bool), source="history")
            rows = self.model.replay(hist)
            _assign(self.state, comps, rows.take(seg[1:] - 1))
            self.fresh = False
            return self.model.rul_quantiles(rows, levels)
        sub = self.state.take(comps)
        out = [np.empty(t.size) for _ in levels]
        for r in range(int(counts.max(initial=0))):
            have = np.flatnonzero(counts > r)
            idx = seg[have] + r
            t_r, h_r = np.full(counts.size, np.nan), np.full(counts.size, np.nan)
            t_r[have], h_r[have] = age[idx], hi[idx]
            sub = self.model.update(sub, t_r, h_r)
            for k, q in enumerate(self.model.rul_quantiles(sub.take(have), levels)):
                out[k][idx] = q
        _assign(self.state, comps, sub)
        self.fresh = False
        return tuple(out)

    def finish(self) -> None:
        """Write the states (and age origins) of the batch's components."""
        cols = self.state.columns()
        have = np.asarray(self.state.n) > 0
        names_c = _columns(self.model)
        values = [np.asarray(self.t0)[have].tolist()] + [
            np.asarray(cols[c])[have].tolist() for c in self.model.state_columns]
        rows = zip([n for n, h in zip(self.names, have, strict=True) if h], *values,
                   strict=True)
        ph = ", ".join("?" * (len(names_c) + 1))
        updates = ", ".join(f"{c} = excluded.{c}" for c in names_c)
        self.conn.executemany(
            f"INSERT INTO model_state (component, {', '.join(names_c)}) VALUES ({ph}) "
            f"ON CONFLICT (component) DO UPDATE SET {updates}", rows)


def model_states(conn: Any, model: FleetModel, names: list[str]) -> Any:
    """The stored model states of ``names`` (the prior for a component without one)."""
    return LearnedPass(conn, model, names).state


__all__ = ["LEVELS", "LearnedPass", "ensure_model_state", "model_axis", "model_states",
           "store_model"]
