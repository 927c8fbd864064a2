"""Persistent component state in SQLite: tracker state per component, history per acquisition.

embedded-rul.md section 4 (the seed's "component state file" and "HI/RUL file"). One database
file holds

* ``meta``: schema version, the :class:`~rulkit.fleet.tracker_chain.TrackerConfig` (JSON) the
  database was created with and, optionally, the
  :class:`~rulkit.fleet.health_index.HealthIndexModel`
  that maps condition indicators (CIs) to HI;
* ``components``: one row per component with its tracker state (the seed's 7 numbers HI, fHI,
  dHI, RUL, fRUL, dRUL, d2RUL, plus the time of the last acquisition, the number of
  acquisitions, validity, alert level and the confidence limits);
* ``history``: one row per acquisition (same fields), primary key (component, t);
* ``ingests``: one row per committed ingestion (audit).

Guarantees (tested in tests/fleet/test_store.py):

* **Validation first.** A batch is validated completely (columns, NaN/inf, HI range, time
  order per component within the batch and against the stored state) before anything is
  written; a bad batch raises :class:`IngestError` naming the row, component and field, and the
  database stays as it was.
* **Transactional ingestion.** The whole batch is applied in one transaction
  (``BEGIN IMMEDIATE`` ... ``COMMIT``); any exception rolls it back, and a process killed
  mid-transaction leaves the last committed state (SQLite's write-ahead log is replayed or
  discarded on the next open). ``synchronous=FULL`` makes a commit durable.
* **Consistent readers.** The database runs in WAL mode: a reader inside a read transaction
  (:meth:`ComponentStore.snapshot`) sees one committed state, never a half-applied batch,
  while a writer proceeds.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from rulkit.fleet.health_index import HealthIndexModel
from rulkit.fleet.tracker_chain import (
    LEVEL_NAMES,
    TrackerConfig,
    TrackerState,
    tracker_outputs,
    tracker_update,
)
from rulkit.tables import cell_repr as _fmt
from rulkit.tables import numeric_columns, read_table

SCHEMA_VERSION = 1
STATE_FIELDS = ("t", "n", "hi", "fhi", "dhi", "rul", "frul", "drul", "d2rul")
OUTPUT_FIELDS = ("valid", "level", "rul_low", "rul_high")
ROW_FIELDS = (*STATE_FIELDS, *OUTPUT_FIELDS)
HISTORY_FIELDS = tuple(f for f in ROW_FIELDS if f != "n")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS components (
    component TEXT PRIMARY KEY,
    t REAL NOT NULL, n INTEGER NOT NULL, hi REAL NOT NULL, fhi REAL NOT NULL, dhi REAL NOT NULL,
    rul REAL NOT NULL, frul REAL NOT NULL, drul REAL NOT NULL, d2rul REAL NOT NULL,
    valid INTEGER NOT NULL, level INTEGER NOT NULL, rul_low REAL NOT NULL, rul_high REAL NOT NULL,
    max_level INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS history (
    component TEXT NOT NULL, t REAL NOT NULL,
    hi REAL NOT NULL, fhi REAL NOT NULL, dhi REAL NOT NULL,
    rul REAL NOT NULL, frul REAL NOT NULL, drul REAL NOT NULL, d2rul REAL NOT NULL,
    valid INTEGER NOT NULL, level INTEGER NOT NULL, rul_low REAL NOT NULL, rul_high REAL NOT NULL,
    ingest INTEGER NOT NULL,
    PRIMARY KEY (component, t)
) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS ingests (
    id INTEGER PRIMARY KEY, source TEXT NOT NULL, n_rows INTEGER NOT NULL,
    n_components INTEGER NOT NULL
);
"""


class IngestError(ValueError):
    """A batch of acquisitions was rejected; the database is unchanged."""


@dataclass(frozen=True)
class Alert:
    """A new alert: a component reached a level above any it had before (latched).

    A warning whose validity flickers on and off is reported once; the alarm after it once.
    ``previous`` is the highest level the component had reached before.
    """

    component: str
    t: float
    level: int
    previous: int
    hi: float
    fhi: float
    frul: float
    valid: bool
    rul_low: float
    rul_high: float

    @property
    def name(self) -> str:
        return LEVEL_NAMES[self.level]


