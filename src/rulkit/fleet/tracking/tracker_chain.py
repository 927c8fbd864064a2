"""The embedded RUL tracker chain of seed 004 (docs/systems/embedded-rul.md sections 2-3).

* :func:`tracker_update`: the per-component chain alpha-beta on HI, RUL from the Paris-law
  relation, alpha-beta-gamma on RUL, for any number of components in one vectorised call, with
  the component state held as a struct of arrays (:class:`TrackerState`);
* the validity rule, the warning and alarm levels and the confidence limits
  (:func:`rul_confidence_limits`, derivation in its docstring).
Many acquisitions per component at once: :mod:`rulkit.fleet.tracking.tracker_run` (same numbers).

The alpha-beta / alpha-beta-gamma gains and updates come from
:mod:`rulkit.estimation.trackers`; this module knows no physics beyond the seed's Paris-law
relation between HI and RUL. The HI itself comes from :mod:`rulkit.fleet.tracking.health_index`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


LEVEL_NONE, LEVEL_WARNING, LEVEL_ALARM = 0, 1, 2
MIN_UPDATES_VALID = 4
"""Acquisitions before a RUL can be valid: the 4th is the first steady-state update of the
alpha-beta-gamma tracker after a two-point initiation (before it d2RUL is 0 by construction,
not estimated, and would pass |d2RUL| < 0.01 trivially); the same rule for both initiations."""
LEVEL_NAMES = {LEVEL_NONE: "ok", LEVEL_WARNING: "warning", LEVEL_ALARM: "alarm"}
INITIATIONS = ("floor", "two-point", "measured")
"""How a new component's trackers start (``TrackerConfig.initiation``; the seed initialises
everything to zero, which would put log(0) into step 2 of :func:`tracker_update`):

``"floor"`` (default): 1st acquisition (n = 0): fHI = HI, dHI = 1/design_life (no
degradation assumed until the tracker measures one), fRUL = RUL, dRUL = d2RUL = 0; then the
steady-state updates 1-3 of :func:`tracker_update`. Safe on noisy HI: no slope is taken
from two noisy points.

``"two-point"``: two-point differencing, the standard initiation of alpha-beta trackers
(Bar-Shalom), applied to both trackers; for short, clean series (few acquisitions per
fault), where the floor start's transient would dominate. On noisy HI the differenced slope
is noise that persists for ~1/beta1 steps under a small tracking index (and can raise
spurious warnings or alarms on healthy components):

* 1st acquisition (n = 0): fHI = HI, dHI = 1/design_life; fRUL = RUL, dRUL = d2RUL = 0;
* 2nd (n = 1): fHI = HI, dHI = max((HI - HI_1) / dt, 1/design_life); the RUL tracker
  restarts at fRUL = RUL, dRUL = d2RUL = 0 (the first RUL that rests on a measured slope);
* 3rd (n = 2): the alpha-beta update as usual; fRUL = RUL, dRUL = (RUL - RUL_2) / dt,
  d2RUL = 0;
* from the 4th on the steady-state updates 1-3.

