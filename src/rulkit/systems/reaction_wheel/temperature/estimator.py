"""The lubricant temperature of a user's wheel telemetry, a whole frame at once or a record of
any length chunk by chunk in bounded memory (docs/systems/reaction-wheel.md §3).

:class:`TemperatureEstimator` holds one filter's state between chunks: ``update(chunk)``
returns the estimates of that chunk's rows, and a record filtered in chunks gives the numbers
of one pass over the whole record (tested). The particle filters carry their cloud
(:func:`rulkit.systems.reaction_wheel.temperature.kernels.pf_steps`), the EKF its mean and
covariance,
the RBPF its particles' Kalman filters. :func:`estimate_temperature` is the one-frame
form; ``rulkit rw estimate-temperature`` streams a file through
:func:`rulkit.systems.reaction_wheel.telemetry.iter_wheel_telemetry`.

Every estimate is checked: a temperature below absolute zero or not finite raises
:class:`ImplausibleEstimateError` naming the row and time; estimates outside the range the
wheel model describes give a warning (``warning``).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from rulkit.systems.reaction_wheel.temperature import kernels as kern
from rulkit.systems.reaction_wheel.temperature.ekf import ekf_setup
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


#: The columns of an estimate.
OUTPUT_COLUMNS = ("time_s", "T_mean", "T_lo", "T_hi", "untrusted")


METHODS = ("adaptive", "apf_eq28", "apf_tempered", "pf", "rbpf", "ekf")


class ImplausibleEstimateError(ValueError):
    """The filter's estimate left physics (non-finite or below absolute zero)."""


class EstimationError(ValueError):
    """A filter failed on the telemetry (the message names the source, row and time)."""


