"""Compile an export with the system C compiler and run it beside the Python reference
(docs/rul-on-the-device.md section 4).

:func:`build` writes the generated sources and a PC harness (``templates/harness.c.j2``) into a
directory and compiles them into a shared library with the strict flags of
:data:`STRICT_FLAGS`; :class:`DeviceLibrary` drives it through ``ctypes`` over many components'
acquisitions in one call; :func:`python_reference` computes the same outputs with
:func:`~rulkit.fleet.tracking.tracker_run.tracker_run` and the learned model's own replay and
RUL quantiles (:mod:`rulkit.fleet.learned.degradation`, :mod:`rulkit.fleet.learned.hi_noise`);
:func:`relative_error` and :func:`scaled_error` measure how far apart they are.
"""

from __future__ import annotations

import ctypes
import math
import os
import shutil
import subprocess
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from rulkit.fleet.export.device_spec import DeviceSpec, ExportError
from rulkit.fleet.export.generator import generate_c, template_environment

FloatArray = NDArray[np.float64]
STRICT_FLAGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2")
SANITIZE_FLAGS = ("-fsanitize=undefined,address", "-fno-sanitize-recover=all",
                  "-fno-omit-frame-pointer", "-g")
REAL_COLUMNS = ("hi", "fhi", "dhi", "rul", "frul", "drul", "d2rul", "rul_low", "rul_high")
LEARNED_COLUMNS = ("rul_median", "rul_p05", "rul_p95")
FLAG_COLUMNS = ("valid", "level", "new_alert", "status")
_RUL_COLUMNS = ("rul", "frul", "drul", "d2rul", "rul_low", "rul_high", *LEARNED_COLUMNS)
ERROR_BOUNDS: dict[str, dict[str, float]] = {
    "float": {"hi": 1e-6, "fhi": 1e-5, "dhi": 1e-3, **dict.fromkeys(_RUL_COLUMNS, 1e-2)},
    "fixed": {"hi": 1e-7, "fhi": 1e-6, "dhi": 1e-4, **dict.fromkeys(_RUL_COLUMNS, 2e-3)},
}
"""The largest :func:`scaled_error` (max |C - Python| / max |Python| over a record) the tests
accept per output and number format (docs/rul-on-the-device.md section 4). Float: a 24-bit
significand (6e-8) per operation, amplified in the RUL by the division by the small rate dHI
and by the trackers' recursions; fixed: the resolutions of section 3 (HI 7.5e-9, dHI 3e-5 of
the floor) with the same amplification. The flags (validity, level) may differ only where the
reference lies within the bound of a decision threshold."""


def compiler() -> str | None:
    """The C compiler: ``$CC``, else ``cc``, ``gcc`` or ``clang`` on the PATH (None if none)."""
    cc = os.environ.get("CC")
    if cc:
        return shutil.which(cc)
    for name in ("cc", "gcc", "clang"):
        found = shutil.which(name)
        if found:
            return found
    return None


def output_columns(device: DeviceSpec) -> tuple[str, ...]:
    """The columns of :meth:`DeviceLibrary.run`, in the harness's order."""
    return (*REAL_COLUMNS, *(LEARNED_COLUMNS if device.learned is not None else ()),
            *FLAG_COLUMNS)


def _harness_context(device: DeviceSpec, number: str, prefix: str) -> dict[str, Any]:
    from rulkit.fleet.export.generator import template_context

    ctx = template_context(device, number, prefix)
    if number == "fixed":
        from rulkit.fleet.export.fixed_point import fixed_context

        ctx.update(fixed_context(device))
    ctx["n_out"] = len(output_columns(device))
    ctx["n_in"] = device.hi_model.n if device.hi_model is not None else 1
    ctx["dt_double"] = repr(float(device.config.dt))
    return ctx


def _compile(cmd: list[str]) -> None:
    res = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise ExportError(f"{' '.join(cmd)} failed:\n{res.stderr}")


def write_sources(device: DeviceSpec, d: Path, number: str, prefix: str) -> dict[str, str]:
    """The export, its harness and its driver written into ``d`` (:class:`ExportError` when
    there is no C compiler to build them)."""
    cc = compiler()
    if cc is None:
        raise ExportError("no C compiler found (set CC, or install gcc: apt-get install gcc)")
    d.mkdir(parents=True, exist_ok=True)
    files = generate_c(device, number, prefix)
    ctx = _harness_context(device, number, prefix)
    env = template_environment()
    files[f"{prefix}_harness.c"] = env.get_template("harness.c.j2").render(**ctx)
    files[f"{prefix}_driver.c"] = env.get_template("driver.c.j2").render(**ctx)
    for name, text in files.items():
        (d / name).write_text(text)
    return files


