"""The batched particle core: numpy and numba versions equal to each other and to independent
oracles (scipy's logsumexp, a per-row searchsorted systematic resampler, numpy's weighted
``inverted_cdf`` quantile), and numba's cache reused across modules in a fresh process."""

from __future__ import annotations

import contextlib
import io
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from scipy.special import logsumexp

from rulkit.estimation import batched as bt


def _logw(rng: np.random.Generator, U: int, N: int) -> np.ndarray:
    lw = rng.normal(scale=30.0, size=(U, N)) + rng.normal(scale=500.0, size=(U, 1))
    lw[rng.random((U, N)) < 0.1] = -np.inf  # zero weights
    lw[:, 0] = rng.normal(size=U)  # at least one finite entry per row
    return lw


@pytest.mark.parametrize("N", [1, 2, 7, 200, 1001])
def test_normalise_matches_scipy_logsumexp_numpy_and_numba(N: int) -> None:
    rng = np.random.default_rng(N)
    lw = _logw(rng, 6, N)
    ref = logsumexp(lw, axis=1)
    lwn, w, ls = bt.normalise_rows(lw)
    lwn2, w2, ls2 = bt.normalise_rows_numba(lw)
    for a, b in ((ls, ref), (ls2, ref), (w2, w), (lwn2, lwn)):
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-300)
    np.testing.assert_allclose(w, np.exp(lw - ref[:, None]), rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, rtol=1e-14)
    np.testing.assert_allclose(logsumexp(lwn, axis=1), 0.0, atol=1e-12)
    # one row = the same function on 1-D input
    a, b, c = bt.normalise_rows(lw[0])
    np.testing.assert_array_equal(a, lwn[0])
    np.testing.assert_array_equal(b, w[0])
    assert float(c) == ls[0]


def test_normalise_degenerate_rows_same_in_both_versions() -> None:
    lw = np.array([[0.0, 1.0, -np.inf], [-np.inf, -np.inf, -np.inf], [0.0, np.nan, 1.0],
                   [0.0, np.inf, 1.0]])
    for fn in (bt.normalise_rows, bt.normalise_rows_numba):
        lwn, w, ls = fn(lw)
        assert ls[0] == pytest.approx(logsumexp(lw[0]))
        assert ls[1] == -np.inf and np.isnan(ls[2]) and np.isnan(ls[3])
        assert np.isnan(w[1:]).all()
        np.testing.assert_array_equal(lwn[1:], lw[1:])
    # the in-place row function leaves a degenerate row untouched
    row, wn = lw[2].copy(), np.full(3, 7.0)
    assert np.isnan(bt.normalise_row(row, wn))
    np.testing.assert_array_equal(wn, 7.0)


def test_normalise_does_not_overflow() -> None:
    lw = np.array([[1000.0, 1000.0], [-1000.0, -1001.0]])
    _, w, ls = bt.normalise_rows(lw)
    _, w2, ls2 = bt.normalise_rows_numba(lw)
    np.testing.assert_allclose(ls, [1000 + np.log(2), logsumexp(lw[1])])
    np.testing.assert_allclose(w2, w, rtol=1e-15)
    np.testing.assert_allclose(ls2, ls, rtol=1e-15)


def test_ess_numpy_numba_and_bounds() -> None:
    rng = np.random.default_rng(3)
    w = rng.dirichlet(np.full(50, 0.3), size=8)
    e = bt.ess_rows(w)
    np.testing.assert_allclose(bt.ess_rows_numba(w), e, rtol=1e-13)
    np.testing.assert_allclose(e, 1.0 / np.einsum("ij,ij->i", w, w), rtol=1e-13)
    assert bt.ess_rows(np.full(4, 0.25)) == pytest.approx(4.0)
    assert bt.ess_rows(np.array([0.0, 1.0, 0.0])) == 1.0
    assert np.all((e >= 1) & (e <= 50))


def _systematic_oracle(w: np.ndarray, u: float) -> np.ndarray:
    """Per-row reference written independently: searchsorted of the N positions."""
    c = np.cumsum(w)
    n = w.size
    idx = np.searchsorted(c, (np.arange(n) + u) / n * c[-1], side="right")
    return np.minimum(idx, np.flatnonzero(w)[-1])


