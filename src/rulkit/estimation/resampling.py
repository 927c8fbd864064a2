"""Resampling schemes for particle filters: plain functions of normalised weights.

Each scheme maps normalised weights ``w`` (N,) to ``N`` ancestor indices (int64, sorted
ascending) such that the expected number of copies of particle ``i`` is ``N w_i``
(unbiasedness; seed 000 section 2.3.1: "the resampling step duplicates the particles with large
weights and eliminates those with small weights", after which every weight is 1/N). The schemes
differ only in the variance of the copy counts (Douc, Cappé & Moulines 2005, "Comparison of
resampling schemes for particle filtering"):

- ``multinomial``: N i.i.d. draws from the categorical distribution ``w``.
- ``stratified``: one uniform per stratum ``[(k)/N, (k+1)/N)``.
- ``systematic``: a single uniform shifted over the N strata; particle ``i`` gets either
  ``floor(N w_i)`` or ``ceil(N w_i)`` copies.
- ``residual``: ``floor(N w_i)`` deterministic copies, the remaining ``R = N - sum floor(N w)``
  drawn multinomially from the residual weights ``N w - floor(N w)`` (normalised). filterpy's
  ``residual_resample`` uses ``w - floor(N w)`` instead, which is biased; the tests show the
  difference.

All schemes are vectorised: positions in [0, 1) are located in the cumulative sum of the weights
by ``numpy.searchsorted``. Positions are scaled by the last element of the cumulative sum, so a
cumulative sum that ends just below (or above) 1 through round-off never yields index ``N``;
zero-weight particles are never selected. Systematic resampling (used by the particle filter
at every resampling) locates its N sorted positions by one merge pass over the cumulative sum,
the compiled row function of the batched particle core (:mod:`rulkit.estimation.batched`),
instead of N binary searches; it returns exactly the indices of the ``searchsorted`` reference
``_systematic_reference`` (tested).

Every function validates its input (1-D, non-empty, finite, non-negative, summing to 1 within
``WEIGHT_SUM_TOL``) and raises ``ValueError`` saying what is wrong.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from rulkit.estimation.batched import systematic_indices
from rulkit.model import plain

__all__ = [
    "RESAMPLERS",
    "WEIGHT_SUM_TOL",
    "Resampler",
    "get_resampler",
    "multinomial",
    "residual",
    "stratified",
    "systematic",
]

Resampler = Callable[[NDArray[np.float64], np.random.Generator], NDArray[np.int64]]

#: Absolute tolerance on ``|sum(w) - 1|`` accepted by the resamplers.
WEIGHT_SUM_TOL = 1e-8


def _check_weights(weights: NDArray[np.float64] | list[float]) -> NDArray[np.float64]:
    """Validate normalised weights and return them as a float64 1-D array."""
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 1:
        raise ValueError(f"weights: expected a 1-D array of shape (N,), got shape {w.shape}")
    if w.size == 0:
        raise ValueError("weights: empty array (need at least one particle)")
    finite = np.isfinite(w)
    if not finite.all():
        i = int(np.flatnonzero(~finite)[0])
        raise ValueError(f"weights: non-finite value {w[i]} at index {i}")
    if (w < 0.0).any():
        i = int(np.flatnonzero(w < 0.0)[0])
        raise ValueError(f"weights: negative value {w[i]} at index {i}")
    s = float(w.sum())
    if abs(s - 1.0) > WEIGHT_SUM_TOL:
        raise ValueError(
            f"weights: must be normalised (sum to 1 within {WEIGHT_SUM_TOL:g}), got sum {plain(s)}"
        )
    return w


def _locate(w: NDArray[np.float64], positions: NDArray[np.float64]) -> NDArray[np.int64]:
    """Indices ``i`` with ``c_{i-1} <= p < c_i`` for sorted positions ``p`` in [0, 1).

    ``c`` is the cumulative sum of ``w``; positions are scaled by ``c[-1]`` so round-off in the
    sum cannot push a position past the end. Zero-weight particles own an empty interval and are
    never selected.
    """
    c = np.cumsum(w)
    idx = np.searchsorted(c, positions * c[-1], side="right")
    if idx[-1] >= w.size:  # only possible through round-off in positions * c[-1]
        last = int(np.flatnonzero(w)[-1])
        np.minimum(idx, last, out=idx)
    return idx.astype(np.int64, copy=False)


def _sorted_uniforms(n: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """``n`` sorted i.i.d. U[0, 1) values in O(n), by normalised exponential spacings."""
    e = np.cumsum(rng.standard_exponential(n + 1))
    return e[:-1] / e[-1]


def _multinomial(w: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.int64]:
    return _locate(w, _sorted_uniforms(w.size, rng))


def _stratified(w: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.int64]:
    n = w.size
    return _locate(w, (np.arange(n) + rng.random(n)) / n)


def _systematic_reference(
    w: NDArray[np.float64], rng: np.random.Generator
) -> NDArray[np.int64]:
    """Systematic resampling by locating all N positions (one binary search each).

    The numpy reference of :func:`_systematic`, which returns the same indices (tested).
    """
    n = w.size
    return _locate(w, (np.arange(n) + rng.random()) / n)


def _systematic_loop(w: NDArray[np.float64], u: float) -> NDArray[np.int64]:
    """Ancestors of systematic resampling with uniform ``u``: the batched core's compiled
    :func:`rulkit.estimation.batched.systematic_indices` (the same positions, cumulative sum
    and comparisons as :func:`_locate`, located by one merge pass instead of N binary
    searches)."""
    return systematic_indices(w, u)  # type: ignore[no-any-return]


def _systematic(w: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.int64]:
    """Systematic resampling in O(N): one uniform, then a compiled merge of the N sorted
    positions with the cumulative weights. Returns the same indices as
    :func:`_systematic_reference` for the same ``rng`` state (tested), without its N binary
    searches and per-call numpy overhead (the particle filter calls it every step).
    """
    return _systematic_loop(w, rng.random())


def _residual(w: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.int64]:
    n = w.size
    nw = w * (n / w.sum())
    # floor(N w); the factor (1 + 1e-12) makes N w that is an integer up to round-off (e.g.
    # 49 * (1/49) = 0.9999999999999999) count as that integer. Bias at most 1e-12 N w_i.
    counts = np.floor(nw * (1.0 + 1e-12))
    rest = n - int(counts.sum())
    if rest > 0:
        resid = np.maximum(nw - counts, 0.0)
        extra = _locate(resid / resid.sum(), _sorted_uniforms(rest, rng))
        counts += np.bincount(extra, minlength=n)
    return np.repeat(np.arange(n, dtype=np.int64), counts.astype(np.int64))


def multinomial(weights: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.int64]:
    """Multinomial resampling: N i.i.d. ancestor draws from the categorical law ``weights``.

    Copy counts are Multinomial(N, w): ``E[copies_i] = N w_i``, ``Var = N w_i (1 - w_i)``.
    Sorted uniforms are generated in O(N) from exponential spacings.
    """
    return _multinomial(_check_weights(weights), rng)


def stratified(weights: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.int64]:
    """Stratified resampling: position ``(k + U_k) / N`` with independent ``U_k ~ U[0, 1)``.

    Unbiased; copy-count variance never exceeds that of multinomial resampling.
    """
    return _stratified(_check_weights(weights), rng)


def systematic(weights: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.int64]:
    """Systematic resampling: positions ``(k + U) / N`` with a single ``U ~ U[0, 1)``.

    Unbiased; particle ``i`` receives ``floor(N w_i)`` or ``ceil(N w_i)`` copies. The default of
    docs/systems/reaction-wheel.md §3.
    """
    return _systematic(_check_weights(weights), rng)


def residual(weights: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.int64]:
    """Residual resampling: ``floor(N w_i)`` deterministic copies, the rest multinomial.

    The ``R = N - sum_i floor(N w_i)`` remaining ancestors are drawn multinomially from the
    residual weights ``(N w_i - floor(N w_i)) / R``, so ``E[copies_i] = N w_i`` (unbiased). Not
    ``w_i - floor(N w_i)`` as in filterpy's biased ``residual_resample``.
    """
    return _residual(_check_weights(weights), rng)


#: Scheme name -> public (validating) resampling function.
RESAMPLERS: dict[str, Resampler] = {
    "multinomial": multinomial,
    "stratified": stratified,
    "systematic": systematic,
    "residual": residual,
}

# Non-validating kernels, used by the particle filter on weights it has normalised itself.
_KERNELS: dict[str, Resampler] = {
    "multinomial": _multinomial,
    "stratified": _stratified,
    "systematic": _systematic,
    "residual": _residual,
}


def get_resampler(name_or_callable: str | Resampler) -> Resampler:
    """Return the resampling function for a scheme name, or a callable unchanged.

    Raises ``ValueError`` listing the known names for an unknown string and ``TypeError`` for
    anything that is neither a string nor callable.
    """
    if isinstance(name_or_callable, str):
        try:
            return RESAMPLERS[name_or_callable]
        except KeyError:
            raise ValueError(
                f"unknown resampler {name_or_callable!r}; choose one of {sorted(RESAMPLERS)}"
            ) from None
    if callable(name_or_callable):
        return name_or_callable
    raise TypeError(
        f"resampler must be a scheme name or a callable(weights, rng) -> indices, "
        f"got {type(name_or_callable).__name__}"
    )
