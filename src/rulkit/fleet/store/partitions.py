"""``rulkit track`` over a directory of Parquet partitions, serially or on Dask workers.

docs/systems/embedded-rul.md §4; cost model in docs/service.md ("Fleet batch on Dask"). A
component's trackers run in time order, but components are independent: the work splits by
component. :func:`track_directory` without a scheduler reads the whole directory (every
``*.parquet`` / ``*.pq`` file under it, in name order) as one batch and ingests it like a file.
With a scheduler, the component ids (read as the ingestion reads them) are sorted and cut
into ``buckets`` of consecutive ids; a Dask task per partition reads it once and splits its
rows by bucket, and a task per bucket takes its piece of every partition (so no task holds the
whole fleet), runs the store's one ingestion path on a private SQLite database seeded with
those components' stored state (tracker state, learned-model state, the stored history they
overlap, the settings), and returns that database's bytes. The client copies each bucket's new
history rows, states and alerts into one database as the buckets finish, in the order of their
ids (each bucket's rows then append after the previous one's in the tables' key order), then
into the store in one transaction. Every bucket ran exactly the code of the serial run on
exactly its rows, so the stored numbers are the same (tested).
"""

from __future__ import annotations

import json
import sqlite3
import tempfile
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from rulkit.fleet.monitoring.rules import MonitoringRules
from rulkit.fleet.rows import arrow_frame
from rulkit.fleet.store.acquisitions import Alert, IngestError, IngestResult
from rulkit.fleet.store.database_file import creation_path, link_into_place
from rulkit.fleet.store.ingest import ingest_into
from rulkit.fleet.store.schema import (
    COMPONENTS,
    HISTORY,
    MODEL_STATE,
    create_schema,
    model_state_table,
    recount_totals,
)
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.tracking.health_index import HealthIndexModel
from rulkit.fleet.tracking.tracker_chain import TrackerConfig


def partition_files(directory: str | Path) -> list[Path]:
    """The Parquet files under ``directory`` (recursively), in name order; IngestError if
    there are none."""
    d = Path(directory)
    files = sorted(p for p in d.rglob("*") if p.suffix.lower() in (".parquet", ".pq")
                   and p.is_file())
    if not files:
        raise IngestError(f"{d}: no .parquet / .pq files in this directory")
    return files


def read_directory(directory: str | Path, components: list[str] | None = None
                   ) -> pd.DataFrame:
    """The rows of every partition (file order, then row order), optionally only those of
    ``components``; the columns of the first partition."""
    import pyarrow.compute as pc
    import pyarrow.dataset as ds

    files = partition_files(directory)
    try:
        dataset = ds.dataset([str(f) for f in files], format="parquet")
        flt = None if components is None else pc.field("component").isin(components)
        table = dataset.to_table(filter=flt)
    except Exception as err:  # pyarrow raises many kinds on bad partitions
        raise IngestError(f"{directory}: cannot be read as Parquet partitions "
                          f"({type(err).__name__}: {str(err).strip()[:200]})") from None
    return arrow_frame(table)


def bucket_ranges(names: list[str], buckets: int) -> list[list[int]]:
    """The indices of ``names`` (distinct component ids) in code-point order of the ids (the
    store's key order), cut into at most ``buckets`` runs of consecutive ids, as equal in
    size as can be."""
    order = sorted(range(len(names)), key=names.__getitem__)
    n = min(max(buckets, 1), len(order))
    return [part.tolist() for part in np.array_split(np.asarray(order, dtype=np.intp), n)
            if part.size]