@pytest.mark.parametrize("N", [1, 3, 64, 500])
def test_systematic_equals_searchsorted_oracle(N: int) -> None:
    rng = np.random.default_rng(10 + N)
    w = rng.dirichlet(np.full(N, 0.5), size=12)
    w[:, -1] = 0.0 if N > 1 else w[:, -1]  # trailing zero weight: never selected
    w /= w.sum(axis=1, keepdims=True)
    u = rng.random(12)
    u[0] = 0.0
    u[1] = np.nextafter(1.0, 0.0)
    ref = np.stack([_systematic_oracle(w[r], u[r]) for r in range(12)])
    np.testing.assert_array_equal(bt.systematic_rows(w, u), ref)
    np.testing.assert_array_equal(bt.systematic_rows_numba(w, u), ref)
    for r in range(3):
        np.testing.assert_array_equal(bt.systematic_rows(w[r], u[r]), ref[r])
        idx, cw = np.empty(N, np.int64), np.empty(N)
        bt.systematic_row(w[r], u[r], idx, cw)
        np.testing.assert_array_equal(idx, ref[r])
    # unbiased copy counts: floor or ceil of N w
    counts = np.stack([np.bincount(ref[r], minlength=N) for r in range(12)])
    assert np.all(counts >= np.floor(N * w - 1e-9)) and np.all(counts <= np.ceil(N * w + 1e-9))


def test_systematic_round_off_never_returns_index_n() -> None:
    w = np.array([0.3, 0.7 - 1e-12, 0.0])  # sums just below 1
    for u in (0.0, 0.999999999999):
        assert bt.systematic_rows(w, u).max() <= 1
        assert bt.systematic_rows_numba(w[None], np.array([u])).max() <= 1


@pytest.mark.parametrize("seed", range(4))
def test_weighted_quantile_equals_numpy_inverted_cdf(seed: int) -> None:
    rng = np.random.default_rng(seed)
    U, N = 5, 37
    x = np.round(rng.normal(size=(U, N)), 1)  # ties
    w = rng.random((U, N))
    w[rng.random((U, N)) < 0.2] = 0.0
    q = np.array([0.0, 0.025, 0.3, 0.5, 0.975, 1.0])
    ref = np.stack([np.quantile(x[r], q, weights=w[r], method="inverted_cdf")
                    for r in range(U)])
    np.testing.assert_array_equal(bt.weighted_quantile_rows(x, w, q), ref)
    np.testing.assert_array_equal(bt.weighted_quantile_rows_numba(x, w, q), ref)
    assert bt.weighted_quantile_rows(x[0], w[0], 0.3) == ref[0, 2]
    # q = 0 never returns a zero-weight particle
    x0, w0 = np.array([-5.0, 1.0, 2.0]), np.array([0.0, 1.0, 1.0])
    assert bt.weighted_quantile_rows(x0, w0, 0.0) == 1.0
    assert bt.weighted_quantile_rows_numba(x0[None], w0[None], np.array([0.0]))[0, 0] == 1.0


_CACHE_SCRIPT = textwrap.dedent("""
    import hashlib
    import json
    import sys
    import numpy as np
    from rulkit.estimation import batched
    from rulkit.systems.reaction_wheel.degradation import quadrature
    from rulkit.systems.reaction_wheel.temperature import kernels
    from rulkit.systems.reaction_wheel.temperature.particle import (
        TemperatureConfig,
        filter_temperature,
    )
    from rulkit.systems.reaction_wheel.wheel import simulate_table3

    def pf():
        h = hashlib.sha256()
        for speed in ("low", "high"):
            d = simulate_table3(np.random.default_rng(0), speed, t_end=5.0)
            for design in ("F1", "F2"):
                for variant in ("pf", "adaptive", "apf_eq28", "apf_tempered"):
                    cfg = TemperatureConfig(design=design, variant=variant, n_particles=20)
                    r = filter_temperature(d.y, d.V, np.random.default_rng(1), cfg,
                                           sigma=(d.sigma_w, d.sigma_I))
                    h.update(np.ascontiguousarray(r.T_mean).tobytes())
        return h, kernels.pf_kernel, batched.normalise_row

    def rows():
        h = hashlib.sha256()
        lw = np.random.default_rng(2).normal(size=(3, 9))
        h.update(batched.normalise_rows_numba(lw)[2].tobytes())
        return h, batched.normalise_rows_numba, batched.normalise_rows_numba

    def stieltjes():
        h = hashlib.sha256()
        u = np.random.default_rng(3).normal(20.0, 3.0, size=(50, 200))
        for a in quadrature._stieltjes_kernel(u, 12):
            h.update(np.ascontiguousarray(a).tobytes())
        return h, quadrature._stieltjes_kernel, quadrature._stieltjes_kernel

    out = {}
    for part in PARTS:
        h, kernel, callee = globals()[part]()
        st = kernel.stats
        out[part] = {"sha": h.hexdigest(), "hits": sum(st.cache_hits.values()),
                     "misses": sum(st.cache_misses.values()),
                     "dirs": [st.cache_path, callee.stats.cache_path]}
    print(json.dumps(out))
""")
_PARTS = ("pf", "rows", "stieltjes")


