"""The lubricant temperature of a user's wheel telemetry, a whole frame at once or a record of
any length chunk by chunk in bounded memory (docs/systems/reaction-wheel.md §3, §3.4).

:class:`TemperatureEstimator` holds one filter's state between chunks: ``update(chunk)``
returns the estimates of that chunk's rows, and a record filtered in chunks gives the numbers
of one pass over the whole record (tested). The default, ``"imm"``, is the compiled
interacting multiple-model EKF of :mod:`rulkit.systems.reaction_wheel.temperature.ekf`: the
most accurate estimator on the simulated records of the tests and benchmarks, the only one
whose printed intervals are calibrated, and the one that takes a real record's defects (gaps,
empty cells, spikes, stuck sensors) in its stride. The particle filters carry their cloud
(:func:`rulkit.systems.reaction_wheel.temperature.kernels.pf_steps`), the RBPF its particles'
Kalman filters; they need complete, regularly sampled telemetry. Every filter runs on the time
since the record's first row, so the result does not depend on the time origin (epoch seconds
or Parquet timestamps give the numbers of a record starting at 0).
:func:`estimate_temperature` is the one-frame form; ``rulkit rw estimate-temperature`` streams a
file through :func:`rulkit.systems.reaction_wheel.telemetry.iter_wheel_telemetry`.

Every estimate is checked: a temperature below absolute zero or not finite raises
:class:`ImplausibleEstimateError` naming the row and time; estimates outside the range the
wheel model describes give a warning (``warning``).
"""

from __future__ import annotations

from dataclasses import replace
from statistics import NormalDist
from typing import Any

import numpy as np

from rulkit.systems.reaction_wheel.temperature import kernels as kern
from rulkit.systems.reaction_wheel.temperature.ekf import (
    FLAG_SPEED_UNUSED,
    PLAIN_EKF,
    EKFConfig,
    ekf_start,
    ekf_steps,
)
from rulkit.systems.reaction_wheel.temperature.particle import (
    DEFAULT_GATE_D2,
    TemperatureConfig,
    _prepare,
    kernel_settings,
)
from rulkit.systems.reaction_wheel.temperature.rbpf import RBPF_INTERVAL_NOTE
from rulkit.systems.reaction_wheel.wheel import NOISE_LEVELS, IthacoParams
from rulkit.systems.reaction_wheel.wheel_kernels import pack_params

#: Temperatures the wheel model describes (C): the viscous coefficient b_v(T) is positive
#: from below -30 C up to 215 C (docs/systems/reaction-wheel.md, (RW-7)).
MODEL_RANGE_C = (-30.0, 215.0)
ABSOLUTE_ZERO_C = -273.15
#: The columns of an estimate: ``flags`` are the bits of
#: :mod:`rulkit.systems.reaction_wheel.temperature.ekf` (``FLAG_*``; the particle filters set
#: only 1, a sample their gate did not trust); ``untrusted`` is bit 1 (the speed, which alone
#: carries the temperature, was not used).
OUTPUT_COLUMNS = ("time_s", "T_mean", "T_lo", "T_hi", "untrusted", "flags")
#: The estimators, the default first.
METHODS = ("imm", "ekf", "rbpf", "pf", "adaptive", "apf", "apf_eq28", "apf_tempered")
DEFAULT_METHOD = "imm"
#: The methods that accept gaps, empty cells and spikes (lenient telemetry).
ROBUST_METHODS = ("imm", "ekf")


class ImplausibleEstimateError(ValueError):
    """The filter's estimate left physics (non-finite or below absolute zero)."""


class EstimationError(ValueError):
    """A filter failed on the telemetry (the message names the source, row and time)."""


def noise_sigmas(noise: str | tuple[float, float]) -> tuple[float, float]:
    """``(sigma_w, sigma_I)`` of a seed Table 5 level ("low", "high") or given as a pair."""
    if isinstance(noise, str):
        if noise not in NOISE_LEVELS:
            raise ValueError(f"noise: expected one of {sorted(NOISE_LEVELS)} or "
                             "(sigma_w, sigma_I)")
        return NOISE_LEVELS[noise]
    sw, sI = float(noise[0]), float(noise[1])
    if not (sw > 0 and sI > 0):
        raise ValueError(f"noise: expected positive (sigma_w, sigma_I), got {noise}")
    return sw, sI


