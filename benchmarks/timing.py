"""Shared timing helper of the benchmark scripts (run from this folder or by path: Python puts
the script's folder first on ``sys.path``)."""

from __future__ import annotations

import importlib
import statistics
import time
from collections.abc import Callable
from typing import Any


def median_time(fn: Callable[[], object], repeats: int) -> float:
    """Median wall time (s) of ``repeats`` calls of ``fn``."""
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def stage_owner(path: str) -> Any:
    """The module or class named by a dotted ``path`` (a profiled stage's home), so that the
    stage's function can be read and replaced on it."""
    mod, _, attr = path.rpartition(".")
    try:
        return importlib.import_module(path)
    except ModuleNotFoundError:
        return getattr(importlib.import_module(mod), attr)


def stage_depth(label: str) -> int:
    """Nesting depth of a stage's label (two spaces of indent per level)."""
    return (len(label) - len(label.lstrip())) // 2
