"""Where ``rulkit track`` of one file into a new database spends its CPU and its memory
(docs/service-load.md, "Where the goals stand"): one ``rulkit track`` process, as bench_scale.py
runs it, with each stage's function wrapped to add up its CPU time and to read the
process's resident memory (``/proc/self/status``) as the stage ends.

Prints, per stage, the CPU time, the wall time (a stage whose wall exceeds its CPU waited:
for the disk, another thread or a core), the resident memory at its end (``VmRSS``) and the highest
resident memory of the process so far (``VmHWM``, Linux's high-water mark) at its end: the
stage where the high-water mark rises is where the peak is made. Nested stages are indented
under the stage that calls them. The first call of the trackers and of the trend pass is
printed apart: it loads numba and its cached machine code (more memory than numpy and
pyarrow together). At the end, the share of the peak that is shared libraries' code
(``RssFile``: numpy, pyarrow, numba's LLVM; pandas when the input needs it), against the
process's own data (``RssAnon``). The child reads cached bytecode and starts BLAS with one
thread (``bench_scale.measured_environment``); it imports the store before the command's root
option runs, which then caps the loaded BLAS through threadpoolctl (a few ms in "the command
otherwise" that ``rulkit track`` itself does not spend).

    .venv/bin/python benchmarks/profile_track.py                      # 2000 x 1000 rows
    .venv/bin/python benchmarks/profile_track.py --components 200     # a quick look
    .venv/bin/python benchmarks/profile_track.py --against /tmp/main/src  # main's code
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from timing import stage_depth

WORKER = "stage's worker: "
"""The label's start of a stage the history stage's worker thread runs."""
STAGES = (
    ("inputs (settings, the file)", "rulkit.fleet.store.cli", "_track_inputs"),
    ("  read the file", "rulkit.fleet.store.acquisitions", "read_acquisitions"),
    ("validation", "rulkit.fleet.store.ingest", "validate_acquisitions"),
    ("new database", "rulkit.fleet.store.ingest", "_build_and_publish"),
    ("  apply", "rulkit.fleet.store.sqlite.ComponentStore", "_apply"),
    ("    order by component", "rulkit.fleet.store.sqlite", "order_by_component"),
    ("    spacing check", "rulkit.fleet.store.sqlite", "check_spacing"),
    ("    trackers", "rulkit.fleet.store.sqlite", "tracker_run"),
    ("    estimator and rules", "rulkit.fleet.store.prognosis.BatchPrognosis", "block"),
    ("      trend pass", "rulkit.fleet.store.prognosis", "trend_run"),
    ("      RUL quantiles", "rulkit.fleet.store.prognosis", "rul_quantiles"),
    ("      alert rules", "rulkit.fleet.store.prognosis", "apply_rules"),
    ("    alerts", "rulkit.fleet.store.sqlite", "block_alerts"),
    ("    history staged (rank windows)", "rulkit.fleet.store.history_stage.HistoryStage",
     "add"),
    ("    history blocks handed over", "rulkit.fleet.store.history_stage.HistoryStage",
     "blocks"),
    ("    history rows built", "rulkit.fleet.store.history_chunks.Chunks", "rows"),
    ("    SQLite inserts", "rulkit.fleet.store.sqlite.ComponentStore", "_write_history"),
    ("    final columns", "rulkit.fleet.store.prognosis.BatchPrognosis", "finish"),
    ("    components upsert", "rulkit.fleet.store.sqlite.ComponentStore", "_write_states"),
    ("  alerts recorded", "rulkit.fleet.store.sqlite.ComponentStore", "_record_alerts"),
    ("printout", "rulkit.fleet.store.cli", "_echo_track"),
    (f"{WORKER}records made, written", "rulkit.fleet.store.history_stage",
     "_write_at"),
    (f"{WORKER}blocks read back", "rulkit.fleet.store.history_stage.HistoryStage",
     "_chunks"),
)
"""(label, where the name is looked up, name): the stages measured. The stages from "new
database" on are timed with the CPU clock of the thread that runs them (work another thread
does beside them is not theirs; the history stage's worker thread, which makes and writes a
window's records while the next window is computed and reads the next block back while
SQLite inserts this one, is timed apart); the others with the process's."""
THREAD_CLOCK = "new database"