@dataclass(frozen=True)
class IngestResult:
    """Outcome of a committed ingestion."""

    n_rows: int
    n_components: int
    n_new_components: int
    alerts: list[Alert] = field(default_factory=list)


# --------------------------------------------------------------------------- validation
def read_acquisitions(path: str | Path) -> pd.DataFrame:
    """Read a CSV (``.csv``, ``.csv.gz``, ``.txt``) or Parquet (``.parquet``, ``.pq``)
    acquisition file (``component`` kept as text); file-level problems raise
    :class:`IngestError` (see :func:`rulkit.tables.read_table`)."""
    return read_table(path, error=IngestError, csv_suffixes=(".csv", ".csv.gz", ".txt"),
                      expected_columns=("component", "time", "hi"),
                      csv_dtype={"component": str})


def _numeric_column(df: pd.DataFrame, col: str) -> np.ndarray:
    """``df[col]`` as finite float64; the error names row (1-based), component and column."""
    return numeric_columns(
        df, [col], error=IngestError,
        row_label=lambda i: f"row {i + 1} (component {df['component'].iloc[i]!r})")[col]


def validate_acquisitions(
    df: pd.DataFrame, config: TrackerConfig, hi_model: HealthIndexModel | None
) -> pd.DataFrame:
    """Check a batch and return it as columns ``component`` (str), ``t``, ``hi``, ``row``.

    ``row`` is the 1-based data row (header excluded) used in error messages. Expected columns:
    ``component``, ``time`` and either ``hi`` or exactly the CI columns of the stored
    HI model. Rejected with :class:`IngestError`: an empty batch, missing / unknown / ambiguous
    columns, an empty component name, non-numeric / NaN / infinite values, HI outside
    [0, hi_max], and time not strictly increasing for a component (unsorted or duplicated).
    """
    if len(df) == 0:
        raise IngestError("the batch holds no acquisitions (0 rows)")
    cols = [str(c) for c in df.columns]
    df = df.copy()
    df.columns = cols
    missing = [c for c in ("component", "time") if c not in cols]
    if missing:
        raise IngestError(f"missing required column(s) {missing}; got {cols}")
    ci_names = list(hi_model.names) if hi_model is not None else []
    value_cols = [c for c in cols if c not in ("component", "time")]
    if "hi" in value_cols:
        extra = [c for c in value_cols if c != "hi"]
        if extra:
            raise IngestError(
                f"unknown column(s) {extra}: give either 'hi' or the CI columns, not both"
                if set(extra) & set(ci_names)
                else f"unknown column(s) {extra}; expected component, time and hi"
                + (f" or the CI columns {ci_names}" if ci_names else "")
            )
        mode = "hi"
    elif value_cols:
        if hi_model is None:
            raise IngestError(
                f"unknown column(s) {value_cols}: the database has no HI model, so the batch "
                "must give 'hi' (or store an HI model fitted on healthy CIs first)"
            )
        unknown = [c for c in value_cols if c not in ci_names]
        if unknown:
            raise IngestError(
                f"unknown column(s) {unknown}; expected component, time and hi or the CI "
                f"columns {ci_names}"
            )
        absent = [c for c in ci_names if c not in value_cols]
        if absent:
            raise IngestError(f"missing CI column(s) {absent} of the HI model {ci_names}")
        mode = "ci"
    else:
        raise IngestError("no value column: expected 'hi'" + (
            f" or the CI columns {ci_names}" if ci_names else ""))

    comp = df["component"]
    empty = comp.isna().to_numpy() | (comp.astype(str).str.strip() == "").to_numpy()
    if empty.any():
        i = int(np.flatnonzero(empty)[0])
        raise IngestError(f"row {i + 1}: empty component name")
    df["component"] = comp.astype(str).str.strip()
    t = _numeric_column(df, "time")
    if mode == "hi":
        hi = _numeric_column(df, "hi")
        source = "hi"
    else:
        assert hi_model is not None
        ci = np.column_stack([_numeric_column(df, c) for c in ci_names])
        hi = hi_model.health_index(ci)
        source = "HI computed from the CIs"
    out_of_range = (hi < 0) | (hi > config.hi_max)
    if out_of_range.any():
        i = int(np.flatnonzero(out_of_range)[0])
        raise IngestError(
            f"row {i + 1} (component {df['component'].iloc[i]!r}): {source} = {_fmt(hi[i])} is "
            f"outside [0, {config.hi_max}]"
        )
    out = pd.DataFrame({"component": df["component"].to_numpy(), "t": t, "hi": hi,
                        "row": np.arange(1, len(df) + 1)})
    # time strictly increasing per component, in file order
    prev_t = out.groupby("component", sort=False)["t"].shift(1).to_numpy()
    back = np.isfinite(prev_t) & ~(t > prev_t)
    if back.any():
        i = int(np.flatnonzero(back)[0])
        what = "repeats" if t[i] == prev_t[i] else "goes backwards from"
        raise IngestError(
            f"row {i + 1} (component {out['component'].iloc[i]!r}): time {_fmt(t[i])} {what} the "
            f"previous acquisition of that component at {_fmt(prev_t[i])} (times must be strictly "
            "increasing per component)"
        )
    return out


