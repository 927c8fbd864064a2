"""Tests of the generic filter-consistency checks (rulkit.estimation.consistency)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import special, stats

from rulkit.estimation import consistency as C


def _random_spd(rng: np.random.Generator, n: int, batch: int) -> np.ndarray:
    A = rng.standard_normal((batch, n, n))
    return A @ np.swapaxes(A, 1, 2) + n * np.eye(n)


def test_normalised_squared_matches_explicit_inverse():
    rng = np.random.default_rng(0)
    S = _random_spd(rng, 3, 50)
    e = rng.standard_normal((50, 3))
    want = np.einsum("bi,bij,bj->b", e, np.linalg.inv(S), e)
    np.testing.assert_allclose(C.normalised_squared(e, S), want, rtol=1e-12)


def test_normalised_squared_rejects_bad_covariance_and_shapes():
    S = np.stack([np.eye(2), np.diag([1.0, -1.0])])
    with pytest.raises(ValueError, match=r"index \(1,\)"):
        C.normalised_squared(np.ones((2, 2)), S)
    with pytest.raises(ValueError, match="cov must have shape"):
        C.normalised_squared(np.ones((2, 2)), np.eye(2))
    with pytest.raises(ValueError, match="err: non-finite"):
        C.normalised_squared(np.array([[np.nan, 0.0]]), np.eye(2)[None])


def test_ellipsoid_probability_closed_forms():
    # chi2 cdf with even dof: 1 - exp(-x/2) sum_{k<n/2} (x/2)^k / k!
    x = 9.0
    assert C.ellipsoid_probability(3.0, 4) == pytest.approx(1 - math.exp(-x / 2) * (1 + x / 2))
    assert C.ellipsoid_probability(3.0, 4) == pytest.approx(0.9389, abs=1e-4)
    assert C.ellipsoid_probability(2.0, 2) == pytest.approx(1 - math.exp(-2.0))
    assert C.ellipsoid_probability(3.0, 1) == pytest.approx(C.erf_statement(3.0), rel=1e-12)
    assert C.erf_statement(3.0) == pytest.approx(0.99730020, abs=1e-8)
    assert C.chebyshev_ellipsoid_bound(3.0, 4) == pytest.approx(5 / 9)
    assert C.chebyshev_ellipsoid_bound(1.0, 4) == 0.0


def test_ellipsoid_probability_by_monte_carlo():
    rng = np.random.default_rng(1)
    P = _random_spd(rng, 4, 1)[0]
    e = rng.multivariate_normal(np.zeros(4), P, size=200000)
    frac = np.mean(C.normalised_squared(e, np.broadcast_to(P, (200000, 4, 4))) <= 9.0)
    assert frac == pytest.approx(C.ellipsoid_probability(3.0, 4), abs=3e-3)
    assert abs(frac - C.erf_statement(3.0)) > 0.05  # the seed's eq. (23) is off for n = 4


def test_chi2_interval_covers_the_mean_of_chi2_variables_at_its_level():
    rng = np.random.default_rng(2)
    lo, hi = C.chi2_interval(2, 50, 0.9)
    means = rng.chisquare(2, size=(20000, 50)).mean(axis=1)
    assert np.mean((means >= lo) & (means <= hi)) == pytest.approx(0.9, abs=0.01)
    assert C.chi2_interval(2, 1, 0.95) == pytest.approx(tuple(stats.chi2.ppf([0.025, 0.975], 2)))
    with pytest.raises(ValueError, match="level"):
        C.chi2_interval(2, 1, 1.5)


def test_bounds_coverage_gaussian():
    rng = np.random.default_rng(3)
    sd = np.array([1.0, 0.01, 100.0])
    e = rng.standard_normal((100000, 3)) * sd
    cov = C.bounds_coverage(e, np.broadcast_to(sd**2, e.shape), 2.0)
    np.testing.assert_allclose(cov, special.erf(2 / np.sqrt(2)), atol=3e-3)
    with pytest.raises(ValueError, match="negative"):
        C.bounds_coverage(np.ones((2, 1)), -np.ones((2, 1)))


def test_autocorrelation_matches_direct_definition_and_detects_ar1():
    rng = np.random.default_rng(4)
    x = rng.standard_normal((500, 2))
    rho = C.normalised_autocorrelation(x, 5)
    xc = x - x.mean(axis=0)
    direct = np.array([[np.sum(xc[:-l, j] * xc[l:, j]) / np.sum(xc[:, j] ** 2)
                        for j in range(2)] for l in range(1, 6)])
    np.testing.assert_allclose(rho, direct, atol=1e-12)
    ar = np.zeros(20000)
    e = rng.standard_normal(20000)
    for k in range(1, 20000):
        ar[k] = 0.5 * ar[k - 1] + e[k]
    assert C.normalised_autocorrelation(ar, 1)[0] == pytest.approx(0.5, abs=0.02)


def test_ljung_box_statistic_and_decisions():
    rng = np.random.default_rng(5)
    white = rng.standard_normal(5000)
    Q, p = C.ljung_box(white, 10)
    rho = C.normalised_autocorrelation(white, 10)
    T = 5000
    assert float(Q) == pytest.approx(T * (T + 2) * np.sum(rho**2 / (T - np.arange(1, 11))))
    assert float(p) == pytest.approx(stats.chi2.sf(float(Q), 10))
    ar = np.convolve(white, [1.0, 0.3], mode="same")
    assert float(C.ljung_box(ar, 10)[1]) < 1e-10
    # under H0 the p-value is uniform: rejection rate at 5 % over many white series
    ps = np.array([float(C.ljung_box(rng.standard_normal(400), 10)[1]) for _ in range(400)])
    assert np.mean(ps < 0.05) == pytest.approx(0.05, abs=0.03)


def test_check_innovations_verdicts():
    rng = np.random.default_rng(6)
    T = 5000
    S = np.broadcast_to(np.array([[2.0, 0.5], [0.5, 1.0]]), (T, 2, 2)).copy()
    L = np.linalg.cholesky(S[0])
    nu = rng.standard_normal((T, 2)) @ L.T
    ok = C.check_innovations(nu, S)
    assert ok.nis_ok and ok.white and ok.consistent
    assert ok.nis_interval[0] < 2.0 < ok.nis_interval[1]
    assert ok.innovation_coverage[0] == pytest.approx(0.9973, abs=0.003)
    big = C.check_innovations(1.2 * nu, S)  # covariance underestimated by 1.44
    assert not big.nis_ok and not big.consistent
    z = rng.standard_normal((T, 2))
    corr = (z + 0.4 * np.roll(z, 1, axis=0)) / np.sqrt(1.16) @ L.T
    col = C.check_innovations(corr, S)
    assert col.nis_ok and not col.white and not col.consistent
    with pytest.raises(ValueError, match="steps"):
        C.check_innovations(nu[:10], S[:10])


def test_check_state_errors_reports_seed_and_correct_statements():
    rng = np.random.default_rng(7)
    T = 20000
    P = np.broadcast_to(np.diag([1.0, 4.0, 0.01, 1e-6]), (T, 4, 4))
    err = rng.standard_normal((T, 4)) * np.sqrt(np.diag(P[0]))
    r = C.check_state_errors(err, P)
    assert r.ellipsoid_fraction == pytest.approx(0.9389, abs=0.006)
    assert r.ellipsoid_nominal == pytest.approx(0.9389, abs=1e-4)
    assert r.chebyshev_bound == pytest.approx(0.5556, abs=1e-4)
    assert r.seed_erf_statement == pytest.approx(0.9973, abs=1e-4)
    assert r.nees_ok
    np.testing.assert_allclose(r.state_coverage, 0.9973, atol=0.002)


def test_check_innovations_drops_skipped_steps_and_rejects_partial_nan():
    rng = np.random.default_rng(8)
    T = 3000
    S = np.broadcast_to(np.eye(2), (T, 2, 2)).copy()
    nu = rng.standard_normal((T, 2))
    full = C.check_innovations(nu, S)
    gappy = nu.copy()
    gappy[::10] = np.nan
    r = C.check_innovations(gappy, S)
    assert r.n_steps == T - T // 10 and full.n_steps == T
    assert r.mean_nis == pytest.approx(np.mean(np.sum(nu[np.arange(T) % 10 != 0] ** 2, axis=1)))
    gappy[5, 0] = np.nan  # partially missing row
    with pytest.raises(ValueError, match="non-finite"):
        C.check_innovations(gappy, S)


def test_state_error_check_leaves_out_undefined_nees_steps():
    rng = np.random.default_rng(9)
    T, n = 400, 3
    P = np.broadcast_to(np.diag([1.0, 2.0, 0.5]), (T, n, n))
    err = rng.standard_normal((T, n)) * np.sqrt(np.diag(P[0]))
    nees = C.normalised_squared(err, P)
    gappy = nees.copy()
    gappy[::4] = np.nan  # steps where the NEES could not be computed
    r = C.state_error_check(gappy, err, np.diagonal(P, axis1=1, axis2=2))
    keep = np.arange(T) % 4 != 0
    assert r.n_steps == keep.sum()
    assert r.mean_nees == pytest.approx(nees[keep].mean(), rel=1e-12)
    # chi-square interval of the mean of 300 chi2_3 variables: 900 degrees of freedom
    lo, hi = stats.chi2.ppf([0.025, 0.975], 3 * keep.sum()) / keep.sum()
    assert r.nees_interval == pytest.approx((lo, hi), rel=1e-12)
    # NaN steps are not counted as outside the ellipsoid
    assert r.ellipsoid_fraction == pytest.approx(np.mean(nees[keep] <= 9.0), rel=1e-12)
    assert r.median_nees == pytest.approx(np.median(nees[keep]))
    assert r.max_nees == pytest.approx(nees[keep].max())
    # the full-P entry point gives the same numbers on the finite steps
    full = C.check_state_errors(err[keep], P[keep])
    assert full.mean_nees == pytest.approx(r.mean_nees) and full.nees_interval == r.nees_interval
    with pytest.raises(ValueError, match="no finite step"):
        C.state_error_check(np.full(T, np.nan), err, np.diagonal(P, axis1=1, axis2=2))
    with pytest.raises(ValueError, match="step 2"):
        C.state_error_check(np.r_[1.0, 1.0, np.inf, np.ones(T - 3)], err,
                            np.diagonal(P, axis1=1, axis2=2))


def test_whiten_and_check_innovations_reject_bad_input():
    S = np.stack([np.eye(2), np.diag([1.0, -1.0])])
    with pytest.raises(ValueError, match=r"S: not positive definite at index \(1,\)"):
        C.whiten(np.ones((2, 2)), S)
    nu = np.random.default_rng(0).standard_normal((100, 2))
    S = np.broadcast_to(np.eye(2), (100, 2, 2))
    with pytest.raises(ValueError, match="whiteness_alpha"):
        C.check_innovations(nu, S, whiteness_alpha=0.0)
    with pytest.raises(ValueError, match="c must be"):
        C.bounds_coverage(nu, np.ones_like(nu), c=np.nan)