def _bucket_filters(files: list[str], buckets: int
                    ) -> tuple[list[list[str]], list[Any], Any]:
    """The components of each bucket (:func:`bucket_ranges` of the ids as the ingestion
    reads them: stripped, numbers as text), per bucket the values of the partitions'
    ``component`` column that are its ids (a pyarrow value set of the column's own type),
    and the partitions' common schema. A refused id raises what the serial run raises,
    naming its row."""
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.dataset as ds

    from rulkit.fleet.rows import component_codes
    from rulkit.fleet.store.acquisitions import ComponentIdError

    try:
        dataset = ds.dataset(files, format="parquet")
        col = dataset.to_table(columns=["component"]).column(0)
        values = pc.unique(col)
    except Exception as err:  # pyarrow raises many kinds on bad partitions
        raise IngestError(f"{files[0]}...: cannot be read as Parquet partitions "
                          f"({type(err).__name__}: {str(err).strip()[:200]})") from None
    if isinstance(values, pa.DictionaryArray):
        values = values.dictionary_decode()
    raw = np.empty(len(values), dtype=object)
    raw[:] = values.to_pylist()
    try:
        codes, names = component_codes(raw, ComponentIdError)
    except ComponentIdError:  # the same refusal with the row the serial run names
        component_codes(col.to_pandas(), ComponentIdError)
        raise
    groups = bucket_ranges(names, buckets)
    bucket_of = np.empty(len(names), dtype=np.intp)
    for b, idx in enumerate(groups):
        bucket_of[idx] = b
    of_value = bucket_of[codes]
    sets = [values.filter(pa.array(of_value == b)) for b in range(len(groups))]
    return [[names[i] for i in idx] for idx in groups], sets, dataset.schema


def _submit(client: Any, files: list[str], schema: Any, value_sets: list[Any],
            seeds: list[dict[str, Any]], now: float) -> list[Any]:
    """The tasks of one run, a future per bucket: each partition read once and split by
    bucket (:func:`_split_file`), then each bucket's pieces ingested (:func:`_run_bucket`)."""
    import operator

    import pyarrow as pa

    values = pa.concat_arrays(value_sets)
    ends = np.cumsum([len(v) for v in value_sets])
    splits = [client.submit(_split_file, f, schema, values, ends, pure=False) for f in files]
    pieces = [[client.submit(operator.getitem, sp, b, pure=False) for sp in splits]
              for b in range(len(value_sets))]
    return [client.submit(_run_bucket, pieces[b], seeds[b], now, pure=False)
            for b in range(len(value_sets))]


def _split_file(file: str, schema: Any, values: Any, ends: np.ndarray) -> list[Any]:
    """On a worker: the rows of one partition (read with the partitions' common ``schema``)
    per bucket, each in the file's row order; bucket ``b``'s ids are ``values[ends[b - 1] :
    ends[b]]``."""
    import pyarrow.compute as pc
    import pyarrow.dataset as ds

    table = ds.dataset(file, format="parquet", schema=schema).to_table()
    where = pc.index_in(table.column("component"), value_set=values).to_numpy(
        zero_copy_only=False)
    bucket = np.searchsorted(ends, where, side="right")  # every row's id is in values
    order = np.argsort(bucket, kind="stable")
    table = table.take(order)
    cuts = np.searchsorted(bucket[order], np.arange(len(ends) + 1))
    return [table.slice(cuts[b], cuts[b + 1] - cuts[b]) for b in range(len(ends))]


def track_directory(db: str | Path, directory: str | Path, *, config: TrackerConfig,
                    hi_model: HealthIndexModel | None = None, scheduler: Any = None,
                    buckets: int = 0, timeout: float = 30.0,
                    rules: MonitoringRules | None = None) -> tuple[IngestResult, bool]:
    """Ingest the partitions under ``directory`` into the SQLite database ``db`` (created if
    missing); ``(result, created)`` as :func:`~rulkit.fleet.store.ingest.ingest_into`.
    ``scheduler``: a Dask scheduler address or ``distributed.Client`` (module docstring);
    ``buckets``: tasks to split the components into (default: 4 per worker). ``rules``: the
    estimator choice and alert rules, as for ``ingest_into`` (rules other than the stored
    ones replace them before the batch; the buckets run under them). Nothing is written (or
    created) when a bucket's rows are refused."""
    source = str(directory)
    if scheduler is None:
        return ingest_into(db, read_directory(directory), config=config, hi_model=hi_model,
                           source=source, timeout=timeout, rules=rules)
    from distributed import Client

    path = Path(db)
    if path.exists():  # the schema (an older history converted) and the rules in force
        ComponentStore(path, config=config, timeout=timeout, rules=rules).close()
    client = scheduler if isinstance(scheduler, Client) else Client(scheduler)
    try:
        files = [str(f) for f in partition_files(directory)]
        n_buckets = buckets or 4 * max(1, len(client.scheduler_info()["workers"]))
        groups, value_sets, schema = _bucket_filters(files, n_buckets)
        seeds = _seeds(path, groups, config, hi_model, timeout, rules)
        now = time.time()  # one calendar time of ingestion for every bucket
        futures = _submit(client, files, schema, value_sets, seeds, now)
        with tempfile.TemporaryDirectory(prefix="rulkit-merge-") as tmp:
            new = not path.exists()
            combined = creation_path(path) if new else Path(tmp) / "all.db"
            try:
                counts = _combine(_in_order(futures), Path(tmp), combined)
                if new:  # the combined buckets become the new database
                    res = _publish(path, combined, counts, seeds[0]["meta"] if seeds else [],
                                   source)
                    if res is not None:
                        return res, True
                    combined = Path(tmp) / "all.db"  # another process created it: merge
                    counts = _combine(_in_order(futures), Path(tmp), combined)
            finally:
                if new:
                    for side in ("", "-wal", "-shm", "-journal"):
                        Path(f"{combined}{side}").unlink(missing_ok=True)
            with ComponentStore(path, config=config, hi_model=hi_model,
                                timeout=timeout) as store:
                return _merge(store, combined, counts, seeds, source), False
    finally:
        if not isinstance(scheduler, Client):
            client.close()


