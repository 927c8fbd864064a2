"""Sequential importance resampling (SIR) particle filter over a batch of particles (N, n_x).

Seed 000 section 2.3 (eqs 13-16): the posterior ``p(x_k | y_{1:k})`` is represented by weighted
particles (eq. 13); with the transition density as importance function the weight recursion is
``w_k^i ∝ w_{k-1}^i p(y_k | x_k^i)`` (eq. 15); the effective sample size is
``N_eff = 1 / sum_i (w_k^i)^2`` (eq. 16) and resampling happens when it falls below a threshold.

Design (docs/engine-api.md, ``rulkit.estimation.particle``; docs/guide.md "Concepts"):

- Log-weights throughout, normalised by log-sum-exp. A degenerate update (every weight zero,
  i.e. every log-weight -inf, or any NaN / +inf log-weight) raises ``DegenerateWeightsError``
  naming the step, unless ``recovery="reset"`` (equal weights, step flagged in ``reset``).
- One step ``k`` (``ys[k]``, :meth:`ParticleFilter.step`, the one loop ``filter`` runs): resample
  if step ``k-1`` asked for it; propagate ``x_k = transition(x_{k-1}, k, rng)``; weight
  ``logw += log_likelihood(x_k, ys[k], k)`` (or the pluggable ``weight_update``); normalise;
  ESS; then the rule ``trigger(state)`` (when given) or ``ESS < ess_threshold * N`` decides
  whether the set is resampled before the next propagation. The posterior after step ``k`` is
  the weighted set before that resampling (the same random draws in the same order as
  resampling at the end of step ``k``).
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
- Posteriors (:class:`rulkit.estimation.base.Posterior`) carry the particles with their
  weights: ``result.posterior(k)``, ``state.posterior()``.

No per-particle Python loop; the per-step cost is a handful of numpy calls on (N,) / (N, n_x)
arrays plus whatever the user's ``transition`` and ``log_likelihood`` cost.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal, cast

import numpy as np
from numpy.typing import NDArray

from rulkit.estimation.base import (
    Estimator,
    EstimatorState,
    FilterResult,
    Posterior,
    refuse_model,
    weighted_moments,
)
from rulkit.estimation.batched import normalise_rows, normalise_weights, systematic_indices
from rulkit.estimation.resampling import _KERNELS, Resampler, get_resampler
from rulkit.estimation.weights import (
    DegenerateWeightsError,
    _describe_degenerate,
    _weighted_quantile,
    effective_sample_size,
    log_normalise,
    weighted_quantile,
)
from rulkit.model import (
    InputLike,
    StateSpaceModel,
    as_batch,
    check_measurements,
    loglik_from_model,
    plain,
    transition_from_model,
)

__all__ = ["ParticleFilter", "ParticleFilterResult", "ParticleState"]

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
class ParticleState(EstimatorState):
    """Mutable state of a running particle filter (for the per-step API and the plug-ins).

    ``particles`` (N, n_x); ``logw`` normalised log-weights (log-sum-exp 0) and ``weights`` their
    exponentials; ``ess`` the effective sample size of ``weights``; ``k`` the last assimilated
    step (-1 after ``initialise``); ``y`` the measurement of step ``k``; ``rng`` the generator
    used for propagation and resampling; ``loglik`` the running log-likelihood estimate and
    ``loglik_increment`` the last increment; flags of the last step: ``resampled`` (the set was
    resampled by :meth:`ParticleFilter.resample` since the last update), ``skipped`` (NaN
    measurement), ``reset`` (degenerate weights reset to equal), ``resample_pending`` (the
    resampling rule fired at step ``k``: :meth:`ParticleFilter.step` resamples before the next
    propagation). ``info`` is a free dict for plug-ins (e.g. an adaptive weight update may count
    clipped particles there).

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
    resample_pending: bool = False
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def n_particles(self) -> int:
        return self.particles.shape[0]

    def mean(self) -> FloatArray:
        """Weighted mean of the particles (n_x,) (bit-identical to ``filter``'s summary)."""
        return self.particles.T.copy() @ self.weights

    def cov(self) -> FloatArray:
        """Weighted covariance of the particles (n_x, n_x) (as ``filter``'s summary)."""
        return weighted_moments(self.particles, self.weights)[1]

    def quantile(self, q: float | FloatArray) -> FloatArray:
        """Weighted marginal quantiles per state component, shape ``q.shape + (n_x,)``."""
        return weighted_quantile(self.particles, self.weights, q)

    def posterior(self, unit: int = 0) -> Posterior:
        """The weighted particles of step ``k`` as a :class:`Posterior` (a copy)."""
        _one_unit(unit)
        return Posterior.from_samples(self.particles, self.weights)


def _one_unit(unit: int) -> None:
    if unit != 0:
        raise ValueError(f"unit: a particle filter estimates one unit (unit 0), got {unit}")


