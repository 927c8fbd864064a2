"""Monte Carlo propagation to a failure threshold and the RUL distribution it produces.

Contract: docs/engine-api.md, section ``rulkit.prognosis.rul``: a small, frozen result type
holding arrays (a RUL distribution = samples + weights + censoring); docs/guide.md, "Censoring".

Censoring convention (decided here, used everywhere in rulkit)
-------------------------------------------------------------
A sample that does not reach the threshold within the prediction horizon ``h`` is *right
censored*: its true RUL is only known to exceed ``h``. It is kept (counted, never dropped) with
its value set to the lower bound ``h`` and ``censored[i] = True``. Then

* ``quantile(q)`` is the inverse of the weighted empirical CDF with censored samples placed at
  ``+inf``: it returns ``inf`` when ``q`` falls inside the censored mass (the quantile is known
  only to lie beyond the horizon);
* ``mean`` and ``std`` are the *restricted* mean and standard deviation of ``min(RUL, h)``
  (the restricted mean survival time of survival analysis): a lower bound of the true mean
  when ``fraction_censored > 0`` and the ordinary weighted mean when nothing is censored.
  ``mean_uncensored`` is the conditional mean over the samples that did cross;
* ``pdf(grid)`` is a weighted Gaussian KDE of the uncensored samples scaled by the uncensored
  mass ``1 - fraction_censored`` (a sub-density; the censored mass sits beyond the horizon).
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rulkit.estimation.base import Posterior
from rulkit.model import input_at, plain

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

_FORMAT = "rulkit.RULDistribution"
_VERSION = 1
# weights whose sum is within this of 1 are kept bit-for-bit (so that JSON/CSV round-trips are
# exact); others are divided by their sum.
_SUM_TOL = 1e-12


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, copy=True)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class RULDistribution:
    """A Remaining Useful Life distribution given by weighted, possibly right-censored samples.

    Parameters
    ----------
    samples
        RUL samples, shape (N,), finite and >= 0. For a censored sample the value is a lower
        bound of its RUL (``propagate_to_threshold`` stores the horizon there).
    weights
        Non-negative importance weights, shape (N,), not all zero; ``None`` means equal weights.
        Stored normalised to sum 1.
    censored
        Boolean mask, shape (N,): True where the sample did not fail within the horizon.
        ``None`` means no sample is censored.
    horizon
        Length of the prediction window (RUL units); ``inf`` when unbounded. When finite, every
        uncensored sample must be <= horizon.

    The treatment of censored samples by every statistic is described in the module docstring.
    Arrays are stored read-only; the object is immutable.
    """

    samples: FloatArray
    # None is accepted and replaced in __post_init__ (uniform weights, nothing censored), so
    # the attributes are always arrays: typed as such for the readers.
    weights: FloatArray = None  # type: ignore[assignment]
    censored: BoolArray = None  # type: ignore[assignment]
    horizon: float = math.inf
    _sorted_values: FloatArray = field(init=False, repr=False)
    _sorted_cumw: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        raw = np.asarray(self.samples)
        if raw.ndim != 1:
            raise ValueError(f"samples: expected a 1-D array (N,), got shape {raw.shape}")
        s = raw.astype(np.float64)
        n = s.shape[0]
        if n == 0:
            raise ValueError("samples: empty; a RUL distribution needs at least one sample")
        bad = np.flatnonzero(~np.isfinite(s))
        if bad.size:
            raise ValueError(
                f"samples: non-finite value {float(s[bad[0]])!r} at index {bad[0]} "
                f"({bad.size} non-finite in total); censored samples carry a finite lower bound"
            )
        neg = np.flatnonzero(s < 0)
        if neg.size:
            raise ValueError(f"samples: negative RUL {float(s[neg[0]])!r} at index {neg[0]}")

        if self.weights is None:
            w = np.full(n, 1.0 / n)
        else:
            w = np.asarray(self.weights, dtype=np.float64)
            if w.shape != (n,):
                raise ValueError(f"weights: expected shape ({n},) like samples, got {w.shape}")
            badw = np.flatnonzero(~np.isfinite(w))
            if badw.size:
                i = badw[0]
                raise ValueError(f"weights: non-finite value {float(w[i])!r} at index {i}")
            negw = np.flatnonzero(w < 0)
            if negw.size:
                i = negw[0]
                raise ValueError(f"weights: negative weight {float(w[i])!r} at index {i}")
            total = w.sum()
            if not total > 0:
                raise ValueError("weights: all zero; at least one weight must be positive")
            if abs(total - 1.0) > _SUM_TOL:
                w = w / total

        if self.censored is None:
            c = np.zeros(n, dtype=bool)
        else:
            c_raw = np.asarray(self.censored)
            if c_raw.shape != (n,):
                raise ValueError(
                    f"censored: expected shape ({n},) like samples, got {c_raw.shape}"
                )
            if c_raw.dtype != np.bool_:
                if not np.all(np.isin(c_raw, (0, 1))):
                    raise ValueError("censored: expected booleans (or 0/1)")
            c = c_raw.astype(bool)

        h = float(self.horizon)
        if math.isnan(h) or h <= 0:
            raise ValueError(f"horizon: expected a positive number or inf, got "
                             f"{plain(self.horizon)}")
        if math.isfinite(h):
            over = np.flatnonzero(~c & (s > h * (1 + 1e-12)))
            if over.size:
                raise ValueError(
                    f"samples: uncensored sample {float(s[over[0]])!r} at index {over[0]} "
                    "exceeds "
                    f"the horizon {plain(h)}; mark it censored or raise the horizon"
                )

        # sort once: censored samples go to +inf (module docstring)
        key = np.where(c, np.inf, s)
        order = np.argsort(key, kind="stable")
        object.__setattr__(self, "samples", _readonly(s))
        object.__setattr__(self, "weights", _readonly(w))
        object.__setattr__(self, "censored", _readonly(c))
        object.__setattr__(self, "horizon", h)
        object.__setattr__(self, "_sorted_values", _readonly(key[order]))
        object.__setattr__(self, "_sorted_cumw", _readonly(np.cumsum(w[order])))

    # ------------------------------------------------------------------ basic properties
    @property
    def n(self) -> int:
        """Number of samples (censored ones included)."""
        return int(self.samples.shape[0])

    @property
    def n_censored(self) -> int:
        """Number of censored samples."""
        return int(np.count_nonzero(self.censored))

    @property
    def fraction_censored(self) -> float:
        """Weight (probability mass) of the censored samples, in [0, 1]."""
        return float(self.weights[self.censored].sum())

    @property
    def effective_sample_size(self) -> float:
        """Kish's effective sample size 1 / sum(w^2) of the normalised weights."""
        return float(1.0 / np.sum(self.weights**2))

    # ------------------------------------------------------------------ moments
    @property
    def mean(self) -> float:
        """Restricted mean ``E[min(RUL, h)]`` = ``sum_i w_i s_i`` (censored at their bound).

        Equals the ordinary weighted mean when nothing is censored; a lower bound of the true
        mean otherwise (check :attr:`fraction_censored`).
        """
        return float(np.dot(self.weights, self.samples))

    @property
    def std(self) -> float:
        """Weighted standard deviation of ``min(RUL, h)`` (same convention as :attr:`mean`)."""
        d = self.samples - self.mean
        return float(math.sqrt(max(np.dot(self.weights, d * d), 0.0)))

    @property
    def mean_uncensored(self) -> float:
        """Weighted mean over the uncensored samples only (``nan`` if all are censored)."""
        m = ~self.censored
        wm = self.weights[m].sum()
        if wm <= 0:
            return math.nan
        return float(np.dot(self.weights[m], self.samples[m]) / wm)

    # ------------------------------------------------------------------ quantiles
    def quantile(self, q: ArrayLike) -> float | FloatArray:
        """Weighted quantile(s): the inverse of the weighted empirical CDF.

        ``Q(q) = min{x_k : F(x_k) >= q}`` where ``F`` sums the weights of samples <= x and
        censored samples sit at ``+inf`` (so ``Q(q) = inf`` when ``q > 1 - fraction_censored``).
        With equal weights and no censoring this is ``numpy.quantile(..., method="inverted_cdf")``.
        ``q`` is a scalar or an array in [0, 1]; returns a float or an array of q's shape.
        """
        qa = np.asarray(q, dtype=np.float64)
        if not np.all(np.isfinite(qa)) or np.any((qa < 0) | (qa > 1)):
            raise ValueError(f"q: expected probabilities in [0, 1], got {plain(q)}")
        # a small tolerance so that q exactly at a jump of F selects that sample despite
        # round-off in the cumulative sum
        idx = np.searchsorted(self._sorted_cumw, qa - 1e-12, side="left")
        # never return a leading zero-weight sample (q = 0 gives the smallest weighted sample)
        first = np.searchsorted(self._sorted_cumw, 0.0, side="right")
        idx = np.clip(np.maximum(idx, first), 0, self.n - 1)
        out = self._sorted_values[idx]
        if qa.ndim == 0:
            return float(out)
        return np.asarray(out, dtype=np.float64)

    @property
    def median(self) -> float:
        """``quantile(0.5)`` (``inf`` when at least half of the mass is censored)."""
        return float(self.quantile(0.5))

    def interval(self, level: float = 0.9) -> tuple[float, float]:
        """Equal-tailed interval ``(Q((1 - level)/2), Q((1 + level)/2))``; bounds may be inf."""
        if not 0 < level < 1:
            raise ValueError(f"level: expected a probability in (0, 1), got {plain(level)}")
        lo, hi = np.asarray(self.quantile([(1 - level) / 2, (1 + level) / 2]))
        return float(lo), float(hi)

    def cdf(self, t: ArrayLike) -> float | FloatArray:
        """Weighted empirical CDF ``P(RUL <= t)`` counting uncensored samples only.

        Exact for ``t`` below the horizon; beyond it, a lower bound (censored mass is unknown).
        """
        ta = np.asarray(t, dtype=np.float64)
        idx = np.searchsorted(self._sorted_values, ta, side="right")
        cum = np.concatenate(([0.0], self._sorted_cumw))
        out = cum[idx]
        return float(out) if ta.ndim == 0 else out

    # ------------------------------------------------------------------ density
    def pdf(self, grid: ArrayLike, bw_method: str | float | None = None) -> FloatArray:
        """Weighted Gaussian KDE of the uncensored samples, scaled by ``1 - fraction_censored``.

        Uses :class:`scipy.stats.gaussian_kde` (Scott's rule with the effective sample size
        unless ``bw_method`` is given). The result integrates to the uncensored mass.
        Raises ``ValueError`` when fewer than two distinct uncensored samples exist.
        """
        from scipy.stats import gaussian_kde

        g = np.asarray(grid, dtype=np.float64)
        m = ~self.censored
        vals = self.samples[m]
        w = self.weights[m]
        pos = w > 0
        vals, w = vals[pos], w[pos]
        if vals.size < 2 or np.ptp(vals) == 0:
            raise ValueError(
                "pdf: needs at least two distinct uncensored samples with positive weight "
                f"(have {vals.size}, {self.n_censored} censored)"
            )
        mass = float(w.sum())
        kde = gaussian_kde(vals, bw_method=bw_method, weights=w / mass)
        return np.asarray(kde(g.ravel()).reshape(g.shape) * mass, dtype=np.float64)

    # ------------------------------------------------------------------ summary / IO
    def summary(self, level: float = 0.9) -> dict[str, float]:
        """Mean, std, median, interval bounds, n, censoring: a flat dict for tables."""
        lo, hi = self.interval(level)
        return {
            "n": float(self.n),
            "mean": self.mean,
            "std": self.std,
            "median": self.median,
            f"q{(1 - level) / 2:.3g}": lo,
            f"q{(1 + level) / 2:.3g}": hi,
            "fraction_censored": self.fraction_censored,
            "horizon": self.horizon,
        }

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON dict (lists of floats/bools; an infinite horizon is stored as null)."""
        return {
            "format": _FORMAT,
            "version": _VERSION,
            "horizon": self.horizon if math.isfinite(self.horizon) else None,
            "samples": self.samples.tolist(),
            "weights": self.weights.tolist(),
            "censored": self.censored.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RULDistribution:
        """Inverse of :meth:`to_dict`; validates the format tag, version and fields."""
        if not isinstance(d, dict):
            raise ValueError(f"from_dict: expected a dict, got {type(d).__name__}")
        if d.get("format") != _FORMAT:
            raise ValueError(f"from_dict: 'format' must be {_FORMAT!r}, got {d.get('format')!r}")
        if d.get("version") != _VERSION:
            raise ValueError(f"from_dict: unsupported version {d.get('version')!r}")
        missing = [k for k in ("samples", "weights", "censored", "horizon") if k not in d]
        if missing:
            raise ValueError(f"from_dict: missing field(s) {missing}")
        cens = d["censored"]
        if not all(isinstance(v, bool) for v in cens):
            raise ValueError("from_dict: 'censored' must be a list of booleans")
        horizon = math.inf if d["horizon"] is None else float(d["horizon"])
        return cls(
            samples=np.asarray(d["samples"], dtype=np.float64),
            weights=np.asarray(d["weights"], dtype=np.float64),
            censored=np.asarray(cens, dtype=bool),
            horizon=horizon,
        )

    def to_json(self, path: str | Path) -> Path:
        """Write strict JSON (no NaN/Infinity tokens); returns the path."""
        p = Path(path)
        p.write_text(json.dumps(self.to_dict(), allow_nan=False))
        return p

    @classmethod
    def from_json(cls, path: str | Path) -> RULDistribution:
        """Read a file written by :meth:`to_json`."""
        p = Path(path)
        text = p.read_text()
        if not text.strip():
            raise ValueError(f"{p}: empty file")
        try:
            d = json.loads(text)
        except json.JSONDecodeError as err:
            raise ValueError(f"{p}: not valid JSON ({err})") from err
        return cls.from_dict(d)

    def to_csv(self, path: str | Path) -> Path:
        """Write ``rul,weight,censored`` rows after two ``#`` header lines (format, horizon).

        Floats are written with ``repr`` so that :meth:`from_csv` restores them exactly.
        """
        p = Path(path)
        buf = io.StringIO()
        buf.write(f"# {_FORMAT} v{_VERSION}\n")
        buf.write(f"# horizon={plain(self.horizon)}\n")
        wr = csv.writer(buf, lineterminator="\n")
        wr.writerow(["rul", "weight", "censored"])
        for s, w, c in zip(self.samples.tolist(), self.weights.tolist(), self.censored.tolist(),
                           strict=True):
            wr.writerow([repr(s), repr(w), "1" if c else "0"])
        p.write_text(buf.getvalue())
        return p

    @classmethod
    def from_csv(cls, path: str | Path) -> RULDistribution:
        """Read a file written by :meth:`to_csv`; errors name the offending line."""
        p = Path(path)
        lines = p.read_text().splitlines()
        if not lines:
            raise ValueError(f"{p}: empty file")
        if lines[0].strip() != f"# {_FORMAT} v{_VERSION}":
            raise ValueError(f"{p}: line 1: expected '# {_FORMAT} v{_VERSION}'")
        if len(lines) < 3 or not lines[1].startswith("# horizon="):
            raise ValueError(f"{p}: line 2: expected '# horizon=<value>'")
        horizon = float(lines[1].split("=", 1)[1])
        if lines[2].strip() != "rul,weight,censored":
            raise ValueError(f"{p}: line 3: expected header 'rul,weight,censored'")
        s: list[float] = []
        w: list[float] = []
        c: list[bool] = []
        for lineno, row in enumerate(csv.reader(lines[3:]), start=4):
            if len(row) != 3:
                raise ValueError(f"{p}: line {lineno}: expected 3 fields, got {len(row)}")
            try:
                s.append(float(row[0]))
                w.append(float(row[1]))
            except ValueError as err:
                raise ValueError(f"{p}: line {lineno}: {err}") from err
            if row[2] not in ("0", "1"):
                raise ValueError(f"{p}: line {lineno}: censored must be 0 or 1, got {row[2]!r}")
            c.append(row[2] == "1")
        if not s:
            raise ValueError(f"{p}: no sample rows")
        return cls(samples=np.asarray(s), weights=np.asarray(w), censored=np.asarray(c),
                   horizon=horizon)

    def to_pandas(self) -> Any:
        """A pandas DataFrame with columns rul, weight, censored (on request only)."""
        import pandas as pd

        return pd.DataFrame(
            {"rul": self.samples, "weight": self.weights, "censored": self.censored}
        )


IndicatorFn = Callable[[FloatArray], FloatArray]
AfterCrossing = Literal["hold", "drop", "continue"]

#: The default step budget of :func:`propagate_to_threshold` (``horizon / dt`` steps).
MAX_STEPS = 1_000_000


def _samples(x0: Any) -> tuple[FloatArray, FloatArray | None]:
    """The samples (N, n) and weights (or None) to propagate: a :class:`Posterior`'s weighted
    samples, or an array of equally likely states (a 1-D array: N samples of a scalar)."""
    if isinstance(x0, Posterior):
        if x0.samples is None:
            raise ValueError("x0: a Gaussian posterior has no samples to propagate; use "
                             "monte_carlo_rul(posterior, ..., n_samples=...) or "
                             "x0.with_samples(n, rng)")
        return np.array(x0.samples, dtype=np.float64), x0.weights
    x = np.array(x0, dtype=np.float64, copy=True)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2:
        raise ValueError(f"x0: expected shape (N, n) or a Posterior, got {np.shape(x0)}")
    if x.shape[0] == 0:
        raise ValueError("x0: empty batch (N = 0); nothing to propagate")
    if not np.all(np.isfinite(x)):
        r = np.argwhere(~np.isfinite(x))[0]
        raise ValueError(f"x0: non-finite value at row {r[0]}, column {r[1]}")
    return x, None


def _check_window(t0: float, dt: float, horizon: float, threshold: float,
                  max_steps: int) -> None:
    """Finite, positive ``dt`` and ``horizon``, finite ``t0`` and ``threshold``, and a step
    budget ``horizon / dt <= max_steps`` (messages print plain numbers)."""
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: expected a positive finite step, got {float(dt):g}")
    if not (np.isfinite(horizon) and horizon > 0):
        raise ValueError(f"horizon: expected a positive finite length, got {float(horizon):g}")
    if not np.isfinite(threshold):
        raise ValueError(f"threshold: expected a finite number, got {float(threshold):g}")
    if not np.isfinite(t0):
        raise ValueError(f"t0: expected a finite time, got {float(t0):g}")
    n_steps = math.ceil(horizon / dt - 1e-9)
    if n_steps > max_steps:
        raise ValueError(
            f"dt: horizon / dt = {float(horizon):g} / {float(dt):g} = {n_steps:.3g} steps exceeds "
            f"the step budget max_steps = {max_steps}; raise dt, shorten the horizon or pass "
            f"a larger max_steps")


def propagate_to_threshold(
    x0: Any,
    step: Callable[..., FloatArray] | None = None,
    indicator: IndicatorFn | None = None,
    threshold: float | None = None,
    *,
    model: Any = None,
    u: Any = None,
    t0: float = 0.0,
    dt: float | None = None,
    horizon: float,
    rng: np.random.Generator,
    direction: Literal["up", "down"] = "up",
    after_crossing: AfterCrossing = "hold",
    max_steps: int = MAX_STEPS,
) -> RULDistribution:
    """Monte Carlo time to threshold of a batch of states (engine-api.md, ``rulkit.prognosis``).

    With ``model=`` (a :class:`rulkit.model.StateSpaceModel`) the step is ``model.step``, the
    indicator ``model.health``, the threshold ``model.threshold`` and ``dt`` defaults to
    ``model.dt``; each may still be given explicitly. ``step`` follows the one calling
    convention ``step(x, u, t, dt, rng)`` (``u`` is the input ``u`` or ``u(t)``).

    ``x0`` is a :class:`~rulkit.estimation.base.Posterior` with samples (a particle filter's:
    its particles are propagated *with their weights*) or an (N, n) array of equally likely
    states (a 1-D ``x0`` is read as N samples of a scalar state). All samples advance together
    from ``t0`` until ``t0 + horizon`` (the last step is shortened to end exactly at the
    horizon), stopping early once every sample has crossed; ``horizon / dt`` must not exceed
    ``max_steps``. The health indicator ``g = indicator(x)`` (shape (N,)) fails when
    ``g >= threshold`` (``direction="up"``) or ``g <= threshold`` (``"down"``). A sample
    crossing between ``t_k`` and ``t_k + h`` gets the linearly interpolated time ``t_k + h
    (thr - g_k) / (g_{k+1} - g_k)``; its RUL is that time minus ``t0``. Samples failed already
    at ``t0`` have RUL 0. Samples that never cross are censored at ``horizon`` (counted, never
    dropped; see the module docstring).

    ``after_crossing`` says what happens to a sample once it has crossed:

    * ``"hold"`` (default): it is frozen at its first state past the threshold. The batch keeps
      its size N (a step may close over per-sample arrays) and the frozen rows are reset after
      every step, so a model that grows without bound after failure never overflows; the
      random draws and every RUL are bit-for-bit those of ``"continue"``.
    * ``"drop"``: it leaves the batch; later steps see only the running samples (fewest
      draws, fastest; the step and indicator must work row by row, as a model's do).
    * ``"continue"``: crossed samples keep being stepped.

    Raises ``ValueError`` for an empty batch, bad shapes, non-finite inputs, non-positive
    ``dt``/``horizon``, a step budget exceeded, or a non-finite indicator of a not-yet-failed
    sample (naming the step and the first bad sample).
    """
    if model is not None:
        step = model.step if step is None else step
        indicator = model.health if indicator is None else indicator
        threshold = model.threshold if threshold is None else threshold
        if dt is None:
            dt = getattr(model, "dt", None)
    if step is None or indicator is None or threshold is None:
        raise TypeError("propagate_to_threshold: give model=... or step, indicator and "
                        "threshold")
    if dt is None:
        raise TypeError("propagate_to_threshold: dt is required (or a model with a dt)")
    if after_crossing not in ("hold", "drop", "continue"):
        raise ValueError(f"after_crossing: expected 'hold', 'drop' or 'continue', got "
                         f"{after_crossing!r}")
    if direction not in ("up", "down"):
        raise ValueError(f"direction: expected 'up' or 'down', got {direction!r}")
    x, weights = _samples(x0)
    _check_window(t0, dt, horizon, threshold, int(max_steps))
    n = x.shape[0]
    g0 = _indicator(indicator, x, n, 0)
    bad = np.flatnonzero(~np.isfinite(g0))
    if bad.size:
        raise ValueError(f"indicator: non-finite value at t0 for sample {bad[0]}")

    def fstep(x: FloatArray, t: float, h: float, g: np.random.Generator) -> FloatArray:
        return step(x, input_at(u, t), t, h, g)  # type: ignore[misc]

    run = _Run(fstep, indicator, float(threshold), direction == "up", float(t0), float(dt),
               float(horizon), rng)
    if after_crossing == "drop":
        rul, active = run.dropping(x, g0)
    else:
        rul, active = run.batch(x, g0, hold=after_crossing == "hold")
    return RULDistribution(samples=rul, weights=cast(FloatArray, weights), censored=active,
                           horizon=horizon)


def _indicator(indicator: IndicatorFn, x: FloatArray, n: int, k: int) -> FloatArray:
    return _as_indicator(indicator(x), n, k)


def _as_indicator(g: Any, n: int, k: int) -> FloatArray:
    if not (isinstance(g, np.ndarray) and g.dtype == np.float64):
        g = np.asarray(g, dtype=np.float64)
    if g.shape != (n,):
        raise ValueError(f"indicator: expected shape ({n},), got {g.shape} at step {k}")
    return g


def _check_step(x: Any, n: int, k: int) -> None:
    if not isinstance(x, np.ndarray) or x.ndim != 2 or x.shape[0] != n:
        raise ValueError(f"step: expected an array of shape ({n}, n), got {np.shape(x)} at "
                         f"step {k}")


@dataclass
class _Run:
    """The stepping loops of :func:`propagate_to_threshold` (validated arguments)."""

    step: Callable[..., FloatArray]
    indicator: IndicatorFn
    threshold: float
    up: bool
    t0: float
    dt: float
    horizon: float
    rng: np.random.Generator

    @property
    def n_steps(self) -> int:
        return max(1, math.ceil(self.horizon / self.dt - 1e-9))

    def _h(self, k: int) -> float:
        return self.dt if k < self.n_steps - 1 else self.horizon - k * self.dt

    def _diverged(self, g: FloatArray, running: Any, k: int, tau: float, h: float) -> None:
        badk = np.flatnonzero(running & ~np.isfinite(g))
        if badk.size:
            raise ValueError(
                f"indicator: non-finite value at step {k + 1} (t = {self.t0 + tau + h:g}) for "
                f"sample {badk[0]} ({badk.size} samples); the model diverged"
            )

    def batch(self, x: FloatArray, g_old: FloatArray, hold: bool) -> tuple[FloatArray, Any]:
        """All N rows stepped every step; crossed rows reset to their frozen state (hold) or
        left to run on (continue)."""
        n = x.shape[0]
        thr0, up = self.threshold, self.up
        failed0 = g_old >= thr0 if up else g_old <= thr0
        active = ~failed0  # not yet crossed
        n_active = int(np.count_nonzero(active))
        rul = np.full(n, self.horizon)
        rul[failed0] = 0.0
        # The loop body is a handful of numpy calls on (N,) arrays: at small N their per-call
        # overhead, not arithmetic, is the cost (benchmarks/run.py measures it). Each sample is
        # compared with its own threshold, NaN once it has crossed (every comparison with NaN
        # is False, even for an indicator that later diverges to +-inf), so one comparison
        # finds the new crossings among the running samples; until the first crossing one
        # reduction (max / min) shows that no sample has crossed.
        thr = np.where(active, thr0, np.nan)
        # Held rows: their indices and frozen states, written back into each step's output
        # (the same values as ``np.where(frozen, x, x_new)``, without an (N, n) pass + copy).
        fidx = np.flatnonzero(~active) if hold and n_active < n else None
        xf = None if fidx is None else x[fidx]
        n_run0 = n_active
        step, indicator, rng, t0, dt = self.step, self.indicator, self.rng, self.t0, self.dt
        n_steps = self.n_steps
        for k in range(n_steps):
            if n_active == 0:
                break
            tau = k * dt
            h = dt if k < n_steps - 1 else self.horizon - k * dt
            x_new = step(x, t0 + tau, h, rng)
            if not isinstance(x_new, np.ndarray) or x_new.ndim != 2 or x_new.shape[0] != n:
                _check_step(x_new, n, k)
            if fidx is not None:
                x_new[fidx] = xf
            x = x_new
            g_new = indicator(x)
            if not (isinstance(g_new, np.ndarray) and g_new.dtype == np.float64
                    and g_new.shape == (n,)):
                g_new = _as_indicator(g_new, n, k + 1)
            if not math.isfinite(g_new.sum()):  # one cheap test; details only when it fails
                self._diverged(g_new, active, k, tau, h)
            if n_active == n_run0 and (g_new.max() < thr0 if up else g_new.min() > thr0):
                g_old = g_new  # (a NaN of a crossed sample makes the test False)
                continue
            new = g_new >= thr if up else g_new <= thr
            idx = new.nonzero()[0]
            if idx.size:
                ga, gb = g_old[idx], g_new[idx]
                # linear interpolation of the crossing: ga < thr <= gb (up) or ga > thr >= gb
                # (down), so 0 < frac <= 1
                rul[idx] = tau + (thr0 - ga) / (gb - ga) * h
                active[idx] = False
                thr[idx] = np.nan
                n_active -= idx.size
                if hold:
                    fidx = np.flatnonzero(~active)
                    xf = x[fidx]
            g_old = g_new
        return rul, active

    def dropping(self, x: FloatArray, g_old: FloatArray) -> tuple[FloatArray, Any]:
        """Only the running rows are stepped: crossed ones leave the batch."""
        n = x.shape[0]
        thr0, up = self.threshold, self.up
        failed0 = g_old >= thr0 if up else g_old <= thr0
        rul = np.full(n, self.horizon)
        rul[failed0] = 0.0
        active = ~failed0
        ids = np.flatnonzero(active)
        x, g_old = x[ids], g_old[ids]
        for k in range(self.n_steps):
            m = ids.size
            if m == 0:
                break
            tau = k * self.dt
            h = self._h(k)
            x = self.step(x, self.t0 + tau, h, self.rng)
            if not isinstance(x, np.ndarray) or x.ndim != 2 or x.shape[0] != m:
                _check_step(x, m, k)
            g_new = self.indicator(x)
            if not (isinstance(g_new, np.ndarray) and g_new.dtype == np.float64
                    and g_new.shape == (m,)):
                g_new = _as_indicator(g_new, m, k + 1)
            if not math.isfinite(g_new.sum()):
                self._diverged(g_new, True, k, tau, h)
            if g_new.max() < thr0 if up else g_new.min() > thr0:
                g_old = g_new
                continue
            new = g_new >= thr0 if up else g_new <= thr0
            idx = new.nonzero()[0]
            ga, gb = g_old[idx], g_new[idx]
            rul[ids[idx]] = tau + (thr0 - ga) / (gb - ga) * h
            active[ids[idx]] = False
            keep = ~new
            ids, x, g_old = ids[keep], x[keep], g_new[keep]
        return rul, active