def _kernel_outputs(parts: tuple[str, ...], env: dict[str, str] | None = None
                    ) -> dict[str, dict]:
    """Per part of _CACHE_SCRIPT: the sha256 of its outputs, its kernel's numba cache hits and
    misses (a compile), the cache directories of the kernel and of a batched function it calls;
    in this process (``env`` None) or in a fresh one."""
    code = f"PARTS = {parts!r}\n" + _CACHE_SCRIPT
    if env is None:
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            exec(compile(code, "_CACHE_SCRIPT", "exec"), {"__name__": "_cache_script"})
        return json.loads(buf.getvalue())
    run = subprocess.run([sys.executable, "-c", code], env=env, check=True,
                         capture_output=True, text=True, timeout=600)
    return json.loads(run.stdout)


def test_numba_kernels_compiled_or_cached_give_the_same_bits(tmp_path: Path) -> None:
    """A compiled and a cached run of the step-1 kernel (every design and variant), batched's row
    functions and the lubrication windows' Stieltjes kernel (fastmath) give the same bits.
    Same seed, same machine, same bits (fastmath reassociation broke this: the in-process and
    the cached machine code rounded differently). The cache holds index files for batched's
    row functions and for the kernel that calls them.

    A kernel this process compiled (an empty numba cache, as in CI) is compared with a fresh
    process loading it from the same cache: the step-1 kernel's long compile is shared with
    the other tests. A kernel this process loaded from a cache is compiled in a fresh process
    on an empty cache and loaded by a second one."""
    here = _kernel_outputs(_PARTS)
    compiled = tuple(p for p in _PARTS if here[p]["misses"] and not here[p]["hits"])
    pairs = []
    if compiled:
        pairs.append((here, _kernel_outputs(compiled, dict(os.environ)), compiled))
    if rest := tuple(p for p in _PARTS if p not in compiled):
        env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
        pairs.append((_kernel_outputs(rest, env), _kernel_outputs(rest, env), rest))
    dirs = []
    for first, second, parts in pairs:
        for p in parts:
            assert first[p]["misses"] > 0 and first[p]["hits"] == 0, (p, "no compile")
            assert second[p]["hits"] > 0 and second[p]["misses"] == 0, (p, "not loaded")
            assert first[p]["sha"] == second[p]["sha"], p
            dirs += [Path(d) for d in first[p]["dirs"]]
    idx = [f.name for d in set(dirs) for f in d.glob("*.nbi")]
    for fn in ("batched.normalise_row", "batched.ess_row", "batched.systematic_row",
               "batched.weighted_quantile_select_row", "batched.normalise_rows_numba",
               "kernels.pf_kernel"):
        assert any(n.startswith(fn + "-") for n in idx), (fn, idx)
    data = [f for d in set(dirs) for f in d.glob("*.nbc") if "pf_kernel" in f.name]
    assert data, "no compiled pf_kernel in the cache"