class TemperatureEstimator:
    """One temperature filter run over a record given in consecutive chunks.

    ``method``: ``"pf"``, ``"adaptive"`` (the default), ``"apf_eq28"``, ``"apf_tempered"``
    (particle filters; need ``rng``), ``"rbpf"`` or ``"ekf"``; ``design``,
    ``noise``, ``config`` and ``level`` as in :func:`estimate_temperature`. ``dt`` the
    sampling step (s). ``source`` names the record in messages.

    ``update(chunk)``: ``chunk`` a clean telemetry frame (the columns of
    :data:`rulkit.systems.reaction_wheel.telemetry.COLUMNS`, float64, rows following the
    previous chunk's; ``attrs["row0"]`` its first row in the record, else counted here).
    Returns a frame with :data:`OUTPUT_COLUMNS`. ``warning`` and ``note`` hold what a user
    must be told about the whole run so far (``None`` when nothing).
    """

    def __init__(
        self,
        method: str = "adaptive",
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
        if isinstance(noise, str):
            if noise not in NOISE_LEVELS:
                raise ValueError(f"noise: expected one of {sorted(NOISE_LEVELS)} or "
                                 "(sigma_w, sigma_I)")
            sigma = NOISE_LEVELS[noise]
        else:
            sigma = (float(noise[0]), float(noise[1]))
        if not 0 < level < 1:
            raise ValueError(f"level: expected 0 < level < 1, got {level}")
        if method not in METHODS:
            raise ValueError(f"method: expected 'ekf', 'rbpf' or one of "
                             f"{sorted(kern.VARIANTS)}, got {method!r}")
        if method != "ekf" and rng is None:
            raise ValueError("a particle-filter method needs rng (a numpy.random.Generator)")
        self.method, self.sigma, self.level, self.dt = method, sigma, level, float(dt)
        self.source, self.rng, self.params = source, rng, params or IthacoParams()
        self.rows = 0  # rows estimated so far
        self.note: str | None = None
        self.warning: str | None = None
        self._n_out, self._first_out = 0, ""
        self.n_untrusted = 0  # samples the outlier gate did not trust, so far
        self.first_untrusted: float | None = None  # the time of the first
        self._last: Any = None  # the previous chunk's last row (y, V, t)
        q = (0.5 - level / 2, 0.5 + level / 2)
        if method == "rbpf":
            from rulkit.systems.reaction_wheel.temperature.rbpf import RBPF_DESIGNS, RBPFConfig

            if config is None:
                name = "RBJ" if design == "F2" else design
                if name not in RBPF_DESIGNS:
                    raise ValueError(f"design: method 'rbpf' takes one of "
                                     f"{sorted(RBPF_DESIGNS)}, got {design!r}")
                config = replace(RBPF_DESIGNS[name], n_particles=n_particles, quantiles=q)
            elif not isinstance(config, RBPFConfig):
                raise ValueError("config: method 'rbpf' needs an RBPFConfig")
            self.note = RBPF_INTERVAL_NOTE
        elif method != "ekf":
            if design not in kern.DESIGNS:
                raise ValueError(f"design: expected one of {sorted(kern.DESIGNS)}, got "
                                 f"{design!r}")
            config = config or TemperatureConfig(
                design=design, variant=method,  # type: ignore[arg-type]
                n_particles=n_particles, quantiles=q, gate_d2=DEFAULT_GATE_D2)
        self.config = config
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
        t = chunk[TIME].to_numpy(dtype=np.float64)
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
            if self.method == "ekf":
                m, lo, hi, flag = self._ekf(t, y, V)
            elif self.method == "rbpf":
                m, lo, hi, flag = self._rbpf(t, y, V)
            else:
                m, lo, hi, flag = self._pf(t, y, V)
        except EstimationError:
            raise
        except (ValueError, ArithmeticError, np.linalg.LinAlgError) as err:
            step = getattr(err, "step", None)  # FilterStepError: the index into ys
            first = self.method == "ekf" and row0 == 0  # ys starts at row 1 (row 0: prior)
            r = None if step is None else int(step) + first
            where = (f"row {row0 + r} (time_s = {t[r]:g})" if r is not None and r < len(t)
                     else f"rows {row0}..{row0 + len(t) - 1}")
            raise EstimationError(f"{self.source}: {where}: the {self.method} filter failed "
                                  f"({err}); the telemetry does not follow the wheel model "
                                  "(wrong units, wrong noise level, or not this wheel)") from err
        self._last = (y[-1], V[-1], t[-1])
        self.rows += len(t)
        est = pd.DataFrame({"time_s": t, "T_mean": m, "T_lo": lo, "T_hi": hi,
                            "untrusted": flag.astype(bool)})
        self._check(est, row0)
        bad = est["untrusted"].to_numpy()
        if bad.any() and self.first_untrusted is None:
            self.first_untrusted = float(t[bad][0])
        self.n_untrusted += int(bad.sum())
        return est

    def finish(self) -> None:
        """The verdict on the whole run: raises :class:`ImplausibleEstimateError` when most
        samples (more than half) were not trusted by the outlier gate or have estimates
        outside the range the wheel model describes: the output would then be the prior or
        a number with no physical meaning, so none is given."""
        half = self.rows / 2
        if self.n_untrusted > half:
            raise ImplausibleEstimateError(
                f"{self.source}: the outlier gate trusted only {self.rows - self.n_untrusted} "
                f"of {self.rows} samples (the estimate would be the prior): the telemetry does "
                "not follow the wheel model (wrong units, wrong --noise level, or not this "
                "wheel); nothing written")
        if self._n_out > half:
            raise ImplausibleEstimateError(
                f"{self.source}: {self._n_out} of {self.rows} estimates are outside "
                f"{MODEL_RANGE_C[0]:g}..{MODEL_RANGE_C[1]:g} C, the range the wheel model "
                f"describes (first: {self._first_out}): the telemetry does not follow the "
                "wheel model; nothing written")

    def _pf(self, t: Any, y: Any, V: Any) -> tuple[Any, Any, Any, Any]:
        cfg = self.config
        first = self._state is None
        if first:
            d = _prepare(y, V, cfg, self.sigma, self.params, self.dt)
            self._inp = (d["S_inv"], d["init_sd"], pack_params(self.params))
            self._settings = kernel_settings(cfg, d, float(t[0]), self.dt)
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
        return m, lo, hi, flag

    def _ekf(self, t: Any, y: Any, V: Any) -> tuple[Any, Any, Any, Any]:
        from statistics import NormalDist

        z = NormalDist().inv_cdf(0.5 + self.level / 2)
        if self._state is None:
            ekf, x0, P0, clock = ekf_setup(y[None, 0], self.sigma, self.params)
            self._state = [ekf, clock, x0, P0]
            self._t0 = float(t[0])
            ys, us, t_base = y[1:], V[:-1], self._t0
        else:  # step j of this call starts at the previous chunk's last row
            ys, us = y, np.concatenate([[self._last[1]], V[:-1]])
            t_base = self._t0 + (self.rows - 1) * self.dt
        ekf, clock, x, P = self._state
        clock.t0, clock.dt = t_base, self.dt
        res = ekf.filter(ys[:, None, :], x, P, us=us)
        self._state[2:] = [res.x[-1], res.P[-1]]
        m, s = res.x[:, 0, 2], np.sqrt(res.P[:, 0, 2, 2])
        if len(ys) < len(t):  # the first chunk: row 0 is the prior
            m = np.concatenate([[x[0, 2]], m])
            s = np.concatenate([[math.sqrt(P[0, 2, 2])], s])
        return m, m - z * s, m + z * s, np.zeros(len(t), dtype=bool)

    def _rbpf(self, t: Any, y: Any, V: Any) -> tuple[Any, Any, Any, Any]:
        from rulkit.systems.reaction_wheel.temperature.rbpf import RBPFStream

        if self._state is None:
            assert self.rng is not None  # checked in __init__
            self._state = RBPFStream(self.rng, self.config, sigma=self.sigma, dt=self.dt,
                                     t0=float(t[0]), params=self.params)
        m, lo, hi = self._state.update(y, V)
        return m, lo, hi, np.zeros(len(t), dtype=bool)

    # ------------------------------------------------------------------ the checks
    def _check(self, est: Any, row0: int) -> None:
        """Refuse a physically impossible estimate; note samples outside the model's range."""
        m = est["T_mean"].to_numpy()
        bad = ~np.isfinite(m) | (m < ABSOLUTE_ZERO_C)
        if bad.any():
            r = int(np.flatnonzero(bad)[0])
            raise ImplausibleEstimateError(
                f"{self.source}: the temperature estimate is {m[r]:.6g} C at time_s = "
                f"{est['time_s'].iloc[r]:g} (row {row0 + r}), below absolute zero or not "
                "finite: the telemetry does not follow the wheel model (wrong units, wrong "
                "noise level, or not this wheel); nothing written")
        lo, hi = MODEL_RANGE_C
        out = (m < lo) | (m > hi)
        if out.any():
            if not self._n_out:
                r = int(np.flatnonzero(out)[0])
                self._first_out = f"{m[r]:.4g} C at time_s = {est['time_s'].iloc[r]:g}"
            self._n_out += int(out.sum())
            self.warning = (
                f"{self._n_out} estimates outside {lo:g}..{hi:g} C, the range the wheel model "
                f"describes (first: {self._first_out}); treat them as a sign the telemetry "
                "does not fit the model")


def estimate_temperature(
    df: Any,
    method: str = "adaptive",
    n_particles: int = 350,
    rng: np.random.Generator | None = None,
    *,
    design: str = "F2",
    noise: str | tuple[float, float] = "low",
    config: Any = None,
    level: float = 0.95,
) -> Any:
    """Estimate the lubricant temperature from wheel telemetry (docs/systems/reaction-wheel.md §3).

    ``df``: a frame with columns time_s, v_comm_V, speed_rad_s, current_A (validated with
    :func:`rulkit.systems.reaction_wheel.telemetry.validate_wheel_telemetry`; regular sampling,
    its step is dt).
    ``method``: ``"pf"``, ``"adaptive"``, ``"apf_eq28"``, ``"apf_tempered"`` (particle filters,
    need ``rng``; outlier-gated, see
    :data:`rulkit.systems.reaction_wheel.temperature.particle.DEFAULT_GATE_D2`), ``"rbpf"``
    (Rao-Blackwellised PF, beyond the seeds: ``design`` one of
    :data:`rulkit.systems.reaction_wheel.temperature.rbpf.RBPF_DESIGNS`, "RBJ" when ``design`` is
    left at
    "F2"; ``config`` may be an :class:`RBPFConfig`) or ``"ekf"`` (deterministic).
    ``noise``: the measurement-noise level assumed ("low", "high" of seed Table 5, or
    ``(sigma_w, sigma_I)``). ``config`` overrides every PF setting. Raises
    :class:`ImplausibleEstimateError` for an estimate below absolute zero and when most samples
    are untrusted or out of the model's range (:meth:`TemperatureEstimator.finish`). Returns a
    DataFrame
    (:data:`OUTPUT_COLUMNS`) with the ``level`` interval (weighted particle quantiles; for the
    EKF mean +- z sd) and ``untrusted`` the samples the outlier gate did not trust; ``attrs``
    ``"note"`` / ``"warning"`` when there is something to say.

    Which method: on the simulated Table 3 path the EKF reference is the most accurate and the
    F2 particle filters beat the seed-faithful F1 (compare the rows of
    ``run_table5(designs=("F1", "F2"), extra=True)``); the seed particle filters' intervals
    are overconfident after the 50 s temperature step (see ``plot_temperature_estimates``).
    Among particle filters use ``"rbpf"``: with q_T = 0.02 C per sample the Gaussian random
    walk gives the 8 C step at 50 s no prior mass, the cloud lags and then overshoots (its
    speeds can only be corrected through T), so every q_T = 0.02 PF is poor for ~200 s. With
    [I, w] marginalised, "RB05" (q_T = 0.05) matches the EKF run with the same q_T, and "RBJ"
    (q_T = 0.01 plus proposed jumps; the default) matches the q_T = 0.02 EKF after 100 s and
    beats it over 0-500 s at N >= 100 (``run_table5(designs=("RB05", "RBJ"),
    coverage=True)``).
    """
    from rulkit.systems.reaction_wheel.telemetry import validate_wheel_telemetry

    clean = validate_wheel_telemetry(df, source="telemetry")
    est = TemperatureEstimator(method, n_particles, rng, dt=float(clean.attrs["dt"]),
                               design=design, noise=noise, config=config, level=level)
    out = est.update(clean)
    est.finish()
    for key in ("note", "warning"):
        if getattr(est, key):
            out.attrs[key] = getattr(est, key)
    return out
