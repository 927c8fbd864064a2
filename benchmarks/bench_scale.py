"""Benchmark: ``rulkit track`` and ``rulkit status`` at fleet scale (issue 13, "Scale").

Each figure is one ``rulkit`` process (the console script, as a user runs it), measured from
outside: wall time, CPU time (user + system, from ``os.wait4``) and peak resident memory of
that process (``ru_maxrss``). On a shared machine the wall time mostly measures waiting for a
core, so the CPU time is printed beside it; medians over ``--repeats``.

* ``track``: a new database from one CSV of ``--components`` x ``--acquisitions`` rows
  (default 2000 x 1000 = 2M rows; HI growing exponentially with noise, rows in time order as
  a feed delivers them). Goal: <= 2 s and <= 250 MB. Beside it, in the same run, the floor of
  its writes: the same rows read by pyarrow and written bare as the same packed history rows;
  with ``--against SRC``, another checkout's ``track`` (e.g. main's ``src/``) in turns, and
  the databases of the last two runs compared table by table (:func:`same_tables`).
* ``status --format table|csv|json`` on a database of ``--status-components`` components
  (default 10^5; ``--status-fleet flat``: 3 acquisitions each, no RUL estimated yet;
  ``growing``: 12 each, every running unit with its own RUL), output to /dev/null. Goal:
  < 1 s for 10^5 (was 8.6 s for 10^4 with the rich table). ``--mmap``: the SQL read of
  status alone with and without SQLite's memory map, the page cache warm and cold.
* the measured processes read compiled bytecode, as an installed package does (written by
  an untimed first run under ``PYTHONPYCACHEPREFIX``, whatever ``PYTHONDONTWRITEBYTECODE``
  says).
* the interpreter start with ``import rulkit.cli`` and the fleet store, the floors under
  ``track`` (its libraries without and with numba's compiled passes), and the floor under
  ``status``: the same command on a database of one component (start-up, typer's option
  parsing with its pydantic adapters, the database opened, the format's libraries).

    .venv/bin/python benchmarks/bench_scale.py              # the defaults above (~2 min)
    .venv/bin/python benchmarks/bench_scale.py --components 200 --repeats 1   # quick look
    git archive main src | tar -x -C /tmp/main     # track and status against main's code, in turns:
    .venv/bin/python benchmarks/bench_scale.py --against /tmp/main/src --repeats 5
    .venv/bin/python benchmarks/bench_scale.py --status-only --status-fleet growing --mmap
    .venv/bin/python benchmarks/bench_scale.py --track-only --against /tmp/main/src
"""

from __future__ import annotations

import argparse
import itertools
import os
import shutil
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

# The peak resident memory of the measured process itself: its VmHWM (Linux) written at exit.
# ru_maxrss from wait4 is not it: a child started by vfork + exec inherits the high-water mark
# of the parent's memory (this benchmark holds the 10^5-component frame it ingested).
_PEAK = ("import atexit, os\n"
         "def _peak():\n"
         "    with open('/proc/self/status') as f, open(os.environ['BENCH_PEAK'], 'w') as o:\n"
         "        o.write(next(l.split()[1] for l in f if l.startswith('VmHWM:')))\n"
         "if os.path.exists('/proc/self/status'): atexit.register(_peak)\n")
# the console script's entry point, in this interpreter
RULKIT = [sys.executable, "-c", _PEAK + "import sys; sys.argv[0] = 'rulkit'\n"
          "from rulkit.cli import main; main()"]


