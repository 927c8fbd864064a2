"""alpha-beta(-gamma) trackers against the steady-state Kalman filter from
scipy.linalg.solve_discrete_are, the (corrected) closed forms of the seed, and per-unit loops."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from rulkit.estimation.kalman import kf_update
from rulkit.estimation.trackers import (
    alpha_beta_gains,
    alpha_beta_gamma_gains,
    alpha_beta_gamma_update,
    alpha_beta_update,
    tracking_index,
)

LAMS = np.logspace(-4, 3, 36)


def cv_ca_model(order, dt, sigma_w, sigma_v):
    """Constant-velocity (order 2) / constant-acceleration (order 3) model with the noise
    convention defining lambda = sigma_w dt^2 / sigma_v (trackers module docstring)."""
    if order == 2:
        F = np.array([[1.0, dt], [0.0, 1.0]])
        G = np.array([dt**2 / 2, dt])
    else:
        F = np.array([[1.0, dt, dt**2 / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
        G = np.array([dt**2 / 2, dt, 1.0])
    H = np.zeros((1, order))
    H[0, 0] = 1.0
    return F, H, sigma_w**2 * np.outer(G, G), np.array([[sigma_v**2]])


def dare_gains(lam, order, dt=1.0, sigma_v=1.0):
    """Steady-state Kalman gain scaled to (alpha, beta, gamma) = K * [1, dt, dt^2]."""
    sigma_w = lam * sigma_v / dt**2
    F, H, Q, R = cv_ca_model(order, dt, sigma_w, sigma_v)
    P = scipy.linalg.solve_discrete_are(F.T, H.T, Q, R)  # predicted (prior) covariance
    K = (P @ H.T / (H @ P @ H.T + R)).ravel()
    return K * dt ** np.arange(order), P


@pytest.mark.parametrize(("dt", "sigma_v"), [(1.0, 1.0), (0.3, 2.5), (24.0, 0.01)])
def test_alpha_beta_gains_equal_dare_steady_state(dt, sigma_v):
    alpha, beta = alpha_beta_gains(LAMS)
    ref = np.array([dare_gains(lam, 2, dt, sigma_v)[0] for lam in LAMS])
    np.testing.assert_allclose(alpha, ref[:, 0], rtol=1e-12, atol=0)
    np.testing.assert_allclose(beta, ref[:, 1], rtol=1e-12, atol=0)


@pytest.mark.parametrize(("dt", "sigma_v"), [(1.0, 1.0), (0.3, 2.5), (24.0, 0.01)])
def test_alpha_beta_gamma_gains_equal_dare_steady_state(dt, sigma_v):
    alpha, beta, gamma = alpha_beta_gamma_gains(LAMS)
    ref = np.array([dare_gains(lam, 3, dt, sigma_v)[0] for lam in LAMS])
    np.testing.assert_allclose(alpha, ref[:, 0], rtol=1e-12, atol=0)
    np.testing.assert_allclose(beta, ref[:, 1], rtol=1e-12, atol=0)
    np.testing.assert_allclose(gamma, ref[:, 2], rtol=1e-12, atol=0)


def test_gains_satisfy_textbook_relations_and_seed_forms():
    alpha, beta = alpha_beta_gains(LAMS)
    # Kalata (1984): lambda^2 = beta^2 / (1 - alpha); seed eq 15 in its printed form
    np.testing.assert_allclose(beta**2 / (1 - alpha), LAMS**2, rtol=1e-10)
    np.testing.assert_allclose(beta, 2 * (2 - alpha) - 4 * np.sqrt(1 - alpha), rtol=1e-6)
    a3, b3, g3 = alpha_beta_gamma_gains(LAMS)
    np.testing.assert_allclose(g3, b3**2 / (2 * a3), rtol=1e-13)
    # s is a root of the seed's cubic s^3 + b s^2 + c s - 1 = 0
    # (s from beta = 2 (1 - s)^2: 1 - alpha = s^2 would cancel for large lambda)
    s = 1 - np.sqrt(b3 / 2)
    np.testing.assert_allclose(s**2, 1 - a3, rtol=1e-15, atol=1e-15)
    b, c = LAMS / 2 - 3, LAMS / 2 + 3
    resid = s**3 + b * s**2 + c * s - 1.0
    eps = np.finfo(float).eps  # bound: rounding of the terms and of s itself
    bound = 8 * eps * (s**3 + np.abs(b) * s**2 + c * s + 1.0 + np.abs(3 * s**2 + 2 * b * s + c))
    assert np.all(np.abs(resid) <= bound)
    np.testing.assert_allclose(b3, 2 * (1 - s) ** 2, rtol=1e-8)


def cardano_corrected(lam):
    """The seed's eqs 17-23 with the two misprints corrected (spec section 2)."""
    b, c = lam / 2 - 3, lam / 2 + 3
    p = c - b**2 / 3
    q = 2 * b**3 / 27 - b * c / 3 - 1
    v = np.sqrt(q**2 + 4 * p**3 / 27)
    z = -np.cbrt((q + v) / 2)
    return z - p / (3 * z) - b / 3