# The child: the stages wrapped, then rulkit's console entry point on the given arguments.
_CHILD = """
import inspect, sys, time
from collections import defaultdict
STAGES = {stages!r}
def mem():
    with open("/proc/self/status") as f:
        d = {{l.split(":")[0]: int(l.split()[1]) // 1024 for l in f if l.startswith("Vm")
             or l.startswith("Rss")}}
    return d
cpu, wall, calls, first, rss, hwm = (defaultdict(float), defaultdict(float), defaultdict(int),
                                     {{}}, {{}}, {{}})
sys.path.insert(0, {here!r})
from timing import stage_owner as owner
start, start_wall = time.process_time(), time.perf_counter()
import rulkit.cli
rulkit_cli = time.process_time()
labels = [label for label, _, _ in STAGES]
threaded = set(labels[labels.index({thread_clock!r}):])
for label, where, name in STAGES:
    try:  # a stage the profiled code does not have (another checkout's) stays at 0
        o = owner(where)
        fn = getattr(o, name)
    except (ImportError, AttributeError):
        continue
    clock = time.thread_time if label in threaded else time.process_time
    def note(label, dt, dw):
        cpu[label] += dt
        wall[label] += dw
        calls[label] += 1
        first.setdefault(label, dt)
        m = mem()
        rss[label], hwm[label] = m["VmRSS"], m["VmHWM"]
    def timed(*a, _fn=fn, _label=label, _clock=clock, **k):
        t0, w0 = _clock(), time.perf_counter()
        try:
            return _fn(*a, **k)
        finally:
            note(_label, _clock() - t0, time.perf_counter() - w0)
    def timed_items(*a, _fn=fn, _label=label, _clock=clock, **k):  # each item as it is taken
        items = _fn(*a, **k)
        while True:
            t0, w0 = _clock(), time.perf_counter()
            try:
                item = next(items)
            except StopIteration:
                return
            finally:
                note(_label, _clock() - t0, time.perf_counter() - w0)
            yield item
    setattr(o, name, timed_items if inspect.isgeneratorfunction(fn) else timed)
instrumented, instrumented_wall = time.process_time(), time.perf_counter()
imported = mem()
sys.argv = ["rulkit", *sys.argv[1:]]
try:
    rulkit.cli.main()
except SystemExit as e:
    if e.code:
        raise
finally:
    end, end_wall = time.process_time(), time.perf_counter()
    m = mem()
    print("start", start, rulkit_cli - start, instrumented - rulkit_cli, end - instrumented,
          end_wall - instrumented_wall,
          m["VmHWM"], m["RssFile"], m["RssAnon"], imported["VmRSS"], imported["VmHWM"],
          file=sys.stderr)
    for label, _, _ in STAGES:
        print("stage", label, cpu[label], wall[label], calls[label], first.get(label, 0.0),
              rss.get(label, 0), hwm.get(label, 0), sep="\t", file=sys.stderr)
"""


