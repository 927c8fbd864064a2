"""One batched particle core: row-wise log-sum-exp normalisation, effective sample size,
systematic resampling and weighted quantiles, each in a numpy version and a numba version.

Every particle filter in rulkit uses these: the generic
:class:`rulkit.estimation.particle.ParticleFilter` and :mod:`rulkit.estimation.resampling` call the
numpy versions (and the compiled systematic row), the fused numba kernels of the systems call
the numba row functions from inside their own compiled loops (numba links them across modules;
``cache=True`` caches both the callee and the caller, tested in a fresh process).

A *row* is one particle population: a 1-D array of ``N`` values. The numpy functions work on
the last axis of arrays of any leading shape (``(N,)`` or ``(U, N)``); the numba row functions
work in place on one 1-D row with caller-provided scratch arrays (no allocation in a hot loop),
and the numba ``*_rows_numba`` functions apply them to every row of a 2-D array (the numba
twins of the numpy functions, tested equal to them and to independent oracles).

Definitions (the contract every caller relies on):

- **normalise**: ``log_sum = m + log sum_i exp(l_i - m)`` with ``m = max_i l_i`` (no overflow),
  normalised log-weights ``l_i - log_sum`` and weights ``exp(l_i - m) / sum_j exp(l_j - m)``.
  A row whose maximum is not finite is *degenerate*: ``log_sum`` is ``-inf`` when every
  log-weight is ``-inf`` (every weight zero) and NaN when any is NaN or ``+inf``; its
  log-weights are left as they were and its weights are NaN (numpy / ``*_rows_numba``) or left
  as they were (the in-place row function). The caller decides what a degenerate row means.
- **ESS**: ``1 / sum_i w_i^2`` of normalised weights (seed 000 eq. 16).
- **systematic resampling** with uniform ``u`` in [0, 1): positions ``p_j = (j + u) / N * c_N``
  (``c`` the cumulative sum of the weights, ``c_N`` its last element, so round-off in the sum
  never yields index ``N``); ancestor ``a_j`` = the number of ``c_i <= p_j`` (numpy's
  ``searchsorted(c, p, side="right")``); a position past the end through round-off goes to the
  last particle with positive weight. Zero-weight particles are never selected.
- **weighted quantile** ``q`` in [0, 1] of values ``x`` with non-negative weights ``w`` (need not
  be normalised): the smallest ``x_(j)`` (sorted ascending) whose cumulative weight
  ``C_j >= q C_N``, and for ``q = 0`` the smallest ``x`` with positive weight; numpy's
  ``np.quantile(x, q, weights=w, method="inverted_cdf")``. Ties in ``x`` return the same value
  whatever the order among them.

Float details: the numba functions sum left to right; numpy's ``sum`` is pairwise, so the two
versions of normalise and ESS agree to a few ulp, not bit for bit (cumulative sums, quantiles and
resampling indices are identical).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
from numpy.typing import NDArray

__all__ = [
    "ess_row",
    "ess_rows",
    "ess_rows_numba",
    "normalise_row",
    "normalise_rows",
    "normalise_rows_numba",
    "normalise_weights",
    "systematic_counts_row",
    "systematic_indices",
    "systematic_row",
    "systematic_rows",
    "systematic_rows_numba",
    "weighted_quantile_pair_row",
    "weighted_quantile_row",
    "weighted_quantile_rows",
    "weighted_quantile_rows_numba",
    "weighted_quantile_select_row",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


# ---------------------------------------------------------------------------------------------
# numpy versions (last axis = particles)
# ---------------------------------------------------------------------------------------------


def normalise_rows(
    logw: FloatArray, weights_from_log: bool = False
) -> tuple[FloatArray, FloatArray, FloatArray | np.float64]:
    """Log-sum-exp normalisation of every row: ``(normalised logw, weights, log_sum)``.

    ``weights_from_log``: weights as ``exp(normalised logw)`` rather than
    ``exp(logw - max) / sum`` (see :func:`normalise_row`).

    ``logw`` (..., N); returns arrays of shapes (..., N), (..., N) and (...) (a float64 scalar
    for a single row). A single row takes the log of its sum with ``math.log``, more rows with
    ``numpy.log`` (the two can differ in the last bit; each caller keeps the one it had).
    Degenerate rows (see the module docstring) get ``log_sum`` -inf (all weights zero) or
    NaN, their log-weights unchanged and NaN weights.
    """
    lw = np.asarray(logw, dtype=np.float64)
    if lw.ndim == 1:  # one row: the scalar log of the C library (math.log), as the kernels
        m = float(lw.max())
        if math.isfinite(m):
            e = np.exp(lw - m)
            s = float(e.sum())
            ls1 = m + math.log(s)
            lwn1 = lw - ls1
            return lwn1, np.exp(lwn1) if weights_from_log else e / s, np.float64(ls1)
    mx = lw.max(axis=-1, keepdims=True)
    ok = np.isfinite(mx)
    if ok.all():
        e = np.exp(lw - mx)
        s = e.sum(axis=-1, keepdims=True)
        ls = mx + np.log(s)
        lwn = lw - ls
        return lwn, np.exp(lwn) if weights_from_log else e / s, ls[..., 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        m0 = np.where(ok, mx, 0.0)
        e = np.exp(lw - m0)
        s = e.sum(axis=-1, keepdims=True)
        bad = np.where(mx == -np.inf, -np.inf, np.nan)
        ls = np.where(ok, m0 + np.log(s), bad)
        lwn = np.where(ok, lw - ls, lw)
        w = np.exp(lwn) if weights_from_log else e / s
        return lwn, np.where(ok, w, np.nan), ls[..., 0]


def normalise_weights(logw: FloatArray) -> tuple[FloatArray, float]:
    """One row's weights and log-sum, as :func:`normalise_rows` without the normalised
    log-weights (for callers that only need the weights; one array operation less).
    Degenerate row: ``(NaN weights, -inf or NaN)``."""
    lw = np.asarray(logw, dtype=np.float64)
    m = float(lw.max())
    if not math.isfinite(m):
        return np.full(lw.shape, np.nan), (-math.inf if m == -math.inf else math.nan)
    e = np.exp(lw - m)
    s = float(e.sum())
    e /= s
    return e, m + math.log(s)


def ess_rows(w: FloatArray) -> FloatArray | float:
    """Effective sample size ``1 / sum_i w_i^2`` of every row of normalised weights (..., N).

    A single row (1-D) returns a float (BLAS dot), more rows an array (pairwise sum)."""
    wa = np.asarray(w, dtype=np.float64)
    if wa.ndim == 1:
        return float(1.0 / np.dot(wa, wa))
    return 1.0 / (wa * wa).sum(axis=-1)


def systematic_rows(w: FloatArray, u: FloatArray | float) -> IntArray:
    """Systematic resampling of every row of ``w`` (N,) or (U, N) with its own uniform ``u``
    (scalar or (U,)); returns ancestor indices of the same shape as ``w`` (int64).

    One ``searchsorted`` for all rows: row ``r`` is shifted to ``[2r, 2r + c_N]`` (needs
    ``c_N < 2``, true for normalised weights). For one row the shift is zero and the result is
    exactly :func:`systematic_row`'s.
    """
    wa = np.asarray(w, dtype=np.float64)
    one = wa.ndim == 1
    W2 = wa[None] if one else wa
    U, N = W2.shape
    ua = np.broadcast_to(np.asarray(u, dtype=np.float64), (U,))
    c = np.cumsum(W2, axis=1)
    pos = (np.arange(N)[None, :] + ua[:, None]) / N * c[:, -1:]
    if U == 1:
        idx = np.searchsorted(c[0], pos[0], side="right")[None]
    else:
        off = 2.0 * np.arange(U)[:, None]  # rows live in disjoint intervals [2r, 2r + 1]
        idx = np.searchsorted((c + off).ravel(), (pos + off).ravel(), side="right")
        idx = idx.reshape(U, N) - N * np.arange(U)[:, None]
    last = N - 1 - np.argmax(W2[:, ::-1] > 0, axis=1)  # round-off guard: last non-zero weight
    out = np.minimum(idx, last[:, None]).astype(np.int64)
    return out[0] if one else out


def weighted_quantile_rows(x: FloatArray, w: FloatArray, q: FloatArray | float) -> FloatArray:
    """Weighted quantiles (inverted CDF, see the module docstring) of every row.

    ``x``, ``w`` (N,) or (U, N); ``q`` scalar or (n_q,). Returns (U, n_q) for 2-D input with
    1-D ``q``, dropping the axes that were scalar / 1-D in the input.
    """
    xa = np.asarray(x, dtype=np.float64)
    wa = np.asarray(w, dtype=np.float64)
    qa = np.asarray(q, dtype=np.float64)
    one = xa.ndim == 1
    X, Wt = (xa[None], wa[None]) if one else (xa, wa)
    q1 = np.atleast_1d(qa)
    order = np.argsort(X, axis=1, kind="mergesort")
    cw = np.cumsum(np.take_along_axis(Wt, order, axis=1), axis=1)
    thr = q1[None, :] * cw[:, -1:]  # (U, n_q)
    # first sorted index with cumulative weight >= q total (> 0 for q = 0)
    ge = cw[:, None, :] >= thr[:, :, None]
    pos0 = cw[:, None, :] > 0.0
    hit = np.where((q1 == 0.0)[None, :, None], pos0, ge)
    n = X.shape[1]
    j = np.where(hit.any(axis=2), hit.argmax(axis=2), n - 1)
    out = np.take_along_axis(X, np.take_along_axis(order, j, axis=1), axis=1)
    if qa.ndim == 0:
        out = out[:, 0]
    return out[0] if one else out


# ---------------------------------------------------------------------------------------------
# numba row functions (in place, scratch arrays from the caller)
# ---------------------------------------------------------------------------------------------


@nb.njit(cache=True)
def normalise_row(lw, wn, weights_from_log=False):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Normalise one row in place: ``wn = exp(lw - max) / sum``, ``lw -= log_sum``.

    ``weights_from_log=True``: ``wn = exp(normalised lw)`` instead (the same number up to the
    last bit; the degradation trackers have always used this form, kept so their tables do
    not move).

    Returns ``log_sum`` (the log-likelihood increment when ``lw`` held normalised log-weights
    plus log-likelihoods). A degenerate row returns -inf (every weight zero) or NaN (a NaN or
    +inf log-weight) and leaves ``lw`` and ``wn`` unchanged.
    """
    n = lw.size
    mx = -np.inf
    for i in range(n):
        v = lw[i]
        if v > mx:
            mx = v
        elif v != v:
            return np.nan
    if not mx > -np.inf:
        return -np.inf
    if mx == np.inf:
        return np.nan
    s = 0.0
    for i in range(n):
        e = math.exp(lw[i] - mx)
        wn[i] = e
        s += e
    ls = mx + math.log(s)
    if weights_from_log:
        for i in range(n):
            lw[i] -= ls
            wn[i] = math.exp(lw[i])
    else:
        for i in range(n):
            wn[i] /= s
            lw[i] -= ls
    return ls


