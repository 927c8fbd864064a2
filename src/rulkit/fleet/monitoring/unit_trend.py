"""The default RUL estimator without a fitted model: a per-unit log-linear trend
(docs/systems/embedded-rul.md §6, eqs. (EI-16)-(EI-19)).

Each unit on its own, no fleet prior: z = ln max(hi, hi_floor) follows a straight line in
time near its last acquisition,

    z(t) = a + b (t - t_last) + e,   var(e) = sigma^2 / hi^2                     (EI-16)

(additive HI noise of one size, seen on the log scale: small HI values weigh less), fitted by
weighted least squares with weights ``forgetting^age * hi^2`` (age counted in acquisitions, so
old points, e.g. a healthy period before degradation set in, fade out; about
``1 / (1 - forgetting)`` acquisitions carry the fit). With a flat prior the posterior of the
line (a, b) is a bivariate Student-t with nu = N - 2 degrees of freedom (N the discounted
count) and scale sigma^2 (X'WX)^-1, sigma^2 = RSS_w / nu (EI-17). The unit reaches HI = 1
(z = 0) when the line does: P(RUL <= r) = P(a + b r >= 0) = T_nu(h(r)) with
h(r) = (a + b r) / sd(r) (EI-18), and a quantile p is the first r >= 0 with h(r) = t_nu^-1(p),
a quadratic in r (EI-19, :func:`first_crossing`). Posterior mass with b <= 0 never fails: a
quantile inside it is +inf (censored mass). Every quantile is >= 0 and the quantiles are
ordered, so the median lies inside its interval. Exponential growth (the seed's Paris law with
m = 2) is its model; on slower (e.g. linear) growth it errs early (shorter RUL), the safe side.

State per unit: 7 discounted sums centred at the last acquisition (no cancellation with
epoch-like times), the last time and HI, the acquisition count (:class:`TrendState`). One
acquisition for many units: :func:`trend_update`; many acquisitions per unit:
:func:`trend_run` (same numbers, tested; a compiled pass for long series).

Usage::

    cfg = TrendConfig()
    state = trend_update(TrendState.empty(3), t, hi, cfg)     # one acquisition per unit
    med, lo, hi90 = rul_quantiles(trend_posterior(state, cfg), (0.5, 0.05, 0.95))
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
SUM_NAMES = ("N", "S0", "S1", "S2", "Sz", "Sxz", "Szz")
"""The discounted sums of a unit's state: count, weights, and the weighted moments of
x = t - t_last and z (:class:`TrendState`)."""
NU_TABLE = 200
"""Degrees of freedom above this use the normal quantile (t_200 differs by < 0.5 %)."""
NU_BLOCK = 16
"""Degrees of freedom computed together in :func:`t_quantiles`' table (1-16, 17-32, ...)."""


