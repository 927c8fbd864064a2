"""Sequential importance resampling (SIR) particle filter over a batch of particles (N, n_x).

Seed 000 section 2.3 (eqs 13-16): the posterior ``p(x_k | y_{1:k})`` is represented by weighted
particles (eq. 13); with the transition density as importance function the weight recursion is
``w_k^i ∝ w_{k-1}^i p(y_k | x_k^i)`` (eq. 15); the effective sample size is
``N_eff = 1 / sum_i (w_k^i)^2`` (eq. 16) and resampling happens when it falls below a threshold.

Design (docs/engine-api.md, ``rulkit.estimation.particle``; docs/guide.md "Concepts"):

- Log-weights throughout, normalised by log-sum-exp. A degenerate update (every weight zero,
  i.e. every log-weight -inf, or any NaN / +inf log-weight) raises ``DegenerateWeightsError``
  naming the step, unless ``recovery="reset"`` (equal weights, step flagged in ``reset``).
- Order of one step ``k`` (``ys[k]``): propagate ``x_k = transition(x_{k-1}, k, rng)``; weight
  ``logw += log_likelihood(x_k, ys[k], k)`` (or the pluggable ``weight_update``); normalise;
  ESS; summaries (of the weighted, not yet resampled set); then resample if
  ``trigger(state)`` (when given) or ``ESS < ess_threshold * N``.
- Missing measurements: a ``ys[k]`` with any NaN component skips the weight update at step
  ``k`` (the transition still runs; the log-likelihood increment is 0; ``skipped[k]`` is True)
  when ``missing="skip"`` (default); ``missing="raise"`` raises ``ValueError`` naming the row;
  ``missing="pass"`` hands the row unchanged to ``log_likelihood``. ``±inf`` in ``ys`` is
  always an error.
- Log-likelihood estimate: ``log p(y_k | y_{1:k-1}) ≈ log sum_i W_{k-1}^i p(y_k | x_k^i)`` with
  ``W_{k-1}`` the normalised weights carried into step ``k`` (``1/N`` after a resampling, which
  gives the familiar "log mean of the likelihoods"). Its exponential is an unbiased estimate
  of the marginal likelihood for the standard (bootstrap) weight update. With a custom
  ``weight_update`` the same quantity is reported; it is then only a diagnostic.

No per-particle Python loop; the per-step cost is a handful of numpy calls on (N,) / (N, n_x)
arrays plus whatever the user's ``transition`` and ``log_likelihood`` cost.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal, cast

import numpy as np
from numpy.typing import NDArray

from rulkit.estimation.batched import (
    normalise_rows,
    normalise_weights,
    systematic_indices,
)
from rulkit.estimation.resampling import _KERNELS, Resampler, get_resampler
from rulkit.estimation.weights import (
    DegenerateWeightsError,
    _describe_degenerate,
    _mean_cov,
    _weighted_quantile,
    effective_sample_size,
    log_normalise,
    weighted_cov,
    weighted_mean,
    weighted_quantile,
)
from rulkit.model import (
    InputLike,
    StateSpaceModel,
    check_measurements,
    loglik_from_model,
    transition_from_model,
)

__all__ = [
    "DegenerateWeightsError",
    "ParticleFilter",
    "ParticleFilterResult",
    "ParticleState",
    "effective_sample_size",
    "log_normalise",
    "weighted_cov",
    "weighted_mean",
    "weighted_quantile",
]

FloatArray = NDArray[np.float64]
Transition = Callable[[FloatArray, int, np.random.Generator], FloatArray]
LogLikelihood = Callable[[FloatArray, Any, int], FloatArray]
WeightUpdate = Callable[[FloatArray, FloatArray, "ParticleState"], FloatArray]
Trigger = Callable[["ParticleState"], bool]

DEFAULT_QUANTILES = (0.025, 0.5, 0.975)


# ---------------------------------------------------------------------------------------------
# State and result
# ---------------------------------------------------------------------------------------------


@dataclass
class ParticleState:
    """Mutable state of a running particle filter (for the per-step API and the plug-ins).

    ``particles`` (N, n_x); ``logw`` normalised log-weights (log-sum-exp 0) and ``weights`` their
    exponentials; ``ess`` the effective sample size of ``weights``; ``k`` the last assimilated
    step (-1 after ``initialise``); ``y`` the measurement of step ``k``; ``rng`` the generator
    used for propagation and resampling; ``loglik`` the running log-likelihood estimate and
    ``loglik_increment`` the last increment; flags of the last step: ``resampled``, ``skipped``
    (NaN measurement), ``reset`` (degenerate weights reset to equal). ``info`` is a free dict for
    plug-ins (e.g. an adaptive weight update may count clipped particles there).

    When a ``weight_update`` or ``trigger`` plug-in is called during step ``k``: ``particles``
    already holds the propagated ``x_k``, ``k`` and ``y`` are the current step's, and
    ``logw``/``weights``/``ess`` are still those carried in from step ``k-1`` (for the trigger:
    the freshly updated ones).
    """

    particles: FloatArray
    logw: FloatArray
    weights: FloatArray
    rng: np.random.Generator
    ess: float
    k: int = -1
    y: Any = None
    loglik: float = 0.0
    loglik_increment: float = 0.0
    resampled: bool = False
    skipped: bool = False
    reset: bool = False
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def n_particles(self) -> int:
        return self.particles.shape[0]

    def mean(self) -> FloatArray:
        """Weighted mean of the particles (n_x,) (bit-identical to ``filter``'s summary)."""
        return self.particles.T.copy() @ self.weights

    def cov(self) -> FloatArray:
        """Weighted covariance of the particles (n_x, n_x) (as ``filter``'s summary)."""
        return _mean_cov(self.particles, self.weights)[1]

    def quantile(self, q: float | FloatArray) -> FloatArray:
        """Weighted marginal quantiles per state component, shape ``q.shape + (n_x,)``."""
        return weighted_quantile(self.particles, self.weights, q)


@dataclass(frozen=True)
class ParticleFilterResult:
    """Output of ``ParticleFilter.filter`` over ``T`` measurements.

    Per step ``k`` (summaries of the weighted particle set after the update of step ``k`` and
    before any resampling): ``mean`` (T, n_x), ``cov`` (T, n_x, n_x), ``quantiles``
    (T, n_q, n_x) at ``quantile_levels`` (None when not requested), ``ess`` (T,),
    ``resampled`` (T,) (resampling happened at the end of step k), ``skipped`` (T,) (NaN
    measurement, no update), ``reset`` (T,) (degenerate weights reset to equal),
    ``loglik_increments`` (T,) and their sum ``loglik``. ``particles`` (N, n_x), ``weights``
    (N,) and ``log_weights`` are the final state (after any final resampling), ready to hand to a
    prognosis; ``particle_history`` (T, N, n_x) and ``weight_history`` (T, N) hold the weighted
    sets behind the summaries when ``keep_particles=True`` (else None).
    """

    mean: FloatArray
    cov: FloatArray
    quantiles: FloatArray | None
    quantile_levels: FloatArray | None
    ess: FloatArray
    resampled: NDArray[np.bool_]
    skipped: NDArray[np.bool_]
    reset: NDArray[np.bool_]
    loglik_increments: FloatArray
    particles: FloatArray
    weights: FloatArray
    log_weights: FloatArray
    particle_history: FloatArray | None = None
    weight_history: FloatArray | None = None

    @property
    def loglik(self) -> float:
        """Log marginal likelihood estimate ``sum_k loglik_increments[k]``."""
        return float(self.loglik_increments.sum())

    @property
    def n_steps(self) -> int:
        return self.mean.shape[0]

    @property
    def n_resampled(self) -> int:
        return int(self.resampled.sum())


# A registry of the particle arrays a filter handed out with non-uniform weights, so that
# propagating them without their weights can be noticed (issue 10, stumble 3). Keyed by id();
# an entry dies with its array (weakref callback), and is only trusted while it is alive.
_WEIGHTED: dict[int, tuple[weakref.ref[np.ndarray], FloatArray]] = {}


def _register_weighted(particles: np.ndarray, weights: FloatArray) -> None:
    key = id(particles)

    def forget(_r: object, k: int = key) -> None:
        _WEIGHTED.pop(k, None)

    ref = weakref.ref(particles, forget)
    _WEIGHTED[key] = (ref, weights)


def weights_of(x: Any) -> FloatArray | None:
    """The weights a particle filter returned together with ``x``, when ``x`` is its final
    ``particles`` array or one step ``particle_history[k]`` of a ``ParticleFilterResult``
    (None otherwise, or when those weights are uniform)."""
    if not isinstance(x, np.ndarray):
        return None
    for cand in (x, x.base):
        if not isinstance(cand, np.ndarray):
            continue
        entry = _WEIGHTED.get(id(cand))
        if entry is None or entry[0]() is not cand:
            continue
        w = entry[1]
        if cand is x:
            return w if w.ndim == 1 else None
        if cand.ndim == 3 and x.shape == cand.shape[1:] and w.ndim == 2:
            off = x.__array_interface__["data"][0] - cand.__array_interface__["data"][0]
            k, rem = divmod(off, cand.strides[0])
            if rem == 0 and 0 <= k < cand.shape[0]:
                return w[k]  # type: ignore[no-any-return]
    return None


# ---------------------------------------------------------------------------------------------
# The filter
# ---------------------------------------------------------------------------------------------


def _check_particles(particles: FloatArray, name: str = "particles0") -> FloatArray:
    x = np.asarray(particles, dtype=np.float64)
    if x.ndim != 2:
        hint = " (use x.reshape(-1, 1) for a scalar state)" if x.ndim == 1 else ""
        raise ValueError(f"{name}: expected shape (N, n_x), got {x.shape}{hint}")
    if x.shape[0] == 0 or x.shape[1] == 0:
        raise ValueError(f"{name}: need at least one particle and one state, got {x.shape}")
    finite = np.isfinite(x)
    if not finite.all():
        i, j = np.argwhere(~finite)[0]
        raise ValueError(f"{name}: non-finite value {x[i, j]} at particle {i}, state {j}")
    return x


def _refuse_model(obj: Any, cls_name: str) -> None:
    """A model (or its bound ``step``) where the low-level function form is expected is a
    ``TypeError`` that names ``from_model`` (issue 10, stumble 2)."""
    owner = getattr(obj, "__self__", None)
    bound_step = isinstance(owner, StateSpaceModel) and getattr(obj, "__name__", "") == "step"
    if isinstance(obj, StateSpaceModel) or bound_step:
        raise TypeError(f"{cls_name}(...) takes the low-level functions; for a model use "
                        f"{cls_name}.from_model(model, ...) (docs/engine-api.md, 'from_model')")


class ParticleFilter:
    """SIR particle filter with log-weights, ESS-triggered resampling and plug-in points.

    Parameters
    ----------
    transition
        ``transition(x (N, n_x), k, rng) -> x_next (N, n_x)``: propagation including process
        noise. Applied before every measurement, including the first. A non-finite propagated
        particle raises ``ValueError`` naming the step and particle (it would otherwise turn
        the weighted mean into NaN, or surface later as an unrelated degenerate-weights error).
    log_likelihood
        ``log_likelihood(x (N, n_x), y, k) -> (N,)``: ``log p(y_k | x_k^i)`` up to a constant
        common to all particles (the constant shifts ``loglik`` only).
    resampler
        scheme name (see ``rulkit.estimation.resampling.RESAMPLERS``) or a callable
        ``(weights, rng) -> indices (N,)``. Default ``"systematic"``.
    ess_threshold
        fraction of N in [0, 1]: resample when ``ESS < ess_threshold * N`` (seed 000 eq. 16;
        ``N_th = N/2`` by default). 0 never resamples; 1 resamples after every update.
    trigger
        ``trigger(state) -> bool`` evaluated after each update; replaces the ESS rule.
    weight_update
        ``weight_update(logw (N,), loglik (N,), state) -> new logw (N,)`` (unnormalised is
        fine); default ``logw + loglik`` (seed 000 eq. 15). Adaptive variants (seed 000 eq. 28,
        likelihood tempering) plug in here; ``state.rng`` is available for randomised rules.
    recovery
        ``"raise"``: ``DegenerateWeightsError`` naming the step; ``"reset"``: equal weights,
        particles kept, ``reset[k]`` flagged and the log-likelihood increment is the (-inf or
        NaN) value actually observed.
    missing
        what to do with a measurement containing NaN: ``"skip"`` (default; no update, flagged),
        ``"raise"`` or ``"pass"`` (give it to ``log_likelihood`` unchanged).
    """

    def __init__(
        self,
        transition: Transition,
        log_likelihood: LogLikelihood,
        *,
        resampler: str | Resampler = "systematic",
        ess_threshold: float = 0.5,
        trigger: Trigger | None = None,
        weight_update: WeightUpdate | None = None,
        recovery: Literal["raise", "reset"] = "raise",
        missing: Literal["skip", "raise", "pass"] = "skip",
    ) -> None:
        _refuse_model(transition, "ParticleFilter")
        if not callable(transition):
            raise TypeError("transition must be callable(x, k, rng) -> x_next")
        if not callable(log_likelihood):
            raise TypeError("log_likelihood must be callable(x, y, k) -> (N,) log-likelihoods")
        thr = float(ess_threshold)
        if not (0.0 <= thr <= 1.0):
            raise ValueError(
                f"ess_threshold: must be a fraction of N in [0, 1], got {ess_threshold}"
            )
        if trigger is not None and not callable(trigger):
            raise TypeError("trigger must be callable(state) -> bool or None")
        if weight_update is not None and not callable(weight_update):
            raise TypeError("weight_update must be callable(logw, loglik, state) -> logw or None")
        if recovery not in ("raise", "reset"):
            raise ValueError(f"recovery: expected 'raise' or 'reset', got {recovery!r}")
        if missing not in ("skip", "raise", "pass"):
            raise ValueError(f"missing: expected 'skip', 'raise' or 'pass', got {missing!r}")
        self.transition = transition
        self.log_likelihood = log_likelihood
        self.resampler = get_resampler(resampler)
        # validated weights come from log_normalise: use the non-validating kernel when known
        self._resample_kernel = (
            _KERNELS[resampler] if isinstance(resampler, str) else self.resampler
        )
        # the compiled kernel called directly (same draw: one rng.random() per resampling)
        self._systematic = isinstance(resampler, str) and resampler == "systematic"
        self.ess_threshold = thr
        self.trigger = trigger
        self.weight_update = weight_update
        self.recovery = recovery
        self.missing = missing
        self.n_x: int | None = None  # known when built from a model: shapes checked up front
        self.n_y: int | None = None

    @classmethod
    def from_model(
        cls,
        model: StateSpaceModel,
        *,
        dt: float | None = None,
        t0: float = 0.0,
        u: InputLike = None,
        R: np.ndarray | None = None,
        log_likelihood: LogLikelihood | None = None,
        **options: Any,
    ) -> ParticleFilter:
        """A bootstrap particle filter for ``model`` (docs/engine-api.md, "from_model").

        The transition is ``model.step(x, u(t_k), t_k, dt, rng)`` with ``t_k = t0 + k dt``
        (``dt`` defaults to ``model.dt``); the likelihood of measurement k (time
        ``t_{k+1}``) is the model's own ``log_likelihood`` when it defines one, else
        ``N(y; model.output(x), R)`` with ``R = model.noise.R`` unless ``R`` or a
        ``log_likelihood(x, y, k)`` is given. ``options`` are the constructor's keywords
        (``resampler``, ``ess_threshold``, ``recovery``, ...). The filter knows the model's
        dimensions: ``filter`` accepts measurements of one unit as (T, n_y) or, for one
        output, (T,), and a wrong shape of them or of the particles is a ``ValueError`` before
        any model code runs.
        """
        pf = cls(
            transition_from_model(model, dt, t0, u),
            log_likelihood if log_likelihood is not None
            else loglik_from_model(model, dt, t0, u, R),
            **options,
        )
        pf.n_x, pf.n_y = model.n_x, model.n_y
        return pf

    # -- per-step API -------------------------------------------------------------------------

    def initialise(
        self,
        particles: FloatArray,
        rng: np.random.Generator,
        *,
        log_weights: FloatArray | None = None,
    ) -> ParticleState:
        """Start a filter run from ``particles`` (N, n_x) (equal weights unless ``log_weights``).

        The particles are copied; the returned state is then advanced with ``step``/``update``.
        """
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        x = _check_particles(particles).copy()
        n = x.shape[0]
        if log_weights is None:
            w = np.full(n, 1.0 / n)
            logw = np.full(n, -math.log(n))
        else:
            lw = np.asarray(log_weights, dtype=np.float64)
            if lw.shape != (n,):
                raise ValueError(f"log_weights: expected shape ({n},), got {lw.shape}")
            w, lse = log_normalise(lw)
            logw = lw - lse
        return ParticleState(
            particles=x, logw=logw, weights=w, rng=rng, ess=effective_sample_size(w)
        )

    def update(self, state: ParticleState, y: Any, *, missing: bool | None = None) -> ParticleState:
        """Propagate and weight one step (no resampling); mutates and returns ``state``.

        ``y`` may be any object ``log_likelihood`` understands; when it converts to a float
        array, NaN/inf are handled per ``missing`` (a non-numeric ``y`` is never "missing").
        ``missing`` (internal fast path) says whether ``y`` holds NaN; computed when None.
        """
        k = state.k + 1
        x = self.transition(state.particles, k, state.rng)
        n = state.logw.shape[0]
        if getattr(x, "shape", None) != state.particles.shape:
            raise ValueError(
                f"transition at step {k}: returned shape {np.shape(x)}, "
                f"expected {state.particles.shape}"
            )
        # one reduction; a non-finite sum (NaN/inf, or overflow of finite values) is examined
        if not math.isfinite(x.sum()) and not np.isfinite(x).all():
            i, j = np.argwhere(~np.isfinite(x))[0]
            raise ValueError(
                f"transition at step {k}: non-finite value {x[i, j]} at particle {i}, state {j} "
                f"(the filter state is left at step {state.k})"
            )
        if missing is None:
            missing = self._is_missing(y, k)
        prev = (state.particles, state.k, state.y)
        state.particles = x
        state.k = k
        state.y = y
        try:
            self._weight(state, x, y, k, n, missing)
        except BaseException:
            # leave the state as it was before this step (no half-applied update)
            state.particles, state.k, state.y = prev
            raise
        return state

    def _weight(
        self, state: ParticleState, x: FloatArray, y: Any, k: int, n: int, missing: bool
    ) -> None:
        if missing:
            state.resampled = False
            state.reset = False
            state.skipped = True
            state.loglik_increment = 0.0
            return
        ll = self.log_likelihood(x, y, k)
        if getattr(ll, "shape", None) != (n,):
            raise ValueError(
                f"log_likelihood at step {k}: returned shape {np.shape(ll)}, expected ({n},)"
            )
        if self.weight_update is None:
            new = state.logw + ll
        else:
            new = np.asarray(self.weight_update(state.logw, ll, state), dtype=np.float64)
            if new.shape != (n,):
                raise ValueError(
                    f"weight_update at step {k}: returned shape {new.shape}, expected ({n},)"
                )
        m = new.max()
        if not math.isfinite(m):
            self._degenerate(state, new, ll, k)
            return
        w = np.subtract(new, m)
        np.exp(w, out=w)
        s = w.sum()
        w /= s
        lse = m + math.log(s)
        if self.weight_update is None:
            inc = lse  # logsumexp(logw_{k-1} + ll), logw_{k-1} normalised
            new -= lse  # our own temporary
        else:
            inc = _logsumexp(state.logw + ll)
            new = new - lse  # the plug-in's array may be referenced elsewhere: not in place
        state.logw = new
        state.weights = w
        state.ess = 1.0 / float(np.dot(w, w))
        state.loglik_increment = inc
        state.loglik += inc
        state.resampled = False
        state.reset = False
        state.skipped = False

    def resample_if_needed(self, state: ParticleState) -> ParticleState:
        """Apply the trigger (or the ESS rule) and resample in place when it fires."""
        if self.trigger is not None:
            fire = bool(self.trigger(state))
        else:
            n = state.logw.shape[0]
            fire = self.ess_threshold >= 1.0 or state.ess < self.ess_threshold * n
        if fire:
            self.resample(state)
        return state

    def resample(self, state: ParticleState) -> ParticleState:
        """Resample ``state`` now with the configured scheme; weights become 1/N."""
        n = state.logw.shape[0]
        if self._systematic:
            idx = systematic_indices(state.weights, state.rng.random())
        else:
            idx = self._resample_kernel(state.weights, state.rng)
        if getattr(idx, "shape", None) != (n,):
            raise ValueError(f"resampler returned shape {np.shape(idx)}, expected ({n},)")
        state.particles = state.particles.take(idx, axis=0)  # = [idx], without fancy indexing
        state.logw = np.full(n, -math.log(n))
        state.weights = np.full(n, 1.0 / n)
        state.ess = float(n)
        state.resampled = True
        return state

    def step(self, state: ParticleState, y: Any) -> ParticleState:
        """One full filter step: ``update`` then ``resample_if_needed``; mutates ``state``."""
        self.update(state, y)
        return self.resample_if_needed(state)

    # -- whole-sequence API -------------------------------------------------------------------

    def filter(
        self,
        ys: Any,
        particles0: FloatArray,
        rng: np.random.Generator,
        *,
        quantiles: tuple[float, ...] | FloatArray | None = DEFAULT_QUANTILES,
        keep_particles: bool = False,
        log_weights0: FloatArray | None = None,
    ) -> ParticleFilterResult:
        """Run the filter over ``ys`` (T, ...) from ``particles0`` (N, n_x).

        ``ys[k]`` is assimilated after the k-th transition. ``quantiles=None`` skips the
        per-step sort. Same ``rng`` seed -> identical result.
        """
        if self.n_y is not None:
            ys = check_measurements(ys, self.n_y)
        if self.n_x is not None:
            p0 = np.asarray(particles0)
            if p0.ndim != 2 or p0.shape[1] != self.n_x:
                raise ValueError(f"particles0: expected shape (N, {self.n_x}) for the model's "
                                 f"{self.n_x} states, got {p0.shape}")
        y_arr = np.asarray(ys, dtype=np.float64)
        if y_arr.ndim == 0 or y_arr.shape[0] == 0:
            raise ValueError(f"ys: expected a non-empty array of shape (T, ...), got {y_arr.shape}")
        t_len = y_arr.shape[0]
        flat = y_arr.reshape(t_len, -1)
        inf_rows = np.isinf(flat).any(axis=1)
        if inf_rows.any():
            raise ValueError(f"ys: infinite value in row {int(np.flatnonzero(inf_rows)[0])}")
        nan_rows = cast(NDArray[np.bool_], np.isnan(flat).any(axis=1))
        if self.missing == "raise" and nan_rows.any():
            raise ValueError(
                f"ys: NaN in row {int(np.flatnonzero(nan_rows)[0])} (missing='raise'; use "
                f"missing='skip' to skip the update for missing measurements)"
            )
        if self.missing == "pass":
            nan_rows[:] = False
        q_levels = None
        if quantiles is not None:
            q_levels = np.atleast_1d(np.asarray(quantiles, dtype=np.float64))
            if q_levels.ndim != 1 or np.any(~((q_levels >= 0) & (q_levels <= 1))):
                raise ValueError(f"quantiles: expected levels in [0, 1], got {quantiles!r}")

        state = self.initialise(particles0, rng, log_weights=log_weights0)
        n, n_x = state.particles.shape
        mean = np.empty((t_len, n_x))
        cov = np.empty((t_len, n_x, n_x))
        qs = None if q_levels is None else np.empty((t_len, q_levels.size, n_x))
        ess = np.empty(t_len)
        resampled = np.zeros(t_len, dtype=bool)
        skipped = np.zeros(t_len, dtype=bool)
        reset = np.zeros(t_len, dtype=bool)
        incs = np.empty(t_len)
        p_hist = np.empty((t_len, n, n_x)) if keep_particles else None
        w_hist = np.empty((t_len, n)) if keep_particles else None

        missing_list = nan_rows.tolist()
        if self.weight_update is None and self.trigger is None:
            self._filter_loop(state, y_arr, missing_list, mean, cov, qs, q_levels, ess,
                              resampled, skipped, reset, incs, p_hist, w_hist)
        else:
            self._filter_loop_plugins(state, y_arr, missing_list, mean, cov, qs, q_levels,
                                      ess, resampled, skipped, reset, incs, p_hist, w_hist)

        if np.ptp(state.weights) > 0:
            _register_weighted(state.particles, state.weights)
        if p_hist is not None and w_hist is not None:
            _register_weighted(p_hist, w_hist)
        return ParticleFilterResult(
            mean=mean,
            cov=cov,
            quantiles=qs,
            quantile_levels=q_levels,
            ess=ess,
            resampled=resampled,
            skipped=skipped,
            reset=reset,
            loglik_increments=incs,
            particles=state.particles,
            weights=state.weights,
            log_weights=state.logw,
            particle_history=p_hist,
            weight_history=w_hist,
        )

    def _filter_loop_plugins(
        self, state: ParticleState, y_arr: FloatArray, missing_list: list[bool],
        mean: FloatArray, cov: FloatArray, qs: FloatArray | None, q_levels: FloatArray | None,
        ess: FloatArray, resampled: NDArray[np.bool_], skipped: NDArray[np.bool_],
        reset: NDArray[np.bool_], incs: FloatArray, p_hist: FloatArray | None,
        w_hist: FloatArray | None,
    ) -> None:
        """``filter``'s loop through the per-step API (a trigger or weight update sees the
        state as documented on :class:`ParticleState`)."""
        for k in range(len(missing_list)):
            self.update(state, y_arr[k], missing=missing_list[k])
            _record_step(k, state.particles, state.weights, state, mean, cov, qs, q_levels, ess,
                         skipped, reset, incs, p_hist, w_hist)
            self.resample_if_needed(state)
            resampled[k] = state.resampled


    def _filter_loop(
        self, state: ParticleState, y_arr: FloatArray, missing_list: list[bool],
        mean: FloatArray, cov: FloatArray, qs: FloatArray | None, q_levels: FloatArray | None,
        ess: FloatArray, resampled: NDArray[np.bool_], skipped: NDArray[np.bool_],
        reset: NDArray[np.bool_], incs: FloatArray, p_hist: FloatArray | None,
        w_hist: FloatArray | None,
    ) -> None:
        """``filter``'s loop without plug-ins: ``update``, ``_weight`` and
        ``resample_if_needed`` inlined (the same numpy operations on the same arrays in the same
        order, hence the same numbers, with fewer Python calls per step); after a resampling
        the equal weights are two read-only arrays made once per run (the state never leaves
        ``filter``; writable copies are put back at the end)."""
        transition, log_likelihood, rng = self.transition, self.log_likelihood, state.rng
        n, n_x = state.particles.shape
        shape = (n, n_x)
        every = self.ess_threshold >= 1.0
        n_thr = self.ess_threshold * n
        systematic, kernel = self._systematic, self._resample_kernel
        u_logw, u_w = np.full(n, -math.log(n)), np.full(n, 1.0 / n)
        u_logw.flags.writeable = False
        u_w.flags.writeable = False
        for k in range(len(missing_list)):
            y = y_arr[k]
            x = transition(state.particles, k, rng)
            if getattr(x, "shape", None) != shape:
                raise ValueError(
                    f"transition at step {k}: returned shape {np.shape(x)}, expected {shape}"
                )
            if not math.isfinite(x.sum()) and not np.isfinite(x).all():
                i, j = np.argwhere(~np.isfinite(x))[0]
                raise ValueError(
                    f"transition at step {k}: non-finite value {x[i, j]} at particle {i}, "
                    f"state {j} (the filter state is left at step {state.k})"
                )
            if missing_list[k]:
                state.particles, state.k, state.y = x, k, y
                state.resampled = state.reset = False
                state.skipped = True
                state.loglik_increment = 0.0
            else:
                ll = log_likelihood(x, y, k)
                if getattr(ll, "shape", None) != (n,):
                    raise ValueError(
                        f"log_likelihood at step {k}: returned shape {np.shape(ll)}, "
                        f"expected ({n},)"
                    )
                new = state.logw + ll
                m = new.max()
                if not math.isfinite(m):
                    prev = (state.particles, state.k, state.y)
                    state.particles, state.k, state.y = x, k, y
                    try:
                        self._degenerate(state, new, ll, k)
                    except BaseException:
                        state.particles, state.k, state.y = prev
                        raise
                else:
                    state.particles, state.k, state.y = x, k, y
                    lwn, w, ls = normalise_rows(new)  # one row: the shared particle core
                    lse = float(ls)
                    state.logw = lwn
                    state.weights = w
                    state.ess = 1.0 / float(np.dot(w, w))
                    state.loglik_increment = lse
                    state.loglik += lse
                    state.resampled = state.reset = state.skipped = False
            w = state.weights
            _record_step(k, x, w, state, mean, cov, qs, q_levels, ess, skipped, reset, incs,
                         p_hist, w_hist)
            if every or state.ess < n_thr:
                if systematic:
                    idx = systematic_indices(w, rng.random())
                else:
                    idx = kernel(w, rng)
                    if getattr(idx, "shape", None) != (n,):
                        raise ValueError(
                            f"resampler returned shape {np.shape(idx)}, expected ({n},)"
                        )
                state.particles = x.take(idx, axis=0)
                state.logw = u_logw
                state.weights = u_w
                state.ess = float(n)
                state.resampled = True
            resampled[k] = state.resampled
        if state.weights is u_w:
            state.logw = np.full(n, -math.log(n))
            state.weights = np.full(n, 1.0 / n)

    # -- internals ----------------------------------------------------------------------------

    def _is_missing(self, y: Any, k: int) -> bool:
        if self.missing == "pass":
            return False
        try:
            ya = np.asarray(y, dtype=np.float64)
        except (TypeError, ValueError):
            return False  # a non-numeric measurement object: left to log_likelihood
        if np.isinf(ya).any():
            raise ValueError(f"measurement at step {k}: infinite value")
        if np.isnan(ya).any():
            if self.missing == "raise":
                raise ValueError(f"measurement at step {k}: NaN (missing='raise')")
            return True
        return False

    def _degenerate(self, state: ParticleState, new: FloatArray, ll: FloatArray, k: int) -> None:
        what = _describe_degenerate(new)
        if self.recovery == "raise":
            raise DegenerateWeightsError(
                f"degenerate weight update at step {k}: {what}; the likelihood gives no "
                f"particle a positive weight (check the model, the measurement or the noise "
                f"levels, or pass recovery='reset')",
                step=k,
            )
        n = new.shape[0]
        inc = _logsumexp(state.logw + ll)
        state.resampled = False
        state.skipped = False
        state.logw = np.full(n, -math.log(n))
        state.weights = np.full(n, 1.0 / n)
        state.ess = float(n)
        state.reset = True
        state.loglik_increment = inc
        state.loglik += inc


def _logsumexp(a: FloatArray) -> float:
    m = a.max()
    if not math.isfinite(m):  # -inf (all zero), +inf or NaN: the value itself
        return float(m)
    return float(normalise_weights(a)[1])

def _record_step(
    k: int, x: FloatArray, w: FloatArray, state: ParticleState, mean: FloatArray,
    cov: FloatArray, qs: FloatArray | None, q_levels: FloatArray | None, ess: FloatArray,
    skipped: NDArray[np.bool_], reset: NDArray[np.bool_], incs: FloatArray,
    p_hist: FloatArray | None, w_hist: FloatArray | None,
) -> None:
    """Write step ``k``'s summaries (both loops of ``ParticleFilter.filter``)."""
    mean[k], cov[k] = _mean_cov(x, w)
    if qs is not None and q_levels is not None:
        qs[k] = _weighted_quantile(x, w, q_levels)
    if p_hist is not None and w_hist is not None:
        p_hist[k] = x
        w_hist[k] = w
    ess[k] = state.ess
    skipped[k] = state.skipped
    reset[k] = state.reset
    incs[k] = state.loglik_increment
