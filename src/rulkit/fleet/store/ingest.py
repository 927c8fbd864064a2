"""A rulkit database by its path: commit a batch into it, creating it when missing, and read
its settings and rules without opening it for writing (docs/systems/embedded-rul.md §4).

Creation is atomic and a rejected batch creates nothing (:mod:`rulkit.fleet.store.sqlite`).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from rulkit.fleet.monitoring.rules import MonitoringRules
from rulkit.fleet.store.acquisitions import IngestResult, validate_acquisitions
from rulkit.fleet.store.database_file import StoreError, _config_from_meta, _probe
from rulkit.fleet.store.sqlite import ComponentStore, _build_and_publish
from rulkit.fleet.tracking.health_index import HealthIndexModel
from rulkit.fleet.tracking.tracker_chain import TrackerConfig

if TYPE_CHECKING:
    import pandas as pd

    from rulkit.fleet.store.acquisitions import Columns


def read_settings(path: str | Path) -> tuple[TrackerConfig, HealthIndexModel | None] | None:
    """The stored tracker settings and HI model of the database at ``path`` (read-only), or
    ``None`` if there is no file; a file that is not a rulkit database raises
    :class:`StoreError`."""
    path = Path(path)
    meta = _probe(path)
    return None if meta is None else _config_from_meta(path, meta)


def read_rules(path: str | Path) -> MonitoringRules | None:
    """The stored monitoring rules of the database at ``path`` (read-only), or ``None`` if
    there is no file (:class:`StoreError` for a file that is not a rulkit database)."""
    path = Path(path)
    if _probe(path) is None:
        return None
    with ComponentStore(path, readonly=True) as store:  # sees the write-ahead log
        return store.rules


def ingest_into(
    path: str | Path,
    df: pd.DataFrame | Columns,
    *,
    config: TrackerConfig | None = None,
    hi_model: HealthIndexModel | None = None,
    source: str = "<dataframe>",
    timeout: float = 30.0,
    rules: MonitoringRules | None = None,
) -> tuple[IngestResult, bool]:
    """Validate ``df`` and commit it to the database at ``path``, creating it if missing.

    Returns ``(result, created)``. Nothing is created or written when the batch is rejected
    (:class:`IngestError`), and a new database appears complete with its first batch or not at all,
    also when several processes create it at once (:mod:`rulkit.fleet.store.sqlite`). ``config``:
    the tracker settings of a new database (default ``TrackerConfig()``); for an existing one it
    must equal the stored settings if given (else :class:`StoreError`). ``hi_model``: the CI -> HI
    model; stored with the batch, in the same transaction, into a database without one; a database
    holding a different one raises :class:`StoreError`. ``rules``: the estimator choice and alert
    rules (:class:`~rulkit.fleet.monitoring.rules.MonitoringRules`; default ones for a new
    database); rules other than the stored ones replace them before the batch
    (:meth:`ComponentStore.set_rules`).
    """
    path = Path(path)
    for _attempt in range(2):
        meta = _probe(path, timeout)
        if meta is None:
            cfg = config or TrackerConfig()
            acq = validate_acquisitions(df, cfg, hi_model)
            res = _build_and_publish(path, cfg, hi_model, acq, source, rules)
            if res is not None:
                return res, True
            continue  # another process created it first: apply the batch to theirs
        # the settings checks and the HI model come from the store's own connection
        with ComponentStore(path, config=config, create=False, timeout=timeout) as store:
            stored_model = store.hi_model
            if hi_model is not None and stored_model is not None and (
                    hi_model.to_dict() != stored_model.to_dict()):
                raise StoreError(f"{path} already holds a different HI model")
            acq = validate_acquisitions(df, store.config, stored_model or hi_model,
                                        store.time_axis)
            new_model = hi_model if stored_model is None else None
            if rules is not None and rules != store.rules:
                store.set_rules(rules)
            return store._ingest_validated(acq, source, new_model=new_model), False
    raise AssertionError("unreachable: the database exists after a lost creation race")


__all__ = ["ingest_into", "read_rules", "read_settings"]
