"""Filter consistency checks, physics-free (seed 003 sections 4.3-4.4;
docs/systems/friction-drive.md §5; Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to
Tracking and Navigation*, 2001, section 5.4).

A Kalman-type filter is *consistent* when its errors are zero-mean with the covariance it reports,
and its innovations are zero-mean, white, with covariance S. This module provides:

- :func:`normalised_squared` - the quadratic form e^T C^{-1} e over a batch (NEES with the state
  error and P, NIS with the innovation and S), by linear solves, no explicit inverse;
- :func:`chi2_interval` - two-sided chi-square acceptance region of a per-step or a time- (or
  run-) averaged normalised statistic;
- :func:`ellipsoid_probability` - P(chi2_n <= c^2), the probability of the c-sigma ellipsoid of an
  n-dimensional Gaussian, beside :func:`chebyshev_ellipsoid_bound` (1 - n/c^2, seed eq. 22) and
  :func:`erf_statement` (erf(c/sqrt 2), seed eq. 23). Seed eq. (23) is exact only for n = 1; for
  n = 4 and c = 3 the ellipsoid holds 93.9 %, not 99.7 %. Each *per-state* interval
  x_hat_i +- c sqrt(P_ii) (seed eq. 24-25) does hold with erf(c/sqrt 2) = 99.73 % (marginal), and
  all n intervals jointly (the bounding box of the ellipsoid) with at least P(chi2_n <= c^2);
- :func:`bounds_coverage` - fraction of steps inside x_hat +- c sigma per component;
- :func:`normalised_autocorrelation` and :func:`ljung_box` - whiteness of a sequence;
- :func:`check_innovations` - all innovation tests together, with a verdict.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy import special, stats

FloatArray = NDArray[np.float64]


def _check_finite(a: np.ndarray, name: str) -> None:
    if not np.all(np.isfinite(a)):
        bad = np.argwhere(~np.isfinite(np.atleast_1d(a)))[0]  # atleast_1d: 0-d has no rows
        raise ValueError(f"{name}: non-finite value at index {tuple(int(i) for i in bad)}")


def _cholesky(C: np.ndarray, name: str) -> FloatArray:
    """Batched lower Cholesky factor of ``C`` (..., n, n); a ``ValueError`` names the first
    index whose matrix is not positive definite."""
    try:
        return np.linalg.cholesky(C)
    except np.linalg.LinAlgError:
        eig = np.linalg.eigvalsh(C).min(axis=-1)
        bad = np.argwhere(eig <= 0)
        where = tuple(int(i) for i in bad[0]) if bad.size else ()
        raise ValueError(f"{name}: not positive definite at index {where}") from None


def normalised_squared(err: np.ndarray, cov: np.ndarray) -> FloatArray:
    """e^T C^{-1} e for every leading index: ``err`` (..., n), ``cov`` (..., n, n) -> (...).

    NEES when ``err`` is the state error x - x_hat and ``cov`` is P; NIS when ``err`` is the
    innovation and ``cov`` is S. Computed with a Cholesky solve; raises ``ValueError`` when a
    covariance is not positive definite (naming its index) or shapes disagree.
    """
    e = np.asarray(err, dtype=np.float64)
    C = np.asarray(cov, dtype=np.float64)
    if e.ndim < 1 or C.shape != (*e.shape, e.shape[-1]):
        raise ValueError(
            f"normalised_squared: err has shape {e.shape}, cov must have shape "
            f"{(*e.shape, e.shape[-1]) if e.ndim else '(..., n, n)'}, got {C.shape}"
        )
    _check_finite(e, "err")
    _check_finite(C, "cov")
    L = _cholesky(C, "cov")
    z = np.linalg.solve(L, e[..., None])[..., 0]
    return np.sum(z * z, axis=-1)


def chi2_interval(dof: int, n_avg: int = 1, level: float = 0.95) -> tuple[float, float]:
    """Two-sided ``level`` acceptance interval of the average of ``n_avg`` chi2_dof statistics.

    The sum of ``n_avg`` independent chi2_dof variables is chi2 with ``n_avg * dof`` degrees of
    freedom; the interval is for the mean, i.e. chi2.ppf([(1-level)/2, (1+level)/2],
    n_avg*dof) / n_avg (Bar-Shalom et al. 2001, eq. 5.4.2-7). ``n_avg = 1``: per-step bounds.
    """
    if dof < 1 or n_avg < 1:
        raise ValueError(f"chi2_interval: dof and n_avg must be >= 1, got {dof}, {n_avg}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"chi2_interval: level must be in (0, 1), got {level}")
    k = dof * n_avg
    lo, hi = stats.chi2.ppf([(1.0 - level) / 2.0, (1.0 + level) / 2.0], k)
    return float(lo / n_avg), float(hi / n_avg)


def ellipsoid_probability(c: float, n: int) -> float:
    """P(e^T P^{-1} e <= c^2) for e ~ N(0, P) in n dimensions: the chi2_n cdf at c^2.

    The correct Gaussian statement behind seed eq. (23): 0.9389 for n = 4, c = 3.
    """
    if n < 1 or not c > 0:
        raise ValueError(f"ellipsoid_probability: need n >= 1 and c > 0, got n={n}, c={c}")
    return float(stats.chi2.cdf(c * c, n))


def chebyshev_ellipsoid_bound(c: float, n: int) -> float:
    """Distribution-free lower bound 1 - n/c^2 (multidimensional Chebyshev, seed eq. 22).

    Clipped at 0. For n = 4, c = 3: 0.5556 (the seed prints 55.5 %).
    """
    if n < 1 or not c > 0:
        raise ValueError(f"chebyshev_ellipsoid_bound: need n >= 1 and c > 0, got n={n}, c={c}")
    return max(0.0, 1.0 - n / (c * c))


def erf_statement(c: float) -> float:
    """erf(c / sqrt 2) as printed in seed eq. (23): the probability of one c-sigma interval.

    Exact for a single Gaussian component (a per-state bound, seed eq. 25), not for the
    n-dimensional ellipsoid unless n = 1; see :func:`ellipsoid_probability`.
    """
    return float(special.erf(c / np.sqrt(2.0)))


def bounds_coverage(err: np.ndarray, var: np.ndarray, c: float = 3.0) -> FloatArray:
    """Fraction of rows with |err_i| <= c sqrt(var_i), per component (seed eq. 24-25).

    ``err`` (T, n) errors x - x_hat (or innovations), ``var`` (T, n) the matching variances
    (diag P or diag S); returns (n,). Under consistency each entry is about erf(c/sqrt 2).
    """
    e = np.asarray(err, dtype=np.float64)
    v = np.asarray(var, dtype=np.float64)
    if e.shape != v.shape or e.ndim != 2 or e.shape[0] == 0:
        raise ValueError(f"bounds_coverage: err and var must share a (T>0, n) shape, got "
                         f"{e.shape} and {v.shape}")
    _check_finite(e, "err")
    _check_finite(v, "var")
    if np.any(v < 0):
        raise ValueError("var: negative variance")
    if not (np.isfinite(c) and c > 0):
        raise ValueError(f"bounds_coverage: c must be finite and > 0, got {c}")
    return np.mean(np.abs(e) <= c * np.sqrt(v), axis=0)


def normalised_autocorrelation(seq: np.ndarray, max_lag: int) -> FloatArray:
    """Sample autocorrelation rho(l) = sum_k e_k e_{k+l} / sum_k e_k^2, lags 1..max_lag.

    ``seq`` (T,) or (T, m) (each column separately, after removing its mean); returns
    (max_lag,) or (max_lag, m). For a white sequence rho(l) is approximately N(0, 1/T), so
    |rho(l)| <= z_{(1+level)/2} / sqrt(T) at the given level (Bar-Shalom et al. 2001, 5.4.2).
    """
    x = np.asarray(seq, dtype=np.float64)
    squeeze = x.ndim == 1
    if squeeze:
        x = x[:, None]
    if x.ndim != 2:
        raise ValueError(f"normalised_autocorrelation: seq must be (T,) or (T, m), got {x.shape}")
    T = x.shape[0]
    if not 1 <= max_lag < T:
        raise ValueError(f"normalised_autocorrelation: need 1 <= max_lag < T={T}, got {max_lag}")
    _check_finite(x, "seq")
    x = x - x.mean(axis=0)
    denom = np.sum(x * x, axis=0)
    if np.any(denom <= 0):
        raise ValueError("normalised_autocorrelation: a column is constant")
    # FFT-based autocovariance (zero-padded), exact same sums as the direct definition.
    nfft = 1 << int(np.ceil(np.log2(2 * T)))
    fx = np.fft.rfft(x, n=nfft, axis=0)
    acov = np.fft.irfft(fx * np.conj(fx), n=nfft, axis=0)[1 : max_lag + 1]
    rho = acov / denom
    return rho[:, 0] if squeeze else rho


def ljung_box(seq: np.ndarray, max_lag: int) -> tuple[FloatArray, FloatArray]:
    """Ljung-Box statistic Q = T(T+2) sum_{l<=L} rho_l^2/(T-l) and its chi2_L p-value.

    ``seq`` (T,) or (T, m); returns (Q, p) each scalar-shaped per column ((,) or (m,)).
    """
    x = np.asarray(seq, dtype=np.float64)
    T = x.shape[0]
    rho = normalised_autocorrelation(x, max_lag)
    lags = np.arange(1, max_lag + 1, dtype=np.float64)
    w = 1.0 / (T - lags)
    if rho.ndim == 2:
        w = w[:, None]
    Q = T * (T + 2.0) * np.sum(rho * rho * w, axis=0)
    p = stats.chi2.sf(Q, max_lag)
    return np.asarray(Q), np.asarray(p)


def whiten(nu: np.ndarray, S: np.ndarray) -> FloatArray:
    """Whitened innovations L^{-1} nu with L L^T = S: (T, m), (T, m, m) -> (T, m).

    Under consistency each component is a unit-variance white sequence.
    """
    nu = np.asarray(nu, dtype=np.float64)
    S = np.asarray(S, dtype=np.float64)
    if nu.ndim < 1 or S.shape != (*nu.shape, nu.shape[-1]):
        raise ValueError(f"whiten: nu {nu.shape} and S {S.shape} disagree")
    _check_finite(nu, "nu")
    _check_finite(S, "S")
    L = _cholesky(S, "S")
    return np.linalg.solve(L, nu[..., None])[..., 0]


@dataclass(frozen=True)
class InnovationCheck:
    """Result of :func:`check_innovations` (seed 4.4; docs/systems/friction-drive.md §5).

    ``mean_nis`` and its ``nis_interval`` (time-averaged, two-sided ``level``);
    ``frac_nis_outside`` the fraction of steps outside the per-step interval ``nis_step_interval``
    (about 1 - level under consistency); ``innovation_coverage`` (m,) the fraction inside
    +- c sqrt(diag S) with its nominal ``innovation_coverage_nominal`` = erf(c/sqrt 2);
    ``max_abs_autocorr`` (m,) over lags 1..``max_lag`` of the whitened innovations, with the
    bound ``autocorr_bound`` and ``frac_autocorr_outside`` (m,); ``ljung_box_p`` (m,).
    Verdicts: ``nis_ok``, ``white`` and ``consistent`` (both).
    """

    n_steps: int
    dof: int
    level: float
    mean_nis: float
    nis_interval: tuple[float, float]
    nis_step_interval: tuple[float, float]
    frac_nis_outside: float
    c: float
    innovation_coverage: tuple[float, ...]
    innovation_coverage_nominal: float
    max_lag: int
    autocorr_bound: float
    max_abs_autocorr: tuple[float, ...]
    frac_autocorr_outside: tuple[float, ...]
    ljung_box_p: tuple[float, ...]
    nis_ok: bool
    white: bool
    consistent: bool = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "consistent", bool(self.nis_ok and self.white))

    def to_dict(self) -> dict:
        return asdict(self)


def check_innovations(
    nu: np.ndarray,
    S: np.ndarray,
    *,
    level: float = 0.95,
    c: float = 3.0,
    max_lag: int = 20,
    whiteness_alpha: float = 0.01,
) -> InnovationCheck:
    """Innovation-based consistency tests of one run (seed 4.4; docs/systems/friction-drive.md §5).

    ``nu`` (T, m) innovations, ``S`` (T, m, m) their predicted covariances.

    - NIS: the time average must lie in the two-sided ``level`` chi-square interval of an
      average of T chi2_m variables (:func:`chi2_interval`); the per-step fraction outside the
      per-step interval is reported.
    - Bounds: fraction of innovations within +- c sqrt(diag S) (seed eq. 26).
    - Whiteness: autocorrelation of each whitened component over lags 1..max_lag against
      +- z/sqrt(T) (``level``), and the Ljung-Box test. The sequence is declared white when every
      component's Ljung-Box p-value exceeds ``whiteness_alpha`` divided by m (Bonferroni).

    Missing steps: rows of ``nu`` that are entirely NaN (skipped updates, as the Kalman filters
    of :mod:`rulkit.estimation.kalman` mark them) are dropped before the tests, and
    ``n_steps`` counts the rows used; the whiteness test then runs on the remaining sequence
    with the gaps closed (approximate when gaps are frequent). Partially NaN rows and infinite
    values are errors.
    """
    nu = np.asarray(nu, dtype=np.float64)
    S = np.asarray(S, dtype=np.float64)
    if nu.ndim != 2 or S.shape != (*nu.shape, nu.shape[1]):
        raise ValueError(f"check_innovations: nu must be (T, m) and S (T, m, m); got {nu.shape}, "
                         f"{S.shape}")
    missing = np.all(np.isnan(nu), axis=1)
    if missing.any():
        nu, S = nu[~missing], S[~missing]
    T, m = nu.shape
    if not 0.0 < whiteness_alpha < 1.0:
        raise ValueError(f"check_innovations: whiteness_alpha must be in (0, 1), got "
                         f"{whiteness_alpha}")
    if T <= max_lag + 1:
        raise ValueError(f"check_innovations: need more than {max_lag + 1} steps, got {T}")
    nis = normalised_squared(nu, S)
    mean_nis = float(nis.mean())
    lo, hi = chi2_interval(m, T, level)
    slo, shi = chi2_interval(m, 1, level)
    frac_out = float(np.mean((nis < slo) | (nis > shi)))
    cov_in = bounds_coverage(nu, np.diagonal(S, axis1=1, axis2=2), c)
    z = whiten(nu, S)
    rho = normalised_autocorrelation(z, max_lag)
    bound = float(stats.norm.ppf((1.0 + level) / 2.0) / np.sqrt(T))
    _, p = ljung_box(z, max_lag)
    p = np.atleast_1d(p)
    white = bool(np.all(p > whiteness_alpha / m))
    return InnovationCheck(
        n_steps=T,
        dof=m,
        level=level,
        mean_nis=mean_nis,
        nis_interval=(lo, hi),
        nis_step_interval=(slo, shi),
        frac_nis_outside=frac_out,
        c=c,
        innovation_coverage=tuple(float(v) for v in cov_in),
        innovation_coverage_nominal=erf_statement(c),
        max_lag=max_lag,
        autocorr_bound=bound,
        max_abs_autocorr=tuple(float(v) for v in np.max(np.abs(rho), axis=0)),
        frac_autocorr_outside=tuple(float(v) for v in np.mean(np.abs(rho) > bound, axis=0)),
        ljung_box_p=tuple(float(v) for v in p),
        nis_ok=bool(lo <= mean_nis <= hi),
        white=white,
    )


@dataclass(frozen=True)
class StateErrorCheck:
    """NEES and per-state bounds coverage when the truth is known (simulation; seed 4.3)."""

    n_steps: int
    dim: int
    c: float
    mean_nees: float
    nees_interval: tuple[float, float]
    ellipsoid_fraction: float
    ellipsoid_nominal: float
    chebyshev_bound: float
    seed_erf_statement: float
    state_coverage: tuple[float, ...]
    state_coverage_nominal: float
    nees_ok: bool
    median_nees: float = float("nan")  # robust beside the mean (chi2_n median under consistency)
    max_nees: float = float("nan")

    def to_dict(self) -> dict:
        return asdict(self)


def check_state_errors(
    err: np.ndarray, P: np.ndarray, *, c: float = 3.0, level: float = 0.95
) -> StateErrorCheck:
    """NEES against chi-square bounds, the c-sigma ellipsoid and per-state coverage.

    ``err`` (T, n) = x - x_hat, ``P`` (T, n, n). The time-averaged NEES interval assumes
    independent steps, which filter errors are not (they are strongly correlated in time), so
    ``nees_ok`` is indicative; Monte Carlo averages over runs are the rigorous test
    (use ``chi2_interval(n, n_runs)`` on a per-step average across runs).
    """
    err = np.asarray(err, dtype=np.float64)
    P = np.asarray(P, dtype=np.float64)
    if err.ndim != 2 or P.shape != (*err.shape, err.shape[1]):
        raise ValueError(f"check_state_errors: err must be (T, n) and P (T, n, n); got "
                         f"{err.shape}, {P.shape}")
    nees = normalised_squared(err, P)
    return state_error_check(nees, err, np.diagonal(P, axis1=1, axis2=2), c=c, level=level)


def state_error_check(
    nees: np.ndarray, err: np.ndarray, var: np.ndarray, *, c: float = 3.0, level: float = 0.95
) -> StateErrorCheck:
    """:class:`StateErrorCheck` from a per-step NEES series ``nees`` (T,), the errors ``err``
    (T, n) and the variances ``var`` (T, n) (diag P): for filters that keep only diag P.

    NaN entries of ``nees`` mark steps where the NEES is undefined (a numerically singular P):
    they are left out of the mean, of the ellipsoid fraction and of the chi-square interval,
    whose degrees of freedom are n times the number of finite steps (``n_steps``).
    Infinite NEES values are errors.
    """
    nees = np.asarray(nees, dtype=np.float64)
    e = np.asarray(err, dtype=np.float64)
    if nees.ndim != 1 or e.ndim != 2 or e.shape[0] != nees.shape[0]:
        raise ValueError(f"state_error_check: nees must be (T,) and err (T, n); got "
                         f"{nees.shape}, {e.shape}")
    if np.any(np.isinf(nees)) or np.any(nees < 0):
        i = int(np.flatnonzero(np.isinf(nees) | (nees < 0))[0])
        raise ValueError(f"nees: infinite or negative value at step {i}")
    ok = ~np.isnan(nees)
    T_used = int(ok.sum())
    if T_used == 0:
        raise ValueError("nees: no finite step")
    n = e.shape[1]
    lo, hi = chi2_interval(n, T_used, level)
    mean_nees = float(nees[ok].mean())
    cov = bounds_coverage(e, var, c)
    return StateErrorCheck(
        n_steps=T_used,
        dim=n,
        c=c,
        mean_nees=mean_nees,
        nees_interval=(lo, hi),
        ellipsoid_fraction=float(np.mean(nees[ok] <= c * c)),
        ellipsoid_nominal=ellipsoid_probability(c, n),
        chebyshev_bound=chebyshev_ellipsoid_bound(c, n),
        seed_erf_statement=erf_statement(c),
        state_coverage=tuple(float(v) for v in cov),
        state_coverage_nominal=erf_statement(c),
        nees_ok=bool(lo <= mean_nees <= hi),
        median_nees=float(np.median(nees[ok])),
        max_nees=float(nees[ok].max()),
    )