# --------------------------------------------------------------------------- the store
class ComponentStore:
    """SQLite store of component tracker state and acquisition history (see module docstring).

    ``ComponentStore(path, config=None, hi_model=None)`` opens (creating if needed) the
    database. A new database stores ``config`` (default ``TrackerConfig()``) and ``hi_model``;
    opening an existing one with a different ``config`` or ``hi_model`` raises ``ValueError``
    (the trackers' gains and state are only meaningful with the configuration they were run
    with). ``create=False`` refuses to create a missing database (``FileNotFoundError``).
    Use as a context manager or call :meth:`close`.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        config: TrackerConfig | None = None,
        hi_model: HealthIndexModel | None = None,
        timeout: float = 30.0,
        create: bool = True,
    ) -> None:
        self.path = Path(path)
        if not create and not self.path.exists():
            raise FileNotFoundError(f"{self.path}: no such database")
        self._conn = sqlite3.connect(str(self.path), timeout=timeout, isolation_level=None,
                                     check_same_thread=False)
        try:
            self._conn.execute("PRAGMA journal_mode=WAL")
            self._conn.execute("PRAGMA synchronous=FULL")
            self._conn.execute("PRAGMA foreign_keys=ON")
            meta = self._read_meta()
            if "schema_version" not in meta:
                if not create:
                    raise FileNotFoundError(f"{self.path}: not a rulkit component database")
                with self._transaction():
                    for stmt in _SCHEMA.split(";"):
                        if stmt.strip():
                            self._conn.execute(stmt)
                    meta = dict(self._conn.execute("SELECT key, value FROM meta").fetchall())
                    if "schema_version" not in meta:
                        cfg = config or TrackerConfig()
                        rows = [("schema_version", str(SCHEMA_VERSION)),
                                ("tracker_config", json.dumps(cfg.to_dict()))]
                        if hi_model is not None:
                            rows.append(("hi_model", json.dumps(hi_model.to_dict())))
                        self._conn.executemany("INSERT INTO meta VALUES (?, ?)", rows)
                        meta = dict(rows)
            if int(meta["schema_version"]) != SCHEMA_VERSION:
                raise ValueError(f"{self.path}: schema version {meta['schema_version']}, "
                                 f"this rulkit reads {SCHEMA_VERSION}")
            self.config = TrackerConfig.from_dict(json.loads(meta["tracker_config"]))
            self.hi_model = (HealthIndexModel.from_dict(json.loads(meta["hi_model"]))
                             if "hi_model" in meta else None)
            if config is not None and config != self.config:
                raise ValueError(
                    f"{self.path} was created with tracker config {self.config.to_dict()}; "
                    f"refusing to continue with a different one {config.to_dict()}"
                )
            if hi_model is not None and (
                self.hi_model is None or hi_model.to_dict() != self.hi_model.to_dict()
            ):
                if self.hi_model is not None:
                    raise ValueError(f"{self.path} already holds a different HI model")
                with self._transaction():
                    self._conn.execute("INSERT INTO meta VALUES ('hi_model', ?)",
                                       (json.dumps(hi_model.to_dict()),))
                self.hi_model = hi_model
        except BaseException:
            self._conn.close()
            raise
        self.gains = self.config.gains()

    # -- plumbing
    def _read_meta(self) -> dict[str, str]:
        exists = self._conn.execute(
            "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'meta'").fetchone()
        if not exists:
            return {}
        return dict(self._conn.execute("SELECT key, value FROM meta").fetchall())

    def close(self) -> None:
        self._conn.close()

    def __enter__(self) -> ComponentStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextmanager
    def _transaction(self, mode: str = "IMMEDIATE") -> Iterator[sqlite3.Connection]:
        self._conn.execute(f"BEGIN {mode}")
        try:
            yield self._conn
        except BaseException:
            self._conn.execute("ROLLBACK")
            raise
        else:
            self._conn.execute("COMMIT")

    @contextmanager
    def snapshot(self) -> Iterator[sqlite3.Connection]:
        """A read transaction: every query inside sees the same committed state."""
        with self._transaction("DEFERRED") as conn:
            yield conn

    # -- reading
    def _load_states(self, names: list[str]) -> dict[str, tuple]:
        out: dict[str, tuple] = {}
        cols = ", ".join(("component", *ROW_FIELDS, "max_level"))
        for i in range(0, len(names), 500):
            chunk = names[i : i + 500]
            q = f"SELECT {cols} FROM components WHERE component IN ({','.join('?' * len(chunk))})"
            for row in self._conn.execute(q, chunk):
                out[row[0]] = row[1:]
        return out

    def status(self) -> pd.DataFrame:
        """All components, worst first (alert level, then filtered HI, descending)."""
        with self.snapshot() as conn:
            df = pd.read_sql_query(
                "SELECT component, " + ", ".join(ROW_FIELDS) + " FROM components", conn
            )
        df["valid"] = df["valid"].astype(bool)
        return df.sort_values(["level", "fhi", "component"], ascending=[False, False, True],
                              kind="stable").reset_index(drop=True)

    def history(self, component: str | None = None) -> pd.DataFrame:
        """History rows (all components, or one), ordered by component and time."""
        cols = "component, " + ", ".join(HISTORY_FIELDS) + ", ingest"
        with self.snapshot() as conn:
            if component is None:
                df = pd.read_sql_query(f"SELECT {cols} FROM history ORDER BY component, t", conn)
            else:
                df = pd.read_sql_query(
                    f"SELECT {cols} FROM history WHERE component = ? ORDER BY t", conn,
                    params=(component,),
                )
        df["valid"] = df["valid"].astype(bool)
        return df

    def counts(self) -> tuple[int, int, int]:
        """(components, sum of their acquisition counts, history rows), in one snapshot."""
        with self.snapshot() as conn:
            n_comp, n_sum = conn.execute(
                "SELECT COUNT(*), COALESCE(SUM(n), 0) FROM components").fetchone()
            n_hist = conn.execute("SELECT COUNT(*) FROM history").fetchone()[0]
        return int(n_comp), int(n_sum), int(n_hist)

    # -- writing
    def ingest_file(self, path: str | Path) -> IngestResult:
        """Read a CSV/Parquet batch and :meth:`ingest` it."""
        return self.ingest(read_acquisitions(path), source=str(path))

    def ingest(self, df: pd.DataFrame, source: str = "<dataframe>") -> IngestResult:
        """Validate and apply a batch of acquisitions in one transaction.

        Acquisitions of the same component are applied in time order; all components with a
        k-th acquisition in the batch are updated in one vectorised
        :func:`~rulkit.fleet.tracker_chain.tracker_update` call. Returns the committed result with
        the new alerts (:class:`Alert`). Raises :class:`IngestError` (database unchanged) on
        bad input.
        """
        acq = validate_acquisitions(df, self.config, self.hi_model)
        with self._transaction("IMMEDIATE"):
            return self._apply(acq, source)

    def _apply(self, acq: pd.DataFrame, source: str) -> IngestResult:
        names = list(dict.fromkeys(acq["component"].tolist()))
        stored = self._load_states(names)
        pos = {name: i for i, name in enumerate(names)}
        b = len(names)
        state = TrackerState.empty(b)
        level = np.zeros(b, dtype=np.int8)  # highest level reached so far (latched)
        for name, row in stored.items():
            i = pos[name]
            vals = dict(zip(ROW_FIELDS, row[:-1], strict=True))
            state.t[i], state.n[i], state.hi[i], state.rul[i] = (
                vals["t"], vals["n"], vals["hi"], vals["rul"])
            state.ab[i] = (vals["fhi"], vals["dhi"])
            state.abg[i] = (vals["frul"], vals["drul"], vals["d2rul"])
            level[i] = row[-1]
        comp_idx = acq["component"].map(pos).to_numpy()
        t = acq["t"].to_numpy()
        hi = acq["hi"].to_numpy()
        # first acquisition of each component in this batch must follow its stored last one
        first = ~acq.duplicated("component").to_numpy()
        last_t = state.t[comp_idx]
        back = first & np.isfinite(last_t) & ~(t > last_t)
        if back.any():
            i = int(np.flatnonzero(back)[0])
            raise IngestError(
                f"row {acq['row'].iloc[i]} (component {names[comp_idx[i]]!r}): time "
                f"{_fmt(t[i])} is not after the component's last stored acquisition at "
                f"{_fmt(last_t[i])}"
            )
        rank = acq.groupby("component", sort=False).cumcount().to_numpy()
        ingest_id = self._insert_ingest(source, len(acq), b)
        alerts: list[Alert] = []
        hist_cols: dict[str, list[np.ndarray]] = {f: [] for f in ("component", *HISTORY_FIELDS)}
        names_arr = np.array(names, dtype=object)
        for r in range(int(rank.max()) + 1):
            sel = rank == r
            ci = comp_idx[sel]
            t_r = np.full(b, np.nan)
            h_r = np.full(b, np.nan)
            t_r[ci] = t[sel]
            h_r[ci] = hi[sel]
            state, out = tracker_update(state, t_r, h_r, self.config, self.gains)
            assert out is not None
            cols = {**state.columns(), "valid": out.valid, "level": out.level,
                    "rul_low": out.rul_low, "rul_high": out.rul_high}
            hist_cols["component"].append(names_arr[ci])
            for f in HISTORY_FIELDS:
                hist_cols[f].append(cols[f][ci])
            for i in ci[out.level[ci] > level[ci]]:
                alerts.append(Alert(
                    component=names[i], t=float(state.t[i]), level=int(out.level[i]),
                    previous=int(level[i]), hi=float(state.hi[i]), fhi=float(state.fhi[i]),
                    frul=float(state.frul[i]), valid=bool(out.valid[i]),
                    rul_low=float(out.rul_low[i]), rul_high=float(out.rul_high[i]),
                ))
            level[ci] = np.maximum(level[ci], out.level[ci])
        history = [np.concatenate(hist_cols[f]).tolist() for f in ("component", *HISTORY_FIELDS)]
        history.append([ingest_id] * len(history[0]))
        self._write_history(list(zip(*history, strict=True)))
        out = tracker_outputs(state, self.config)
        final = {**state.columns(), "valid": out.valid, "level": out.level,
                 "rul_low": out.rul_low, "rul_high": out.rul_high}
        rows = [names] + [np.asarray(final[f]).tolist() for f in ROW_FIELDS]
        rows.append(level.tolist())
        self._write_states(list(zip(*rows, strict=True)))
        return IngestResult(n_rows=len(acq), n_components=b,
                            n_new_components=b - len(stored), alerts=alerts)

    def _insert_ingest(self, source: str, n_rows: int, n_components: int) -> int:
        """Record one ingestion (audit row) and return its id (backend hook)."""
        cur = self._conn.execute(
            "INSERT INTO ingests (source, n_rows, n_components) VALUES (?, ?, ?)",
            (source, n_rows, n_components),
        )
        assert cur.lastrowid is not None
        return int(cur.lastrowid)

    def _write_history(self, rows: list[tuple]) -> None:
        cols = ("component", *HISTORY_FIELDS, "ingest")
        self._conn.executemany(
            f"INSERT INTO history ({', '.join(cols)}) VALUES ({', '.join('?' * len(cols))})",
            rows,
        )

    def _write_states(self, rows: list[tuple]) -> None:
        cols = ("component", *ROW_FIELDS, "max_level")
        updates = ", ".join(f"{c} = excluded.{c}" for c in cols[1:])
        self._conn.executemany(
            f"INSERT INTO components ({', '.join(cols)}) VALUES ({', '.join('?' * len(cols))}) "
            f"ON CONFLICT(component) DO UPDATE SET {updates}",
            rows,
        )

    def meta(self) -> dict[str, Any]:
        """The stored configuration (tracker config and HI model as dicts)."""
        return {"tracker_config": self.config.to_dict(),
                "hi_model": self.hi_model.to_dict() if self.hi_model else None}