``"measured"``: the HI tracker starts as in ``"two-point"``; the RUL tracker is (re)started
at (RUL, 0, 0) at every acquisition where no degradation is measured yet (dHI at its floor
1/design_life, or fHI <= hi_floor), so it never starts from, nor carries the dynamics of,
the floor's RUL (e.g. -h ln h / dHI = 690 at h = 1e-3, dHI = 1e-5): it restarts once more
at the first acquisition with a measured slope (the previous state was still flat), and
from there on runs the steady-state updates. dRUL = 0 after a restart makes the RUL invalid
(the validity band is open at 0) until the tracker has estimated a rate."""


# --------------------------------------------------------------------------------------------
# 2. The tracker chain
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TrackerConfig:
    """Configuration of the per-component tracker chain (docs/systems/embedded-rul.md sections 2-3).

    Gains: the alpha-beta tracker on HI uses tracking index ``lambda_hi`` and the
    alpha-beta-gamma tracker on RUL ``lambda_rul`` (lambda = sigma_w dt^2 / sigma_v, see
    :meth:`from_noise`), both at the nominal acquisition interval ``dt``; the gains are computed
    once (the seed: "initialized at startup and persisted"). An update whose actual interval
    differs from ``dt`` uses the actual interval in the prediction and in the derivative
    corrections but keeps the steady-state gains (documented approximation).

    ``design_life``: dHI is floored at 1 / design_life (components do not heal).
    ``hi_floor``: the Paris-law RUL is evaluated at max(fHI, hi_floor) so that fHI <= 0 gives a
    finite RUL. ``hi_sigma``: one standard deviation of the measured HI, used by the confidence
    limits (default: none given -> 0). ``load_factor`` (0.10) and ``load_exponent`` shape the
    confidence limits (:func:`rul_confidence_limits`): the growth rate scales with the load to
    the power ``load_exponent``, by default (None) the Paris exponent ``paris_exponent``, so
    setting m alone keeps the limits consistent with the RUL formula. ``paris_exponent`` m:
    the crack-growth exponent of the RUL relation (2 = the seed's formula; see
    :func:`paris_rul`). ``initiation``: how a new component's trackers start, ``"floor"`` or
    ``"two-point"`` (the seed's behaviour, kept by name for the reproduction) or ``"measured"``
    (see :func:`tracker_update`). ``rul_clip``: fRUL is clipped at 0 (and each clip is counted
    in :attr:`TrackerOutput.clipped`); False keeps the seed's unclipped tracker.
    The seed's chain is ``TrackerConfig()`` / :meth:`seed`; :meth:`safe` and
    :func:`~rulkit.fleet.tracking.tracker_settings.fit_tracker_config` give the safe chain
    (measured initiation, clipping).

    **Time unit.** Every rate is per unit of the database's time column (hours in the seed,
    kcycles for the crack data, seconds if the file holds epoch seconds): ``design_life``
    (dHI floor = 1/design_life per time unit), ``dt``, ``warn_rul``, ``valid_drul`` (RUL time
    per time, dimensionless) and ``valid_d2rul`` (per time unit).
    :func:`~rulkit.fleet.tracking.tracker_settings.check_time_unit` rejects a design life that,
    at the acquisitions' spacing, alone moves the HI by more than
    ``max_floor_step`` per acquisition (the "hourly acquisitions, epoch seconds" false alarm).
    Validity (seed section 6): ``valid_drul = (-2, 0)`` open interval for dRUL/dt and
    ``|d2RUL/dt2| < valid_d2rul``. Warning: fHI >= ``warn_hi`` and valid and fRUL < ``warn_rul``;
    alarm: fHI >= ``alarm_hi``. ``hi_max`` bounds an accepted HI measurement (ingestion checks).
    Times are in the user's unit (hours in the seed, kcycles for the crack data); ``warn_rul``
    and ``valid_d2rul`` are in that unit.
    """

    dt: float = 1.0
    lambda_hi: float = 0.01
    lambda_rul: float = 0.01
    design_life: float = 1.0e5
    hi_floor: float = 1.0e-3
    hi_sigma: float = 0.0
    load_factor: float = 0.10
    load_exponent: float | None = None
    paris_exponent: float = 2.0
    initiation: str = "floor"
    rul_clip: bool = False
    valid_drul: tuple[float, float] = (-2.0, 0.0)
    valid_d2rul: float = 0.01
    warn_hi: float = 0.75
    warn_rul: float = 100.0
    alarm_hi: float = 1.0
    hi_max: float = 10.0

    def __post_init__(self) -> None:
        for name in ("dt", "lambda_hi", "lambda_rul", "design_life", "hi_floor", "hi_max",
                     "paris_exponent"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"TrackerConfig.{name}: expected a positive number, got {v!r}")
        for name in ("hi_sigma", "load_factor", "valid_d2rul", "warn_rul"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"TrackerConfig.{name}: expected a number >= 0, got {v!r}")
        if self.load_exponent is not None and not (
            math.isfinite(self.load_exponent) and self.load_exponent >= 0
        ):
            raise ValueError(
                f"TrackerConfig.load_exponent: expected a number >= 0 or None (= the Paris "
                f"exponent), got {self.load_exponent!r}"
            )
        if self.load_factor >= 1:
            raise ValueError(f"TrackerConfig.load_factor: expected < 1, got {self.load_factor}")
        lo, hi = self.valid_drul
        if not lo < hi:
            raise ValueError(
                f"TrackerConfig.valid_drul: expected (low, high), low < high, got {self.valid_drul}"
            )
        object.__setattr__(self, "valid_drul", (float(lo), float(hi)))
        if self.initiation not in INITIATIONS:
            raise ValueError(
                f"TrackerConfig.initiation: expected one of {INITIATIONS}, got "
                f"{self.initiation!r}"
            )
        object.__setattr__(self, "rul_clip", bool(self.rul_clip))

    @classmethod
    def from_noise(
        cls, *, sigma_w_hi: float, sigma_v_hi: float, sigma_w_rul: float, sigma_v_rul: float,
        dt: float, **kwargs: Any,
    ) -> TrackerConfig:
        """Config from process / measurement noise standard deviations (seed eqs 12 and 16).

        ``hi_sigma`` defaults to ``sigma_v_hi`` (the HI measurement noise).
        """
        from rulkit.estimation.trackers import tracking_index

        kwargs.setdefault("hi_sigma", sigma_v_hi)
        return cls(
            dt=dt,
            lambda_hi=float(tracking_index(sigma_w_hi, sigma_v_hi, dt)),
            lambda_rul=float(tracking_index(sigma_w_rul, sigma_v_rul, dt)),
            **kwargs,
        )

    @classmethod
    def seed(cls, **kwargs: Any) -> TrackerConfig:
        """The seed-004 chain as published (floor initiation, no clipping): today's default."""
        return cls(**kwargs)

    @classmethod
    def safe(cls, **kwargs: Any) -> TrackerConfig:
        """The safe chain: measured initiation, fRUL clipped at 0 (:func:`tracker_update`)."""
        kwargs.setdefault("initiation", "measured")
        kwargs.setdefault("rul_clip", True)
        return cls(**kwargs)

    def gains(self) -> TrackerGains:
        """The five steady-state gains (rulkit.estimation.trackers, docs/systems/embedded-rul.md
        §2)."""
        from rulkit.estimation.trackers import alpha_beta_gains, alpha_beta_gamma_gains

        a1, b1 = alpha_beta_gains(self.lambda_hi)
        a2, b2, g2 = alpha_beta_gamma_gains(self.lambda_rul)
        return TrackerGains(float(a1), float(b1), float(a2), float(b2), float(g2))

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict."""
        d = asdict(self)
        d["valid_drul"] = list(self.valid_drul)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrackerConfig:
        """Inverse of :meth:`to_dict` (unknown keys are an error)."""
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"TrackerConfig: unknown keys {sorted(unknown)}")
        d = dict(d)
        if "valid_drul" in d:
            d["valid_drul"] = tuple(d["valid_drul"])
        return cls(**d)


@dataclass(frozen=True)
class TrackerGains:
    """alpha1, beta1 (alpha-beta on HI) and alpha2, beta2, gamma2 (alpha-beta-gamma on RUL)."""

    alpha1: float
    beta1: float
    alpha2: float
    beta2: float
    gamma2: float


STATE_COLUMNS = ("t", "n", "hi", "fhi", "dhi", "rul", "frul", "drul", "d2rul")


@dataclass
class TrackerState:
    """State of B components as a struct of arrays (seed section 4, the component state file).

    ``ab (B, 2)`` = [fHI, dHI] and ``abg (B, 3)`` = [fRUL, dRUL, d2RUL] are the tracker states in
    the layout of :mod:`rulkit.estimation.trackers` (so they are passed without copies);
    ``hi (B,)`` the last measured HI and ``rul (B,)`` the last raw (Paris-law) RUL: these are the
    seed's 7 numbers per component. Book-keeping: ``t (B,)`` the time of the last acquisition
    (NaN before the first) and ``n (B,)`` the number of acquisitions assimilated.
    """

    t: FloatArray
    n: IntArray
    hi: FloatArray
    ab: FloatArray
    rul: FloatArray
    abg: FloatArray

    @classmethod
    def empty(cls, size: int) -> TrackerState:
        """B fresh components (no acquisition yet; numeric fields NaN, n = 0)."""
        nan = np.full(size, np.nan)
        return cls(
            t=nan.copy(), n=np.zeros(size, dtype=np.int64), hi=nan.copy(),
            ab=np.full((size, 2), np.nan), rul=nan.copy(), abg=np.full((size, 3), np.nan),
        )

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def fhi(self) -> FloatArray:
        return self.ab[:, 0]

    @property
    def dhi(self) -> FloatArray:
        return self.ab[:, 1]

    @property
    def frul(self) -> FloatArray:
        return self.abg[:, 0]

    @property
    def drul(self) -> FloatArray:
        return self.abg[:, 1]

    @property
    def d2rul(self) -> FloatArray:
        return self.abg[:, 2]

    @property
    def nbytes(self) -> int:
        """Bytes held per all components (7 tracker numbers + t + n = 72 bytes each)."""
        return sum(a.nbytes for a in (self.t, self.n, self.hi, self.ab, self.rul, self.abg))

    def take(self, idx: np.ndarray) -> TrackerState:
        """The components at ``idx`` (copies)."""
        return TrackerState(
            t=self.t[idx], n=self.n[idx], hi=self.hi[idx], ab=self.ab[idx], rul=self.rul[idx],
            abg=self.abg[idx],
        )

    def columns(self) -> dict[str, np.ndarray]:
        """The state as named 1-D columns (``STATE_COLUMNS``), e.g. for storage."""
        return {
            "t": self.t, "n": self.n, "hi": self.hi, "fhi": self.fhi, "dhi": self.dhi,
            "rul": self.rul, "frul": self.frul, "drul": self.drul, "d2rul": self.d2rul,
        }

    @classmethod
    def from_columns(cls, cols: dict[str, Any]) -> TrackerState:
        """Inverse of :meth:`columns` (None in a column reads as NaN)."""
        def f(name: str) -> FloatArray:
            return np.array(cols[name], dtype=np.float64)
        return cls(
            t=f("t"), n=np.asarray(cols["n"], dtype=np.int64), hi=f("hi"),
            ab=np.column_stack([f("fhi"), f("dhi")]), rul=f("rul"),
            abg=np.column_stack([f("frul"), f("drul"), f("d2rul")]),
        )


@dataclass(frozen=True)
class TrackerOutput:
    """Per-component outputs of one update (B,): validity, alert level, confidence limits.

    ``updated`` marks the components that assimilated an acquisition in this call;
    ``clipped`` those whose fRUL was clipped at 0 in this call (``config.rul_clip``).
    """

    updated: NDArray[np.bool_]
    valid: NDArray[np.bool_]
    level: NDArray[np.int8]
    rul_low: FloatArray
    rul_high: FloatArray
    clipped: NDArray[np.bool_] | None = None

    @property
    def n_clipped(self) -> int:
        """Number of fRUL values clipped at 0 in this call."""
        return 0 if self.clipped is None else int(self.clipped.sum())


def paris_rul(
    fhi: np.ndarray, dhi: np.ndarray, hi_floor: float = 1e-3, exponent: float = 2.0
) -> FloatArray:
    """RUL to HI = 1 under the Paris law (seed section 4, its pseudo-code for exponent 2).

    da/dN = D (2 sigma alpha sqrt(pi a))^m with HI proportional to the crack length a gives
    dHI/dt = c HI^p with p = m/2. For m = 2: HI(t) = HI_0 exp(c t), HI = 1 at t = -ln(HI_0)/c,
    and the tracker's c = dHI / fHI gives ``RUL = -fHI ln(fHI) / dHI`` (seed eq 11 prints the
    product with dHI instead of the division; its pseudo-code is right). For m != 2:
    t = (1 - HI_0^(1-p)) / (c (1-p)) with c = dHI / fHI^p, i.e.
    ``RUL = (fHI^p - fHI) / ((1 - p) dHI)`` (tends to the m = 2 form as p -> 1).

    Defined behaviour at the edges: fHI >= 1 gives RUL = 0 (at or past the alarm level);
    fHI < hi_floor is evaluated at hi_floor (finite RUL, no log(0)); dHI must be > 0 (the
    tracker floors it at 1/design life). Never NaN for finite inputs.
    """
    h = np.clip(fhi, hi_floor, 1.0)
    if exponent == 2.0:
        return -h * np.log(h) / dhi
    p = 0.5 * exponent
    return (h**p - h) / ((1.0 - p) * dhi)


def _time_to_one(h0: np.ndarray, c: np.ndarray, p: float) -> FloatArray:
    """Time for dHI/dt = c HI^p to go from h0 (<= 1) to 1."""
    if p == 1.0:
        return -np.log(h0) / c
    return (1.0 - h0 ** (1.0 - p)) / (c * (1.0 - p))


def rul_confidence_limits(
    fhi: np.ndarray, dhi: np.ndarray, config: TrackerConfig
) -> tuple[FloatArray, FloatArray]:
    """Low and high RUL under HI +- one standard deviation and load +- 10 %
    (docs/systems/embedded-rul.md §3).

    Derivation (the seed's eqs 27-29 are garbled in print; same Paris-law model as
    :func:`paris_rul`). With exponent m = 2 the growth rate is k = 4 pi D alpha^2 sigma^2 per
    cycle, so HI(t) = HI_0 exp(k t) and, given the current estimates, k = dHI / fHI (eq 27:
    dHI/dt = -ln(HI) / RUL . HI, i.e. k = -ln(HI)/RUL). The future HI is
    HI_t = exp(k t + ln HI_0) (eq 28). A load (gross stress sigma) scaled by (1 + delta) scales k
    by (1 + delta)^m, and an HI one standard deviation s higher starts the growth from HI_0 + s
    (eq 29). Solving HI_t = 1 for t:

        RUL_low  = -ln(min(fHI + s, 1))         / (k (1 + delta)^p)     (pessimistic)
        RUL_high = -ln(max(fHI - s, hi_floor))  / (k (1 - delta)^p)     (optimistic)

    with p = ``config.load_exponent``, by default the Paris exponent m of the RUL formula
    (``config.paris_exponent``, 2 for the seed's formula: da/dN is proportional to the stress
    to the power m); the seed's eq 29 multiplies the rate by 1.10 for a 10 % higher load, i.e.
    p = 1 (set ``load_exponent=1`` to reproduce it). For m != 2 the times to HI = 1 are those of
    dHI/dt = k HI^(m/2) (see :func:`paris_rul`). s = ``config.hi_sigma``, delta =
    ``config.load_factor``. RUL_low <= RUL <= RUL_high by construction; both are >= 0 and finite.
    """
    h = np.clip(fhi, config.hi_floor, 1.0)
    p = 0.5 * config.paris_exponent
    c = dhi / h**p
    s, d = config.hi_sigma, config.load_factor
    q = config.paris_exponent if config.load_exponent is None else config.load_exponent
    h_lo = np.clip(h + s, config.hi_floor, 1.0)
    h_hi = np.clip(h - s, config.hi_floor, 1.0)
    rul_low = _time_to_one(h_lo, c * (1.0 + d) ** q, p)
    rul_high = _time_to_one(h_hi, c * (1.0 - d) ** q, p)
    return rul_low, rul_high


def _interval_inputs(fhi: np.ndarray, frul: np.ndarray, config: TrackerConfig
                     ) -> tuple[FloatArray, FloatArray, float, float]:
    """fHI clipped to [hi_floor, 1], RUL = max(fRUL, 0), the exponents p = m/2 and q."""
    h = np.clip(np.asarray(fhi, dtype=np.float64), config.hi_floor, 1.0)
    rul = np.maximum(np.asarray(frul, dtype=np.float64), 0.0)
    q = config.paris_exponent if config.load_exponent is None else config.load_exponent
    return h, rul, 0.5 * config.paris_exponent, float(q)


def tracker_rul_interval(fhi: np.ndarray, frul: np.ndarray, config: TrackerConfig
                         ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The tracker chain's RUL with limits around that same RUL (docs/systems/embedded-rul.md
    §6, (EI-14)).

    The point is the filtered RUL, never negative: ``max(fRUL, 0)``. The seed's eq 27 takes
    the growth rate from the RUL itself (dHI/dt = -ln(HI) HI / RUL for m = 2), so the limits
    of eq 29 (HI +- one standard deviation s, load +- delta) scale the point by the ratio of
    the times to HI = 1 at unit rate, T1(h) = -ln h (m = 2) or (1 - h^(1-p)) / (1 - p):

        low = RUL T1(fHI + s) / T1(fHI) / (1 + delta)^q <= RUL <= RUL T1(fHI - s) / T1(fHI)
              / (1 - delta)^q = high,

    with the HI clipped to [hi_floor, 1] as in :func:`rul_confidence_limits`. At fHI >= 1
    (T1 = 0) the interval is [0, RUL]. Limits, not a probability interval. Returns
    (RUL, low, high); NaN stays NaN.
    """
    h, rul, p, q = _interval_inputs(fhi, frul, config)
    s, d = config.hi_sigma, config.load_factor
    one = np.ones_like(h)
    t_mid = _time_to_one(h, one, p)
    t_lo = _time_to_one(np.clip(h + s, config.hi_floor, 1.0), one, p)
    t_hi = _time_to_one(np.clip(h - s, config.hi_floor, 1.0), one, p)
    with np.errstate(invalid="ignore", divide="ignore"):
        low = np.where(t_mid > 0, rul * (t_lo / t_mid) / (1.0 + d) ** q, 0.0) + 0.0
        high = np.where(t_mid > 0, rul * (t_hi / t_mid) / (1.0 - d) ** q, rul)
    nan = np.isnan(rul)
    return rul, np.where(nan, np.nan, np.minimum(low, rul)), np.where(
        nan, np.nan, np.maximum(high, rul))