# The floor under track's writes: the same CSV read the same way (pyarrow in blocks of 4 MB,
# the component ids dictionary-encoded, Arrow's unused memory released), its rows sorted by
# (component, time) with one argsort of the codes and written as the packed history rows the
# store writes (one per component, rulkit.fleet.store.history_chunks: records of the same
# width, t and HI in every field) in blocks of the store's size, one transaction, the new
# database's pragmas, one fsync; no validation, no tracker, no pandas, no numba. What the bare
# writes of the same rows cost on this machine.
_BARE = _PEAK + """
import os, sqlite3, sys
import numpy as np, pyarrow as pa, pyarrow.csv as pc
from rulkit.fleet.store import history_chunks as hc
from rulkit.fleet.store.schema import create_schema
src, db = sys.argv[1], sys.argv[2]
text = pa.dictionary(pa.int32(), pa.string())
reader = pc.open_csv(src, convert_options=pc.ConvertOptions(column_types={"component": text}),
                     read_options=pc.ReadOptions(block_size=1 << 22))  # as rulkit.fleet.rows
tab = pa.Table.from_batches(list(reader), schema=reader.schema).unify_dictionaries()
comp = tab.column("component").chunks  # one dictionary for all chunks
names = np.asarray(comp[0].dictionary.to_pylist(), dtype=object)
key = np.argsort(names, kind="stable")  # the names in SQLite's key order
rank = np.empty(key.size, dtype=np.int32)
rank[key] = np.arange(key.size, dtype=np.int32)
codes = rank[np.concatenate([c.indices.to_numpy() for c in comp])]
names = names[key]
order = np.argsort(codes, kind="stable")
t = tab.column("time").to_numpy()[order]
hi = tab.column("hi").to_numpy()[order]
seg = np.concatenate([[0], np.cumsum(np.bincount(codes, minlength=len(names)))])
del tab, comp, codes, order
pa.default_memory_pool().release_unused()
conn = sqlite3.connect(db, isolation_level=None)
conn.execute("PRAGMA journal_mode=MEMORY")
conn.execute("PRAGMA synchronous=OFF")
conn.execute("PRAGMA cache_size=-8192")
conn.execute("BEGIN")
create_schema(conn, "sqlite")
k0 = 0
while k0 < len(names):  # blocks of whole components, at most the store's block of rows
    k1 = max(k0 + 1, int(np.searchsorted(seg, seg[k0] + BLOCK, side="right")) - 1)
    a, b = seg[k0], seg[k1]
    rec = np.empty((b - a, hc.WIDTH))
    rec[:] = hi[a:b, None]
    rec[:, 0] = t[a:b]
    hc.write_chunks(conn, hc.chunk_rows(names[k0:k1], seg[k0:k1 + 1] - a, rec, 1))
    k0 = k1
conn.execute("COMMIT")
conn.close()
fd = os.open(db, os.O_RDWR); os.fsync(fd); os.close(fd)
""".replace("BLOCK", "25_000")


# The floor of track's libraries, before any row: rulkit's CLI and store (numpy, pyarrow;
# no pandas on a plain CSV) and the two compiled passes a long series takes (the trackers'
# and the trend's, numba loading them from its on-disk cache; numba imports scipy.linalg for
# its BLAS check). _LIBS_NO_JIT: the same without numba.
_LIBS_NO_JIT = _PEAK + """
import numpy as np
import rulkit.cli, rulkit.fleet.store.ingest, pyarrow.csv
"""
_LIBS = _LIBS_NO_JIT + """
from rulkit.fleet.monitoring.unit_trend import TrendConfig, TrendState, trend_run
from rulkit.fleet.tracking.tracker_chain import TrackerConfig, TrackerState
from rulkit.fleet.tracking.tracker_run import tracker_run
seg, t, hi = np.array([0, 3]), np.arange(3.0), np.array([0.1, 0.2, 0.3])
tracker_run(TrackerState.empty(1), seg, t, hi, TrackerConfig(), strategy="jit")
trend_run(TrendState.empty(1), seg, t, hi, TrendConfig(), strategy="jit")
"""