def method_config(method: str, n_particles: int, design: str, config: Any,
                  level: float) -> Any:
    """The settings object of ``method``: ``config`` when given (checked), else the method's
    defaults (:class:`EKFConfig` for "imm", :data:`PLAIN_EKF` for "ekf", the RBJ design for
    "rbpf", a gated :class:`TemperatureConfig` for the seed particle filters)."""
    q = (0.5 - level / 2, 0.5 + level / 2)
    if method in ROBUST_METHODS:
        if config is None:
            return EKFConfig() if method == "imm" else PLAIN_EKF
        if not isinstance(config, EKFConfig):
            raise ValueError(f"config: method {method!r} needs an EKFConfig")
        return config
    if method == "rbpf":
        from rulkit.systems.reaction_wheel.temperature.rbpf import RBPF_DESIGNS, RBPFConfig

        if config is None:
            name = "RBJ" if design == "F2" else design
            if name not in RBPF_DESIGNS:
                raise ValueError(f"design: method 'rbpf' takes one of {sorted(RBPF_DESIGNS)}, "
                                 f"got {design!r}")
            return replace(RBPF_DESIGNS[name], n_particles=n_particles, quantiles=q)
        if not isinstance(config, RBPFConfig):
            raise ValueError("config: method 'rbpf' needs an RBPFConfig")
        return config
    if design not in kern.DESIGNS:
        raise ValueError(f"design: expected one of {sorted(kern.DESIGNS)}, got {design!r}")
    return config or TemperatureConfig(design=design, variant=method,  # type: ignore[arg-type]
                                       n_particles=n_particles, quantiles=q,
                                       gate_d2=DEFAULT_GATE_D2)