def tracker_hi_forecast(fhi: np.ndarray, frul: np.ndarray, horizons: np.ndarray,
                        config: TrackerConfig) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The HI the chain forecasts ``horizons`` (B, K) after the last acquisition (seed eq 28,
    docs/systems/embedded-rul.md §6, (EI-15)): dHI/dt = c HI^(m/2) from fHI with the rate c
    of :func:`tracker_rul_interval` (c = T1(fHI) / RUL), and the two paths of its limits
    (from fHI + s at c (1 + delta)^q, from fHI - s at c (1 - delta)^q). Each path reaches
    HI = 1 at the RUL, its low or its high limit. Returns (median path, lower, upper), HI
    capped at 1 once reached."""
    h, rul, p, q = _interval_inputs(fhi, frul, config)
    s, d = config.hi_sigma, config.load_factor
    r = np.asarray(horizons, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        c = (_time_to_one(h, np.ones_like(h), p) / rul)[:, None]

        def path(h0: np.ndarray, rate: np.ndarray) -> FloatArray:
            """h^(1-p) = h0^(1-p) + (1-p) c r (h0 exp(c r) at p = 1); past a blow-up, 1."""
            h0 = np.clip(h0, config.hi_floor, 1.0)[:, None]
            if p == 1.0:
                out = h0 * np.exp(rate * r)
            else:
                base = h0 ** (1.0 - p) + (1.0 - p) * rate * r
                out = np.where(base > 0, np.abs(base) ** (1.0 / (1.0 - p)), np.inf)
            return np.minimum(np.where(np.isnan(out), 1.0, out), 1.0)

        return (path(h, c), path(h - s, c * (1.0 - d) ** q), path(h + s, c * (1.0 + d) ** q))


def rul_validity(drul: np.ndarray, d2rul: np.ndarray, config: TrackerConfig) -> NDArray[np.bool_]:
    """Seed section 6: RUL valid when lo < dRUL/dt < hi (-2, 0) and |d2RUL/dt2| < 0.01.

    :func:`tracker_outputs` also requires ``n >= MIN_UPDATES_VALID`` acquisitions.
    """
    lo, hi = config.valid_drul
    return (drul > lo) & (drul < hi) & (np.abs(d2rul) < config.valid_d2rul)


def alert_level(
    fhi: np.ndarray, frul: np.ndarray, valid: np.ndarray, config: TrackerConfig
) -> NDArray[np.int8]:
    """0 ok, 1 warning (fHI >= 0.75 and RUL valid and fRUL < warn_rul), 2 alarm (fHI >= 1).

    The levels are applied to the filtered HI (one noisy acquisition above 1 does not raise an
    alarm by itself; the HI threshold itself already carries the designed PFA per acquisition).
    NaN (never-updated components) gives level 0.
    """
    level = np.where(fhi >= config.alarm_hi, LEVEL_ALARM, LEVEL_NONE)
    warn = (fhi >= config.warn_hi) & valid & (frul < config.warn_rul) & (level == LEVEL_NONE)
    return np.where(warn, LEVEL_WARNING, level).astype(np.int8)


def tracker_update(
    state: TrackerState,
    t: np.ndarray,
    hi: np.ndarray,
    config: TrackerConfig,
    gains: TrackerGains | None = None,
    *,
    outputs: bool = True,
) -> tuple[TrackerState, TrackerOutput | None]:
    """Assimilate one acquisition per component, for all B components in one vectorised call.

    ``t (B,)`` acquisition times and ``hi (B,)`` measured HI, aligned with ``state``. A
    component whose ``hi`` or ``t`` is NaN or infinite has no acquisition in this call and keeps
    its state (``TrackerOutput.updated`` is False for it); ingestion (component_store) rejects
    such rows with an error instead.
    The chain per component (seed section 4 pseudo-code; docs/systems/embedded-rul.md §2):

    1. alpha-beta on HI: predict fHI += dHI dt, r = HI - fHI, fHI += alpha1 r, dHI += beta1 r/dt
       (``alpha_beta_update``), then dHI = max(dHI, 1/design_life) (no healing);
    2. RUL = -fHI ln(fHI) / dHI (:func:`paris_rul`);
    3. alpha-beta-gamma on RUL: fRUL += dRUL dt + d2RUL dt^2/2, dRUL += d2RUL dt,
       r = RUL - fRUL, fRUL += alpha2 r, dRUL += beta2 r/dt, d2RUL += gamma2 r/dt^2
       (``alpha_beta_gamma_update``: the steady-state Kalman update of the constant-acceleration
       model; the seed's pseudo-code omits the rate prediction and divides by 2 dt^2, half the
       Kalman gain, see docs/systems/embedded-rul.md §2 and rulkit.estimation.trackers).

    Track initiation (``config.initiation``): see :data:`INITIATIONS`.

    With ``config.rul_clip`` fRUL is clipped at 0 after the update (a filtered RUL never goes
    negative); :attr:`TrackerOutput.clipped` counts the clips.

    A component is therefore not valid before its RUL tracker has estimated dRUL and d2RUL.
    dt = t - t_last must be > 0 for every updated component (``ValueError`` naming the first
    offending index otherwise; nothing is modified since the function is pure).

    Returns the new state (new arrays; the input is not modified) and, when ``outputs``, the
    :class:`TrackerOutput` (validity, level, confidence limits) for every component.
    """
    from rulkit.estimation.trackers import alpha_beta_gamma_update, alpha_beta_update

    if gains is None:
        gains = config.gains()
    t = np.asarray(t, dtype=np.float64)
    z = np.asarray(hi, dtype=np.float64)
    b = len(state)
    if t.shape != (b,) or z.shape != (b,):
        raise ValueError(f"t and hi: expected shape ({b},), got {t.shape} and {z.shape}")
    have = np.isfinite(z) & np.isfinite(t)
    n_prev = state.n
    two_point = config.initiation in ("two-point", "measured")
    measured = config.initiation == "measured"
    n_init = 3 if config.initiation == "two-point" else (2 if measured else 1)
    initiating = bool((n_prev < n_init).any())
    all_have = bool(have.all())
    dt, zz = _steps(state, t, z, have, config, initiating)
    dhi_min = 1.0 / config.design_life

    ab = alpha_beta_update(state.ab, zz, dt, gains.alpha1, gains.beta1)
    np.maximum(ab[:, 1], dhi_min, out=ab[:, 1])
    if initiating:  # floor start; two-point initiation of the HI tracker
        first = n_prev == 0
        second = (n_prev == 1) if two_point else np.zeros(b, dtype=bool)
        slope = np.maximum((zz - state.hi) / dt, dhi_min)
        ab[:, 0] = np.where(first | second, zz, ab[:, 0])
        ab[:, 1] = np.where(first, dhi_min, np.where(second, slope, ab[:, 1]))
    rul = paris_rul(ab[:, 0], ab[:, 1], config.hi_floor, config.paris_exponent)
    abg = alpha_beta_gamma_update(state.abg, rul, dt, gains.alpha2, gains.beta2, gains.gamma2)
    if initiating or measured:
        abg = _start_rul_tracker(state, ab, rul, abg, dt, config, n_init)
    clipped = None
    if config.rul_clip:
        clipped = have & (abg[:, 0] < 0.0)
        if clipped.any():
            abg = abg.copy()
            abg[:, 0] = np.maximum(abg[:, 0], 0.0)
    n = state.n + 1
    new_t = t
    new_hi = z
    if not all_have:
        ab = np.where(have[:, None], ab, state.ab)
        abg = np.where(have[:, None], abg, state.abg)
        rul = np.where(have, rul, state.rul)
        n = np.where(have, n, state.n)
        new_t = np.where(have, t, state.t)
        new_hi = np.where(have, z, state.hi)
    new = TrackerState(t=new_t, n=n, hi=new_hi, ab=ab, rul=rul, abg=abg)
    if not outputs:
        return new, None
    out = tracker_outputs(new, config, updated=have)
    if clipped is not None:
        out = TrackerOutput(updated=out.updated, valid=out.valid, level=out.level,
                            rul_low=out.rul_low, rul_high=out.rul_high, clipped=clipped)
    return new, out


def _steps(state: TrackerState, t: np.ndarray, z: np.ndarray, have: np.ndarray,
           config: TrackerConfig, initiating: bool) -> tuple[np.ndarray, np.ndarray]:
    """The time steps and measurements of :func:`tracker_update`: ``ValueError`` naming the
    first updated component whose time is not after its last; components without an
    acquisition get a placeholder step and HI (their state is kept)."""
    dt = t - state.t
    if initiating:
        fresh = state.n == 0
        dt = np.where(fresh, config.dt, dt)  # placeholder; fresh rows are overwritten later
    bad = have & ~(dt > 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"component index {i}: time {float(t[i])!r} is not after its last acquisition "
            f"{float(state.t[i])!r} (dt must be > 0)"
        )
    if bool(have.all()):
        return dt, z
    return np.where(have, dt, config.dt), np.where(have, z, 0.0)


def _start_rul_tracker(state: TrackerState, ab: np.ndarray, rul: np.ndarray, abg: np.ndarray,
                       dt: np.ndarray, config: TrackerConfig, n_init: int) -> np.ndarray:
    """The RUL tracker's (re)starts of :func:`tracker_update`'s initiation modes: at (RUL, 0,
    0) during initiation, with the two-point slope at the third acquisition, and, in mode
    ``"measured"``, while no degradation is measured and at the first measured slope (so the
    tracker never carries the floor's RUL)."""
    b = len(state)
    n_prev = state.n
    dhi_min = 1.0 / config.design_life
    if bool((n_prev < n_init).any()):
        zero = np.zeros(b)
        third = (n_prev == 2) if config.initiation == "two-point" else np.zeros(b, dtype=bool)
        with np.errstate(invalid="ignore"):
            rate = np.where(third, (rul - state.rul) / dt, 0.0)
        init = np.column_stack([rul, rate, zero])
        abg = np.where((n_prev < n_init)[:, None], init, abg)
    if config.initiation == "measured":
        with np.errstate(invalid="ignore"):
            flat = ((ab[:, 1] <= dhi_min) | (ab[:, 0] <= config.hi_floor)
                    | (state.ab[:, 1] <= dhi_min) | (state.ab[:, 0] <= config.hi_floor))
        if flat.any():
            abg = np.where(flat[:, None], np.column_stack([rul, np.zeros(b), np.zeros(b)]), abg)
    return abg


def tracker_outputs(
    state: TrackerState, config: TrackerConfig, updated: np.ndarray | None = None
) -> TrackerOutput:
    """Validity, alert level and confidence limits of a state (docs/systems/embedded-rul.md §3)."""
    fhi, dhi = state.fhi, state.dhi
    valid = rul_validity(state.drul, state.d2rul, config) & (state.n >= MIN_UPDATES_VALID)
    level = alert_level(fhi, state.frul, valid, config)
    with np.errstate(invalid="ignore"):
        lo, hi = rul_confidence_limits(fhi, dhi, config)
    if updated is None:
        updated = np.zeros(len(state), dtype=bool)
    return TrackerOutput(updated=np.asarray(updated, dtype=bool), valid=valid, level=level,
                         rul_low=lo, rul_high=hi)


def track_series(
    t: np.ndarray, hi: np.ndarray, config: TrackerConfig
) -> dict[str, np.ndarray]:
    """Run the chain over a (T, B) panel of acquisitions (NaN = none); history as (T, B) arrays.

    One vectorised :func:`tracker_update` per time step across all B components. Returns a dict
    with the history of every :data:`STATE_COLUMNS` field plus ``valid``, ``level``,
    ``rul_low``, ``rul_high``, ``updated`` and ``clipped``, each of shape (T, B).
    """
    t = np.asarray(t, dtype=np.float64)
    hi = np.atleast_2d(np.asarray(hi, dtype=np.float64))
    if hi.ndim != 2 or (t.ndim == 1 and t.shape[0] != hi.shape[0]):
        raise ValueError(f"t (T,) or (T, B) and hi (T, B) expected, got {t.shape} and {hi.shape}")
    n_t, b = hi.shape
    tt = np.broadcast_to(t[:, None] if t.ndim == 1 else t, (n_t, b))
    gains = config.gains()
    state = TrackerState.empty(b)
    keys = [*STATE_COLUMNS, "valid", "level", "rul_low", "rul_high", "updated", "clipped"]
    hist: dict[str, np.ndarray] = {k: np.empty((n_t, b)) for k in keys}
    for k in range(n_t):
        state, out = tracker_update(state, tt[k], hi[k], config, gains)
        assert out is not None
        for name, col in state.columns().items():
            hist[name][k] = col
        hist["valid"][k] = out.valid
        hist["level"][k] = out.level
        hist["rul_low"][k] = out.rul_low
        hist["rul_high"][k] = out.rul_high
        hist["updated"][k] = out.updated
        hist["clipped"][k] = out.clipped if out.clipped is not None else False
    for name in ("valid", "updated", "clipped"):
        hist[name] = hist[name].astype(bool)
    hist["level"] = hist["level"].astype(np.int8)
    hist["n"] = hist["n"].astype(np.int64)
    return hist


def tracker_update_loop(
    state: TrackerState, t: np.ndarray, hi: np.ndarray, config: TrackerConfig,
    gains: TrackerGains | None = None,
) -> TrackerState:
    """Per-component plain-Python reference of :func:`tracker_update` (state only).

    The seed's pseudo-code transcribed line by line with ``math`` scalars (Kalman-consistent
    gamma convention, same initialisation and edge rules). It is the naive baseline of the
    benchmark and the independent reference of the vectorised path in the tests; never use it
    on a fleet.
    """
    if gains is None:
        gains = config.gains()
    a1, b1, a2, b2, g2 = gains.alpha1, gains.beta1, gains.alpha2, gains.beta2, gains.gamma2
    dhi_min = 1.0 / config.design_life
    m_paris = config.paris_exponent
    two_point = config.initiation in ("two-point", "measured")
    slope_start = config.initiation == "two-point"
    measured = config.initiation == "measured"
    p_half = 0.5 * m_paris
    out = state.take(np.arange(len(state)))
    for i in range(len(state)):
        z, ti = float(hi[i]), float(t[i])
        if not (math.isfinite(z) and math.isfinite(ti)):
            continue
        n_i = int(out.n[i])
        dt = ti - out.t[i] if n_i > 0 else config.dt
        if not dt > 0:
            raise ValueError(f"component index {i}: dt must be > 0")
        fhi, dhi = out.ab[i]
        if n_i == 0:
            fhi, dhi = z, dhi_min
        elif n_i == 1 and two_point:
            fhi, dhi = z, max((z - out.hi[i]) / dt, dhi_min)
        else:
            fhi = fhi + dhi * dt
            r = z - fhi
            fhi = fhi + a1 * r
            dhi = max(dhi + b1 * r / dt, dhi_min)
        h = min(max(fhi, config.hi_floor), 1.0)
        if m_paris == 2.0:
            rul = -h * math.log(h) / dhi
        else:
            rul = (h**p_half - h) / ((1.0 - p_half) * dhi)
        frul, drul, d2rul = out.abg[i]
        if n_i == 0 or (n_i == 1 and two_point):
            frul, drul, d2rul = rul, 0.0, 0.0
        elif n_i == 2 and slope_start:
            frul, drul, d2rul = rul, (rul - out.rul[i]) / dt, 0.0
        else:
            frul = frul + drul * dt + d2rul * dt * dt / 2.0
            drul = drul + d2rul * dt  # constant-acceleration prediction of the rate
            r = rul - frul
            frul = frul + a2 * r
            drul = drul + b2 * r / dt
            d2rul = d2rul + g2 * r / (dt * dt)
        prev_flat = n_i > 0 and (out.ab[i, 1] <= dhi_min or out.ab[i, 0] <= config.hi_floor)
        if measured and (dhi <= dhi_min or fhi <= config.hi_floor or prev_flat):
            frul, drul, d2rul = rul, 0.0, 0.0
        if config.rul_clip:
            frul = max(frul, 0.0)
        out.t[i], out.n[i], out.hi[i], out.rul[i] = ti, out.n[i] + 1, z, rul
        out.ab[i] = (fhi, dhi)
        out.abg[i] = (frul, drul, d2rul)
    return out


__all__ = [
    "INITIATIONS",
    "LEVEL_ALARM",
    "LEVEL_NAMES",
    "LEVEL_NONE",
    "LEVEL_WARNING",
    "MIN_UPDATES_VALID",
    "STATE_COLUMNS",
    "TrackerConfig",
    "TrackerGains",
    "TrackerOutput",
    "TrackerState",
    "alert_level",
    "paris_rul",
    "rul_confidence_limits",
    "rul_validity",
    "track_series",
    "tracker_hi_forecast",
    "tracker_outputs",
    "tracker_rul_interval",
    "tracker_update",
    "tracker_update_loop",
]
