"""Step 2 on a user's record: the lubricant-loss measurements and the window sums of the step-1
estimate over them (docs/systems/reaction-wheel.md §7.2).

The measurements come as a table with ``time_s`` (the end of each measurement interval, in
the telemetry's clock: seconds or date-times) and one of

- ``loss_mL``: the lubricant lost over the interval since the previous row (the first row's
  interval starts at the record's first sample);
- ``cumulative_mL``: the total lost since some reference; consecutive rows give the intervals
  (the first row only starts them);
- ``injected_mL`` (an injection log): a lubricator refills what was lost, so an injection
  measures the loss since the previous one [R] (the first row's interval starts at the
  record's first sample).

:class:`WindowAccumulator` takes the step-1 estimate chunk by chunk (time order) and keeps only
the open window's samples; when a window closes it keeps the Gauss rule of its distribution of
``1/T^`` (:func:`rulkit.systems.reaction_wheel.degradation.quadrature.window_quadrature`), the
number of 0.05 s samples its length stands for (so ``S_k(b) dt`` is the integral of
``exp(-b / T^)`` over the window, whatever the telemetry's sampling step), its mean ``T^`` and
its sample count. A window without any estimate (the telemetry has a gap over it) is marked
missing and left out of step 2.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rulkit.systems.reaction_wheel.degradation.quadrature import (
    WindowQuadrature,
    window_quadrature,
)
from rulkit.systems.reaction_wheel.lubrication import SAMPLE_DT, T_MIN_C

FloatArray = np.ndarray
#: The loss columns a measurement file may have (exactly one).
LOSS_KINDS = {"loss_mL": "loss", "cumulative_mL": "cumulative", "injected_mL": "injections"}
#: Samples kept per window at most: a longer window is thinned evenly (the distribution of
#: a slowly varying 1/T^ is kept; 2^20 samples are 14 hours at 20 Hz).
MAX_WINDOW_SAMPLES = 2**20


class LossFileError(ValueError):
    """A loss-measurement or injection file that cannot be used (names file, column, row)."""


@dataclass(frozen=True)
class LossRecord:
    """Measured lubricant losses over consecutive windows ``(start_s, end_s]`` (absolute times
    of the telemetry's clock), ``loss_mL`` each; ``kind`` one of the values of
    :data:`LOSS_KINDS`; ``source`` the file."""

    start_s: FloatArray
    end_s: FloatArray
    loss_mL: FloatArray
    kind: str
    source: str

    @property
    def n_windows(self) -> int:
        """Number of windows W."""
        return int(self.end_s.size)


def read_losses(path: str | Path, record_start: float) -> LossRecord:
    """The loss windows of the measurement or injection file ``path`` (module docstring);
    ``record_start`` the time of the record's first sample (the start of the first window of
    per-interval files). Raises :class:`LossFileError` naming the file, column and row."""
    from rulkit.tables import did_you_mean, numeric_columns, read_table, time_seconds

    df = read_table(path, error=LossFileError, expected_columns=("time_s", "loss_mL"))
    src = str(path)
    found = [c for c in LOSS_KINDS if c in df.columns]
    if "time_s" not in df.columns or len(found) != 1:
        hint = did_you_mean("time_s", df.columns) if "time_s" not in df.columns else ""
        raise LossFileError(
            f"{src}: expected a column 'time_s'{hint} and exactly one of "
            f"{', '.join(repr(c) for c in LOSS_KINDS)} (columns found: {list(df.columns)})")
    col = found[0]
    for c in ("time_s", col):
        if df[c].dtype == bool or df[c].map(lambda v: isinstance(v, bool | np.bool_)).any():
            raise LossFileError(f"{src}: column {c!r} holds booleans (true/false), not numbers")
    sec = time_seconds(df["time_s"], "time_s", error=LossFileError, source=src)
    vals = numeric_columns(df, [col] if sec is not None else ["time_s", col],
                           error=LossFileError, source=src)
    t = sec if sec is not None else vals["time_s"]
    y = vals[col]
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        r = int(bad[0]) + 1
        raise LossFileError(f"{src}: column 'time_s', row {r + 1}: time {t[r]:.10g} is not after "
                            f"the previous row's {t[r - 1]:.10g} (strictly increasing needed)")
    kind = LOSS_KINDS[col]
    if kind == "cumulative":
        if t.size < 2:
            raise LossFileError(f"{src}: a cumulative loss needs at least 2 rows, got {t.size}")
        return LossRecord(t[:-1], t[1:], np.diff(y), kind, src)
    if not t[0] > record_start:
        raise LossFileError(
            f"{src}: column 'time_s', row 1: the first interval ends at {t[0]:.10g}, not after "
            f"the record's first sample at {record_start:.10g} (the losses and the telemetry "
            "must share a clock)")
    return LossRecord(np.concatenate([[record_start], t[:-1]]), t, y, kind, src)


@dataclass(frozen=True)
class WindowSums:
    """The step-1 estimate summarised per loss window: ``quad`` the Gauss rules (arrays
    (1, W, n), ``count`` (W,) the 0.05 s samples each window stands for), ``T_mean`` and
    ``n_samples`` per window, ``present`` which windows had any estimate."""

    quad: WindowQuadrature
    T_mean: FloatArray
    n_samples: FloatArray
    present: FloatArray


class WindowAccumulator:
    """The window sums of a step-1 estimate given chunk by chunk in time order (module
    docstring); memory holds one window's samples. :meth:`state` / :meth:`from_state` carry
    it through a checkpoint."""

    def __init__(self, losses: LossRecord, n_nodes: int = 4) -> None:
        W = losses.n_windows
        self.losses, self.n_nodes = losses, int(n_nodes)
        self.center, self.scale = np.zeros(W), np.zeros(W)
        self.nodes, self.weights = np.zeros((W, self.n_nodes)), np.zeros((W, self.n_nodes))
        self.T_mean, self.n_samples = np.full(W, np.nan), np.zeros(W)
        self.k = 0  # the open window
        self._buf: list[FloatArray] = []
        self._seen = 0  # samples of the open window seen (before thinning)

    def add(self, t: FloatArray, T: FloatArray, dt: float) -> None:
        """Take the estimates ``T`` (C) at absolute times ``t`` (increasing, after every time
        given before); ``dt`` the sampling step (s)."""
        t = np.asarray(t, dtype=np.float64)
        T = np.asarray(T, dtype=np.float64)
        lo = self.losses
        W = lo.n_windows
        win = np.searchsorted(lo.end_s, t, side="left")  # t <= end[win], t > end[win - 1]
        inside = (win < W) & (t > lo.start_s[np.minimum(win, W - 1)])
        bad = inside & ~(T >= T_MIN_C)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"the temperature estimate is {T[i]:.4g} C at time_s = {t[i]:.10g}: the loss law "
                f"exp(-b / T) with T in deg C is singular at 0 C and needs T >= {T_MIN_C:g} C "
                "(docs/systems/reaction-wheel.md §4)")
        win, T = win[inside], T[inside]
        if win.size == 0:
            return
        cuts = np.flatnonzero(np.diff(win)) + 1
        for part_w, part_T in zip(np.split(win, cuts), np.split(T, cuts), strict=True):
            k = int(part_w[0])
            while self.k < k:
                self._close()
            self._take(part_T, dt)

    def _take(self, T: FloatArray, dt: float) -> None:
        lo = self.losses
        expect = (lo.end_s[self.k] - lo.start_s[self.k]) / dt
        stride = max(1, int(np.ceil(expect / MAX_WINDOW_SAMPLES)))
        first = (-self._seen) % stride  # keep every stride-th sample of the window
        self._buf.append(1.0 / T[first::stride])
        self._seen += T.size

    def _close(self) -> None:
        """Summarise the open window (if it has samples) and open the next."""
        k = self.k
        if self._buf:
            u = np.concatenate(self._buf)
            q = window_quadrature(u[None, :], self.n_nodes)
            self.center[k], self.scale[k] = q.center[0], q.scale[0]
            self.nodes[k], self.weights[k] = q.nodes[0], q.weights[0]
            self.T_mean[k] = float(np.mean(1.0 / u))
            self.n_samples[k] = self._seen
        self._buf, self._seen = [], 0
        self.k += 1

    def finish(self) -> WindowSums:
        """Close every window (the record has ended) and return the sums."""
        while self.k < self.losses.n_windows:
            self._close()
        lo = self.losses
        present = self.n_samples > 0
        count = (lo.end_s - lo.start_s) / SAMPLE_DT
        quad = WindowQuadrature(self.center[None], self.scale[None], self.nodes[None],
                                self.weights[None], count[None])
        return WindowSums(quad, self.T_mean.copy(), self.n_samples.copy(), present)

    def state(self) -> dict[str, Any]:
        """Arrays that restore this accumulator (:meth:`from_state`)."""
        buf = np.concatenate(self._buf) if self._buf else np.empty(0)
        return {"center": self.center, "scale": self.scale, "nodes": self.nodes,
                "weights": self.weights, "T_mean": self.T_mean, "n_samples": self.n_samples,
                "open": np.array([self.k, self._seen], dtype=np.int64), "buffer": buf}

    @classmethod
    def from_state(cls, losses: LossRecord, n_nodes: int, st: dict[str, Any]
                   ) -> WindowAccumulator:
        """The accumulator of :meth:`state` (a checkpoint), for the same ``losses``."""
        acc = cls(losses, n_nodes)
        for name in ("center", "scale", "nodes", "weights", "T_mean", "n_samples"):
            getattr(acc, name)[...] = st[name]
        acc.k, acc._seen = (int(v) for v in st["open"])
        acc._buf = [np.asarray(st["buffer"])] if len(st["buffer"]) else []
        return acc


def iter_temperature_estimate(path: str | Path, chunk_rows: int = 1_000_000) -> Any:
    """The chunks ``(t, T_mean, dt)`` of a step-1 estimate file (``rulkit rw
    estimate-temperature``'s output: ``time_s``, ``T_mean``; CSV or Parquet), checked: times
    increasing, temperatures finite."""
    from rulkit.tables import numeric_columns, read_table_chunks, time_seconds

    last = -np.inf
    dt = None
    for chunk in read_table_chunks(path, ("time_s", "T_mean"), chunk_rows=chunk_rows,
                                   error=LossFileError):
        missing = [c for c in ("time_s", "T_mean") if c not in chunk.columns]
        if missing:
            raise LossFileError(f"{path}: missing column(s) {missing} (a step-1 estimate file "
                                "has time_s and T_mean)")
        row0 = int(chunk.attrs["row0"])

        def label(r: int, row0: int = row0) -> str:
            return f"row {row0 + r + 1}"

        sec = time_seconds(chunk["time_s"], "time_s", error=LossFileError, source=str(path),
                           row_label=label)
        vals = numeric_columns(chunk, ["T_mean"] if sec is not None else ["time_s", "T_mean"],
                               error=LossFileError, source=str(path), row_label=label)
        t = sec if sec is not None else vals["time_s"]
        d = np.diff(np.concatenate([[last], t]))
        if (d <= 0).any():
            r = int(np.flatnonzero(d <= 0)[0])
            raise LossFileError(f"{path}: column 'time_s', row {row0 + r + 1}: times must be "
                                "strictly increasing")
        if dt is None and t.size > 1:
            dt = float(np.median(np.diff(t[:1001])))
        last = float(t[-1])
        yield t, vals["T_mean"], dt or 1.0
