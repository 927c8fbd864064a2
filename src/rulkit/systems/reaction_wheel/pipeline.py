"""Streaming a long wheel record through step 1 (docs/systems/reaction-wheel.md §3): read,
check, filter and write a telemetry file chunk by chunk in bounded memory, replacing the output
only when the whole record went through.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


class StreamSummary:
    """What ``rw estimate-temperature`` reports: rows, the last estimate, notes for stderr."""

    def __init__(self) -> None:
        self.rows = 0
        self.out_of_range = 0
        self.last: dict[str, float] = {}
        self.notes: list[str] = []


def stream_temperature(file: Path, dest: Path, *, wheel: Any = None, method: str | None = None,
                       particles: int | None = None, seed: int = 0,
                       noise: str | tuple[float, float] | None = None, level: float = 0.95,
                       chunk_rows: int = 100_000) -> StreamSummary:
    """Read ``file`` chunk by chunk, filter each chunk, and append its estimates to a
    temporary file beside ``dest`` that replaces ``dest`` only when the whole record has been
    read, checked and filtered (an error leaves ``dest`` as it was). Memory is bounded by
    ``chunk_rows``, not the record's length. ``wheel`` a
    :class:`rulkit.systems.reaction_wheel.wheel_file.WheelFile` (default the seed's);
    ``method``, ``particles`` and ``noise`` override the wheel file's."""
    import os

    import numpy as np

    from rulkit.systems.reaction_wheel.telemetry import iter_wheel_telemetry
    from rulkit.systems.reaction_wheel.temperature.estimator import (
        ROBUST_METHODS,
        TemperatureEstimator,
    )
    from rulkit.systems.reaction_wheel.wheel_file import read_wheel_file, step1_config
    from rulkit.tables import TableWriter, table_format

    w = wheel or read_wheel_file(None)
    m = method or w.method
    tmp = dest.with_name(f".{dest.name}.{os.getpid()}.partial")
    summary = StreamSummary()
    est: TemperatureEstimator | None = None
    try:
        with TableWriter(tmp, fmt=table_format(dest)) as writer:
            for chunk in iter_wheel_telemetry(file, chunk_rows=chunk_rows, limits=w.limits,
                                              lenient=m in ROBUST_METHODS):
                if est is None:
                    est = TemperatureEstimator(
                        m, particles or w.particles, np.random.default_rng(seed),
                        dt=float(chunk.attrs["dt"]), design=w.design, noise=noise or w.sigma,
                        config=step1_config(w, m), level=level, source=str(file),
                        params=w.params)
                part = est.update(chunk)
                writer.write(part)
                summary.last = {c: float(part[c].iloc[-1])
                                for c in ("time_s", "T_mean", "T_lo", "T_hi")}
                summary.out_of_range = int(chunk.attrs.get("n_out_of_range", 0))
        assert est is not None  # iter_wheel_telemetry yields at least one chunk or raises
        est.finish()
        os.replace(tmp, dest)
    finally:
        tmp.unlink(missing_ok=True)
    summary.rows = est.rows
    summary.notes = estimate_notes(est, summary.out_of_range)
    return summary


def estimate_notes(est: Any, out_of_range: int = 0) -> list[str]:
    """What a user must be told about a finished step-1 run: the estimator's note and warning,
    and how many samples were not used and why (the ``flags`` bits)."""
    from rulkit.systems.reaction_wheel.temperature import ekf

    notes = [f"note: {est.note}"] if est.note else []
    if est.warning:
        notes.append(f"warning: {est.warning}")
    words = {ekf.FLAG_SPEED_UNUSED: "speed samples not used (missing, stuck or gated)",
             ekf.FLAG_CURRENT_UNUSED: "current samples not used (missing, stuck or gated)",
             ekf.FLAG_GATED: "samples refused by the outlier gate",
             ekf.FLAG_COMMAND: "commands missing or a one-sample spike (held / replaced)",
             ekf.FLAG_REANCHORED: "restarts of [I, w] at the measurement (gap or lost speed)",
             ekf.FLAG_GAP: "steps longer than 1.5 dt (gaps, predicted over)"}
    counts = [f"{n} {words[bit]}" for bit, n in sorted(est.flag_counts.items()) if bit in words]
    if out_of_range:
        counts.append(f"{out_of_range} values beyond the plausibility limits (kept as missing)")
    if counts:
        first = (f", the first speed sample not used at time_s = {est.first_untrusted:g}"
                 if est.first_untrusted is not None else "")
        notes.append("note: " + "; ".join(counts) + first + " (column 'flags')")
    return notes