@nb.njit(cache=True)
def ess_row(wn):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """``1 / sum_i w_i^2`` of one row of normalised weights."""
    s = 0.0
    for i in range(wn.size):
        s += wn[i] * wn[i]
    return 1.0 / s


@nb.njit(cache=True)
def systematic_row(wn, u, idx, cw):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Systematic resampling of one row with uniform ``u``: ancestors into ``idx`` (int64,
    N), ``cw`` (N) scratch for the cumulative sum. One merge pass over the N sorted
    positions (see the module docstring for the definition)."""
    n = wn.size
    acc = 0.0
    for i in range(n):
        acc += wn[i]
        cw[i] = acc
    last_nz = n - 1
    while last_nz > 0 and wn[last_nz] == 0.0:
        last_nz -= 1
    total = cw[n - 1]
    i = 0
    for j in range(n):
        pos = (j + u) / n * total
        while i < n and cw[i] <= pos:
            i += 1
        idx[j] = i if i < n else last_nz


@nb.njit(cache=True)
def weighted_quantile_row(x, w, q, order, cw):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Weighted quantile ``q`` of one row (inverted CDF); ``order`` (int64, N) and ``cw`` (N)
    are scratch. Smallest sorted ``x`` with cumulative weight >= ``q`` total (> 0 for q = 0)."""
    n = x.size
    order[:] = np.argsort(x, kind="mergesort")
    acc = 0.0
    for j in range(n):
        acc += w[order[j]]
        cw[j] = acc
    qq = q * cw[n - 1]
    if q == 0.0:
        for j in range(n):
            if cw[j] > 0.0:
                return x[order[j]]
    else:
        for j in range(n):
            if cw[j] >= qq:
                return x[order[j]]
    return x[order[n - 1]]


