"""Streaming a long wheel record through step 1 (docs/systems/reaction-wheel.md §3): read,
check, filter and write a telemetry file chunk by chunk in bounded memory, replacing the output
only when the whole record went through.
"""

from __future__ import annotations

from pathlib import Path


class StreamSummary:
    """What ``rw estimate-temperature`` reports: rows, the last estimate, notes for stderr."""

    def __init__(self) -> None:
        self.rows = 0
        self.last: dict[str, float] = {}
        self.notes: list[str] = []


def stream_temperature(file: Path, dest: Path, *, method: str, particles: int, seed: int,
                       noise: str, level: float, chunk_rows: int) -> StreamSummary:
    """Read ``file`` chunk by chunk, filter each chunk, and append its estimates to a
    temporary file beside ``dest`` that replaces ``dest`` only when the whole record has been
    read, checked and filtered (an error leaves ``dest`` as it was). Memory is bounded by
    ``chunk_rows``, not the record's length."""
    import os

    import numpy as np

    from rulkit.systems.reaction_wheel.telemetry import iter_wheel_telemetry
    from rulkit.systems.reaction_wheel.temperature.estimator import TemperatureEstimator
    from rulkit.tables import TableWriter, table_format

    tmp = dest.with_name(f".{dest.name}.{os.getpid()}.partial")
    summary = StreamSummary()
    est: TemperatureEstimator | None = None
    try:
        with TableWriter(tmp, fmt=table_format(dest)) as writer:
            for chunk in iter_wheel_telemetry(file, chunk_rows=chunk_rows):
                if est is None:
                    est = TemperatureEstimator(method, particles, np.random.default_rng(seed),
                                               dt=float(chunk.attrs["dt"]), noise=noise,
                                               level=level, source=str(file))
                part = est.update(chunk)
                writer.write(part)
                summary.last = {c: float(part[c].iloc[-1])
                                for c in ("time_s", "T_mean", "T_lo", "T_hi")}
        assert est is not None  # iter_wheel_telemetry yields at least one chunk or raises
        est.finish()
        os.replace(tmp, dest)
    finally:
        tmp.unlink(missing_ok=True)
    summary.rows = est.rows
    if est.note:
        summary.notes.append(f"note: {est.note}")
    if est.warning:
        summary.notes.append(f"warning: {est.warning}")
    if est.n_untrusted:
        summary.notes.append(f"warning: {est.n_untrusted} samples not trusted (outlier gate; "
                             f"column 'untrusted'), the first at time_s = "
                             f"{est.first_untrusted:g}")
    return summary
