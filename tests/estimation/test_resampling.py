"""Resampling schemes: unbiasedness (E[copies_i] = N w_i), round-off, edge cases, validation.

Oracle: the defining property of an unbiased resampler, checked by Monte Carlo over many
independent draws with a z-test per particle; the counter-example (filterpy's residual scheme,
re-implemented below) shows the test can fail.
"""

from __future__ import annotations

import numpy as np
import pytest

from rulkit.estimation import resampling as rs
from rulkit.estimation.resampling import (
    RESAMPLERS,
    get_resampler,
    multinomial,
    residual,
    stratified,
    systematic,
)

SCHEMES = sorted(RESAMPLERS)

# N w = [2.2, 1.0, 0.6, 0.2, 0, 1.0 + 0.5, 0.5]: deterministic parts, residuals, a zero weight
W_MIXED = np.array([0.275, 0.125, 0.075, 0.025, 0.0, 0.1875, 0.0625, 0.25])
M_DRAWS = 20_000
Z_MAX = 5.0


def copy_counts(fn, w: np.ndarray, m: int, seed: int) -> np.ndarray:
    """Copy counts (m, N) of m independent resampling draws (one bincount for all draws)."""
    rng = np.random.default_rng(seed)
    n = w.size
    idx = np.concatenate([fn(w, rng) for _ in range(m)])
    draw = np.repeat(np.arange(m), n)
    return np.bincount(draw * n + idx, minlength=m * n).reshape(m, n)


def max_bias_z(counts: np.ndarray, w: np.ndarray) -> float:
    """Largest |z| of mean copies against N w over particles (exact match where var is 0)."""
    n = w.size
    mean = counts.mean(axis=0)
    se = counts.std(axis=0, ddof=1) / np.sqrt(counts.shape[0])
    target = n * w
    det = se == 0
    if np.any(np.abs(mean[det] - target[det]) > 1e-9):
        return np.inf
    return float(np.max(np.abs(mean[~det] - target[~det]) / se[~det]))