def _in_order(futures: list[Any]) -> Iterator[tuple[bytes, int]]:
    """The futures' results in the futures' order, each taken as soon as it and every one
    before it are done (a later bucket that finishes first waits, its bytes held)."""
    from distributed import as_completed

    index = {f.key: i for i, f in enumerate(futures)}
    ready: dict[int, tuple[bytes, int]] = {}
    nxt = 0
    for fut in as_completed(futures):
        ready[index[fut.key]] = fut.result()
        while nxt in ready:
            yield ready.pop(nxt)
            nxt += 1


def _publish(path: Path, combined: Path, counts: tuple[int, int, int],
             meta: list[tuple[str, str]], source: str) -> IngestResult | None:
    """A new database at ``path`` from the buckets combined in the private file ``combined``
    beside it (:func:`_combine`): the settings and the ingestion's audit row added, then
    linked into place as :func:`~rulkit.fleet.store.ingest.ingest_into` publishes one
    (complete or absent). ``None`` when another process created ``path`` meanwhile (then the
    caller merges)."""
    n_rows, n_comp, n_dup = counts
    conn = sqlite3.connect(str(combined), isolation_level=None)
    try:
        conn.execute("BEGIN")
        conn.executemany("INSERT INTO meta VALUES (?, ?)", meta)
        conn.execute("INSERT INTO ingests (id, source, n_rows, n_components) VALUES "
                     "(1, ?, ?, ?)", (source, n_rows, n_comp))
        alerts = [_alert(r) for r in conn.execute(
            "SELECT id, component, t, level, previous, hi, fhi, rul, rul_low, rul_high, "
            "reason, raised FROM alerts ORDER BY id").fetchall()]
        recount_totals(conn)
        conn.execute("COMMIT")
        conn.execute("PRAGMA journal_mode=WAL")
    finally:
        conn.close()
    if not link_into_place(combined, path):
        return None
    return IngestResult(n_rows=n_rows, n_components=n_comp, n_new_components=n_comp,
                        alerts=sorted(alerts, key=lambda a: (a.t, a.component)),
                        n_duplicates=n_dup)


def _seeds(path: Path, groups: list[list[str]], config: TrackerConfig,
           hi_model: HealthIndexModel | None, timeout: float,
           rules: MonitoringRules | None = None) -> list[dict[str, Any]]:
    """Each bucket's starting point: the settings (``meta``; a new database's rules are
    ``rules``, default ones if ``None``) and, for an existing database, the stored rows of
    its components (states, learned states, history), every column."""
    from rulkit.fleet.monitoring.unit_trend import TrendConfig
    from rulkit.fleet.store.database_file import _meta_rows
    from rulkit.fleet.store.prognosis import monitoring_meta

    empty: dict[str, Any] = {t.name: ([], []) for t in (COMPONENTS, MODEL_STATE, HISTORY)}
    if not path.exists():
        meta = [*_meta_rows(config, hi_model),
                monitoring_meta(rules or MonitoringRules(), TrendConfig())]
        return [{"meta": meta, **empty} for _ in groups]
    with ComponentStore(path, config=config, readonly=True, timeout=timeout) as store:
        meta = store._conn.execute("SELECT key, value FROM meta").fetchall()
        if hi_model is not None and store.hi_model is None:
            meta.append(("hi_model", json.dumps(hi_model.to_dict())))
        return [{"meta": meta, **{t.name: _rows(store._conn, t.name, g)
                                  for t in (COMPONENTS, MODEL_STATE, HISTORY)}}
                for g in groups]