class TemperatureEstimator:
    """One temperature filter run over a record given in consecutive chunks.

    ``method``: one of :data:`METHODS` (``"imm"`` the default; the particle filters need
    ``rng``); ``design``, ``noise``, ``config`` and ``level`` as in
    :func:`estimate_temperature`. ``dt`` the sampling step (s). ``source`` names the record in
    messages; ``params`` the wheel (default the seed's).

    ``update(chunk)``: ``chunk`` a clean telemetry frame (the columns of
    :data:`rulkit.systems.reaction_wheel.telemetry.COLUMNS`, float64, rows following the
    previous chunk's; ``attrs["row0"]`` its first row in the record, else counted here; empty
    cells and gaps only for :data:`ROBUST_METHODS`). Returns a frame with
    :data:`OUTPUT_COLUMNS`. ``warning`` and ``note`` hold what a user must be told about the
    whole run so far (``None`` when nothing).
    """

    def __init__(
        self,
        method: str = DEFAULT_METHOD,
        n_particles: int = 350,
        rng: np.random.Generator | None = None,
        *,
        dt: float,
        design: str = "F2",
        noise: str | tuple[float, float] = "low",
        config: Any = None,
        level: float = 0.95,
        source: str = "telemetry",
        params: IthacoParams | None = None,
    ) -> None:
        if method not in METHODS:
            raise ValueError(f"method: expected one of {', '.join(METHODS)}, got {method!r}")
        if not 0 < level < 1:
            raise ValueError(f"level: expected 0 < level < 1, got {level}")
        if method not in ROBUST_METHODS and method != "rbpf" and rng is None:
            raise ValueError("a particle-filter method needs rng (a numpy.random.Generator)")
        if method == "rbpf" and rng is None:
            raise ValueError("a particle-filter method needs rng (a numpy.random.Generator)")
        self.method, self.sigma, self.level, self.dt = method, noise_sigmas(noise), level, float(dt)
        self.source, self.rng, self.params = source, rng, params or IthacoParams()
        self.config = method_config(method, n_particles, design, config, level)
        self.rows = 0  # rows estimated so far
        self.note: str | None = RBPF_INTERVAL_NOTE if method == "rbpf" else None
        self.warning: str | None = None
        self._n_out, self._first_out = 0, ""
        self.n_untrusted = 0  # samples whose speed was not used, so far
        self.first_untrusted: float | None = None  # the time of the first
        self.flag_counts: dict[int, int] = {}  # rows per flag bit
        self._last: Any = None  # the previous chunk's last row (y, V, t)
        self._state: Any = None

    # ------------------------------------------------------------------ the filters
    def update(self, chunk: Any) -> Any:
        """Estimates for the rows of ``chunk`` (see the class docstring)."""
        import pandas as pd

        from rulkit.systems.reaction_wheel.telemetry import CURRENT, SPEED, TIME, VOLT

        row0 = int(chunk.attrs.get("row0", self.rows))
        if row0 != self.rows:
            raise ValueError(f"chunk starts at row {row0}, expected row {self.rows} (chunks "
                             "must follow each other)")
        t = np.array(chunk[TIME].to_numpy(dtype=np.float64))
        y = np.column_stack([chunk[SPEED].to_numpy(dtype=np.float64),
                             chunk[CURRENT].to_numpy(dtype=np.float64)])
        # a fresh writable copy: pandas (copy-on-write) hands out read-only views, and numba
        # compiles a read-only array as another type: the first chunk and the later ones
        # (writable, from np.concatenate) would run two separately compiled kernels, which
        # may differ in the last digit (one from the cache, one compiled in this process)
        V = np.array(chunk[VOLT].to_numpy(dtype=np.float64))
        if len(t) == 0:
            return pd.DataFrame({c: np.empty(0) for c in OUTPUT_COLUMNS})
        try:
            m, lo, hi, flags = self._filter(t, y, V)
        except EstimationError:
            raise
        except (ValueError, ArithmeticError, np.linalg.LinAlgError) as err:
            step = getattr(err, "step", None)  # FilterStepError: the index into ys
            r = None if step is None else int(step)
            where = (f"row {row0 + r} (time_s = {t[r]:g})" if r is not None and r < len(t)
                     else f"rows {row0}..{row0 + len(t) - 1}")
            raise EstimationError(f"{self.source}: {where}: the {self.method} filter failed "
                                  f"({err}); the telemetry does not follow the wheel model "
                                  "(wrong units, wrong noise level, or not this wheel)") from err
        self._last = (y[-1], V[-1], t[-1])
        self.rows += len(t)
        untrusted = (flags & FLAG_SPEED_UNUSED) != 0
        est = pd.DataFrame({"time_s": t, "T_mean": m, "T_lo": lo, "T_hi": hi,
                            "untrusted": untrusted, "flags": flags.astype(np.int8)})
        self._check(est, row0)
        self._count(t, untrusted, flags)
        return est

    def _filter(self, t: Any, y: Any, V: Any) -> tuple[Any, Any, Any, Any]:
        if self.method in ROBUST_METHODS:
            return self._ekf(t, y, V)
        if self.method == "rbpf":
            return self._rbpf(t, y, V)
        return self._pf(t, y, V)

    def _count(self, t: Any, untrusted: Any, flags: Any) -> None:
        if untrusted.any() and self.first_untrusted is None:
            self.first_untrusted = float(t[untrusted][0])
        self.n_untrusted += int(untrusted.sum())
        for bit in range(7):
            n = int(np.count_nonzero(flags & (1 << bit)))
            if n:
                self.flag_counts[1 << bit] = self.flag_counts.get(1 << bit, 0) + n

    def finish(self) -> None:
        """The verdict on the whole run: raises :class:`ImplausibleEstimateError` when most
        samples (more than half) had their speed not used (missing, stuck or refused by the
        outlier gate) or have estimates outside the range the wheel model describes: the
        output would then be the prior or a number with no physical meaning, so none is
        given."""
        half = self.rows / 2
        if self.n_untrusted > half:
            raise ImplausibleEstimateError(
                f"{self.source}: only {self.rows - self.n_untrusted} of {self.rows} speed "
                "samples could be used (the others were missing, stuck or refused by the "
                "outlier gate; the estimate would be the prior): the telemetry does not follow "
                "the wheel model (wrong units, wrong noise level, or not this wheel); nothing "
                "written")
        if self._n_out > half:
            raise ImplausibleEstimateError(
                f"{self.source}: {self._n_out} of {self.rows} estimates are outside "
                f"{MODEL_RANGE_C[0]:g}..{MODEL_RANGE_C[1]:g} C, the range the wheel model "
                f"describes (first: {self._first_out}): the telemetry does not follow the "
                "wheel model; nothing written")

    def state(self) -> tuple[dict[str, Any], dict[str, Any]]:
        """(arrays, values) that restore this run of a robust method in another process
        (:meth:`restore`): the filter's state and the counts behind :meth:`finish` and the
        notes. The particle filters' clouds and generators are not saved."""
        if self.method not in ROBUST_METHODS:
            raise ValueError(f"state: only the methods {ROBUST_METHODS} can be checkpointed")
        arrays = dict(self._state._asdict()) if self._state is not None else {}
        values = {"rows": self.rows, "n_untrusted": self.n_untrusted,
                  "first_untrusted": self.first_untrusted, "n_out": self._n_out,
                  "first_out": self._first_out, "warning": self.warning,
                  "flag_counts": {str(k): v for k, v in self.flag_counts.items()}}
        return arrays, values

    def restore(self, arrays: dict[str, Any], values: dict[str, Any]) -> None:
        """Continue the run saved by :meth:`state` (same method, settings and wheel)."""
        from rulkit.systems.reaction_wheel.temperature.ekf import EKFState

        if arrays:
            self._state = EKFState(*(np.array(arrays[f]) for f in EKFState._fields))
            cfg: EKFConfig = self.config
            self._ekf_settings = cfg.settings(self.dt, self.sigma)
            self._qT = np.array(cfg.q_T, dtype=np.float64)
            self._P = pack_params(self.params)
        self.rows, self.n_untrusted = int(values["rows"]), int(values["n_untrusted"])
        self.first_untrusted = values["first_untrusted"]
        self._n_out, self._first_out = int(values["n_out"]), str(values["first_out"])
        self.warning = values["warning"]
        self.flag_counts = {int(k): int(v) for k, v in values["flag_counts"].items()}

    def _pf(self, t: Any, y: Any, V: Any) -> tuple[Any, Any, Any, Any]:
        cfg = self.config
        first = self._state is None
        if first:
            d = _prepare(y, V, cfg, self.sigma, self.params, self.dt)
            self._inp = (d["S_inv"], d["init_sd"], pack_params(self.params))
            self._settings = kernel_settings(cfg, d, 0.0, self.dt)  # time since the start
            st, *row0 = kern.pf_start(d["y"][0], d["init_sd"], self._settings, self.rng)
            self._state = st
            yy, VV = d["y"], d["V"]
        else:
            yy = np.vstack([self._last[0][None], y])
            VV = np.concatenate([[self._last[1]], V])
        inp = kern.KernelInputs(yy, VV, *self._inp)
        out = kern.pf_steps(inp, self._settings, self.rng, self._state, max(self.rows - 1, 0))
        m, _, lo, hi = (a if first else a[1:] for a in out[:4])
        flag = out[9] if first else out[9][1:]
        if first:
            m[0], lo[0], hi[0] = row0[0], row0[2], row0[3]
        return m, lo, hi, flag.astype(np.int8)

    def _ekf(self, t: Any, y: Any, V: Any) -> tuple[Any, Any, Any, Any]:
        cfg: EKFConfig = self.config
        if self._state is None:
            self._state = ekf_start(len(cfg.q_T))
            self._ekf_settings = cfg.settings(self.dt, self.sigma)
            self._qT = np.array(cfg.q_T, dtype=np.float64)
            self._P = pack_params(self.params)
        m, sd, flags = ekf_steps(t, V, y, self._state, self._ekf_settings, self._qT, self._P)
        half = NormalDist().inv_cdf(0.5 + self.level / 2) * cfg.interval_scale * sd
        return m, m - half, m + half, flags

    def _rbpf(self, t: Any, y: Any, V: Any) -> tuple[Any, Any, Any, Any]:
        from rulkit.systems.reaction_wheel.temperature.rbpf import RBPFStream

        if self._state is None:
            assert self.rng is not None  # checked in __init__
            self._state = RBPFStream(self.rng, self.config, sigma=self.sigma, dt=self.dt,
                                     t0=0.0, params=self.params)  # time since the start
        m, lo, hi = self._state.update(y, V)
        return m, lo, hi, np.zeros(len(t), dtype=np.int8)

    # ------------------------------------------------------------------ the checks
    def _check(self, est: Any, row0: int) -> None:
        """Refuse a physically impossible estimate; note samples outside the model's range."""
        m = est["T_mean"].to_numpy()
        bad = ~np.isfinite(m) | (m < ABSOLUTE_ZERO_C)
        if bad.any():
            r = int(np.flatnonzero(bad)[0])
            raise ImplausibleEstimateError(
                f"{self.source}: the temperature estimate is {m[r]:.6g} C at time_s = "
                f"{est['time_s'].iloc[r]:.10g} (row {row0 + r}), below absolute zero or not "
                "finite: the telemetry does not follow the wheel model (wrong units, wrong "
                "noise level, or not this wheel); nothing written")
        lo, hi = MODEL_RANGE_C
        out = (m < lo) | (m > hi)
        if out.any():
            if not self._n_out:
                r = int(np.flatnonzero(out)[0])
                self._first_out = f"{m[r]:.4g} C at time_s = {est['time_s'].iloc[r]:.10g}"
            self._n_out += int(out.sum())
            self.warning = (
                f"{self._n_out} estimates outside {lo:g}..{hi:g} C, the range the wheel model "
                f"describes (first: {self._first_out}); treat them as a sign the telemetry "
                "does not fit the model")