# ---------------------------------------------------------------------------------------------
# numba twins of the numpy functions (2-D, one row at a time)
# ---------------------------------------------------------------------------------------------


@nb.njit(cache=True)
def normalise_rows_numba(logw):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """numba twin of :func:`normalise_rows` for (U, N) input."""
    U, N = logw.shape
    lw = logw.copy()
    w = np.full((U, N), np.nan)
    ls = np.empty(U)
    for r in range(U):
        ls[r] = normalise_row(lw[r], w[r])
        if not ls[r] > -np.inf:
            w[r, :] = np.nan
    return lw, w, ls


@nb.njit(cache=True)
def systematic_counts_row(wn, u, idx, cw, cnt):  # type: ignore[no-untyped-def]  # pragma: no cover
    """:func:`systematic_row` without data-dependent branches: the same ancestors into ``idx``
    (int64, N); ``cw`` (N) and ``cnt`` (int64, N + 1) scratch.

    The positions ``p_j = (j + u) / N * c_N`` are non-decreasing in ``j``, so the ancestor of
    ``j`` (the first ``i`` with ``c_i > p_j``) is the number of particles whose boundary
    ``K_i = #{j : p_j < c_i}`` is ``<= j``. Each ``K_i`` is estimated as
    ``ceil(c_i N / c_N - u)`` and corrected with the exact positions (the same floating-point
    expression as :func:`systematic_row`; the corrections almost never run), counted in
    ``cnt``, and a running sum gives the ancestors; an index ``N`` (a position past the end
    through round-off) goes to the last particle of positive weight. The merge of
    :func:`systematic_row` branches on every comparison, which the processor mispredicts for
    ever-changing weights; this version is 2-3x faster at N = 1,000-10,000 (tested equal).
    """
    n = wn.size
    acc = 0.0
    for i in range(n):
        acc += wn[i]
        cw[i] = acc
        cnt[i] = 0
    cnt[n] = 0
    last_nz = n - 1
    while last_nz > 0 and wn[last_nz] == 0.0:
        last_nz -= 1
    total = cw[n - 1]
    scale = n / total
    for i in range(n):
        c = cw[i]
        k = min(max(int(math.ceil(c * scale - u)), 0), n)  # noqa: RUF046 - numba types
        while k > 0 and (k - 1 + u) / n * total >= c:
            k -= 1
        while k < n and (k + u) / n * total < c:
            k += 1
        cnt[k] += 1
    s = 0
    for j in range(n):
        s += cnt[j]
        idx[j] = min(s, last_nz)


