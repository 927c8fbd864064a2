"""The tables a group commit writes, compared with another checkout's code: the same groups of
batches (``ComponentStore.ingest_many``, joined runs, new components beside stored ones, a
re-sent batch of duplicates and a conflicting one, alerts) written by this code and by the
code at ``--against SRC`` into new SQLite databases, with and without the writer's kept rows
(``keep_states``); every row of every table the store writes (rowids included) and every
result, with each value's type and, for a float, its exact bits, must be the same
(docs/service-load.md, "The store's rows as arrays").

    git archive main src | tar -x -C /tmp/main
    .venv/bin/python benchmarks/compare_ingest_tables.py --against /tmp/main/src
"""

from __future__ import annotations

import argparse
import os
import sqlite3
import subprocess
import sys
import tempfile
from pathlib import Path

TABLES = ("components", "history", "ingests", "alerts", "level_counts", "seen_counts")


def write(db: str, keep: bool) -> None:
    """Write the groups into a new database at ``db`` with the code on ``sys.path``; print
    the results, then every table's rows with their values' types."""
    import numpy as np
    import pandas as pd

    from rulkit.fleet.store.acquisitions import validate_acquisitions
    from rulkit.fleet.store.sqlite import ComponentStore
    from rulkit.fleet.tracking.tracker_chain import TrackerConfig

    cfg = TrackerConfig(dt=1.0, lambda_hi=0.5, lambda_rul=0.5, design_life=1e4, warn_rul=30.0)
    rng = np.random.default_rng(7)
    names = [f"u{i:03d}" for i in range(300)]
    with ComponentStore(db, config=cfg) as store:
        if keep:
            store.keep_states()
        for k in range(12):
            frames = []
            for w in range(4):  # each writer's components grow and shrink: new beside stored
                sub = names[w::4][: 40 + 10 * ((k + w) % 3)]
                rows = [(c, float(t), (0.3 + 0.002 * j) * np.exp(0.05 * t)
                         + rng.normal(0, 0.003))
                        for t in range(3 * k, 3 * k + 3) for j, c in enumerate(sub)]
                frames.append(pd.DataFrame(rows, columns=["component", "time", "hi"]))
            if k == 5:  # a re-sent batch (duplicates) and a conflicting one
                bad = frames[1].copy()
                bad["hi"] += 0.5
                frames += [frames[0].copy(), bad]
            res = store.ingest_many([(validate_acquisitions(f, store.config, store.hi_model),
                                      "t", 1.7e9 + k) for f in frames])
            print([repr(r) for r in res])
    con = sqlite3.connect(db)
    for t in TABLES:
        for r in con.execute(f"SELECT rowid, * FROM {t} ORDER BY rowid"):
            print(t, [(type(v).__name__, v.hex() if isinstance(v, float | bytes) else v)
                      for v in r])
    con.close()


def run(src: Path | None, db: Path, keep: bool) -> list[str]:
    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = str(src.resolve())
    out = subprocess.run([sys.executable, __file__, "--write", str(db)]
                         + (["--keep"] if keep else []), env=env, check=True,
                         capture_output=True, text=True).stdout
    return out.splitlines()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--against", type=Path, help="The other checkout's src directory.")
    ap.add_argument("--write", help=argparse.SUPPRESS)
    ap.add_argument("--keep", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.write:
        write(args.write, args.keep)
        return
    if args.against is None:
        ap.error("--against SRC is required")
    failed = False
    with tempfile.TemporaryDirectory(prefix="rulkit-compare-") as tmp:
        for keep in (True, False):
            ours = run(None, Path(tmp) / f"ours{keep}.db", keep)
            theirs = run(args.against, Path(tmp) / f"theirs{keep}.db", keep)
            diff = [i for i, (a, b) in enumerate(zip(ours, theirs, strict=False)) if a != b]
            same = not diff and len(ours) == len(theirs)
            failed |= not same
            kinds = {t: sum(line.startswith(t + " ") for line in ours) for t in TABLES}
            print(f"kept rows {'on' if keep else 'off'}: {len(ours)} lines ("
                  + ", ".join(f"{t} {n}" for t, n in kinds.items()) + "): "
                  + ("the same" if same else f"DIFFERENT, first at line {(diff or [0])[0]}"))
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