def run_sanitized(device: DeviceSpec, workdir: str | Path, start: np.ndarray, t: np.ndarray,
                  x: np.ndarray, number: str = "double", prefix: str = "rk"
                  ) -> dict[str, np.ndarray]:
    """The export and its harness compiled as one program under
    ``-fsanitize=undefined,address`` (:data:`SANITIZE_FLAGS`), run over the acquisitions with
    every state kept as saved bytes; any sanitizer report fails the run
    (:class:`ExportError` with the report). Returns the outputs as :meth:`DeviceLibrary.run`."""
    d = Path(workdir)
    write_sources(device, d, number, prefix)
    exe = d / f"{prefix}_{number}_sanitized"
    cc = compiler()
    assert cc is not None
    _compile([cc, *STRICT_FLAGS, *SANITIZE_FLAGS, "-o", str(exe),
              *(str(d / f"{prefix}{s}.c") for s in ("", "_harness", "_driver")), "-lm"])
    n_in = device.hi_model.n if device.hi_model is not None else 1
    st = np.ascontiguousarray(start, dtype=np.uint32)
    blob = (np.array([st.size - 1, len(t)], dtype=np.uint32).tobytes() + st.tobytes()
            + np.ascontiguousarray(t, dtype=np.float64).tobytes()
            + np.ascontiguousarray(np.asarray(x, dtype=np.float64).reshape(-1, n_in)).tobytes())
    (d / "in.bin").write_bytes(blob)
    res = subprocess.run([str(exe), str(d / "in.bin"), str(d / "out.bin")],
                         capture_output=True, text=True, check=False)
    if res.returncode != 0 or res.stderr:
        raise ExportError(f"{exe} exited {res.returncode}:\n{res.stderr}")
    cols = output_columns(device)
    out = np.fromfile(d / "out.bin", dtype=np.float64).reshape(len(t), len(cols))
    return {c: out[:, j] for j, c in enumerate(cols)}


def build(device: DeviceSpec, workdir: str | Path, number: str = "double", prefix: str = "rk"
          ) -> DeviceLibrary:
    """Generate, compile (:data:`STRICT_FLAGS`) and load the export with its harness as a
    shared library (the sanitized run is :func:`run_sanitized`: a sanitizer runtime must be
    loaded first, which a library inside Python cannot). :class:`ExportError` without a
    compiler or when the compiler refuses the code (its messages included)."""
    d = Path(workdir)
    files = write_sources(device, d, number, prefix)
    cc = compiler()
    assert cc is not None
    # a name per content: the dynamic loader returns an already loaded library by its path
    digest = zlib.crc32("".join(files.values()).encode())
    lib = d / f"lib{prefix}_{number}_{digest:08x}.so"
    sources = [str(d / f"{prefix}.c"), str(d / f"{prefix}_harness.c")]
    cmd = [cc, *STRICT_FLAGS, "-fPIC", "-shared",
           "-o", str(lib), *sources, "-lm"]
    _compile(cmd)
    return DeviceLibrary(lib, device, prefix)