# The SQL read of ``rulkit status`` alone (rulkit.fleet.store.status_view.read_status: a
# read-only connection, one read transaction, the stored columns fetched), with SQLite's
# mmap_size from argv, after evicting the file's pages from the page cache when asked
# (posix_fadvise DONTNEED: the next read comes from the disk). Prints "wall_s cpu_s".
_MMAP_READ = """
import os, sqlite3, sys, time
from rulkit.fleet.store.status_view import STORED_COLUMNS
db, mmap_size, cold = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "cold"
if cold:
    fd = os.open(db, os.O_RDONLY)
    os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
    os.close(fd)
w0, c0 = time.perf_counter(), time.process_time()
conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True, isolation_level=None)
conn.execute(f"PRAGMA mmap_size = {mmap_size}")
conn.execute("BEGIN DEFERRED")
rows = conn.execute(f"SELECT {', '.join(STORED_COLUMNS)} FROM components").fetchall()
conn.execute("COMMIT")
conn.close()
print(time.perf_counter() - w0, time.process_time() - c0)
"""


def mmap_part(sdb: Path, repeats: int) -> None:
    """The SQL read of ``status`` with and without SQLite's memory map (mmap_size 1 GB or
    0), warm (the file in the page cache) and cold (evicted first), in turns."""
    sides = {(m, state): [] for state in ("warm", "cold") for m in (0, 1 << 30)}
    for _ in range(max(repeats, 5)):
        for (m, state), got in sides.items():
            out = subprocess.run([sys.executable, "-c", _MMAP_READ, str(sdb), str(m), state],
                                 capture_output=True, text=True, check=True).stdout.split()
            got.append((float(out[0]), float(out[1])))
    for (m, state), got in sides.items():
        print(f"  status's SQL read, mmap_size {m:>10}, {state}: wall "
              f"{1000 * statistics.median(g[0] for g in got):.0f} ms, CPU "
              f"{1000 * statistics.median(g[1] for g in got):.0f} ms")
    print(f"  load average {os.getloadavg()[0]:.1f}")


def measure(cmd: list[str], env: dict[str, str] | None = None) -> tuple[float, float, float]:
    """(wall s, CPU s, peak RSS MB) of one process running ``cmd`` (stdout discarded), with
    ``env`` added to the environment."""
    fd, peak_file = tempfile.mkstemp(prefix="rulkit-bench-peak-")
    os.close(fd)
    t0 = time.perf_counter()
    try:
        with open(os.devnull, "wb") as null:
            proc = subprocess.Popen(cmd, stdout=null, stderr=subprocess.PIPE,
                                    env={**os.environ, **(env or {}), "BENCH_PEAK": peak_file})
            _, status, ru = os.wait4(proc.pid, 0)
            wall = time.perf_counter() - t0
            err = proc.stderr.read().decode() if proc.stderr else ""
        if os.waitstatus_to_exitcode(status) != 0:
            raise RuntimeError(f"{' '.join(cmd)} failed: {err}")
        text = Path(peak_file).read_text().strip()
        peak = int(text) / 1024.0 if text else ru.ru_maxrss / 1024.0  # VmHWM is in kB
    finally:
        os.unlink(peak_file)
    return wall, ru.ru_utime + ru.ru_stime, peak


def median3(rows: list[tuple[float, float, float]]) -> tuple[float, float, float]:
    return tuple(statistics.median(r[i] for r in rows) for i in range(3))  # type: ignore[return-value]


def warm_median(cmd: list[str], repeats: int, env: dict[str, str] | None = None
                ) -> tuple[float, float, float]:
    """:func:`median3` of ``repeats`` runs of ``cmd`` (with ``env`` added) after an untimed
    one (bytecode written)."""
    measure(cmd, env)
    return median3([measure(cmd, env) for _ in range(repeats)])