def report(err: str, wall: float) -> None:
    """Print the child's figures (its stderr's last lines); ``wall``: the child process's
    wall time, measured from outside."""
    stages: dict[str, tuple[float, float, int, float, int, int]] = {}
    head: list[str] = []
    for line in err.splitlines():
        if line.startswith("start "):
            head = line.split()[1:]
        elif line.startswith("stage\t"):
            label, c, w, n, f, r, h = line.split("\t")[1:]
            stages[label] = (float(c), float(w), int(n), float(f), int(r), int(h))
    py, imp, store, run, run_wall, peak, file_mb, anon_mb, rss0, hwm0 = (
        float(x) for x in head)
    total = py + imp + store + run
    print(f"CPU {total:.2f} s in all, wall {wall:.2f} s, peak resident memory {peak:.0f} MB "
          f"(at exit: {file_mb:.0f} MB of it shared libraries' code, {anon_mb:.0f} MB data)")
    print(f"  {'stage':38s} {'CPU s':>6s} {'share':>6s} {'wall s':>6s} {'RSS MB':>7s} "
          f"{'peak MB':>8s}")
    print(f"  {'interpreter start':38s} {py:6.2f} {py / total:6.1%}")
    print(f"  {'import rulkit.cli':38s} {imp:6.2f} {imp / total:6.1%}")
    print(f"  {'import the store':38s} {store:6.2f} {store / total:6.1%} {'':6s} {rss0:7.0f} "
          f"{hwm0:8.0f}  (the command imports numpy and pyarrow when it runs)")
    print(f"  {'(the three above, and the exit)':38s} {'':6s} {'':6s} {wall - run_wall:6.2f}")
    labels = [label for label, _, _ in STAGES]
    for j, label in enumerate(labels):
        c, w, n, f, r, h = stages[label]
        note = f"  ({n} calls; the first {f:.2f} s: numba loaded)" if (
            label.strip() in ("trackers", "trend pass") and n > 1 and f > 0.05) else (
            f"  ({n} calls)" if n > 1 else "")
        print(f"  {label:38s} {c:6.2f} {c / total:6.1%} {w:6.2f} {r:7d} {h:8d}{note}")
        kids = []
        for other in labels[j + 1:]:
            if stage_depth(other) <= stage_depth(label):
                break
            if stage_depth(other) == stage_depth(label) + 1:
                kids.append(other)
        if kids:
            rest = c - sum(stages[k][0] for k in kids)
            rest_w = w - sum(stages[k][1] for k in kids)
            print(f"  {'  ' * (stage_depth(label) + 1) + 'the rest':38s} {rest:6.2f} "
                  f"{rest / total:6.1%} {rest_w:6.2f}")
    outer = sum(stages[k][0] for k in labels if stage_depth(k) == 0)
    outer_w = sum(stages[k][1] for k in labels if stage_depth(k) == 0
                  and not k.startswith(WORKER))  # the worker's time overlaps the others'
    print(f"  {'the command otherwise':38s} {run - outer:6.2f} {(run - outer) / total:6.1%} "
          f"{run_wall - outer_w:6.2f}"
          "  (typer, options, imports inside the command)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--components", type=int, default=2000)
    ap.add_argument("--acquisitions", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--against", type=Path, default=None,
                    help="the src/ of another checkout: profile its track instead")
    args = ap.parse_args()
    from bench_scale import fleet_csv, measured_environment

    with tempfile.TemporaryDirectory(prefix="rulkit-profile-track-") as tmp:
        measured_environment(Path(tmp))
        env = {**os.environ}
        if args.against is not None:
            env["PYTHONPATH"] = str(args.against.resolve())
        src = Path(tmp) / "acquisitions.csv"
        fleet_csv(src, args.components, args.acquisitions, np.random.default_rng(args.seed))
        for _ in range(2):  # the first run writes bytecode and numba's cache: not reported
            db = Path(tmp) / "track.db"
            db.unlink(missing_ok=True)
            child = _CHILD.format(stages=STAGES, here=str(Path(__file__).parent),
                                  thread_clock=THREAD_CLOCK)
            t0 = time.perf_counter()
            proc = subprocess.run(
                [sys.executable, "-c", child, "track", "--db", str(db),
                 str(src)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                env=env)
            wall = time.perf_counter() - t0
            if proc.returncode != 0:
                raise SystemExit(proc.stderr[-2000:])
        print(f"rulkit track{f' with {args.against}' if args.against else ''} of "
              f"{args.components * args.acquisitions:,} rows "
              f"({args.components} components x {args.acquisitions}, CSV "
              f"{src.stat().st_size / 2**20:.0f} MB) into a new database; load average "
              f"{os.getloadavg()[0]:.1f}")
        report(proc.stderr, wall)


if __name__ == "__main__":
    main()