@nb.njit(cache=True)
def systematic_indices(w, u):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """The ancestors of :func:`systematic_row` in a fresh index array, computed by
    :func:`systematic_counts_row` (scratch allocated inside)."""
    n = w.size
    idx = np.empty(n, dtype=np.int64)
    systematic_counts_row(w, u, idx, np.empty(n), np.empty(n + 1, dtype=np.int64))
    return idx


@nb.njit(cache=True)
def ess_rows_numba(w):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """numba twin of :func:`ess_rows` for (U, N) input."""
    U = w.shape[0]
    out = np.empty(U)
    for r in range(U):
        out[r] = ess_row(w[r])
    return out


@nb.njit(cache=True)
def systematic_rows_numba(w, u):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """numba twin of :func:`systematic_rows` for (U, N) weights and (U,) uniforms."""
    U, N = w.shape
    idx = np.empty((U, N), dtype=np.int64)
    cw = np.empty(N)
    for r in range(U):
        systematic_row(w[r], u[r], idx[r], cw)
    return idx


@nb.njit(cache=True)
def weighted_quantile_rows_numba(x, w, q):  # type: ignore[no-untyped-def]  # pragma: no cover
    """numba twin of :func:`weighted_quantile_rows` for (U, N) input and (n_q,) levels."""
    U, N = x.shape
    out = np.empty((U, q.size))
    order = np.empty(N, dtype=np.int64)
    cw = np.empty(N)
    for r in range(U):
        for j in range(q.size):
            out[r, j] = weighted_quantile_row(x[r], w[r], q[j], order, cw)
    return out