def filterpy_residual(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """filterpy 1.4 / 2.0 ``residual_resample`` (the biased one), vectorised, with our rng.

    The bug: the residual is ``w - floor(N w)`` instead of ``N w - floor(N w)``.
    """
    n = len(weights)
    num_copies = np.floor(n * np.asarray(weights)).astype(int)
    det = np.repeat(np.arange(n), num_copies)
    resid = weights - num_copies
    resid = resid / resid.sum()
    cs = np.cumsum(resid)
    cs[-1] = 1.0
    rest = np.searchsorted(cs, rng.random(n - det.size))
    return np.concatenate([det, rest])


@pytest.fixture(scope="module")
def dirichlet_weights() -> np.ndarray:
    return np.random.default_rng(42).dirichlet(np.full(12, 0.7))


@pytest.mark.parametrize("name", SCHEMES)
@pytest.mark.parametrize("which", ["mixed", "dirichlet"])
def test_unbiased(name, which, dirichlet_weights):
    w = W_MIXED if which == "mixed" else dirichlet_weights
    counts = copy_counts(RESAMPLERS[name], w, M_DRAWS, seed=7)
    assert np.all(counts.sum(axis=1) == w.size)
    assert max_bias_z(counts, w) < Z_MAX


def test_residual_uses_nw_minus_floor_and_test_detects_filterpy_bias():
    # The counter-example must fail the same unbiasedness test that ours passes.
    w = np.array([0.55, 0.25, 0.15, 0.05])  # N w = [2.2, 1, 0.6, 0.2]
    ours = copy_counts(residual, w, M_DRAWS, seed=3)
    buggy = copy_counts(filterpy_residual, w, M_DRAWS, seed=3)
    assert max_bias_z(ours, w) < Z_MAX
    assert max_bias_z(buggy, w) > 20
    # residual copies: exactly floor(N w) deterministic + residual draws from N w - floor(N w)
    # -> the only random copy goes to particle 0, 2 or 3 with probabilities 0.2, 0.6, 0.2
    extra = ours - np.floor(4 * w)
    assert np.all(extra >= 0) and np.all(extra.sum(axis=1) == 1)
    freq = extra.mean(axis=0)
    np.testing.assert_allclose(freq, [0.2, 0.0, 0.6, 0.2], atol=5 * np.sqrt(0.25 / M_DRAWS))


@pytest.mark.parametrize("name", SCHEMES)
def test_output_sorted_int64_in_range(name, dirichlet_weights):
    idx = RESAMPLERS[name](dirichlet_weights, np.random.default_rng(0))
    assert idx.dtype == np.int64 and idx.shape == dirichlet_weights.shape
    assert np.all(np.diff(idx) >= 0)
    assert idx.min() >= 0 and idx.max() < dirichlet_weights.size


@pytest.mark.parametrize("name", SCHEMES)
def test_zero_weight_never_selected(name):
    w = np.array([0.0, 0.3, 0.0, 0.0, 0.7, 0.0])
    counts = copy_counts(RESAMPLERS[name], w, 2000, seed=1)
    assert np.all(counts[:, w == 0] == 0)


class _ExtremeRng:
    """Stand-in generator whose uniforms are the largest double below 1 (and exponential
    spacings that put the last multinomial position at exactly 1.0 after scaling)."""

    top = np.nextafter(1.0, 0.0)

    def random(self, size=None):
        return self.top if size is None else np.full(size, self.top)

    def standard_exponential(self, size):
        e = np.ones(size)
        e[-1] = 1e-300
        return e


@pytest.mark.parametrize("name", SCHEMES)
def test_cumsum_ending_below_one_never_returns_n(name):
    # 0.1 ten times sums to 0.9999999999999999: a position of 1 - 2^-53 lies past the end
    w = np.full(10, 0.1)
    assert np.cumsum(w)[-1] < 1.0
    idx = RESAMPLERS[name](w, _ExtremeRng())
    assert idx.max() <= 9
    # trailing zero weights and a sum a little below 1 (inside the tolerance): the last
    # position must fall on the last particle with positive weight, not on a zero-weight one
    w2 = np.array([0.3, 0.2, 0.5 - 4e-9, 0.0, 0.0])
    idx2 = RESAMPLERS[name](w2, _ExtremeRng())
    assert idx2.max() == 2
    assert idx2.size == 5


@pytest.mark.parametrize("name", SCHEMES)
def test_single_nonzero_weight(name):
    w = np.zeros(7)
    w[4] = 1.0
    np.testing.assert_array_equal(RESAMPLERS[name](w, np.random.default_rng(0)), np.full(7, 4))
    np.testing.assert_array_equal(RESAMPLERS[name](np.ones(1), np.random.default_rng(0)), [0])


@pytest.mark.parametrize("fn", [systematic, stratified, residual])
@pytest.mark.parametrize("n", [1, 3, 10, 49, 1000, 4097])
def test_equal_weights_each_particle_once(fn, n):
    # 49 * (1/49) = 0.9999999999999999 in floating point: residual must still give 1 copy each
    for seed in range(5):
        np.testing.assert_array_equal(
            fn(np.full(n, 1.0 / n), np.random.default_rng(seed)), np.arange(n)
        )


def test_systematic_counts_are_floor_or_ceil(dirichlet_weights):
    w = dirichlet_weights
    counts = copy_counts(systematic, w, 5000, seed=11)
    nw = w.size * w
    assert np.all((counts == np.floor(nw)) | (counts == np.ceil(nw)))


def test_residual_counts_at_least_floor(dirichlet_weights):
    w = dirichlet_weights
    counts = copy_counts(residual, w, 5000, seed=12)
    assert np.all(counts >= np.floor(w.size * w))


@pytest.mark.parametrize("name", ["stratified", "systematic", "residual"])
def test_variance_not_above_multinomial(name, dirichlet_weights):
    # Var(copies_i) <= N w_i (1 - w_i), the multinomial variance (Douc et al. 2005);
    # 20 000 draws: relative standard error of a sample variance ~ 1 %, allow 10 %
    w = dirichlet_weights
    counts = copy_counts(RESAMPLERS[name], w, M_DRAWS, seed=13)
    var_multi = w.size * w * (1 - w)
    assert np.all(counts.var(axis=0) <= 1.10 * var_multi + 1e-12)
    # and multinomial itself reaches it (the bound is not vacuous)
    cm = copy_counts(multinomial, w, M_DRAWS, seed=14)
    np.testing.assert_allclose(cm.var(axis=0), var_multi, rtol=0.1, atol=1e-3)


@pytest.mark.parametrize("name", SCHEMES)
def test_reproducible_from_seed(name, dirichlet_weights):
    fn = RESAMPLERS[name]
    a = fn(dirichlet_weights, np.random.default_rng(5))
    b = fn(dirichlet_weights, np.random.default_rng(5))
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("name", SCHEMES)
def test_public_equals_kernel(name, dirichlet_weights):
    a = RESAMPLERS[name](dirichlet_weights, np.random.default_rng(9))
    b = rs._KERNELS[name](dirichlet_weights, np.random.default_rng(9))
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("name", SCHEMES)
@pytest.mark.parametrize(
    ("weights", "match"),
    [
        (np.full((2, 2), 0.25), "1-D"),
        (np.array([]), "empty"),
        (np.array([0.5, np.nan, 0.5]), "non-finite value nan at index 1"),
        (np.array([0.5, np.inf]), "non-finite value inf at index 1"),
        (np.array([1.2, -0.2]), "negative value -0.2 at index 1"),
        (np.array([0.5, 0.4]), "normalised"),
        (np.array([0.0, 0.0]), "normalised"),
    ],
)
def test_invalid_weights_raise(name, weights, match):
    with pytest.raises(ValueError, match=match):
        RESAMPLERS[name](weights, np.random.default_rng(0))


def test_accepts_list_and_tolerance():
    idx = systematic([0.5, 0.5 + 5e-9], np.random.default_rng(0))
    np.testing.assert_array_equal(idx, [0, 1])


def test_get_resampler():
    for name, fn in RESAMPLERS.items():
        assert get_resampler(name) is fn
    assert get_resampler(residual) is residual
    with pytest.raises(ValueError, match="unknown resampler 'bogus'"):
        get_resampler("bogus")
    with pytest.raises(TypeError, match="resampler must be"):
        get_resampler(3)  # type: ignore[arg-type]


# ------------------------------------------- compiled systematic kernel vs the numpy reference
class _FixedUniform:
    """Stand-in generator whose single ``random()`` draw is ``u`` (to probe boundary cases)."""

    def __init__(self, u: float) -> None:
        self.u = u

    def random(self) -> float:
        return self.u


def _weight_cases(rng: np.random.Generator):
    yield W_MIXED
    for n in (1, 2, 3, 7, 49, 1000, 10_007):
        yield np.full(n, 1.0 / n)  # every position on or next to a cumulative-sum boundary
    for n in (5, 60, 999, 4097):
        yield rng.dirichlet(np.ones(n))
        w = rng.random(n) * (rng.random(n) < 0.2)  # many zeros, including trailing ones
        w[0] += 1.0
        w[-(n // 4 or 1):] = 0.0
        yield w / w.sum()
        w = rng.integers(0, 4, n).astype(float)  # ties and exact multiples of 1/sum
        w[n // 2] += 1.0
        yield w / w.sum()
        yield (w := rng.exponential(size=n) ** 8) / w.sum()  # a few dominant weights
    w = np.full(10, 0.1)
    w[-1] = 0.1 - 1e-9  # sum just below 1 (within the tolerance) with positive last weight
    yield w


@pytest.mark.parametrize("u", [0.0, 1.0 / 3.0, 0.5, float(np.nextafter(1.0, 0.0)), None])
def test_systematic_kernel_equals_searchsorted_reference(u):
    """The compiled merge pass returns exactly the indices of the numpy binary-search path,
    including uniforms at 0 and just below 1 and weights whose cumulative sums meet the
    positions exactly (equal weights, integer ratios)."""
    rng = np.random.default_rng(11)
    for w in _weight_cases(rng):
        uu = rng.random() if u is None else u
        ref = rs._systematic_reference(w, _FixedUniform(uu))
        got = rs._systematic(w, _FixedUniform(uu))
        assert got.dtype == np.int64
        np.testing.assert_array_equal(got, ref)
        # and the uncompiled body of the kernel (plain Python) agrees as well
        if w.size <= 1000:
            np.testing.assert_array_equal(rs._systematic_loop(w, uu), ref)


def test_systematic_kernel_equals_reference_with_a_generator():
    """Same generator state -> same indices as the reference, over many random weight sets."""
    wr = np.random.default_rng(12)
    for _ in range(200):
        n = int(wr.integers(1, 3000))
        w = wr.dirichlet(np.full(n, float(wr.choice([0.05, 1.0, 20.0]))))
        a = rs._systematic(w, np.random.default_rng(n))
        b = rs._systematic_reference(w, np.random.default_rng(n))
        np.testing.assert_array_equal(a, b)