def estimate_temperature(
    df: Any,
    method: str = DEFAULT_METHOD,
    n_particles: int = 350,
    rng: np.random.Generator | None = None,
    *,
    design: str = "F2",
    noise: str | tuple[float, float] = "low",
    config: Any = None,
    level: float = 0.95,
    params: IthacoParams | None = None,
) -> Any:
    """Estimate the lubricant temperature from wheel telemetry (docs/systems/reaction-wheel.md §3).

    ``df``: a frame with columns time_s, v_comm_V, speed_rad_s, current_A (validated with
    :func:`rulkit.systems.reaction_wheel.telemetry.validate_wheel_telemetry`, leniently for
    :data:`ROBUST_METHODS`).
    ``method``: ``"imm"`` (the default: the interacting multiple-model EKF, calibrated
    intervals, robust to a record's defects; ``config`` an :class:`EKFConfig`), ``"ekf"`` (one
    model, q_T = 0.02 C per sample), ``"rbpf"`` (Rao-Blackwellised PF, beyond the seeds:
    ``design`` one of :data:`rulkit.systems.reaction_wheel.temperature.rbpf.RBPF_DESIGNS`, "RBJ"
    when ``design`` is left at "F2"), or the seeds' particle filters ``"pf"``, ``"adaptive"``,
    ``"apf"`` (auxiliary PF after Pitt and Shephard), ``"apf_eq28"``, ``"apf_tempered"``
    (outlier-gated, see
    :data:`rulkit.systems.reaction_wheel.temperature.particle.DEFAULT_GATE_D2`); the particle
    filters need ``rng``.
    ``noise``: the measurement-noise level assumed ("low", "high" of seed Table 5, or
    ``(sigma_w, sigma_I)``); ``params`` the wheel. Raises :class:`ImplausibleEstimateError` for
    an estimate below absolute zero and when most samples are untrusted or out of the model's
    range (:meth:`TemperatureEstimator.finish`). Returns a DataFrame (:data:`OUTPUT_COLUMNS`)
    with the ``level`` interval (the IMM's calibrated mean +- z scale sd, the EKF's mean +- z
    sd, weighted particle quantiles) and ``attrs`` ``"note"`` / ``"warning"`` when there is
    something to say.
    """
    from rulkit.systems.reaction_wheel.telemetry import validate_wheel_telemetry

    clean = validate_wheel_telemetry(df, source="telemetry", lenient=method in ROBUST_METHODS)
    est = TemperatureEstimator(method, n_particles, rng, dt=float(clean.attrs["dt"]),
                               design=design, noise=noise, config=config, level=level,
                               params=params)
    out = est.update(clean)
    est.finish()
    for key in ("note", "warning"):
        if getattr(est, key):
            out.attrs[key] = getattr(est, key)
    return out