def _columns(conn: Any, table: str, schema: str = "main") -> list[str]:
    return [r[1] for r in conn.execute(f"PRAGMA {schema}.table_info({table})").fetchall()]


def _rows(conn: Any, table: str, names: list[str]) -> tuple[list[str], list[tuple]]:
    """(columns, rows) of ``names`` in ``table``; stored history keeps ingest 0 in a bucket,
    so only the bucket's own rows are copied back."""
    cols = _columns(conn, table)
    if not cols:
        return [], []
    use = ["0" if table == "history" and c == "ingest" else c for c in cols]
    out: list[tuple] = []
    for i in range(0, len(names), 500):
        chunk = names[i:i + 500]
        out += conn.execute(f"SELECT {', '.join(use)} FROM {table} WHERE component IN "
                            f"({','.join('?' * len(chunk))})", chunk).fetchall()
    return cols, out


def _run_bucket(pieces: list[Any], seed: dict[str, Any], now: float) -> tuple[bytes, int]:
    """On a worker: a bucket's rows (its piece of each partition, :func:`_split_file`, in
    partition order) through the one ingestion path, on a private database seeded with
    ``seed``; the database's bytes and the number of rows already stored."""
    import pyarrow as pa

    df = pa.concat_tables(pieces).to_pandas()
    with tempfile.TemporaryDirectory(prefix="rulkit-bucket-") as tmp:
        path = Path(tmp) / "bucket.db"
        _write_seed(path, seed)
        with ComponentStore(path, create=False) as store:
            # a private scratch file, set up as a new database is built (sqlite.py's
            # _build_and_publish): no write-ahead log, no syncs, an 8 MB page cache
            for pragma in ("journal_mode=MEMORY", "synchronous=OFF", "cache_size=-8192"):
                store._conn.execute(f"PRAGMA {pragma}")
            store.now = now
            res = store.ingest(df, "bucket")
        return path.read_bytes(), res.n_duplicates


def _write_seed(path: Path, seed: dict[str, Any]) -> None:
    conn = sqlite3.connect(str(path), isolation_level=None)
    try:
        conn.execute("BEGIN")
        create_schema(conn, "sqlite")
        conn.executemany("INSERT INTO meta VALUES (?, ?)", seed["meta"])
        _model_state_like(conn, seed[MODEL_STATE.name][0])
        for table in (COMPONENTS, MODEL_STATE, HISTORY):
            cols, rows = seed[table.name]
            if rows:
                conn.executemany(f"INSERT INTO {table.name} ({', '.join(cols)}) VALUES "
                                 f"({', '.join('?' * len(cols))})", rows)
        recount_totals(conn)
        conn.execute("COMMIT")
    finally:
        conn.close()


def _model_state_like(conn: Any, cols: list[str]) -> None:
    """Table ``main.model_state`` (still empty) made with the columns ``cols`` of the stored
    model's states (their columns are the model's own: :func:`model_state_table`)."""
    if not cols or _columns(conn, "model_state") == cols:
        return
    conn.execute("DROP TABLE main.model_state")
    for stmt in model_state_table(tuple(cols[1:])).create("sqlite"):
        conn.execute(stmt)


def _copy(conn: Any, table: str, where: str = "", params: tuple = (), *,
          replace: bool = False, skip: tuple[str, ...] = (), set_ingest: bool = False,
          returning: str = "") -> list[tuple]:
    """``INSERT INTO main.table SELECT ... FROM part.table`` over the columns both have."""
    have = set(_columns(conn, table, "main"))
    cols = [c for c in _columns(conn, table, "part") if c in have and c not in skip]
    target = ", ".join(cols + (["ingest"] if set_ingest else []))
    source = ", ".join(cols + (["?"] if set_ingest else []))
    verb = "INSERT OR REPLACE" if replace else "INSERT"
    sql = (f"{verb} INTO main.{table} ({target}) SELECT {source} FROM part.{table} {where}"
           + (f" RETURNING {returning}" if returning else ""))
    return conn.execute(sql, params).fetchall()