# ---------------------------------------------------------------------------------------------
# numba: weighted quantiles by selection (no sort), for per-step intervals in a filter loop
# ---------------------------------------------------------------------------------------------


@nb.njit(cache=True)
def weighted_quantile_select_row(x, w, q, buf):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Weighted quantile ``q`` of one row (the inverted-CDF definition of the module
    docstring) by three-way quickselect, expected O(N), without sorting. ``buf`` int64 scratch
    of size N.

    The inverted-CDF quantile is the smallest value ``v`` with ``S(v) = sum_{x_i <= v} w_i >=
    q sum_i w_i`` (and the smallest value of positive weight for q = 0), so it only needs the
    weight below and at a pivot value, not the order. The partial sums are taken in another
    order than the sorted cumulative sum, so the result can differ from
    :func:`weighted_quantile_row` only when ``S(v)`` and ``q`` x total agree to the last bits;
    that is the rule, not the exception, for equal weights (a prior, a resampled cloud), which
    therefore take the sorted path.
    """
    n = x.size
    total = 0.0
    for i in range(n):
        total += w[i]
    if q == 0.0:
        best = np.inf
        for i in range(n):
            if w[i] > 0.0 and x[i] < best:
                best = x[i]
        return best
    equal = True
    for i in range(1, n):
        if w[i] != w[0]:
            equal = False
            break
    if equal:  # equal weights sit on the boundary S(v) = q total: sum in sorted order
        order = np.empty(n, dtype=np.int64)
        return weighted_quantile_row(x, w, q, order, np.empty(n))
    target = q * total
    for i in range(n):
        buf[i] = i
    lo = 0
    hi = n
    below = 0.0
    while lo < hi:
        a = x[buf[lo]]
        b = x[buf[(lo + hi) // 2]]
        c = x[buf[hi - 1]]
        p = max(min(a, b), min(max(a, b), c))  # median of three
        lt = lo  # [lo, lt) < p, [lt, i) == p, (gt, hi) > p
        i = lo
        gt = hi - 1
        w_lt = 0.0
        w_eq = 0.0
        while i <= gt:
            v = x[buf[i]]
            if v < p:
                w_lt += w[buf[i]]
                t = buf[lt]
                buf[lt] = buf[i]
                buf[i] = t
                lt += 1
                i += 1
            elif v > p:
                t = buf[gt]
                buf[gt] = buf[i]
                buf[i] = t
                gt -= 1
            else:
                w_eq += w[buf[i]]
                i += 1
        if below + w_lt >= target:
            hi = lt
        elif below + w_lt + w_eq >= target:
            return p
        else:
            below += w_lt + w_eq
            lo = gt + 1
    mx = -np.inf  # round-off: q total above every partial sum -> the largest value of
    for i in range(n):  # positive weight (where the sorted cumulative sum reaches its total)
        if w[i] > 0.0 and x[i] > mx:
            mx = x[i]
    return mx


@nb.njit(cache=True)
def weighted_quantile_pair_row(x, w, qa, qb, ibuf, fbuf):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Weighted quantiles ``qa <= qb`` (both in (0, 1]) of one row (the inverted-CDF definition
    of the module docstring) by one histogram pass: the two per-step interval bounds of a
    filter loop at about a third of the cost of two :func:`weighted_quantile_select_row`.

    The positive-weight values are binned into ``N`` equal-width bins between their minimum
    and maximum (the bin index is monotone in ``x``, so the bins keep the order and ties share
    a bin); the bin sums' running total finds the bin that holds each quantile, and only that
    bin's few values are sorted and summed in order. ``ibuf`` int64 scratch of size N,
    ``fbuf`` float64 scratch of size 3N. As for the selection, the partial sums are taken in
    another order than the sorted cumulative sum, so equal weights (where ``S(v) = q total``
    exactly) take the sorted path, and so does a bin holding more than 64 values (a cloud
    with far outliers).
    """
    n = x.size
    total = 0.0
    lo = np.inf
    hi = -np.inf
    equal = True
    finite = True
    w0 = w[0]
    for i in range(n):
        wi = w[i]
        total += wi
        if wi != w0:
            equal = False
        if wi > 0.0:
            xi = x[i]
            if xi < lo:
                lo = xi
            if xi > hi:
                hi = xi
            if xi != xi:
                finite = False
    if equal or not finite or not (hi > lo) or not (hi - lo < np.inf):
        return (weighted_quantile_select_row(x, w, qa, ibuf),
                weighted_quantile_select_row(x, w, qb, ibuf))
    nbin = n
    for b in range(nbin):
        fbuf[b] = 0.0
    scale = nbin / (hi - lo)
    for i in range(n):
        if w[i] > 0.0:  # zero weight never sets a quantile with q > 0
            b = int((x[i] - lo) * scale)
            if b >= nbin:
                b = nbin - 1
            ibuf[i] = b
            fbuf[b] += w[i]
        else:
            ibuf[i] = -1
    ta = qa * total
    tb = qb * total
    ba = -1
    bb = -1
    ca = 0.0
    cb = 0.0
    c = 0.0
    for b in range(nbin):
        cn = c + fbuf[b]
        if ba < 0 and cn >= ta:
            ba = b
            ca = c
        if cn >= tb:
            bb = b
            cb = c
            break
        c = cn
    ra = _in_bin(x, w, ibuf, fbuf, ba, ca, ta, n, hi)
    rb = _in_bin(x, w, ibuf, fbuf, bb, cb, tb, n, hi)
    if ra != ra or rb != rb:  # a crowded bin: the selection
        return (weighted_quantile_select_row(x, w, qa, ibuf),
                weighted_quantile_select_row(x, w, qb, ibuf))
    return ra, rb


@nb.njit(cache=True)
def _in_bin(x, w, ibuf, fbuf, b, below, target, n, hi):  # type: ignore[no-untyped-def]  # pragma: no cover
    """The smallest value of bin ``b`` whose running weight from ``below`` reaches ``target``
    (insertion sort of the bin's values in ``fbuf[n:3n]``); ``hi`` when round-off leaves the
    target above every running sum (or no bin was found); NaN when the bin holds > 64 values."""
    if b < 0:
        return hi
    gx = fbuf[n:2 * n]
    gw = fbuf[2 * n:3 * n]
    m = 0
    for i in range(n):
        if ibuf[i] == b:
            if m == 64:
                return np.nan
            v = x[i]
            wv = w[i]
            j = m
            while j > 0 and gx[j - 1] > v:
                gx[j] = gx[j - 1]
                gw[j] = gw[j - 1]
                j -= 1
            gx[j] = v
            gw[j] = wv
            m += 1
    acc = below
    for j in range(m):
        acc += gw[j]
        if acc >= target:
            return gx[j]
    return gx[m - 1] if m > 0 else hi