def test_corrected_cardano_agrees_where_it_is_defined_and_fails_beyond():
    lam = np.logspace(-2, np.log10(15.0), 20)
    s = cardano_corrected(lam)
    a3, _, _ = alpha_beta_gamma_gains(lam)
    np.testing.assert_allclose(1 - s**2, a3, rtol=1e-8)
    with np.errstate(invalid="ignore"):
        assert np.isnan(cardano_corrected(np.array([50.0, 1000.0]))).all()
    # ours stays finite and in range there
    a, b, g = alpha_beta_gamma_gains(np.array([50.0, 1000.0]))
    assert np.all((0 < a) & (a < 1) & (0 < b) & (b < 2) & (g > 0))


def test_scalar_and_vector_lambda_agree():
    a, b = alpha_beta_gains(LAMS)
    a3, b3, g3 = alpha_beta_gamma_gains(LAMS)
    for i in (0, 7, 20, 35):
        sa, sb = alpha_beta_gains(float(LAMS[i]))
        assert isinstance(sa, float) and sa == a[i] and sb == b[i]
        assert alpha_beta_gamma_gains(float(LAMS[i])) == (a3[i], b3[i], g3[i])
    a2d, _ = alpha_beta_gains(LAMS.reshape(6, 6))
    np.testing.assert_array_equal(a2d.ravel(), a)


def test_tracking_index_and_validation():
    assert tracking_index(2.0, 0.5, 3.0) == pytest.approx(2.0 * 9.0 / 0.5, rel=1e-15)
    np.testing.assert_allclose(tracking_index(np.array([1.0, 2.0]), 1.0, 0.5), [0.25, 0.5])
    for bad in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(ValueError, match="lam"):
            alpha_beta_gains(bad)
        with pytest.raises(ValueError, match="lam"):
            alpha_beta_gamma_gains(np.array([1.0, bad]))
        with pytest.raises(ValueError, match="sigma_v"):
            tracking_index(1.0, bad, 1.0)
    with pytest.raises(ValueError, match="dt"):
        tracking_index(1.0, 1.0, 0.0)


def loop_ab(state, z, dt, alpha, beta):
    out = state.copy()
    for i in range(len(z)):
        f, d = out[i]
        f = f + d * dt[i]
        r = z[i] - f
        f = f + alpha[i] * r
        d = d + beta[i] * r / dt[i]
        out[i] = f, d
    return out


def loop_abg(state, z, dt, alpha, beta, gamma):
    out = state.copy()
    for i in range(len(z)):
        f, d, a = out[i]
        f = f + d * dt[i] + a * dt[i] * dt[i] / 2
        d = d + a * dt[i]
        r = z[i] - f
        f = f + alpha[i] * r
        d = d + beta[i] * r / dt[i]
        a = a + gamma[i] * r / (dt[i] * dt[i])
        out[i] = f, d, a
    return out


