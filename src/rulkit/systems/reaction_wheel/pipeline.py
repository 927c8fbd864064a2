"""Steps 1-3 over a wheel's long record, streaming, resumable (docs/systems/reaction-wheel.md
§7.4); and the streaming of ``rulkit rw estimate-temperature``.

A record is one telemetry file or a directory of them (daily Parquet or CSV files, taken in
name order as one continuous record). :func:`run_pipeline` reads it chunk by chunk with one
set of checks across the files (time keeps increasing from file to file), runs the step-1
estimator over it with its state carried across chunks and files, and feeds the estimate to
the window sums of the loss measurements (:class:`~rulkit.systems.reaction_wheel.degradation.
windows.WindowAccumulator`) and to an hourly summary; memory holds one chunk and one window.
After every file it writes a checkpoint (``checkpoint.json`` + ``checkpoint.npz``, replaced
atomically): a run stopped for any reason continues from the next file with the same numbers
(tested). Then step 2 (:mod:`rulkit.systems.reaction_wheel.degradation.track`) and step 3
(:mod:`rulkit.systems.reaction_wheel.rul.predict`) run on the summaries, and
:mod:`rulkit.systems.reaction_wheel.record_report` writes the tables, figures and ``report.md``.
Several wheels run as independent tasks (:func:`run_fleet`; worker processes or a Dask
cluster).

A wheel directory may hold everything: ``telemetry/`` (the files), ``losses.csv`` (or
``losses.parquet``, ``injections.csv``, ...; see
:func:`rulkit.systems.reaction_wheel.degradation.windows.read_losses`), ``wheel.toml`` and
``future.csv`` (a future temperature profile); options given explicitly win.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

TELEMETRY_SUFFIXES = (".csv", ".parquet", ".pq")
#: Files a wheel directory may hold besides ``telemetry/`` (first found wins).
LOSS_FILES = ("losses.csv", "losses.parquet", "injections.csv", "injections.parquet")
CHECKPOINT_VERSION = 1
#: ``progress(rows, message)``: called after every chunk with the rows it held.
Progress = Callable[[int, str], None]


class PipelineError(ValueError):
    """Inputs of the pipeline that cannot be used (the message names the file or option)."""


@dataclass(frozen=True)
class WheelRecord:
    """One wheel's inputs: its ``telemetry`` files (in order), its loss measurements or
    injection log (``None``: step 1 only), its wheel file and future profile (``None``: the
    seed's wheel; the last days repeated), and a ``name``."""

    name: str
    telemetry: tuple[Path, ...]
    losses: Path | None = None
    wheel: Path | None = None
    future: Path | None = None
    #: A step-1 estimate file (``rulkit rw estimate-temperature``'s output) used instead of
    #: running step 1 on ``telemetry`` (then empty).
    temperature: Path | None = None


def find_record(path: Path, *, losses: Path | None = None, wheel: Path | None = None,
                future: Path | None = None) -> WheelRecord:
    """The record at ``path``: a telemetry file, a directory of telemetry files, or a wheel
    directory (``telemetry/`` plus optional ``losses.csv``, ``wheel.toml``, ``future.csv``);
    explicit ``losses``, ``wheel`` and ``future`` override what the directory holds."""
    path = Path(path)
    if not path.exists():
        raise PipelineError(f"{path}: no such file or directory")
    if path.is_file():
        return WheelRecord(path.stem, (path,), losses, wheel, future)
    tel_dir = path / "telemetry" if (path / "telemetry").is_dir() else path
    files = tuple(sorted(p for p in tel_dir.iterdir()
                         if p.is_file() and p.name.lower().endswith(TELEMETRY_SUFFIXES)
                         and p.name not in LOSS_FILES and p.name != "future.csv"))
    if not files:
        raise PipelineError(f"{tel_dir}: no telemetry files (*.csv, *.parquet, *.pq)")
    if tel_dir != path:
        losses = losses or next((path / n for n in LOSS_FILES if (path / n).exists()), None)
        wheel = wheel or (path / "wheel.toml" if (path / "wheel.toml").exists() else None)
        future = future or (path / "future.csv" if (path / "future.csv").exists() else None)
    return WheelRecord(path.name, files, losses, wheel, future)


@dataclass(frozen=True)
class PipelineOptions:
    """How to run a record: the loss ``threshold_mL`` of step 3 (``None``: no RUL), the days of
    the estimate repeated as the future when there is no profile (``repeat_days``), the
    ``seed`` of the step-2 trackers, the ``level`` of the step-2/3 intervals, the rows read at
    a time (``chunk_rows``), whether to write the estimate of every sample (``samples``), to
    ignore a checkpoint (``restart``), and a step-1 ``method`` overriding the wheel file's."""

    threshold_mL: float | None = None
    repeat_days: float = 7.0
    seed: int = 0
    level: float = 0.9
    chunk_rows: int = 1_000_000
    samples: bool = False
    restart: bool = False
    method: str | None = None


@dataclass
class PipelineResult:
    """What a record gave: step-1 counts and notes, the hourly summary (a DataFrame), the step-2
    tracks, the step-3 RUL distributions per tracker, timings, and the files written."""

    record: WheelRecord
    wheel: Any
    options: PipelineOptions
    rows: int
    span_s: tuple[float, float]
    notes: list[str]
    hourly: Any
    tracks: Any = None
    ruls: dict[str, Any] = field(default_factory=dict)
    future: str = ""
    timings: dict[str, float] = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)
    resumed_after: int = 0
    windows: Any = None  # (LossRecord, WindowSums) of step 2, for ``rw rul``