@dataclass
class DeviceLibrary:
    """A compiled export with its harness, loaded by ``ctypes``."""

    path: Path
    device: DeviceSpec
    prefix: str

    def __post_init__(self) -> None:
        self._lib = ctypes.CDLL(str(self.path))
        dbl = ctypes.POINTER(ctypes.c_double)
        u32 = ctypes.POINTER(ctypes.c_uint32)
        u8 = ctypes.POINTER(ctypes.c_uint8)
        f = getattr(self._lib, f"{self.prefix}_run_series")
        f.argtypes = [ctypes.c_uint32, u32, dbl, dbl, ctypes.c_int, dbl]
        f.restype = ctypes.c_int
        g = getattr(self._lib, f"{self.prefix}_state_after")
        g.argtypes = [ctypes.c_uint32, dbl, dbl, u8]
        g.restype = ctypes.c_int
        h = getattr(self._lib, f"{self.prefix}_resume")
        h.argtypes = [u8, ctypes.c_uint32, ctypes.c_double, dbl, u8, dbl]
        h.restype = ctypes.c_int
        c = getattr(self._lib, f"{self.prefix}_crc32")
        c.argtypes = [u8, ctypes.c_uint32]
        c.restype = ctypes.c_uint32
        self._run, self._after, self._resume, self._crc = f, g, h, c
        size = getattr(self._lib, f"{self.prefix}_state_struct_bytes")
        size.restype = ctypes.c_uint32
        self.state_struct_bytes = int(size())  # sizeof, as this compiler lays the struct out
        self.columns = output_columns(self.device)
        self.n_in = self.device.hi_model.n if self.device.hi_model is not None else 1

    def _inputs(self, x: np.ndarray) -> FloatArray:
        return np.ascontiguousarray(np.asarray(x, dtype=np.float64).reshape(-1, self.n_in))

    def run(self, start: np.ndarray, t: np.ndarray, x: np.ndarray,
            through_bytes: bool = False) -> dict[str, np.ndarray]:
        """Outputs per acquisition (:func:`output_columns`) of components whose rows are
        ``start[u]:start[u+1]`` of ``t`` (time) and ``x`` (HI, or one row of CIs)."""
        st = np.ascontiguousarray(start, dtype=np.uint32)
        tt = np.ascontiguousarray(t, dtype=np.float64)
        xx = self._inputs(x)
        out = np.empty((tt.size, len(self.columns)))
        ptr = ctypes.POINTER(ctypes.c_double)
        rc = self._run(st.size - 1, st.ctypes.data_as(ctypes.POINTER(ctypes.c_uint32)),
                       tt.ctypes.data_as(ptr), xx.ctypes.data_as(ptr), int(through_bytes),
                       out.ctypes.data_as(ptr))
        if rc < 0:
            raise ExportError("the state did not survive save / restore")
        return {c: out[:, j] for j, c in enumerate(self.columns)}

    def state_bytes(self, t: np.ndarray, x: np.ndarray, size: int) -> tuple[int, bytes]:
        """(status, saved state) of one component after the acquisitions ``t``, ``x``."""
        tt = np.ascontiguousarray(t, dtype=np.float64)
        xx = self._inputs(x)
        buf = (ctypes.c_uint8 * size)()
        ptr = ctypes.POINTER(ctypes.c_double)
        rc = self._after(tt.size, tt.ctypes.data_as(ptr), xx.ctypes.data_as(ptr), buf)
        return int(rc), bytes(buf)

    def resume(self, saved: bytes, t: float, x: np.ndarray) -> tuple[int, bytes, FloatArray]:
        """Restore ``saved``, assimilate one acquisition, save: (status, new bytes, outputs)."""
        src = (ctypes.c_uint8 * max(len(saved), 1)).from_buffer_copy(saved or b"\0")
        dst = (ctypes.c_uint8 * 4096)()
        row = np.full(len(self.columns), np.nan)
        xx = self._inputs(x)
        ptr = ctypes.POINTER(ctypes.c_double)
        rc = self._resume(src, len(saved), float(t), xx.ctypes.data_as(ptr), dst,
                          row.ctypes.data_as(ptr))
        return int(rc), bytes(dst), row

    def crc32(self, data: bytes) -> int:
        """The export's CRC-32 of ``data``."""
        buf = (ctypes.c_uint8 * max(len(data), 1)).from_buffer_copy(data or b"\0")
        return int(self._crc(buf, len(data)))


def segments(frame: pd.DataFrame) -> tuple[np.ndarray, pd.DataFrame]:
    """Acquisitions grouped by component (first-appearance order, time order inside) and the
    row offsets of each component: (start, sorted frame)."""
    codes, _ = pd.factorize(frame["component"], sort=False)
    order = np.lexsort((frame["time"].to_numpy(), codes))
    df = frame.iloc[order].reset_index(drop=True)
    counts = np.bincount(codes[order])
    return np.concatenate([[0], np.cumsum(counts)]).astype(np.int64), df


def python_reference(device: DeviceSpec, start: np.ndarray, t: np.ndarray, hi: np.ndarray
                     ) -> dict[str, np.ndarray]:
    """The outputs of the Python implementation for the same acquisitions (same columns as
    :meth:`DeviceLibrary.run`, without ``status``)."""
    from rulkit.fleet.learned.histories import Histories
    from rulkit.fleet.tracking.tracker_chain import TrackerState
    from rulkit.fleet.tracking.tracker_run import tracker_run

    b = start.size - 1
    _, rows = tracker_run(TrackerState.empty(b), start, t, hi, device.config)
    out = {"hi": np.asarray(hi, dtype=np.float64), **{k: rows[k] for k in (
        "fhi", "dhi", "rul", "frul", "drul", "d2rul", "rul_low", "rul_high")}}
    out["valid"] = rows["valid"].astype(np.float64)
    out["level"] = rows["level"].astype(np.float64)
    out["new_alert"] = _new_alerts(start, rows["level"])
    if device.learned is not None:
        from rulkit.fleet.store.learned_state import LEVELS

        unit = np.repeat(np.arange(b), np.diff(start))
        hist = Histories(unit=unit, t=np.asarray(t, dtype=np.float64),
                         hi=np.asarray(hi, dtype=np.float64),
                         names=np.arange(b).astype(object), start=start.astype(np.int64),
                         failed=np.zeros(b, dtype=bool), source="reference")
        # the device's event: the first measured crossing (eq. (5b)), or one measurement's
        q = device.learned.rul_quantiles(device.learned.replay(hist), LEVELS,
                                         one_reading=device.one_measurement)
        out.update(dict(zip(LEARNED_COLUMNS, q, strict=True)))
    return out