@dataclass(frozen=True)
class ParticleFilterResult(FilterResult):
    """Output of ``ParticleFilter.filter`` over ``T`` measurements.

    Per step ``k`` (summaries of the weighted particle set after the update of step ``k``):
    ``mean`` (T, n_x), ``cov`` (T, n_x, n_x), ``quantiles`` (T, n_q, n_x) at
    ``quantile_levels`` (None when not requested), ``ess`` (T,), ``resampled`` (T,) (the
    resampling rule fired at step k: the set was resampled before step k+1), ``skipped`` (T,)
    (NaN measurement, no update), ``reset`` (T,) (degenerate weights reset to equal),
    ``loglik_increments`` (T,) and their sum ``loglik``. ``final`` is the weighted set after the
    last step as a :class:`Posterior` (particles with their weights), ready for a prognosis;
    ``particle_history`` (T, N, n_x) and ``weight_history`` (T, N) hold the weighted sets behind
    the summaries when ``keep_particles=True`` (else None). ``posterior(k)`` gives step ``k``'s
    set as a ``Posterior`` (any ``k`` with the history, the last one without).
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
    final: Posterior
    particle_history: FloatArray | None = None
    weight_history: FloatArray | None = None

    @property
    def loglik(self) -> float:
        """Log marginal likelihood estimate ``sum_k loglik_increments[k]``."""
        return float(self.loglik_increments.sum())

    @property
    def n_steps(self) -> int:
        return int(self.mean.shape[0])

    @property
    def n_resampled(self) -> int:
        return int(self.resampled.sum())

    def posterior(self, k: int | None = None, unit: int = 0) -> Posterior:
        """Step ``k``'s weighted particles (None or the last step: ``final``; an earlier step
        needs ``filter(..., keep_particles=True)``)."""
        _one_unit(unit)
        t = self.n_steps
        if k is None:
            return self.final
        if not -t <= k < t:
            raise ValueError(f"k: expected a step in [{-t}, {t - 1}], got {k}")
        k = k % t
        if k == t - 1:
            return self.final
        if self.particle_history is None or self.weight_history is None:
            raise ValueError(f"k: the particles of step {k} were not kept; run "
                             "filter(..., keep_particles=True) for posteriors before the last step")
        return Posterior.from_samples(self.particle_history[k], self.weight_history[k])

    def moments(self, unit: int = 0) -> tuple[FloatArray, FloatArray]:
        """``(mean (T, n_x), cov (T, n_x, n_x))``."""
        _one_unit(unit)
        return self.mean, self.cov


@dataclass
class _Recorder:
    """The per-step summaries ``filter`` writes (preallocated arrays of a run of T steps)."""

    mean: FloatArray
    cov: FloatArray
    q_levels: FloatArray | None
    quantiles: FloatArray | None
    ess: FloatArray
    resampled: NDArray[np.bool_]
    skipped: NDArray[np.bool_]
    reset: NDArray[np.bool_]
    incs: FloatArray
    p_hist: FloatArray | None
    w_hist: FloatArray | None

    @classmethod
    def allocate(cls, t_len: int, n: int, n_x: int, q_levels: FloatArray | None,
                 keep: bool) -> _Recorder:
        return cls(np.empty((t_len, n_x)), np.empty((t_len, n_x, n_x)), q_levels,
                   None if q_levels is None else np.empty((t_len, q_levels.size, n_x)),
                   np.empty(t_len), np.zeros(t_len, dtype=bool), np.zeros(t_len, dtype=bool),
                   np.zeros(t_len, dtype=bool), np.empty(t_len),
                   np.empty((t_len, n, n_x)) if keep else None,
                   np.empty((t_len, n)) if keep else None)

    def record(self, k: int, state: ParticleState) -> None:
        x, w = state.particles, state.weights
        self.mean[k], self.cov[k] = weighted_moments(x, w)
        if self.quantiles is not None and self.q_levels is not None:
            self.quantiles[k] = _weighted_quantile(x, w, self.q_levels)
        if self.p_hist is not None and self.w_hist is not None:
            self.p_hist[k] = x
            self.w_hist[k] = w
        self.ess[k] = state.ess
        self.resampled[k] = state.resample_pending
        self.skipped[k] = state.skipped
        self.reset[k] = state.reset
        self.incs[k] = state.loglik_increment

    def result(self, state: ParticleState) -> ParticleFilterResult:
        return ParticleFilterResult(
            mean=self.mean, cov=self.cov, quantiles=self.quantiles,
            quantile_levels=self.q_levels, ess=self.ess, resampled=self.resampled,
            skipped=self.skipped, reset=self.reset, loglik_increments=self.incs,
            final=state.posterior(), particle_history=self.p_hist, weight_history=self.w_hist)


# ---------------------------------------------------------------------------------------------
# The filter
# ---------------------------------------------------------------------------------------------


class ParticleFilter(Estimator):
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
        refuse_model(transition, "ParticleFilter")
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
        prior: FloatArray | Posterior,
        rng: np.random.Generator | None = None,
        *,
        log_weights: FloatArray | None = None,
    ) -> ParticleState:
        """Start a filter run from ``prior``: particles (N, n_x) (equal weights unless
        ``log_weights``) or a :class:`Posterior` with samples (its particles and weights).

        The particles are copied; the returned state is then advanced with ``step``/``update``.
        """
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        if isinstance(prior, Posterior):
            if prior.samples is None or prior.weights is None:
                raise ValueError("prior: a Gaussian posterior has no particles; draw them with "
                                 "prior.with_samples(n_particles, rng)")
            if log_weights is not None:
                raise ValueError("log_weights: the prior posterior carries its own weights")
            particles = prior.samples
            if np.ptp(prior.weights) > 0:  # equal weights start exactly as a plain array
                with np.errstate(divide="ignore"):
                    log_weights = np.log(prior.weights)
        else:
            particles = prior
        x = as_batch(particles, self.n_x, "particles0", single=False).copy()
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
            self._weight(state, y, k, n, missing)
        except BaseException:
            # leave the state as it was before this step (no half-applied update)
            state.particles, state.k, state.y = prev
            raise
        return state

    def _weight(self, state: ParticleState, y: Any, k: int, n: int, missing: bool) -> None:
        state.resampled = state.reset = False
        state.skipped = missing
        if missing:
            state.loglik_increment = 0.0
            return
        ll = self.log_likelihood(state.particles, y, k)
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
        if not math.isfinite(new.max()):
            self._degenerate(state, new, ll, k)
            return
        lwn, w, ls = normalise_rows(new)  # one row: the shared particle core
        # the increment is logsumexp(logw_{k-1} + ll) (logw_{k-1} normalised): for the
        # bootstrap update that is the normaliser itself
        inc = float(ls) if self.weight_update is None else _logsumexp(state.logw + ll)
        state.logw = lwn
        state.weights = w
        state.ess = 1.0 / float(np.dot(w, w))
        state.loglik_increment = inc
        state.loglik += inc

    def fires(self, state: ParticleState) -> bool:
        """Whether the resampling rule fires for ``state``: ``trigger(state)`` when given, else
        ``ESS < ess_threshold * N`` (every step for a threshold of 1)."""
        if self.trigger is not None:
            return bool(self.trigger(state))
        n = state.logw.shape[0]
        return self.ess_threshold >= 1.0 or state.ess < self.ess_threshold * n

    def resample_if_needed(self, state: ParticleState) -> ParticleState:
        """Apply the trigger (or the ESS rule) and resample in place when it fires."""
        if self.fires(state):
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
        state.resample_pending = False
        return state

    def step(self, state: ParticleState, y: Any, *, missing: bool | None = None
             ) -> ParticleState:
        """One full filter step (module docstring): the resampling step ``k-1`` asked for,
        ``update``, then the rule decides on the next resampling; mutates ``state``. Afterwards
        ``state`` holds the weighted posterior of step ``k``."""
        saved = (state.particles, state.logw, state.weights, state.ess, state.resampled,
                 state.resample_pending)
        try:
            if state.resample_pending:
                self.resample(state)
            self.update(state, y, missing=missing)
        except BaseException:  # a failed step leaves the weighted set as it was
            (state.particles, state.logw, state.weights, state.ess, state.resampled,
             state.resample_pending) = saved
            raise
        state.resample_pending = self.fires(state)
        return state

    # -- whole-sequence API -------------------------------------------------------------------

    def filter(
        self,
        ys: Any,
        prior: FloatArray | Posterior,
        rng: np.random.Generator | None = None,
        *,
        quantiles: tuple[float, ...] | FloatArray | None = DEFAULT_QUANTILES,
        keep_particles: bool = False,
        log_weights0: FloatArray | None = None,
    ) -> ParticleFilterResult:
        """Run the filter over ``ys`` (T, ...) from ``prior``: the initial particles
        (N, n_x) or a :class:`Posterior` with samples (see :meth:`initialise`).

        ``ys[k]`` is assimilated after the k-th transition, by :meth:`step`. ``quantiles=None``
        skips the per-step sort. Same ``rng`` seed -> identical result.
        """
        y_arr, missing = self._measurements(ys)
        q_levels = None
        if quantiles is not None:
            q_levels = np.atleast_1d(np.asarray(quantiles, dtype=np.float64))
            if q_levels.ndim != 1 or np.any(~((q_levels >= 0) & (q_levels <= 1))):
                raise ValueError(f"quantiles: expected levels in [0, 1], got {plain(quantiles)}")
        state = self.initialise(prior, rng, log_weights=log_weights0)
        n, n_x = state.particles.shape
        rec = _Recorder.allocate(y_arr.shape[0], n, n_x, q_levels, keep_particles)
        for k, miss in enumerate(missing):
            self.step(state, y_arr[k], missing=miss)
            rec.record(k, state)
        return rec.result(state)

    def _measurements(self, ys: Any) -> tuple[FloatArray, list[bool]]:
        """``ys`` as a float array (T, ...) and, per row, whether it counts as missing."""
        if self.n_y is not None:
            ys = check_measurements(ys, self.n_y)
        y_arr = np.asarray(ys, dtype=np.float64)
        if y_arr.ndim == 0 or y_arr.shape[0] == 0:
            raise ValueError(f"ys: expected a non-empty array of shape (T, ...), got {y_arr.shape}")
        flat = y_arr.reshape(y_arr.shape[0], -1)
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
        return y_arr, nan_rows.tolist()

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
