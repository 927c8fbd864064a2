"""The settings of a :class:`~rulkit.fleet.store.sqlite.ComponentStore` that are replaced
after it was created (docs/systems/embedded-rul.md §4, §6-7): the learned degradation model
``rulkit fit`` stores, the estimator choice and alert rules, and the tracker settings of a
database without components. Each is replaced in one write transaction, every component's
RUL columns replayed under the new setting where it changes them.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Callable
from contextlib import AbstractContextManager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rulkit.fleet.store.database_file import StoreError
from rulkit.fleet.store.prognosis import replay, write_monitoring

if TYPE_CHECKING:
    from rulkit.fleet.monitoring.rules import MonitoringRules
    from rulkit.fleet.monitoring.unit_trend import TrendConfig
    from rulkit.fleet.tracking.tracker_chain import TrackerConfig


class StoreSettings:
    """The setters of the module docstring, a part of
    :class:`~rulkit.fleet.store.sqlite.ComponentStore`."""

    if TYPE_CHECKING:  # the store's, which this class is a part of
        path: Path
        _conn: sqlite3.Connection
        config: TrackerConfig
        gains: Any
        degradation: Any
        time_axis: Any
        rules: MonitoringRules
        trend: TrendConfig
        _transaction: Callable[..., AbstractContextManager[sqlite3.Connection]]

    def set_degradation_model(self, model: Any) -> int:
        """Store a fitted model (:mod:`rulkit.fleet.learned.candidates`) in one transaction:
        meta ``degradation_model`` and ``time_axis``, the table ``model_state`` for its state
        columns, and every component's model state and RUL columns replayed from its stored
        history (:func:`~rulkit.fleet.store.prognosis.replay`). Returns the number of
        components replayed. Refused (:class:`StoreError`) when the stored history was read on
        another time axis (:meth:`_check_time_axis`), or when the model counts ages from an
        ``installed`` column the stored history does not hold."""
        from rulkit.fleet.store.learned_state import model_axis, store_model

        axis = model_axis(model)
        previous = self.degradation, self.time_axis
        try:
            with self._transaction("IMMEDIATE"):
                self._check_time_axis(axis)
                n_comp = self._conn.execute("SELECT COUNT(*) FROM components").fetchone()[0]
                if n_comp and axis.origin == "installed":
                    raise StoreError(
                        f"{self.path}: the model counts ages from an 'installed' column, which "
                        f"the stored history of {n_comp} components does not hold; fit it into "
                        "a new database")
                store_model(self._conn, model)
                self.degradation, self.time_axis = model, axis
                n = replay(self)
        except BaseException:
            self.degradation, self.time_axis = previous
            raise
        return n

    def set_rules(self, rules: MonitoringRules) -> int:
        """Replace the estimator choice and alert rules in one transaction, every component's
        RUL columns and levels replayed under them (no alert is raised again). Returns the
        number of components replayed."""
        previous = self.rules
        try:
            with self._transaction("IMMEDIATE"):
                write_monitoring(self._conn, rules, self.trend)
                self.rules = rules
                n = replay(self)
        except BaseException:
            self.rules = previous
            raise
        return n

    def _check_time_axis(self, axis: Any) -> None:
        """Inside a transaction: refuse a time axis other than the stored one (or, for a
        database from before time axes were stored, one with date-times) while components
        are stored, since their times were read on the old axis."""
        n = self._conn.execute("SELECT COUNT(*) FROM components").fetchone()[0]
        if n == 0:
            return
        stored = self.time_axis
        if stored is not None and stored != axis:
            raise StoreError(
                f"{self.path}: holds {n} components whose times were read as "
                f"'{stored.describe()}', not '{axis.describe()}'; fit with the same time "
                "column and --time-unit, or into a new database")
        if stored is None and axis.timestamps:
            raise StoreError(
                f"{self.path}: holds {n} components tracked before a time axis was stored "
                "(date-times then became seconds since 1970); a model fitted on date-times in "
                f"{axis.label()} cannot continue them: fit it into a new database")

    def set_tracker_config(self, config: TrackerConfig, axis: Any) -> None:
        """Replace the tracker settings (and store the time axis they were fitted on) of a
        database without components (:class:`StoreError` otherwise: the trackers' state is
        only meaningful with the settings it was run with)."""
        with self._transaction("IMMEDIATE"):
            n = self._conn.execute("SELECT COUNT(*) FROM components").fetchone()[0]
            if n:
                raise StoreError(
                    f"{self.path}: holds {n} components tracked with the stored tracker "
                    "settings, which are fixed once a component is tracked; fit the tracker "
                    "before the first 'rulkit track', or into a new database")
            self._check_time_axis(axis)
            if self.time_axis is not None and self.time_axis != axis:
                raise StoreError(
                    f"{self.path}: its learned model reads time as '{self.time_axis.describe()}'"
                    f", the tracker histories as '{axis.describe()}'; fit both from histories "
                    "with the same time column and --time-unit")
            self._conn.execute("DELETE FROM meta WHERE key IN ('tracker_config', 'time_axis')")
            self._conn.executemany("INSERT INTO meta VALUES (?, ?)", [
                ("tracker_config", json.dumps(config.to_dict())),
                ("time_axis", json.dumps(axis.to_dict()))])
        self.config, self.gains, self.time_axis = config, config.gains(), axis


__all__ = ["StoreSettings"]