def fleet_csv(path: Path, n_comp: int, n_acq: int, rng: np.random.Generator) -> None:
    t = np.arange(n_acq, dtype=np.float64)
    h0 = rng.uniform(0.05, 0.3, n_comp)
    names = np.array([f"unit-{i:06d}" for i in range(n_comp)], dtype=object)
    # time-major order: all components' k-th acquisition, then the (k+1)-th
    comp = np.tile(names, n_acq)
    tt = np.repeat(t, n_comp)
    hi = np.clip(np.tile(h0, n_acq) * np.exp(0.002 * tt)
                 + rng.normal(0.0, 0.005, n_comp * n_acq), 0.0, 10.0)
    pd.DataFrame({"component": comp, "time": tt, "hi": hi}).to_csv(path, index=False)


STATUS_FLEETS = {
    "flat": "3 acquisitions each at times 0, 1, 2, a constant HI: no RUL estimated yet, "
            "the units at HI >= 1 failed",
    "growing": "12 acquisitions each, 10 apart from a start drawn in [0, 1000), HI growing "
               "exponentially with multiplicative noise: every running unit has its own RUL "
               "median and interval, about half have failed"}


def status_fleet(kind: str, n: int, rng: np.random.Generator) -> pd.DataFrame:
    """The acquisitions of the ``status`` database (:data:`STATUS_FLEETS`), in time order."""
    if kind == "flat":
        return pd.DataFrame({"component": np.repeat([f"c{i:07d}" for i in range(n)], 3),
                             "time": np.tile([0.0, 1.0, 2.0], n),
                             "hi": np.repeat(rng.uniform(0.05, 1.2, n), 3)})
    steps = np.arange(12) * 10.0
    t = rng.integers(0, 1000, n).astype(np.float64)[:, None] + steps
    hi = (rng.uniform(0.05, 0.6, n)[:, None] * np.exp(rng.uniform(0.002, 0.02, n)[:, None]
                                                      * steps)
          * np.exp(rng.normal(0.0, 0.02, (n, steps.size))))
    order = np.argsort(t.ravel(), kind="stable")
    return pd.DataFrame({"component": np.repeat([f"c{i:07d}" for i in range(n)],
                                                steps.size)[order],
                         "time": t.ravel()[order], "hi": hi.ravel()[order]})


def track_part(args: argparse.Namespace, tmp: Path, rng: np.random.Generator) -> None:
    """``track`` of the CSV into a new database, beside the bare writes of the same rows; with
    ``--against SRC``, the same command with another checkout's code, in turns."""
    n_rows = args.components * args.acquisitions
    src = tmp / "acquisitions.csv"
    fleet_csv(src, args.components, args.acquisitions, rng)
    size_mb = src.stat().st_size / 2**20
    runs, other = [], []
    for k in range(args.repeats):
        db = tmp / f"track{k}.db"
        runs.append(measure([*RULKIT, "track", "--db", str(db), str(src)]))
        if args.against is not None:  # in turns: the same load for both
            theirs = tmp / f"against{k}.db"
            other.append(measure([*RULKIT, "track", "--db", str(theirs), str(src)],
                                 {"PYTHONPATH": str(args.against.resolve())}))
            if k == args.repeats - 1:
                print(f"the databases of the last runs: {same_tables(db, theirs)}")
            theirs.unlink()
        db.unlink()
    if other:
        ow, oc, om = median3(other)
        print(f"track with {args.against}: wall {ow:.2f} s, CPU {oc:.2f} s, peak {om:.0f} MB")
    w, c, m = median3(runs)
    print(f"track {n_rows:,} rows ({args.components} components x {args.acquisitions}, "
          f"CSV {size_mb:.0f} MB) into a new database: wall {w:.2f} s, CPU {c:.2f} s, "
          f"peak {m:.0f} MB ({m / size_mb:.1f}x the file); goal <= 2 s, <= 250 MB")
    bare = []
    for k in range(args.repeats):
        db = tmp / f"bare{k}.db"
        bare.append(measure([sys.executable, "-c", _BARE, str(src), str(db)]))
        db.unlink()
    bw, bc, bm = median3(bare)
    print(f"  the same rows read and written bare (pyarrow, sort, packed history rows, "
          f"no validation, no tracker, no pandas, no numba): wall {bw:.2f} s, CPU {bc:.2f} s, "
          f"peak {bm:.0f} MB; "
          f"track / bare CPU = {c / bc:.2f}"
          + (f"; track CPU ours / {args.against} = {c / oc:.2f}" if other else "")
          + f"; load average {os.getloadavg()[0]:.1f}")
    src.unlink()