@dataclass(frozen=True)
class TrendConfig:
    """Settings of the trend estimator (module docstring).

    ``forgetting`` in (0, 1]: weight kept per newer acquisition (0.95: about the last 20
    acquisitions carry the fit; 1: all, the textbook regression); ``min_points`` >= 3:
    acquisitions before the first estimate (before that the RUL is "not estimated yet"; with
    fewer than 10 a noisy HI's slope is so uncertain that the 5 % quantile says "any time"
    on every new unit); ``hi_floor`` > 0: HI values below it are read as it (log of 0).
    """

    forgetting: float = 0.95
    min_points: int = 10
    hi_floor: float = 1e-3

    def __post_init__(self) -> None:
        if not (0.0 < self.forgetting <= 1.0):
            raise ValueError(f"TrendConfig.forgetting: expected a number in (0, 1], got "
                             f"{self.forgetting!r}")
        if isinstance(self.min_points, bool) or int(self.min_points) != self.min_points or \
                self.min_points < 3:
            raise ValueError(f"TrendConfig.min_points: expected an integer >= 3, got "
                             f"{self.min_points!r}")
        if not (math.isfinite(self.hi_floor) and 0.0 < self.hi_floor < 1.0):
            raise ValueError(f"TrendConfig.hi_floor: expected a number in (0, 1), got "
                             f"{self.hi_floor!r}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrendConfig:
        """Inverse of :meth:`to_dict`."""
        return cls(**d)


@dataclass
class TrendState:
    """B units (struct of arrays): ``t (B,)`` last acquisition time (NaN before the first),
    ``hi (B,)`` last HI, ``n (B,)`` acquisitions, ``s (B, 7)`` the sums :data:`SUM_NAMES`
    centred at ``t``."""

    t: FloatArray
    hi: FloatArray
    n: NDArray[np.int64]
    s: FloatArray

    @classmethod
    def empty(cls, size: int) -> TrendState:
        """B units without an acquisition."""
        return cls(t=np.full(size, np.nan), hi=np.full(size, np.nan),
                   n=np.zeros(size, dtype=np.int64), s=np.zeros((size, len(SUM_NAMES))))

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def take(self, idx: np.ndarray) -> TrendState:
        """The units at ``idx`` (copies)."""
        return TrendState(t=self.t[idx], hi=self.hi[idx], n=self.n[idx], s=self.s[idx])


@dataclass(frozen=True)
class TrendPosterior:
    """The line's posterior per unit at its last acquisition (EI-17): level ``a`` (z at the
    last acquisition), rate ``b`` per time unit, covariance ``vaa, vab, vbb``, degrees of
    freedom ``nu`` (an integer >= 1, as a float); all NaN where there is no estimate yet."""

    a: FloatArray
    b: FloatArray
    vaa: FloatArray
    vab: FloatArray
    vbb: FloatArray
    nu: FloatArray


# ----------------------------------------------------------------------------- updates
def _weights(hi: FloatArray, hi_floor: float) -> tuple[FloatArray, FloatArray]:
    h = np.maximum(hi, hi_floor)
    return np.log(h), h * h


def trend_update(state: TrendState, t: np.ndarray, hi: np.ndarray,
                 config: TrendConfig) -> TrendState:
    """Assimilate one acquisition per unit (``t``, ``hi`` (B,); NaN: none, state kept).

    Recentre the sums at the new time (x -> x - dt), discount them by ``forgetting``, add the
    new point at x = 0 with weight hi^2 (EI-16). Times must increase per unit (the store
    validates them). Returns a new state.
    """
    t = np.asarray(t, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    have = np.isfinite(t) & np.isfinite(hi)
    z, w = _weights(np.where(have, hi, 1.0), config.hi_floor)
    d = np.where(have & (state.n > 0), t - state.t, 0.0)
    n_, s0, s1, s2, sz, sxz, szz = (state.s[:, k] for k in range(len(SUM_NAMES)))
    s2 = s2 - 2.0 * d * s1 + d * d * s0
    s1 = s1 - d * s0
    sxz = sxz - d * sz
    lam = config.forgetting
    new = np.column_stack([lam * n_ + 1.0, lam * s0 + w, lam * s1, lam * s2, lam * sz + w * z,
                           lam * sxz, lam * szz + w * z * z])
    keep = ~have
    if keep.any():
        new = np.where(keep[:, None], state.s, new)
    return TrendState(t=np.where(have, t, state.t), hi=np.where(have, hi, state.hi),
                      n=state.n + have, s=new)


def _trend_pass(seg, t, z, w, lam, t0, n0, s_in, s_out):  # type: ignore[no-untyped-def]
    """:func:`trend_update` over the rows ``seg[c]:seg[c + 1]`` of each unit c, in order (the
    same operations in the same order); ``s_out`` receives the sums after each row."""
    for c in range(seg.shape[0] - 1):
        n_ = s_in[c, 0]
        s0 = s_in[c, 1]
        s1 = s_in[c, 2]
        s2 = s_in[c, 3]
        sz = s_in[c, 4]
        sxz = s_in[c, 5]
        szz = s_in[c, 6]
        tp = t0[c]
        k = n0[c]
        for i in range(seg[c], seg[c + 1]):
            d = t[i] - tp if k > 0 else 0.0
            s2 = s2 - 2.0 * d * s1 + d * d * s0
            s1 = s1 - d * s0
            sxz = sxz - d * sz
            zi = z[i]
            wi = w[i]
            n_ = lam * n_ + 1.0
            s0 = lam * s0 + wi
            s1 = lam * s1
            s2 = lam * s2
            sz = lam * sz + wi * zi
            sxz = lam * sxz
            szz = lam * szz + wi * zi * zi
            s_out[i, 0] = n_
            s_out[i, 1] = s0
            s_out[i, 2] = s1
            s_out[i, 3] = s2
            s_out[i, 4] = sz
            s_out[i, 5] = sxz
            s_out[i, 6] = szz
            tp = t[i]
            k += 1


_COMPILED: dict[str, Any] = {}
# Cost model of trend_run's three equal-result ways, in seconds (measured on the 2-core
# development machine, `benchmarks/bench_tracker_steps.py`): one vectorised trend_update per
# acquisition rank (~40 us a call plus ~75 ns a row: many components, few acquisitions each),
# the per-unit pass as Python (~5 us a row: small batches) or compiled by numba (~0.02 us a
# row, but ~0.5 s to load numba once per process).
_COST_PER_RANK, _COST_PER_RANK_ROW = 4e-5, 7.5e-8
_COST_PER_PYTHON_ROW, _COST_PER_JIT_ROW, _COST_JIT_LOAD = 5e-6, 2e-8, 0.5


def trend_strategy(n_ranks: int, n_rows: int) -> str:
    """``"ranks"``, ``"python"`` or ``"jit"``: the cheapest way for :func:`trend_run` to run
    ``n_rows`` acquisitions that take ``n_ranks`` rank steps (the most rows of one unit)."""
    costs = {"ranks": n_ranks * _COST_PER_RANK + n_rows * _COST_PER_RANK_ROW,
             "python": n_rows * _COST_PER_PYTHON_ROW,
             "jit": n_rows * _COST_PER_JIT_ROW + (0.0 if _COMPILED else _COST_JIT_LOAD)}
    return min(costs, key=costs.__getitem__)


def _pass(compiled: bool) -> Any:
    if not compiled:
        return _trend_pass
    if "pass" not in _COMPILED:
        import numba

        try:  # compiled once, then loaded from numba's on-disk cache
            _COMPILED["pass"] = numba.njit(cache=True)(_trend_pass)
        except RuntimeError:  # no writable cache location: compile in memory
            _COMPILED["pass"] = numba.njit(_trend_pass)
    return _COMPILED["pass"]


def _run_by_rank(state: TrendState, seg: np.ndarray, t: FloatArray, hi: FloatArray,
                 config: TrendConfig) -> FloatArray:
    """The sums after each row by one :func:`trend_update` per acquisition rank (the
    reference the passes are tested against)."""
    counts = np.diff(seg)
    b = counts.size
    rows_s = np.empty((t.size, len(SUM_NAMES)))
    if b and bool((counts == counts[0]).all()) and bool(np.isfinite(t).all()) \
            and bool(np.isfinite(hi).all()):  # every unit at every rank
        _run_full(state, t.reshape(b, -1), hi, config, rows_s.reshape(b, -1, len(SUM_NAMES)))
        return rows_s
    for r in range(int(counts.max(initial=0))):
        have = np.flatnonzero(counts > r)
        idx = seg[have] + r
        tt, hh = np.full(b, np.nan), np.full(b, np.nan)
        tt[have], hh[have] = t[idx], hi[idx]
        state = trend_update(state, tt, hh, config)
        rows_s[idx] = state.s[have]
    return rows_s


def _run_full(state: TrendState, t: FloatArray, hi: FloatArray, config: TrendConfig,
              out: FloatArray) -> None:
    """:func:`trend_update` once per rank when every unit has a (finite) acquisition at every
    rank: ``t`` (B, K) unit c's times in order, ``hi`` its HI values (B * K,), ``out``
    (B, K, 7) receives the sums after each row. The same operations on the same values in the
    same order as :func:`trend_update` (so the same bits), on each rank's contiguous values
    (the rows' weights computed once for all ranks), copied into their rows."""
    tt, ht = (np.ascontiguousarray(x.reshape(t.shape).T) for x in (t, hi))  # (K, B)
    z, w = _weights(ht, config.hi_floor)
    wz = w * z
    wzz = wz * z
    lam = config.forgetting
    n_, s0, s1, s2, sz, sxz, szz = state.s.T.copy()
    started = state.n > 0
    tp = state.t
    tmp = np.empty(t.shape[0])
    for r in range(t.shape[1]):
        d = tt[r] - tp
        if r == 0 and not started.all():
            d = np.where(started, d, 0.0)
        np.multiply(2.0, d, out=tmp)
        tmp *= s1
        s2 = s2 - tmp  # s2 - 2 d s1 + d d s0, evaluated left to right
        np.multiply(d, d, out=tmp)
        tmp *= s0
        s2 += tmp
        s1 = s1 - np.multiply(d, s0, out=tmp)
        sxz = sxz - np.multiply(d, sz, out=tmp)
        n_ = lam * n_
        n_ += 1.0
        s0 = lam * s0
        s0 += w[r]
        s1 *= lam
        s2 *= lam
        sz = lam * sz
        sz += wz[r]
        sxz *= lam
        szz = lam * szz
        szz += wzz[r]
        o = out[:, r]
        o[:, 0], o[:, 1], o[:, 2], o[:, 3], o[:, 4], o[:, 5], o[:, 6] = \
            n_, s0, s1, s2, sz, sxz, szz
        tp = tt[r]


def trend_run(state: TrendState, seg: np.ndarray, t: np.ndarray, hi: np.ndarray,
              config: TrendConfig, *, strategy: str | None = None
              ) -> tuple[TrendState, TrendState]:
    """Many acquisitions per unit: unit c assimilates ``t[seg[c]:seg[c + 1]]``, ``hi[...]``
    in order (``seg`` (B + 1,) offsets from 0 to len(t); finite values, times increasing per
    unit). Returns (the state after each unit's last row, the state after every row), equal
    to one :func:`trend_update` per row (tested). ``strategy``: ``"ranks"`` (one vectorised
    update per acquisition rank), ``"python"`` or ``"jit"`` (the per-unit pass, as Python or
    compiled by numba); default the cheapest (:func:`trend_strategy`)."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    hi = np.ascontiguousarray(hi, dtype=np.float64)
    seg = np.ascontiguousarray(seg, dtype=np.int64)
    b, m = len(state), t.shape[0]
    if seg.shape != (b + 1,) or hi.shape != (m,) or seg[0] != 0 or seg[-1] != m:
        raise ValueError(f"seg: expected {b + 1} offsets from 0 to {m}, got {seg.shape}")
    counts = np.diff(seg)
    if strategy is None:
        strategy = trend_strategy(int(counts.max(initial=0)), m)
    if strategy == "ranks":
        rows_s = _run_by_rank(state, seg, t, hi, config)
    elif strategy in ("python", "jit"):
        z, w = _weights(hi, config.hi_floor)
        rows_s = np.empty((m, len(SUM_NAMES)))
        _pass(strategy == "jit")(seg, t, z, w, float(config.forgetting),
                                 np.ascontiguousarray(state.t), np.ascontiguousarray(state.n),
                                 np.ascontiguousarray(state.s), rows_s)
    else:
        raise ValueError(f"strategy: expected ranks, python or jit, got {strategy!r}")
    n_rows = np.repeat(state.n - seg[:-1], counts) + np.arange(1, m + 1)  # n + rank + 1
    rows = TrendState(t=t.copy(), hi=hi.copy(), n=n_rows, s=rows_s)
    new = state.take(np.arange(b))
    upd = np.flatnonzero(counts > 0)
    last = seg[1:][upd] - 1
    new.t[upd], new.hi[upd], new.n[upd], new.s[upd] = t[last], hi[last], rows.n[last], \
        rows_s[last]
    return new, rows


# ----------------------------------------------------------------------------- posterior
def trend_posterior(state: TrendState, config: TrendConfig) -> TrendPosterior:
    """The line's Student-t posterior per unit (EI-17); NaN where fewer than
    ``min_points`` acquisitions or a degenerate design (all weight on one time)."""
    # the sums as contiguous columns (one transposing copy, the passes below' own: they read
    # each column many times, and write into some)
    n_, s0, s1, s2, sz, sxz, szz = state.s.T.copy()
    # each result written into a buffer whose value is no longer needed: the operations of
    # the formulas as written, in their order, with fewer temporaries
    with np.errstate(invalid="ignore", divide="ignore"):
        det = s0 * s2
        tmp = s1 * s1
        det -= tmp  # s0 s2 - s1 s1
        np.multiply(1e-12, s0, out=tmp)
        tmp *= s2
        ok = det > tmp
        ok &= state.n >= config.min_points
        ok &= n_ > 3.0
        b = s0 * sxz
        b -= np.multiply(s1, sz, out=tmp)
        b /= det  # (s0 sxz - s1 sz) / det
        a = np.multiply(b, s1)
        np.subtract(sz, a, out=a)
        a /= s0  # (sz - b s1) / s0
        rss = np.multiply(a, sz)
        np.subtract(szz, rss, out=rss)
        rss -= np.multiply(b, sxz, out=tmp)
        np.maximum(rss, 0.0, out=rss)  # max(szz - a sz - b sxz, 0)
        n_ -= 2.0
        nu = np.floor(n_)
        sig2 = rss
        sig2 /= n_
        # a perfect fit (sig2 = 0) still has the rounding of its sums: keep a floor
        np.divide(szz, s0, out=tmp)
        np.maximum(tmp, 1e-300, out=tmp)
        tmp *= 1e-24
        np.maximum(sig2, tmp, out=sig2)
        vaa = np.multiply(sig2, s2, out=s2)
        vaa /= det
        vab = np.negative(sig2, out=tmp)
        vab *= s1
        vab /= det
        vbb = np.multiply(sig2, s0, out=s0)
        vbb /= det
    np.logical_not(ok, out=ok)
    for v in (a, b, vaa, vab, vbb, nu):
        v[ok] = np.nan
    return TrendPosterior(a, b, vaa, vab, vbb, nu)


def t_cdf(x: FloatArray, nu: FloatArray) -> FloatArray:
    """Student-t CDF for integer degrees of freedom ``nu`` >= 1 in closed form: with
    theta = atan(x / sqrt(nu)), P(|T| < x) is (2/pi)(theta + sin(theta) S) for odd nu and
    sin(theta) S for even nu, S the finite series cos + (2/3) cos^3 + (2.4)/(3.5) cos^5 ...
    (odd) or 1 + (1/2) cos^2 + (1.3)/(2.4) cos^4 ... (even) up to the power nu - 2
    (Abramowitz & Stegun 26.7.3-26.7.4; no scipy at run time)."""
    x, nu = np.broadcast_arrays(np.asarray(x, dtype=np.float64),
                                np.asarray(nu, dtype=np.float64))
    theta = np.arctan(x / np.sqrt(nu))
    c2 = np.cos(theta) ** 2
    odd = nu % 2 == 1
    term = np.where(odd, np.cos(theta), 1.0)
    total = np.where(odd & (nu < 3), 0.0, term)
    for k in range(1, int(nu.max(initial=1)) // 2 + 1):
        term = term * c2 * np.where(odd, 2 * k / (2 * k + 1), (2 * k - 1) / (2 * k))
        total = total + np.where(np.where(odd, 2 * k + 1, 2 * k) <= nu - 2, term, 0.0)
    s = np.sin(theta)
    return 0.5 + 0.5 * np.where(odd, (2.0 / np.pi) * (theta + s * total), s * total)


_T_QUANTILES: dict[tuple[int, float], float] = {}


def _t_quantiles(nus: np.ndarray, p: np.ndarray) -> FloatArray:
    """t_nu^-1(p) for the integers ``nus`` and the levels ``p`` (element by element) by
    bisection of :func:`t_cdf` (to the last bit; tested against scipy's stdtrit); the normal
    quantile above :data:`NU_TABLE`; 0 at p = 1/2, the centre of a symmetric law, exactly."""
    normal = nus > NU_TABLE
    nu = np.where(normal, 1.0, nus)
    lo, hi = np.full(nus.size, -1e12), np.full(nus.size, 1e12)
    for _ in range(90):
        mid = 0.5 * (lo + hi)
        below = np.where(normal, _normal_cdf(mid), t_cdf(mid, nu)) < p
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return np.where(p == 0.5, 0.0, 0.5 * (lo + hi))


def _normal_cdf(x: FloatArray) -> FloatArray:
    return np.array([0.5 * math.erfc(-v / math.sqrt(2.0)) for v in np.ravel(x)]).reshape(
        np.shape(x))


def t_quantile(nu: FloatArray, p: float) -> FloatArray:
    """Student-t quantile t_nu^-1(p) for integer ``nu`` >= 1 (:func:`t_quantiles` of one
    level)."""
    return t_quantiles(nu, (p,))[0]


def t_quantiles(nu: FloatArray, levels: tuple[float, ...]) -> FloatArray:
    """Student-t quantiles t_nu^-1(p), one row per level ``p`` (shape (levels, nu's size)),
    for integer ``nu`` >= 1: each computed once per degree of freedom and level, then looked
    up; the normal quantile above :data:`NU_TABLE`; NaN where ``nu`` is NaN. A degree of
    freedom not yet computed brings the others of its block of :data:`NU_BLOCK` into the same
    bisection: a pass costs about what its largest degree of freedom does, and a fleet's
    units gain degrees of freedom one acquisition at a time. Each element's bits are its own
    whatever else is in the pass (the series' terms past an element's ``nu`` add 0)."""
    nu = np.asarray(nu, dtype=np.float64)
    key = np.where(np.isfinite(nu), np.clip(nu, 1, NU_TABLE + 1), 0).astype(np.int64)
    present = (np.flatnonzero(np.bincount(key, minlength=NU_TABLE + 2)[1:]) + 1).tolist()
    table = np.full((len(levels), NU_TABLE + 2), np.nan)
    missing = {k for p in levels for k in present if (k, p) not in _T_QUANTILES}
    wanted = sorted({m for k in missing for m in (
        [k] if k > NU_TABLE else range(k - (k - 1) % NU_BLOCK,
                                       min(k - (k - 1) % NU_BLOCK + NU_BLOCK, NU_TABLE + 1)))})
    need = [(k, p) for p in levels for k in wanted if (k, p) not in _T_QUANTILES]
    if need:  # every level's in one bisection
        arr = np.array(need, dtype=np.float64).T
        for kp, v in zip(need, _t_quantiles(arr[0], arr[1]).tolist(), strict=True):
            _T_QUANTILES[kp] = v
    for j, p in enumerate(levels):
        table[j, present] = [_T_QUANTILES[(k, p)] for k in present]
    return np.take(table, key, axis=1)  # a faster gather than table[:, key]


def first_crossing(a: FloatArray, b: FloatArray, v0: FloatArray, v1: FloatArray,
                   v2: FloatArray, c: FloatArray) -> FloatArray:
    """The smallest r >= 0 with (a + b r) / sqrt(v0 + v1 r + v2 r^2) >= c, +inf if none
    (EI-19); NaN inputs give NaN. The margin is continuous, so past r = 0 this is the first
    root of (a + b r)^2 = c^2 (v0 + v1 r + v2 r^2) with a + b r of the sign of c: a quadratic,
    solved per element in its numerically stable form."""
    # the line's terms once at its own shape (a unit's, not a unit's per level), then each
    # level's: the same operations, in the same order, on the same values
    a, b, v0, v1, v2 = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64)
                                             for x in (a, b, v0, v1, v2)))
    c = np.asarray(c, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        at0 = a >= c * np.sqrt(v0)
        if np.all((c == 0.0) | np.isnan(c)):  # the median: the line's own crossing below
            best = np.full(np.broadcast_shapes(a.shape, c.shape), np.inf)
        else:
            best = _quadratic_crossing(a, b, v0, v1, v2, c)
        # the median (c = 0) exactly: where the line itself reaches the threshold
        best = np.where(c == 0.0, np.where(b > 0.0, -a / b, np.inf), best)
        best[at0] = 0.0
    line_ok = (np.isfinite(a) & np.isfinite(b) & np.isfinite(v0) & np.isfinite(v1)
               & np.isfinite(v2))
    best[~(line_ok & np.isfinite(c))] = np.nan
    return best


def _quadratic_crossing(a: FloatArray, b: FloatArray, v0: FloatArray, v1: FloatArray,
                        v2: FloatArray, c: FloatArray) -> FloatArray:
    """:func:`first_crossing`'s smallest root r >= 0 of the quadratic (+inf if none), before
    its median and r = 0 cases (inside its error state). Each result is written into a
    buffer whose value is no longer needed (the same operations on the same values: fewer
    temporaries)."""
    shape = np.broadcast_shapes(a.shape, c.shape)
    if not shape:  # scalars: as arrays of one
        return _quadratic_crossing(*(x.reshape(1) for x in (a, b, v0, v1, v2, c))).reshape(())
    c2 = c * c
    q2, q1, q0 = c2 * v2, c2 * v1, c2 * v0
    np.subtract(b * b, q2, out=q2)  # b b - c2 v2
    np.subtract(2.0 * a * b, q1, out=q1)  # 2 a b - c2 v1
    np.subtract(a * a, q0, out=q0)  # a a - c2 v0
    q1q1 = q1 * q1
    q2q0 = 4.0 * q2
    q2q0 *= q0
    disc = q1q1 - q2q0
    np.abs(q2q0, out=q2q0)
    q2q0 += q1q1
    q2q0 *= -1e-12  # -(1e-12 (q1 q1 + |4 q2 q0|))
    real = disc >= q2q0
    np.maximum(disc, 0.0, out=disc)
    np.sqrt(disc, out=disc)
    np.copysign(disc, q1, out=disc)
    disc += q1
    qq = np.multiply(-0.5, disc, out=disc)  # -(q1 + sign(q1) sqrt(disc)) / 2
    small = np.abs(q1, out=q1q1)
    small += np.abs(q0, out=q2q0)
    small += 1e-300
    small *= 1e-14
    lin = np.abs(q2, out=q2q0) <= small
    r1 = np.divide(qq, q2, out=q2)
    r2 = np.divide(q0, qq, out=q1q1)
    if lin.any():
        r1[lin] = -q0[lin] / q1[lin]
        r2[lin] = np.inf
    del q0, q1, qq, small
    best = np.full(shape, np.inf)
    abs_a, sign_c = np.abs(a), np.sign(c)
    for r in (r1, r2):
        br = b * r
        num = a + br
        # near c = 0 the two roots merge and each carries ~sqrt(eps) of rounding
        sign_ok = np.sign(num) == sign_c
        np.abs(br, out=br)
        br += abs_a
        br *= 1e-7
        sign_ok |= np.abs(num, out=num) <= br
        ok = np.isfinite(r)
        ok &= real
        ok &= r >= 0.0
        ok &= sign_ok
        ok &= r < best
        np.copyto(best, r, where=ok)
    return best


def rul_quantiles(post: TrendPosterior, levels: tuple[float, ...] = (0.5, 0.05, 0.95)
                  ) -> tuple[FloatArray, ...]:
    """RUL quantiles (the data's time unit) per unit (EI-18, EI-19): >= 0, ordered with the
    level, +inf inside the never-failing mass, NaN where there is no estimate."""
    for p in levels:
        if not 0.0 < p < 1.0:
            raise ValueError(f"levels: expected probabilities in (0, 1), got {p!r}")
    # every level in one pass: the posterior's (n,) arrays broadcast against (levels, n); the
    # median's own pass (the line's crossing: no quadratic to solve)
    c = t_quantiles(post.nu, tuple(levels))
    line = (post.a, post.b, post.vaa, 2.0 * post.vab, post.vbb)
    med = [j for j, p in enumerate(levels) if p == 0.5]
    rest = [j for j, p in enumerate(levels) if p != 0.5]
    out = np.empty_like(c)
    for group in (med, rest):
        if group:
            out[group] = first_crossing(*line, c[group])
    return tuple(out)


def hi_quantiles(post: TrendPosterior, horizons: np.ndarray,
                 levels: tuple[float, ...] = (0.5, 0.05, 0.95)) -> tuple[FloatArray, ...]:
    """Quantiles of the HI line ``horizons`` (B, K) time units after the last acquisition:
    exp(a + b r + t_nu^-1(p) sd(r)); the level-p curve reaches HI = 1 at the RUL quantile
    1 - p (EI-18), so the band and the RUL interval agree."""
    r = np.asarray(horizons, dtype=np.float64)
    col = lambda v: np.asarray(v)[:, None]  # noqa: E731
    mean = col(post.a) + col(post.b) * r
    with np.errstate(invalid="ignore"):
        sd = np.sqrt(np.maximum(col(post.vaa) + 2.0 * r * col(post.vab) + r * r * col(post.vbb),
                                0.0))
        return tuple(np.exp(mean + col(t_quantile(post.nu, p)) * sd) for p in levels)


__all__ = [
    "NU_BLOCK",
    "NU_TABLE",
    "SUM_NAMES",
    "TrendConfig",
    "TrendPosterior",
    "TrendState",
    "first_crossing",
    "hi_quantiles",
    "rul_quantiles",
    "t_cdf",
    "t_quantile",
    "t_quantiles",
    "trend_posterior",
    "trend_run",
    "trend_strategy",
    "trend_update",
]