class HourlySummary:
    """Mean, lowest lower bound and highest upper bound of the step-1 estimate per hour since
    the record's start (for the report; a few numbers per hour whatever the record's length)."""

    def __init__(self) -> None:
        self.t0: float | None = None
        self.sum = np.zeros(0)
        self.n = np.zeros(0)
        self.lo = np.zeros(0)
        self.hi = np.zeros(0)

    def add(self, t: Any, m: Any, lo: Any, hi: Any) -> None:
        """Take the estimates ``m`` with interval ``[lo, hi]`` at absolute times ``t``."""
        if self.t0 is None:
            self.t0 = float(t[0])
        h = ((t - self.t0) // 3600.0).astype(np.int64)
        size = int(h[-1]) + 1
        if size > self.sum.size:
            grow = size - self.sum.size
            self.sum = np.concatenate([self.sum, np.zeros(grow)])
            self.n = np.concatenate([self.n, np.zeros(grow)])
            self.lo = np.concatenate([self.lo, np.full(grow, np.inf)])
            self.hi = np.concatenate([self.hi, np.full(grow, -np.inf)])
        self.sum += np.bincount(h, weights=m, minlength=self.sum.size)
        self.n += np.bincount(h, minlength=self.n.size)
        np.minimum.at(self.lo, h, lo)
        np.maximum.at(self.hi, h, hi)

    def frame(self) -> Any:
        """One row per hour with data: hour, time_s (its start), T_mean, T_lo, T_hi, samples."""
        import pandas as pd

        k = np.flatnonzero(self.n > 0)
        return pd.DataFrame({"hour": k, "time_s": (self.t0 or 0.0) + 3600.0 * k,
                             "T_mean": self.sum[k] / self.n[k], "T_lo": self.lo[k],
                             "T_hi": self.hi[k], "samples": self.n[k].astype(np.int64)})

    def state(self) -> dict[str, Any]:
        """Arrays for a checkpoint."""
        return {"t0": np.array([np.nan if self.t0 is None else self.t0]), "sum": self.sum,
                "n": self.n, "lo": self.lo, "hi": self.hi}

    def restore(self, st: dict[str, Any]) -> None:
        """Continue from :meth:`state`."""
        t0 = float(st["t0"][0])
        self.t0 = None if np.isnan(t0) else t0
        self.sum, self.n = np.array(st["sum"]), np.array(st["n"])
        self.lo, self.hi = np.array(st["lo"]), np.array(st["hi"])


class Step1Stream:
    """Step 1 over a record's files with everything it carries between chunks: the checks, the
    estimator, the window sums, the hourly summary (module docstring)."""

    def __init__(self, record: WheelRecord, wheel: Any, options: PipelineOptions) -> None:
        from rulkit.systems.reaction_wheel.temperature.estimator import ROBUST_METHODS

        self.record, self.wheel, self.options = record, wheel, options
        self.method = options.method or wheel.method
        if self.method not in ROBUST_METHODS:
            raise PipelineError(
                f"step-1 method {self.method!r}: the pipeline runs {' or '.join(ROBUST_METHODS)} "
                "(a particle filter over months of 20 Hz telemetry is out of reach, and only "
                "these take a record's gaps and dropouts); use --method imm")
        self.check: Any = None
        self.est: Any = None
        self.acc: Any = None
        self.hourly = HourlySummary()
        self.record_start: float | None = None
        self.files_done: list[dict[str, Any]] = []

    def _start(self, chunk: Any) -> None:
        """At the record's first chunk: the estimator and the window sums."""
        from rulkit.systems.reaction_wheel.degradation.windows import (
            WindowAccumulator,
            read_losses,
        )
        from rulkit.systems.reaction_wheel.temperature.estimator import TemperatureEstimator
        from rulkit.systems.reaction_wheel.wheel_file import step1_config

        w = self.wheel
        self.record_start = float(chunk["time_s"].iloc[0])
        self.est = TemperatureEstimator(self.method, dt=float(chunk.attrs["dt"]),
                                        noise=w.sigma, config=step1_config(w, self.method),
                                        source=self.record.name, params=w.params)
        if self.record.losses is not None:
            losses = read_losses(self.record.losses, self.record_start)
            self.acc = WindowAccumulator(losses, w.degradation.n_nodes)

    def run_file(self, path: Path, progress: Progress | None = None) -> Any:
        """Filter one file of the record; returns its per-sample estimate when the options
        ask for samples (else ``None``)."""
        import pandas as pd

        from rulkit.systems.reaction_wheel.telemetry import (
            COLUMNS,
            TelemetryCheck,
            TelemetryError,
        )
        from rulkit.tables import read_table_chunks

        parts = []
        for raw in read_table_chunks(path, COLUMNS, chunk_rows=self.options.chunk_rows,
                                     error=TelemetryError):
            if self.check is None:
                self.check = TelemetryCheck(str(path), raw.attrs["format"] == "csv", 0.01,
                                            raw.attrs["header"], lenient=True,
                                            limits=self.wheel.limits)
            else:
                self.check.source = str(path)
                self.check.csv = raw.attrs["format"] == "csv"
                _header_has_columns(self.check, raw.attrs["header"])
            chunk = self.check.chunk(raw, int(raw.attrs["row0"]))
            if self.est is None:
                self._start(chunk)
            est = self.est.update(chunk)
            t = est["time_s"].to_numpy()
            m, lo, hi = (est[c].to_numpy() for c in ("T_mean", "T_lo", "T_hi"))
            self.hourly.add(t, m, lo, hi)
            if self.acc is not None:
                self.acc.add(t, m, float(chunk.attrs["dt"]))
            if self.options.samples:
                parts.append(est)
            if progress is not None:
                progress(len(chunk), f"{path.name}: {self.check.rows:,} rows")
        st = path.stat()
        self.files_done.append({"path": str(path), "size": st.st_size,
                                "mtime_ns": st.st_mtime_ns, "rows": self.check.rows})
        return pd.concat(parts, ignore_index=True) if parts else None

    # ------------------------------------------------------------------ the checkpoint
    def save(self, out: Path) -> None:
        """Write the checkpoint (npz first, then the json that names it: the commit point)."""
        est_arrays, est_values = self.est.state()
        arrays = {f"est_{k}": v for k, v in est_arrays.items()}
        arrays |= {f"hour_{k}": v for k, v in self.hourly.state().items()}
        if self.acc is not None:
            arrays |= {f"acc_{k}": v for k, v in self.acc.state().items()}
        tmp = out / f".checkpoint.{os.getpid()}.npz"
        np.savez(tmp, **arrays)
        os.replace(tmp, out / "checkpoint.npz")
        meta = {"version": CHECKPOINT_VERSION, "fingerprint": _fingerprint(self),
                "files_done": self.files_done, "record_start": self.record_start,
                "check": self.check.state(), "estimator": est_values,
                "npz_size": (out / "checkpoint.npz").stat().st_size}
        tmpj = out / f".checkpoint.{os.getpid()}.json"
        tmpj.write_text(json.dumps(meta, indent=1))
        os.replace(tmpj, out / "checkpoint.json")

    def load(self, out: Path) -> int:
        """Continue from the checkpoint in ``out`` if there is one for these inputs; returns
        the number of files already done (0: none). A checkpoint of other inputs raises."""
        meta_path = out / "checkpoint.json"
        if not meta_path.exists():
            return 0
        meta = json.loads(meta_path.read_text())
        if meta.get("version") != CHECKPOINT_VERSION or meta["fingerprint"] != _fingerprint(self):
            raise PipelineError(f"{out}: the checkpoint there was made with other inputs or "
                                "settings; use --restart to start over (or another --out)")
        done = meta["files_done"]
        for d, path in zip(done, self.record.telemetry, strict=False):
            st = path.stat()
            if (d["path"], d["size"], d["mtime_ns"]) != (str(path), st.st_size, st.st_mtime_ns):
                raise PipelineError(f"{path}: changed since the checkpoint in {out} (or the "
                                    "files are not the same); use --restart to start over")
        if len(done) > len(self.record.telemetry):
            raise PipelineError(f"{out}: the checkpoint has more files than the record; use "
                                "--restart")
        with np.load(out / "checkpoint.npz") as z:
            arrays = {k: z[k] for k in z.files}
        self._restore(meta, arrays)
        return len(done)

    def _restore(self, meta: dict[str, Any], arrays: dict[str, Any]) -> None:
        from rulkit.systems.reaction_wheel.degradation.windows import (
            WindowAccumulator,
            read_losses,
        )
        from rulkit.systems.reaction_wheel.telemetry import TelemetryCheck
        from rulkit.systems.reaction_wheel.temperature.estimator import TemperatureEstimator
        from rulkit.systems.reaction_wheel.wheel_file import step1_config

        w = self.wheel
        self.files_done = meta["files_done"]
        self.record_start = float(meta["record_start"])
        self.check = TelemetryCheck(self.files_done[-1]["path"], False, 0.01,
                                    ["time_s", "v_comm_V", "speed_rad_s", "current_A"],
                                    lenient=True, limits=w.limits)
        self.check.restore(meta["check"])
        self.est = TemperatureEstimator(self.method, dt=float(self.check.dt), noise=w.sigma,
                                        config=step1_config(w, self.method),
                                        source=self.record.name, params=w.params)
        self.est.restore({k[4:]: v for k, v in arrays.items() if k.startswith("est_")},
                         meta["estimator"])
        self.hourly.restore({k[5:]: v for k, v in arrays.items() if k.startswith("hour_")})
        if self.record.losses is not None:
            losses = read_losses(self.record.losses, self.record_start)
            self.acc = WindowAccumulator.from_state(
                losses, w.degradation.n_nodes,
                {k[4:]: v for k, v in arrays.items() if k.startswith("acc_")})


def _header_has_columns(check: Any, header: list[str]) -> None:
    """A later file of the record must have the telemetry columns too."""
    from rulkit.systems.reaction_wheel.telemetry import COLUMNS, TelemetryError

    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise TelemetryError(f"{check.source}: missing column(s) {missing} (columns found: "
                             f"{header})")


def _fingerprint(s: Step1Stream) -> dict[str, Any]:
    """What must not change for a checkpoint to be continued: the wheel's values, the step-1
    method, the loss file (path, size, time)."""
    lp = s.record.losses
    loss = ([str(lp), lp.stat().st_size, lp.stat().st_mtime_ns] if lp is not None else None)
    wheel = json.loads(json.dumps(s.wheel.values, default=str, sort_keys=True))
    return {"method": s.method, "wheel": wheel, "losses": loss}


def run_pipeline(record: WheelRecord, out: Path, options: PipelineOptions | None = None,
                 progress: Progress | None = None) -> PipelineResult:
    """Steps 1-3 over ``record`` into ``out`` (module docstring); returns the result after
    writing the report (:func:`rulkit.systems.reaction_wheel.record_report.write_record_report`).
    """
    from rulkit.systems.reaction_wheel.wheel_file import read_wheel_file

    opts = options or PipelineOptions()
    if opts.chunk_rows <= 1000:
        raise PipelineError(f"chunk_rows: expected > 1000 (the sampling step comes from the "
                            f"first 1000 steps), got {opts.chunk_rows}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    wheel = read_wheel_file(record.wheel)
    if record.temperature is not None:
        return _from_estimate_file(record, wheel, opts, out)
    stream = Step1Stream(record, wheel, opts)
    if opts.restart:
        for name in ("checkpoint.json", "checkpoint.npz"):
            (out / name).unlink(missing_ok=True)
    t0 = time.perf_counter()
    done = stream.load(out)
    for path in record.telemetry[done:]:
        samples = stream.run_file(path, progress)
        if samples is not None:
            _write_samples(samples, out / "temperature" / f"{path.stem}.parquet")
        stream.save(out)
    stream.check.finish()
    stream.est.finish()
    result = PipelineResult(record, wheel, opts, stream.est.rows,
                            (float(stream.record_start or 0.0), float(stream.check.last_t)),
                            _notes(stream), stream.hourly.frame(), resumed_after=done)
    result.timings["step 1 (this run)"] = time.perf_counter() - t0
    return _after_step_1(stream, result, out)


def _after_step_1(stream: Any, result: PipelineResult, out: Path) -> PipelineResult:
    """Steps 2 and 3 when the record has losses, then the report into ``out``; ``result``."""
    from rulkit.systems.reaction_wheel.record_report import write_record_report

    if stream.acc is not None:
        _steps_2_and_3(stream, result)
    write_record_report(result, out)
    return result


def _steps_2_and_3(stream: Any, result: PipelineResult) -> None:
    """Step 2 on the window sums, then step 3 from its posteriors (when a threshold is set)."""
    from rulkit.systems.reaction_wheel.degradation.track import track_degradation

    w, opts = stream.wheel, stream.options
    t = time.perf_counter()
    sums = stream.acc.finish()
    losses = stream.acc.losses
    tracks = track_degradation(losses, sums, w.degradation, loss_sd_mL=w.loss_sd_mL,
                               seed=opts.seed, level=opts.level)
    result.tracks, result.windows = tracks, (losses, sums)
    result.timings["step 2"] = time.perf_counter() - t
    if opts.threshold_mL is None:
        result.notes.append("no threshold given: step 3 (the RUL) was not run")
        return
    t = time.perf_counter()
    cycle = future_cycle(w, stream.record.future, losses, sums, opts.repeat_days)
    result.future = cycle.description
    result.ruls = ruls(tracks.posteriors, tracks.X_end, cycle, opts.threshold_mL,
                       w.rul["horizon_days"])
    result.timings["step 3"] = time.perf_counter() - t


def future_cycle(wheel: Any, profile: Path | None, losses: Any, sums: Any,
                 repeat_days: float) -> Any:
    """The future of step 3: the ``profile`` file in windows of the wheel file's
    ``forecast_window_h``, or the loss windows of the record's last ``repeat_days`` days."""
    from rulkit.systems.reaction_wheel.degradation.quadrature import WindowQuadrature
    from rulkit.systems.reaction_wheel.rul.predict import (
        cycle_from_profile,
        cycle_from_windows,
        read_profile,
    )

    if profile is not None:
        ts, T = read_profile(profile)
        return cycle_from_profile(ts, T, wheel.rul["forecast_window_h"] * 3600.0,
                                  description=f"the profile {Path(profile).name}, repeated")
    keep = np.asarray(sums.present, dtype=bool)
    q = sums.quad
    quad = WindowQuadrature(q.center[:, keep], q.scale[:, keep], q.nodes[:, keep],
                            q.weights[:, keep], np.asarray(q.count)[..., keep])
    return cycle_from_windows(quad, losses.start_s[keep], losses.end_s[keep],
                              repeat_days * 86400.0)


def ruls(posteriors: dict[str, Any], X_end: float, cycle: Any, threshold_mL: float,
         horizon_days: float) -> dict[str, Any]:
    """The RUL distribution of every tracker's posterior (step 3)."""
    from rulkit.systems.reaction_wheel.rul.predict import predict_rul

    return {name: predict_rul(parts, weights, X_end, cycle, threshold_mL, horizon_days)
            for name, (parts, weights) in posteriors.items()}


class _EstimateFileStream:
    """Step 1 read from an estimate file: the window sums and the hourly summary."""

    def __init__(self, record: WheelRecord, wheel: Any, options: PipelineOptions) -> None:
        self.record, self.wheel, self.options = record, wheel, options
        self.hourly = HourlySummary()
        self.acc: Any = None
        self.rows, self.first, self.last = 0, float("nan"), float("nan")

    def run(self) -> None:
        from rulkit.systems.reaction_wheel.degradation.windows import (
            WindowAccumulator,
            iter_temperature_estimate,
            read_losses,
        )

        assert self.record.temperature is not None
        for t, T, dt in iter_temperature_estimate(self.record.temperature,
                                                  self.options.chunk_rows):
            if self.acc is None:
                self.first = float(t[0])
                if self.record.losses is not None:
                    self.acc = WindowAccumulator(read_losses(self.record.losses, self.first),
                                                 self.wheel.degradation.n_nodes)
            self.hourly.add(t, T, T, T)
            if self.acc is not None:
                self.acc.add(t, T, dt)
            self.rows += t.size
            self.last = float(t[-1])


def _from_estimate_file(record: WheelRecord, wheel: Any, opts: PipelineOptions,
                        out: Path) -> PipelineResult:
    """Steps 2-3 on a step-1 estimate file (``record.temperature``)."""
    t0 = time.perf_counter()
    s = _EstimateFileStream(record, wheel, opts)
    s.run()
    result = PipelineResult(record, wheel, opts, s.rows, (s.first, s.last),
                            [f"step 1 read from {record.temperature}"], s.hourly.frame())
    result.timings["reading the step-1 estimate"] = time.perf_counter() - t0
    return _after_step_1(s, result, out)


def _write_samples(df: Any, dest: Path) -> None:
    """One file's per-sample estimate, written whole (tmp then rename)."""
    from rulkit.tables import TableWriter

    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = dest.with_name(f".{dest.name}.{os.getpid()}.partial")
    with TableWriter(tmp, fmt="parquet") as w:
        w.write(df)
    os.replace(tmp, dest)


def _notes(stream: Step1Stream) -> list[str]:
    notes = estimate_notes(stream.est, stream.check.n_out_of_range)
    return [n.removeprefix("note: ").removeprefix("warning: ") for n in notes]


def _fleet_task(task: tuple[WheelRecord, str, PipelineOptions], rng: np.random.Generator
                ) -> dict[str, Any]:
    """One wheel of :func:`run_fleet` (``rng`` unused: the options carry the seed)."""
    from rulkit.systems.reaction_wheel.record_report import summary_row

    record, out, opts = task
    return summary_row(run_pipeline(record, Path(out), opts))


def run_fleet(records: list[WheelRecord], out: Path, options: PipelineOptions, *,
              workers: int = 1, scheduler: str | None = None, progress: Any = None) -> Any:
    """Every record into ``out/<name>/`` as independent tasks (serial, ``workers`` processes
    or a Dask ``scheduler``, :func:`rulkit.runner.run_independent`); writes and returns the
    fleet table ``out/fleet.csv`` (one row per wheel,
    :func:`rulkit.systems.reaction_wheel.record_report.summary_row`)."""
    import pandas as pd

    from rulkit.runner import run_independent

    names = [r.name for r in records]
    if len(set(names)) != len(names):
        raise PipelineError(f"two records share a name ({names}); give them distinct "
                            "directory or file names")
    tasks = [(r, str(Path(out) / r.name), options) for r in records]
    rows = run_independent(_fleet_task, tasks, seed=options.seed, workers=workers,
                           scheduler=scheduler, progress=progress, description="wheels")
    table = pd.DataFrame(rows)
    Path(out).mkdir(parents=True, exist_ok=True)
    table.to_csv(Path(out) / "fleet.csv", index=False)
    return table


# --------------------------------------------------------------------------------------------
# rulkit rw estimate-temperature: one file, step 1 only


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
        first = (f", the first speed sample not used at time_s = {est.first_untrusted:.10g}"
                 if est.first_untrusted is not None else "")
        notes.append("note: " + "; ".join(counts) + first + " (column 'flags')")
    return notes


def options_dict(opts: PipelineOptions) -> dict[str, Any]:
    """The options as a plain dict (for the report)."""
    return asdict(opts)


def with_options(opts: PipelineOptions, **kw: Any) -> PipelineOptions:
    """A copy of ``opts`` with fields replaced (``None`` values ignored)."""
    return replace(opts, **{k: v for k, v in kw.items() if v is not None})