CLOCK_COLUMNS = {"components": ("seen", "due"), "alerts": ("raised",)}
"""Columns that hold the clock at the ingestion (the runs differ by their start)."""


def same_tables(a: Path, b: Path) -> str:
    """Whether the databases ``a`` and ``b`` hold the same tables, row by row in rowid order
    (rowids included), every value of the same type and, for a float, the same bits, every
    blob byte for byte (:data:`CLOCK_COLUMNS` apart); the first difference otherwise."""
    import struct

    def cell(v: object) -> object:
        return ("f", struct.pack("<d", v)) if isinstance(v, float) else (type(v).__name__, v)

    ca, cb = sqlite3.connect(a), sqlite3.connect(b)
    try:
        tables = [t for (t,) in ca.execute(
            "SELECT name FROM sqlite_master WHERE type = 'table' ORDER BY name")]
        if tables != [t for (t,) in cb.execute(
                "SELECT name FROM sqlite_master WHERE type = 'table' ORDER BY name")]:
            return "different tables"
        rows = 0
        for t in tables:
            cols = [c for (c,) in ca.execute(f"SELECT name FROM pragma_table_info('{t}')")
                    if c not in CLOCK_COLUMNS.get(t, ())]
            q = f"SELECT rowid, {', '.join(cols)} FROM {t} ORDER BY rowid"
            for ra, rb in itertools.zip_longest(ca.execute(q), cb.execute(q)):
                if ra is None or rb is None or [cell(v) for v in ra] != [cell(v) for v in rb]:
                    return f"table {t} differs at rowid {(ra or rb)[0]}"
                rows += 1
        return (f"the same {rows:,} rows in {len(tables)} tables (every value's type and "
                f"bits, the blobs byte for byte; {CLOCK_COLUMNS} apart)")
    finally:
        ca.close()
        cb.close()


def status_part(args: argparse.Namespace, tmp: Path, rng: np.random.Generator) -> None:
    """``status`` in each format on a database of ``--status-components`` components; with
    ``--against SRC``, the same commands with ``PYTHONPATH=SRC`` (another checkout's code)
    measured in turns with ours, and the ratio of the CPU medians."""
    n = args.status_components
    sdb = tmp / "status.db"
    from rulkit.fleet.store.ingest import ingest_into

    ingest_into(sdb, status_fleet(args.status_fleet, n, rng))
    print(f"status database: {n:,} components, the {args.status_fleet} fleet "
          f"({STATUS_FLEETS[args.status_fleet]})")
    sides = {"": None} if args.against is None else {
        "this code": None, f"{args.against}": {"PYTHONPATH": str(args.against)}}
    one = tmp / "one.db"  # the floor: start-up, options, the database opened, the format's code
    ingest_into(one, status_fleet(args.status_fleet, 1, rng))
    floor = {(side, fmt): warm_median([*RULKIT, "status", "--db", str(one), "--format", fmt],
                                      args.repeats, env)[1]
             for side, env in sides.items() for fmt in ("table", "csv", "json")}
    for side in sides:
        print(f"status of 1 component{f' ({side})' if side else ''}, its floor (start-up, "
              "option parsing, the database opened, the format's libraries), CPU: "
              + ", ".join(f"{fmt} {floor[side, fmt]:.2f} s" for fmt in ("table", "csv", "json")))
    for fmt in ("table", "csv", "json"):
        cmd = [*RULKIT, "status", "--db", str(sdb), "--format", fmt]
        runs: dict[str, list[tuple[float, float, float]]] = {k: [] for k in sides}
        for env in sides.values():  # untimed: bytecode written, pages cached
            measure(cmd, env)
        for _ in range(args.repeats):  # in turns
            for side, env in sides.items():
                runs[side].append(measure(cmd, env))
        cpu = {}
        for side in sides:
            w, c, m = median3(runs[side])
            cpu[side] = c
            print(f"status --format {fmt:5s} {n:,} components{f' ({side})' if side else ''}: "
                  f"wall {w:.2f} s, CPU {c:.2f} s (minus its floor "
                  f"{c - floor[side, fmt]:.2f} s), peak {m:.0f} MB; goal < 1 s")
        if args.against is not None:
            mine, theirs = cpu.values()
            print(f"  CPU ratio this code / {args.against}: {mine / theirs:.2f}; load average "
                  f"{os.getloadavg()[0]:.1f}")
    if args.mmap:
        mmap_part(sdb, args.repeats)