def test_weighted_quantile_by_selection_equals_inverted_cdf() -> None:
    """The quickselect quantile used in the filter loops equals np.quantile's inverted CDF
    (ties, zero weights, resampled copies, q = 0 and 1, a single particle)."""
    rng = np.random.default_rng(5)
    for N in (1, 2, 3, 50, 350):
        buf = np.empty(N, np.int64)
        for trial in range(20):
            x = np.round(rng.normal(size=N), 1 if trial % 2 else 6)
            if trial % 3 == 0:  # resampled cloud: many copies
                x = x[rng.integers(0, max(1, N // 10), N)]
            w = rng.dirichlet(np.full(N, 0.3))
            w[rng.random(N) < 0.2] = 0.0
            if not w.sum() > 0:
                w[0] = 1.0
            for q in (0.0, 0.025, 0.05, 0.5, 0.95, 0.975, 1.0):
                ref = np.quantile(x, q, weights=w, method="inverted_cdf")
                assert bt.weighted_quantile_select_row(x, w, q, buf) == ref, (N, trial, q)
                if q > 0:
                    order, cw = np.empty(N, np.int64), np.empty(N)
                    assert bt.weighted_quantile_row(x, w, q, order, cw) == ref


def test_weights_from_log_form_is_the_same_weights_up_to_rounding() -> None:
    lw = _logw(np.random.default_rng(9), 4, 60)
    a = bt.normalise_rows(lw)
    b = bt.normalise_rows(lw, weights_from_log=True)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_allclose(b[1], a[1], rtol=1e-13, atol=1e-300)
    np.testing.assert_array_equal(b[1], np.exp(a[0]))
    row, wn = lw[1].copy(), np.empty(60)
    bt.normalise_row(row, wn, True)
    np.testing.assert_allclose(wn, b[1][1], rtol=1e-13, atol=1e-300)
    np.testing.assert_allclose(wn, np.exp(row), rtol=1e-15, atol=0)  # libm vs numpy exp


def test_normalise_weights_and_systematic_indices_match_the_row_functions() -> None:
    lw = _logw(np.random.default_rng(11), 1, 80)[0]
    w, ls = bt.normalise_weights(lw)
    _, w2, ls2 = bt.normalise_rows(lw)
    np.testing.assert_array_equal(w, w2)
    assert ls == ls2 == pytest.approx(logsumexp(lw), rel=1e-14)
    wd, lsd = bt.normalise_weights(np.full(3, -np.inf))
    assert lsd == -np.inf and np.isnan(wd).all()
    assert np.isnan(bt.normalise_weights(np.array([0.0, np.nan]))[1])
    np.testing.assert_array_equal(bt.systematic_indices(w, 0.3), _systematic_oracle(w, 0.3))


@pytest.mark.parametrize("N", [1, 2, 7, 1000])
def test_branch_free_systematic_equals_the_merge_and_the_oracle(N: int) -> None:
    """systematic_counts_row (counts of per-particle boundaries) gives exactly the ancestors
    of the merge (systematic_row) and of the searchsorted oracle, including zero weights at
    either end, a single non-zero weight, equal weights, u = 0 and u just below 1."""
    rng = np.random.default_rng(40 + N)
    for t in range(60):
        w = rng.random(N) ** rng.integers(1, 6)
        if t % 3 == 0:
            w[rng.random(N) < 0.5] = 0.0
        if t % 5 == 0:
            w[-(N // 3):] = 0.0
        if t % 7 == 0:
            w[:] = 1.0
        if t % 11 == 0:
            w[:] = 0.0
            w[rng.integers(N)] = 1.0
        if w.sum() == 0:
            w[0] = 1.0
        w /= w.sum()
        u = 0.0 if t % 13 == 0 else np.nextafter(1.0, 0.0) if t % 17 == 0 else rng.random()
        merge, cw = np.empty(N, dtype=np.int64), np.empty(N)
        bt.systematic_row(w, u, merge, cw)
        idx, cnt = np.full(N, -1, dtype=np.int64), np.full(N + 1, 99, dtype=np.int64)
        bt.systematic_counts_row(w, u, idx, cw, cnt)
        np.testing.assert_array_equal(idx, merge)
        np.testing.assert_array_equal(idx, _systematic_oracle(w, u))
        np.testing.assert_array_equal(bt.systematic_indices(w, u), merge)


def test_weighted_quantile_pair_by_histogram_equals_inverted_cdf() -> None:
    """The histogram pair (the filter loops' interval bounds) equals np.quantile's inverted CDF
    for both bounds: ties, zero weights, resampled copies, far outliers (a crowded bin takes
    the selection), equal weights (the sorted path), q = 1 and a single particle."""
    rng = np.random.default_rng(6)
    for N in (1, 2, 3, 50, 350, 1000):
        ibuf, fbuf = np.empty(N, np.int64), np.empty(3 * N)
        for trial in range(30):
            x = np.round(rng.normal(size=N), 1 if trial % 2 else 6)
            if trial % 3 == 0:  # resampled cloud: many copies
                x = x[rng.integers(0, max(1, N // 10), N)]
            if trial % 5 == 1 and N > 2:  # far outliers: most values in one bin
                x[:2] = (1e6, -1e6)
            w = rng.dirichlet(np.full(N, 0.3))
            w[rng.random(N) < 0.2] = 0.0
            if trial % 7 == 3:
                w[:] = 1.0 / N
            if not w.sum() > 0:
                w[0] = 1.0
            for qa, qb in ((0.025, 0.975), (0.05, 0.95), (0.5, 0.5), (0.1, 1.0)):
                ref = np.quantile(x, [qa, qb], weights=w, method="inverted_cdf")
                got = bt.weighted_quantile_pair_row(x, w, qa, qb, ibuf, fbuf)
                assert got == (ref[0], ref[1]), (N, trial, qa, qb, got, ref)