def test_updates_equal_per_unit_loop_with_per_unit_gains_and_dt():
    rng = np.random.default_rng(11)
    B = 50
    lam = 10 ** rng.uniform(-3, 2, B)
    dt = rng.uniform(0.1, 5.0, B)
    z = rng.normal(size=B)
    s2 = rng.normal(size=(B, 2))
    s3 = rng.normal(size=(B, 3))
    a, b = alpha_beta_gains(lam)
    a3, b3, g3 = alpha_beta_gamma_gains(lam)
    np.testing.assert_allclose(
        alpha_beta_update(s2, z, dt, a, b), loop_ab(s2, z, dt, a, b), rtol=1e-14, atol=1e-14
    )
    np.testing.assert_allclose(
        alpha_beta_gamma_update(s3, z, dt, a3, b3, g3),
        loop_abg(s3, z, dt, a3, b3, g3),
        rtol=1e-13,
        atol=1e-13,
    )
    # scalar dt and gains broadcast to every unit
    ones = np.ones(B)
    np.testing.assert_allclose(
        alpha_beta_update(s2, z, 2.0, 0.3, 0.05),
        loop_ab(s2, z, 2 * ones, 0.3 * ones, 0.05 * ones),
        rtol=1e-14,
        atol=1e-14,
    )


@pytest.mark.parametrize("order", [2, 3])
def test_update_equals_steady_state_kalman_update(order):
    rng = np.random.default_rng(12)
    B = 6
    lam = np.array([1e-3, 0.05, 1.0, 7.0, 60.0, 500.0])
    dt = np.array([0.5, 1.0, 2.0, 0.1, 3.0, 1.0])
    sigma_v = 0.7
    state = rng.normal(size=(B, order))
    z = rng.normal(size=B)
    if order == 2:
        gains = alpha_beta_gains(lam)
        new = alpha_beta_update(state, z, dt, *gains)
    else:
        gains = alpha_beta_gamma_gains(lam)
        new = alpha_beta_gamma_update(state, z, dt, *gains)
    for b in range(B):
        _, P = dare_gains(lam[b], order, dt[b], sigma_v)
        F, H, _, R = cv_ca_model(order, dt[b], lam[b] * sigma_v / dt[b] ** 2, sigma_v)
        xp = state[b : b + 1] @ F.T
        xk, _, _ = kf_update(xp, P[None], z[b : b + 1, None], H, R)
        np.testing.assert_allclose(new[b], xk[0], rtol=1e-10, atol=1e-12)


def test_missing_and_bad_measurements():
    s = np.array([[1.0, 0.5, 0.1], [2.0, -1.0, 0.0]])
    z = np.array([np.nan, 2.5])
    out = alpha_beta_gamma_update(s, z, 2.0, 0.5, 0.2, 0.02)
    np.testing.assert_allclose(out[0], [1.0 + 0.5 * 2 + 0.1 * 2, 0.5 + 0.1 * 2, 0.1])
    np.testing.assert_allclose(
        out[1], alpha_beta_gamma_update(s[1:], z[1:], 2.0, 0.5, 0.2, 0.02)[0]
    )
    np.testing.assert_array_equal(s, [[1.0, 0.5, 0.1], [2.0, -1.0, 0.0]])  # not modified
    out2 = alpha_beta_update(s[:, :2], z, 2.0, 0.5, 0.2)
    np.testing.assert_allclose(out2[0], [2.0, 0.5])
    with pytest.raises(ValueError, match="z: infinite value at unit 1"):
        alpha_beta_update(s[:, :2], np.array([1.0, np.inf]), 1.0, 0.5, 0.2)
    with pytest.raises(ValueError, match=r"z: expected shape \(2,\)"):
        alpha_beta_update(s[:, :2], np.array([1.0]), 1.0, 0.5, 0.2)
    with pytest.raises(ValueError, match=r"state: expected shape \(B, 3\)"):
        alpha_beta_gamma_update(s[:, :2], z, 1.0, 0.5, 0.2, 0.1)


@pytest.mark.parametrize("dt", [0.0, -1.0, np.nan, np.inf])
def test_bad_dt_is_refused(dt):
    with pytest.raises(ValueError, match="dt"):
        alpha_beta_update(np.zeros((3, 2)), np.zeros(3), dt, 0.5, 0.1)
    with pytest.raises(ValueError, match="dt"):
        alpha_beta_gamma_update(np.zeros((3, 3)), np.zeros(3), dt, 0.5, 0.1, 0.01)


def test_bad_gains_are_refused():
    with pytest.raises(ValueError, match="alpha"):
        alpha_beta_update(np.zeros((3, 2)), np.zeros(3), 1.0, np.nan, 0.1)
    with pytest.raises(ValueError, match="gamma"):
        alpha_beta_gamma_update(np.zeros((3, 3)), np.zeros(3), 1.0, 0.5, 0.1, np.ones(2))