def measured_environment(tmp: Path) -> None:
    """The environment of the measured processes (this one's, which they inherit): they read
    compiled bytecode as an installed package does (pip writes it at install), written by
    each command's untimed first run and kept apart from the trees; and their BLAS libraries
    start with one thread, as every rulkit command's root option (``--blas-threads 1``) has
    them start before the command imports numpy (a process importing numpy without it starts
    OpenBLAS's threads, whose spinning adds about 0.1 s of CPU to the floors)."""
    from rulkit.cli import limit_blas_threads

    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    os.environ["PYTHONPYCACHEPREFIX"] = str(tmp / "bytecode")
    limit_blas_threads(1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--components", type=int, default=2000)
    ap.add_argument("--acquisitions", type=int, default=1000)
    ap.add_argument("--status-components", type=int, default=100_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--status-only", action="store_true", help="skip track and its floor")
    ap.add_argument("--track-only", action="store_true", help="skip status")
    ap.add_argument("--status-fleet", choices=sorted(STATUS_FLEETS), default="flat",
                    help="the status database's acquisitions (flat: no RUL estimated yet)")
    ap.add_argument("--mmap", action="store_true",
                    help="also status's SQL read with and without SQLite's mmap, warm and cold")
    ap.add_argument("--against", type=Path, default=None,
                    help="the src/ of another checkout: track and status with its code, in turns")
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    tmp = Path(tempfile.mkdtemp(prefix="rulkit-bench-scale-"))
    measured_environment(tmp)
    try:
        print(f"rulkit bench_scale: {os.cpu_count()} cores, load average "
              f"{os.getloadavg()[0]:.1f}, seed {args.seed}, medians of {args.repeats} runs "
              f"(bytecode cached)")
        floor = warm_median([sys.executable, "-c",
                             _PEAK + "import rulkit.cli, rulkit.fleet.store.sqlite"],
                            args.repeats)
        print(f"import rulkit.cli, rulkit.fleet.store.sqlite (start-up floor): "
              f"wall {floor[0]:.2f} s, CPU {floor[1]:.2f} s, peak {floor[2]:.0f} MB")

        if not args.status_only:
            bare_libs = warm_median([sys.executable, "-c", _LIBS_NO_JIT], args.repeats)
            print(f"track's libraries without numba (numpy, pyarrow, the store), no data: "
                  f"wall {bare_libs[0]:.2f} s, CPU {bare_libs[1]:.2f} s, peak "
                  f"{bare_libs[2]:.0f} MB")
            libs = warm_median([sys.executable, "-c", _LIBS], args.repeats)
            print(f"track's libraries and numba's compiled passes loaded, no data (the floor "
                  f"of its start-up): wall {libs[0]:.2f} s, CPU {libs[1]:.2f} s, peak "
                  f"{libs[2]:.0f} MB")
            track_part(args, tmp, rng)
        if not args.track_only:
            status_part(args, tmp, rng)
        print(f"load average at end {os.getloadavg()[0]:.1f}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