def _new_alerts(start: np.ndarray, level: np.ndarray) -> FloatArray:
    """1 where the level exceeds every earlier level of the component (the latched alert)."""
    new = np.zeros(level.size)
    for u in range(start.size - 1):
        top = 0
        for k in range(start[u], start[u + 1]):
            if level[k] > top:
                new[k], top = 1.0, int(level[k])
    return new


def long_records(rng: np.random.Generator, n_units: int = 4, n_acq: int = 20_000,
                 noise_sd: float = 0.01, irregular: bool = True
                 ) -> tuple[np.ndarray, FloatArray, FloatArray]:
    """Long run-to-failure records for the number-format errors: HI = h0 exp(k t) + noise
    (the Paris law with m = 2 of docs/systems/embedded-rul.md (EI-9)), h0 in [0.05, 0.3], the
    unit reaching HI = 1 after about ``n_acq`` acquisitions of mean interval 1 (exponential
    gaps of at least 0.1 if ``irregular``), HI clipped at 0. Returns (start, t, hi)."""
    ts, his = [], []
    for _ in range(n_units):
        gaps = rng.exponential(1.0, n_acq) if irregular else np.ones(n_acq)
        t = np.cumsum(np.maximum(gaps, 0.1))
        h0 = rng.uniform(0.05, 0.3)
        k = -np.log(h0) / t[-1]
        ts.append(t)
        his.append(np.maximum(h0 * np.exp(k * t) + noise_sd * rng.standard_normal(n_acq), 0.0))
    start = np.arange(n_units + 1, dtype=np.int64) * n_acq
    return start, np.concatenate(ts), np.concatenate(his)


def long_record_case(n_units: int = 2, n_acq: int = 20_000, seed: int = 1
                     ) -> tuple[DeviceSpec, np.ndarray, FloatArray, FloatArray]:
    """The long-record case of the number-format errors: :func:`long_records` (regular
    sampling) with the safe chain set for its time scale (life ~2e4 intervals: design life
    100 lives, warning 10 % of a life, validity 10 / life) and a learned Paris model (m = 2)
    of the same scale. Returns (device, start, t, hi)."""
    from rulkit.fleet.learned.degradation import DegradationModel
    from rulkit.fleet.tracking.tracker_chain import TrackerConfig

    cfg = TrackerConfig.safe(dt=1.0, design_life=2e6, hi_sigma=0.01, warn_rul=2000.0,
                             valid_d2rul=5e-4, lambda_hi=1e-4, lambda_rul=1e-3)
    model = DegradationModel("paris", 0.0, (-1.5, 1.5), (0.3, 0.0, 0.1), 0.02, 0.01, 2e4)
    start, t, hi = long_records(np.random.default_rng(seed), n_units, n_acq, irregular=False)
    return DeviceSpec("long", "long_record_case", cfg, None, model), start, t, hi


def scaled_error(got: np.ndarray, ref: np.ndarray) -> float:
    """max |got - ref| / max |ref| over the finite reference values (0 if all are 0): the
    error of a number format relative to the range of the quantity."""
    ok = np.isfinite(ref)
    scale = float(np.max(np.abs(ref[ok]), initial=0.0))
    diff = np.abs(np.asarray(got)[ok] - ref[ok])
    if not np.all(np.isfinite(diff)):
        return math.inf
    return float(diff.max(initial=0.0)) / scale if scale > 0 else float(diff.max(initial=0.0))


def relative_error(got: np.ndarray, ref: np.ndarray, floor: float = 0.0) -> FloatArray:
    """|got - ref| / max(|ref|, floor) per element; 0 where both are equal (inf = inf, NaN =
    NaN), inf where only one of them is NaN or infinite."""
    got = np.asarray(got, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    same = (got == ref) | (np.isnan(got) & np.isnan(ref))
    with np.errstate(invalid="ignore", divide="ignore"):
        err = np.abs(got - ref) / np.maximum(np.abs(ref), floor)
    err = np.where(same, 0.0, err)
    return np.where(np.isnan(err), np.inf, err)


__all__ = [
    "ERROR_BOUNDS",
    "LEARNED_COLUMNS",
    "REAL_COLUMNS",
    "SANITIZE_FLAGS",
    "STRICT_FLAGS",
    "DeviceLibrary",
    "build",
    "compiler",
    "long_record_case",
    "long_records",
    "output_columns",
    "python_reference",
    "relative_error",
    "run_sanitized",
    "scaled_error",
    "segments",
]