def _combine(parts: Iterable[tuple[bytes, int]], tmp: Path, path: Path
             ) -> tuple[int, int, int]:
    """One private database at ``path`` of every bucket's new rows (history of its
    ingestion, final states, learned states, alerts), each bucket copied in as it comes;
    (acquisitions, components, rows already stored)."""
    conn = sqlite3.connect(str(path), isolation_level=None)
    n_rows = n_comp = n_dup = 0
    try:
        conn.execute("PRAGMA journal_mode=OFF")
        conn.execute("PRAGMA synchronous=OFF")
        create_schema(conn, "sqlite")
        for k, (data, dup) in enumerate(parts):
            f = tmp / f"b{k}.db"
            f.write_bytes(data)
            del data
            conn.execute("ATTACH DATABASE ? AS part", (str(f),))
            (bid,) = conn.execute("SELECT MAX(id) FROM part.ingests").fetchone()
            got = conn.execute("SELECT n_rows, n_components FROM part.ingests WHERE id = ?",
                               (bid,)).fetchone()
            n, c = got if got is not None else (0, 0)  # every row already stored
            n_rows, n_comp, n_dup = n_rows + n, n_comp + c, n_dup + dup
            _copy(conn, "history", "WHERE ingest = ?", (1, bid), skip=("ingest",),
                  set_ingest=True)
            _copy(conn, "components")
            _model_state_like(conn, _columns(conn, "model_state", "part"))
            _copy(conn, "model_state")
            _copy(conn, "alerts", "ORDER BY id", skip=("id",))
            conn.execute("DETACH DATABASE part")
            f.unlink()
    finally:
        conn.close()
    return n_rows, n_comp, n_dup


def _merge(store: ComponentStore, combined: Path, counts: tuple[int, int, int],
           seeds: list[dict[str, Any]], source: str) -> IngestResult:
    """Copy the buckets' new rows (combined in ``combined`` by :func:`_combine`) into the
    store in one transaction. Refused (nothing written) when a seeded component changed
    meanwhile (another writer): retry."""
    n_rows, n_comp, n_dup = counts
    conn = store._conn
    conn.execute("ATTACH DATABASE ? AS part", (str(combined),))
    try:
        with store._transaction("IMMEDIATE"):
            _check_unchanged(store, seeds)
            ingest_id = store._insert_ingest(source, n_rows, n_comp)
            alerts = _copy_part(conn, ingest_id)
    finally:
        conn.execute("DETACH DATABASE part")
    n_new = n_comp - sum(len(seed["components"][1]) for seed in seeds)
    return IngestResult(n_rows=n_rows, n_components=n_comp, n_new_components=max(n_new, 0),
                        alerts=sorted(alerts, key=lambda a: (a.t, a.component)),
                        n_duplicates=n_dup)


def _check_unchanged(store: ComponentStore, seeds: list[dict[str, Any]]) -> None:
    """StoreBusyError when a seeded component's stored state changed since it was read."""
    from rulkit.fleet.store.database_file import StoreBusyError

    for seed in seeds:
        cols, rows = seed["components"]
        for row in rows:
            now = store._conn.execute("SELECT t FROM components WHERE component = ?",
                                      (row[0],)).fetchone()
            if now is None or now[0] != row[cols.index("t")]:
                raise StoreBusyError(f"{store.path}: component {row[0]!r} changed while the "
                                     "partitions were tracked; nothing was written, retry")


def _copy_part(conn: sqlite3.Connection, ingest_id: int) -> list[Alert]:
    """Inside the caller's transaction: the attached ``part``'s rows into the store."""
    _copy(conn, "history", "", (ingest_id,), skip=("ingest",), set_ingest=True)
    _copy(conn, "components", replace=True)
    _copy(conn, "model_state", replace=True)
    recount_totals(conn)
    return [_alert(r) for r in _copy(
        conn, "alerts", "ORDER BY id", skip=("id",),
        returning="id, component, t, level, previous, hi, fhi, rul, rul_low, rul_high, "
                  "reason, raised")]


def _alert(row: tuple) -> Alert:
    aid, comp, t, level, prev, hi, fhi, rul, low, high, reason, raised = row
    nan = float("nan")
    return Alert(component=comp, t=t, level=int(level), previous=int(prev),
                 hi=nan if hi is None else hi, fhi=nan if fhi is None else fhi,
                 rul=nan if rul is None else rul, rul_low=nan if low is None else low,
                 rul_high=nan if high is None else high, reason=reason or "",
                 id=int(aid), raised=raised)


