"""Many acquisitions per component: the embedded RUL tracker chain of
:mod:`rulkit.fleet.tracking.tracker_chain` run as two sequential passes per component (the
ingestion of a batch, docs/systems/embedded-rul.md sections 2-3), with the same numbers as one
:func:`~rulkit.fleet.tracking.tracker_chain.tracker_update` per acquisition rank (tested).

:func:`tracker_strategy` picks the cheapest of three equal-result ways from a cost model;
:func:`tracker_run` runs it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rulkit.fleet.tracking.tracker_chain import (
    MIN_UPDATES_VALID,
    TrackerConfig,
    TrackerGains,
    TrackerState,
    alert_level,
    paris_rul,
    rul_confidence_limits,
    rul_validity,
    tracker_update,
)

# Cost model of :func:`tracker_run`'s three equal-result strategies, in seconds, measured on
# the 2-core development machine (`benchmarks/bench_tracker_steps.py` prints the rank steps'
# constants and the compiled pass per row, `benchmarks/bench_scale.py` the outcome): one
# vectorised tracker_update per acquisition rank (~0.11 ms a call plus ~0.13 us a row: many
# components, few ranks, e.g. a fleet's periodic batch or the rank windows of a wide one), the
# per-component passes as plain Python (~3 us an acquisition: small batches) or compiled by
# numba (~0.06 us an acquisition, but loading numba and its cache costs ~0.55 s and ~100 MB
# once per process: long series).
_COST_PER_RANK = 1.1e-4
_COST_PER_RANK_ROW = 1.3e-7
_COST_PER_PYTHON_ROW = 3e-6
_COST_PER_JIT_ROW = 6e-8
_COST_JIT_LOAD = 0.55


def tracker_strategy(n_ranks: int, n_rows: int) -> str:
    """``"ranks"``, ``"python"`` or ``"jit"``: the cheapest way for :func:`tracker_run` to
    run ``n_rows`` acquisitions that take ``n_ranks`` rank steps (the most acquisitions of
    one component, summed over the calls)."""
    costs = {"ranks": n_ranks * _COST_PER_RANK + n_rows * _COST_PER_RANK_ROW,
             "python": n_rows * _COST_PER_PYTHON_ROW,
             "jit": n_rows * _COST_PER_JIT_ROW + (0.0 if _JITTED else _COST_JIT_LOAD)}
    return min(costs, key=costs.__getitem__)


def _hi_pass(seg, t, z, t0, n0, hi0, fhi0, dhi0, dt_fresh, a1, b1, dhi_min,  # type: ignore[no-untyped-def]
             two_point, fhi_out, dhi_out, dt_out):
    """Step 1 of :func:`tracker_update` (alpha-beta on HI, dHI floor, initiation) for the rows
    ``seg[c]:seg[c + 1]`` of each component c, in order; the same IEEE operations in the same
    order as the vectorised update (numpy's ``maximum``: NaN propagates)."""
    for c in range(seg.shape[0] - 1):
        tp = t0[c]
        n = n0[c]
        hp = hi0[c]
        x = fhi0[c]
        v = dhi0[c]
        for i in range(seg[c], seg[c + 1]):
            ti = t[i]
            zi = z[i]
            dt = dt_fresh if n == 0 else ti - tp
            xp = x + v * dt
            r = zi - xp
            x1 = xp + a1 * r
            v1 = v + b1 * r / dt
            if v1 < dhi_min:
                v1 = dhi_min
            if n == 0:
                x1 = zi
                v1 = dhi_min
            elif two_point and n == 1:
                s = (zi - hp) / dt
                x1 = zi
                v1 = dhi_min if s < dhi_min else s
            fhi_out[i] = x1
            dhi_out[i] = v1
            dt_out[i] = dt
            x = x1
            v = v1
            tp = ti
            hp = zi
            n += 1


def _rul_pass(seg, rul, dt, fhi, dhi, n0, rul0, frul0, drul0, d2rul0, fhi0, dhi0,  # type: ignore[no-untyped-def]
              a2, b2, g2, n_init, slope_start, measured, dhi_min, hi_floor, clip,
              x_out, v_out, a_out):
    """Step 3 of :func:`tracker_update` (alpha-beta-gamma on the Paris-law RUL ``rul`` from
    step 2, (re)starts, clip) for the rows of each component, in order (NaN RUL: predict
    only, as a missing measurement)."""
    for c in range(seg.shape[0] - 1):
        n = n0[c]
        rp = rul0[c]
        x = frul0[c]
        v = drul0[c]
        a = d2rul0[c]
        fp = fhi0[c]
        dp = dhi0[c]
        for i in range(seg[c], seg[c + 1]):
            d = dt[i]
            zi = rul[i]
            adt = a * d
            xp = x + (v + 0.5 * adt) * d
            r = zi - xp
            if zi != zi:
                r = 0.0
            rdt = r / d
            x1 = xp + a2 * r
            v1 = v + adt + b2 * rdt
            a1 = a + g2 * rdt / d
            if n < n_init:
                x1 = zi
                v1 = (zi - rp) / d if (slope_start and n == 2) else 0.0
                a1 = 0.0
            f1 = fhi[i]
            d1 = dhi[i]
            if measured and (d1 <= dhi_min or f1 <= hi_floor or dp <= dhi_min
                             or fp <= hi_floor):
                x1 = zi
                v1 = 0.0
                a1 = 0.0
            if clip and x1 < 0.0:
                x1 = 0.0
            x_out[i] = x1
            v_out[i] = v1
            a_out[i] = a1
            x = x1
            v = v1
            a = a1
            rp = zi
            fp = f1
            dp = d1
            n += 1


_JITTED: dict[str, Any] = {}


def _passes(strategy: str) -> tuple[Any, Any]:
    """The two passes, as Python or compiled (numba, on-disk cache)."""
    if strategy == "python":
        return _hi_pass, _rul_pass
    if not _JITTED:
        import numba

        try:  # compiled once, then loaded from numba's on-disk cache
            jitted = numba.njit(cache=True)(_hi_pass), numba.njit(cache=True)(_rul_pass)
        except RuntimeError:  # no writable cache location: compile in memory
            jitted = numba.njit(_hi_pass), numba.njit(_rul_pass)
        _JITTED["hi"], _JITTED["rul"] = jitted
    return _JITTED["hi"], _JITTED["rul"]


def _run_by_rank(state: TrackerState, seg: np.ndarray, t: np.ndarray, z: np.ndarray,
                 config: TrackerConfig, gains: TrackerGains
                 ) -> tuple[TrackerState, dict[str, np.ndarray]]:
    """:func:`tracker_run` as one :func:`tracker_update` per acquisition rank over the
    components that have one (the definition the passes are tested against), the outputs
    (:func:`_row_outputs`) over all rows at the end."""
    m = t.shape[0]
    b = len(state)
    counts = np.diff(seg)
    rows: dict[str, np.ndarray] = {k: np.empty(m) for k in (
        "fhi", "dhi", "rul", "frul", "drul", "d2rul")}
    n = np.empty(m, dtype=np.int64)
    if b and bool((counts == counts[0]).all()):  # every unit at every rank
        state = _run_full(state, t.reshape(b, -1), z.reshape(b, -1), config, gains,
                          {k: v.reshape(b, -1) for k, v in rows.items()}, n.reshape(b, -1))
    else:
        for r in range(int(counts.max(initial=0))):
            have = np.flatnonzero(counts > r)
            idx = seg[have] + r
            t_r = np.full(b, np.nan)  # fresh: the new state may hold these arrays
            z_r = np.full(b, np.nan)
            t_r[have] = t[idx]
            z_r[have] = z[idx]
            state, _ = tracker_update(state, t_r, z_r, config, gains, outputs=False)
            _rank_rows(rows, n, idx, state, have)
    rows.update(_row_outputs(rows["fhi"], rows["dhi"], rows["drul"], rows["d2rul"],
                             rows["frul"], n, config))
    return state, rows


def _rank_rows(rows: dict[str, np.ndarray], n: np.ndarray, idx: Any, state: TrackerState,
               sel: Any) -> None:
    """The rows ``idx`` of one rank: the state after it of the components ``sel``."""
    rows["fhi"][idx], rows["dhi"][idx] = state.ab[sel, 0], state.ab[sel, 1]
    rows["frul"][idx], rows["drul"][idx] = state.abg[sel, 0], state.abg[sel, 1]
    rows["d2rul"][idx], rows["rul"][idx], n[idx] = state.abg[sel, 2], state.rul[sel], \
        state.n[sel]


def _run_full(state: TrackerState, t: np.ndarray, z: np.ndarray, config: TrackerConfig,
              gains: TrackerGains, rows: dict[str, np.ndarray], n: np.ndarray) -> TrackerState:
    """:func:`_run_by_rank` when every component has an acquisition at every rank: ``t``, ``z``
    (B, K) each component's row of rank r in column r, ``rows`` and ``n`` (B, K) views of the
    outputs. The ranks where a component starts its trackers (every rank in mode
    ``"measured"``), or whose values are not all finite, are :func:`tracker_update` calls; the
    others its operations on the same values in the same order (the same bits) on each rank's
    contiguous values, copied into their rows, without the checks and copies of a general
    call."""
    n_init = {"floor": 1, "two-point": 3, "measured": 2}[config.initiation]
    simple = config.initiation != "measured" and bool(np.isfinite(t).all()) \
        and bool(np.isfinite(z).all()) and all(math.isfinite(g) for g in (
            gains.alpha1, gains.beta1, gains.alpha2, gains.beta2, gains.gamma2))
    k, r0 = t.shape[1], 0
    while r0 < k and not (simple and bool((state.n >= n_init).all())):
        state, _ = tracker_update(state, t[:, r0].copy(), z[:, r0].copy(), config, gains,
                                  outputs=False)
        _rank_rows(rows, n, (slice(None), r0), state, slice(None))
        r0 += 1
    if r0 == k:
        return state
    fhi, dhi, rul, frul, drul, d2rul = (rows[c] for c in (
        "fhi", "dhi", "rul", "frul", "drul", "d2rul"))
    x, v, fx, fv, fa = (np.ascontiguousarray(c) for c in (
        state.ab[:, 0], state.ab[:, 1], state.abg[:, 0], state.abg[:, 1], state.abg[:, 2]))
    tt, zt = np.ascontiguousarray(t.T), np.ascontiguousarray(z.T)
    tp, hp, rp, dhi_min = state.t, state.hi, state.rul, 1.0 / config.design_life
    for r in range(r0, k):
        dt = tt[r] - tp
        if not bool((dt > 0.0).all()):  # tracker_update's own error names the component
            now = _state_of(tp, state.n + (r - r0), hp, x, v, rp, fx, fv, fa)
            tracker_update(now, t[:, r].copy(), z[:, r].copy(), config, gains)
            raise AssertionError("tracker_update accepted a step it must refuse")
        # alpha-beta on HI (alpha_beta_update), then the floor of its rate
        xp = v * dt
        xp += x  # x + v dt
        res = zt[r] - xp
        x = gains.alpha1 * res
        x += xp
        res *= gains.beta1
        res /= dt
        v = v + res
        np.maximum(v, dhi_min, out=v)
        raw = paris_rul(x, v, config.hi_floor, config.paris_exponent)
        fhi[:, r], dhi[:, r], rul[:, r] = x, v, raw
        rp = rul[:, r]
        # alpha-beta-gamma on the RUL (alpha_beta_gamma_update)
        adt = fa * dt
        xp = np.multiply(0.5, adt)
        xp += fv
        xp *= dt
        xp += fx  # x + (v + a dt / 2) dt
        res = np.subtract(raw, xp, out=raw)
        rdt = res / dt
        res *= gains.alpha2
        fx = np.add(xp, res, out=xp)
        adt += fv
        fv = gains.beta2 * rdt
        fv += adt  # v + a dt + beta r / dt
        rdt *= gains.gamma2
        rdt /= dt
        fa = fa + rdt
        if config.rul_clip and bool((fx < 0.0).any()):
            np.maximum(fx, 0.0, out=fx)
        frul[:, r], drul[:, r], d2rul[:, r] = fx, fv, fa
        tp, hp = tt[r], zt[r]
    n[:, r0:] = state.n[:, None] + np.arange(1, k - r0 + 1)
    return _state_of(tp, n[:, -1], hp, x, v, rp, fx, fv, fa)


def _state_of(t: np.ndarray, n: np.ndarray, hi: np.ndarray, fhi: np.ndarray, dhi: np.ndarray,
              rul: np.ndarray, frul: np.ndarray, drul: np.ndarray, d2rul: np.ndarray
              ) -> TrackerState:
    """A :class:`TrackerState` of copies of the given columns."""
    return TrackerState(t=t.copy(), n=n.copy(), hi=hi.copy(), ab=np.column_stack([fhi, dhi]),
                        rul=rul.copy(), abg=np.column_stack([frul, drul, d2rul]))


def _row_outputs(fhi: np.ndarray, dhi: np.ndarray, drul: np.ndarray, d2rul: np.ndarray,
                 frul: np.ndarray, n: np.ndarray, config: TrackerConfig
                 ) -> dict[str, np.ndarray]:
    """Each row's ``n``, ``valid``, ``level``, ``rul_low`` and ``rul_high`` from its state
    after the update: :func:`~rulkit.fleet.tracking.tracker_chain.tracker_outputs`'
    element-wise operations over rows instead of components."""
    valid = rul_validity(drul, d2rul, config) & (n >= MIN_UPDATES_VALID)
    level = alert_level(fhi, frul, valid, config)
    with np.errstate(invalid="ignore"):
        lo, hi_lim = rul_confidence_limits(fhi, dhi, config)
    return {"n": n, "valid": valid, "level": level, "rul_low": lo, "rul_high": hi_lim}


def tracker_run(
    state: TrackerState,
    seg: np.ndarray,
    t: np.ndarray,
    hi: np.ndarray,
    config: TrackerConfig,
    gains: TrackerGains | None = None,
    strategy: str | None = None,
) -> tuple[TrackerState, dict[str, np.ndarray]]:
    """Run the chain of :func:`tracker_update` over many acquisitions per component.

    Component c of ``state`` (B components) assimilates the acquisitions
    ``t[seg[c]:seg[c + 1]]``, ``hi[...]`` in that order (``seg`` (B + 1,) nondecreasing
    offsets; every ``t`` and ``hi`` finite and the times increasing per component: the
    ingestion validates them). The result equals one :func:`tracker_update` call per
    acquisition rank (same operations, same rounding; tested), which is one of the three
    ``strategy`` choices, the cheapest by default: ``"ranks"`` does exactly that (few
    acquisitions per component); ``"python"`` and ``"jit"`` (numba) run the sequential
    alpha-beta (step 1) and alpha-beta-gamma (step 3) recursions as loops over each
    component's acquisitions and the Paris-law RUL (step 2) and the outputs (validity, level,
    confidence limits, docs/systems/embedded-rul.md §3) as numpy over all rows (long series:
    no call per rank).

    Returns the state after the last acquisition of each component and the per-acquisition
    history: ``fhi, dhi, rul, frul, drul, d2rul, rul_low, rul_high`` (float64), ``n``
    (acquisitions assimilated so far), ``valid`` and ``level`` (int8), each aligned with ``t``.
    """
    if gains is None:
        gains = config.gains()
    t = np.ascontiguousarray(t, dtype=np.float64)
    z = np.ascontiguousarray(hi, dtype=np.float64)
    seg = np.ascontiguousarray(seg, dtype=np.int64)
    b = len(state)
    m = t.shape[0]
    if seg.shape != (b + 1,) or z.shape != (m,) or seg[0] != 0 or seg[-1] != m:
        raise ValueError(f"seg: expected {b + 1} offsets from 0 to {m}, got {seg.shape}")
    counts = np.diff(seg)
    if strategy is None:
        strategy = tracker_strategy(int(counts.max(initial=0)), m)
    if strategy == "ranks":
        return _run_by_rank(state, seg, t, z, config, gains)
    two_point = config.initiation in ("two-point", "measured")
    measured = config.initiation == "measured"
    n_init = 3 if config.initiation == "two-point" else (2 if measured else 1)
    dhi_min = 1.0 / config.design_life
    hi_pass, rul_pass = _passes(strategy)
    f = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    n0 = np.ascontiguousarray(state.n, dtype=np.int64)
    fhi0, dhi0 = f(state.ab[:, 0]), f(state.ab[:, 1])
    fhi, dhi, dt = np.empty(m), np.empty(m), np.empty(m)
    hi_pass(seg, t, z, f(state.t), n0, f(state.hi), fhi0, dhi0, float(config.dt),
            float(gains.alpha1), float(gains.beta1), dhi_min, two_point, fhi, dhi, dt)
    rul = paris_rul(fhi, dhi, config.hi_floor, config.paris_exponent)
    frul, drul, d2rul = np.empty(m), np.empty(m), np.empty(m)
    rul_pass(seg, rul, dt, fhi, dhi, n0, f(state.rul), f(state.abg[:, 0]), f(state.abg[:, 1]),
             f(state.abg[:, 2]), fhi0, dhi0, float(gains.alpha2), float(gains.beta2),
             float(gains.gamma2), n_init, config.initiation == "two-point", measured, dhi_min,
             float(config.hi_floor), bool(config.rul_clip), frul, drul, d2rul)
    del dt
    n = np.repeat(n0 - seg[:-1], counts) + np.arange(1, m + 1)  # n0[c] + rank + 1
    rows = {"fhi": fhi, "dhi": dhi, "rul": rul, "frul": frul, "drul": drul, "d2rul": d2rul,
            **_row_outputs(fhi, dhi, drul, d2rul, frul, n, config)}
    new = state.take(np.arange(b))
    last = seg[1:][counts > 0] - 1
    upd = np.flatnonzero(counts > 0)
    new.t[upd], new.n[upd], new.hi[upd], new.rul[upd] = t[last], n[last], z[last], rul[last]
    new.ab[upd, 0], new.ab[upd, 1] = fhi[last], dhi[last]
    new.abg[upd, 0], new.abg[upd, 1], new.abg[upd, 2] = frul[last], drul[last], d2rul[last]
    return new, rows
