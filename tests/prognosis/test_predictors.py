"""Unscented-transform and Monte Carlo RUL predictors, against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rulkit import Posterior, monte_carlo_rul, unscented_rul
from rulkit.prognosis.predictors import sigma_points


class Ramp:
    """damage += rate dt (noise-free when rng is None); failure at damage >= 1."""

    dt = 0.25
    threshold = 1.0

    def __init__(self, q: float = 0.0) -> None:
        self.q = q

    def step(self, x, u, t, dt, rng=None):
        out = x.copy()
        out[:, 0] += x[:, 1] * dt
        if rng is not None and self.q:
            out[:, 0] += self.q * math.sqrt(dt) * rng.standard_normal(x.shape[0])
        return out

    def health(self, x):
        return x[:, 0]


@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_sigma_points_reproduce_mean_and_covariance(n: int) -> None:
    rng = np.random.default_rng(n)
    A = rng.standard_normal((n, n))
    P = A @ A.T + 0.1 * np.eye(n)
    m = rng.standard_normal(n)
    pts, w = sigma_points(m, P)
    assert pts.shape == (2 * n + 1, n) and np.all(w >= 0) and w.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(w @ pts, m, atol=1e-12)
    d = pts - m
    np.testing.assert_allclose((d.T * w) @ d, P, rtol=1e-10, atol=1e-12)
    with pytest.raises(ValueError, match="kappa"):
        sigma_points(m, P, kappa=-1.0)


def test_unscented_rul_is_exact_for_a_linear_time_of_event() -> None:
    """With a known rate r the time to failure (1 - d) / r is linear in the damage d, so the
    unscented mean and standard deviation are exact: (1 - m_d) / r and sd_d / r."""
    m = np.array([0.3, 0.02])
    P = np.diag([0.05**2, 0.0])
    dist = unscented_rul(Posterior(m, P), Ramp(), horizon=200.0)
    assert dist.n == 5 and dist.n_censored == 0
    assert dist.mean == pytest.approx((1 - 0.3) / 0.02, rel=1e-9)
    assert dist.std == pytest.approx(0.05 / 0.02, rel=1e-9)


def test_unscented_rul_close_to_monte_carlo_for_an_uncertain_rate() -> None:
    """Time of event (1 - d) / r is nonlinear in r: the unscented mean is second-order accurate
    (relative error O(cv^2) with cv = sd_r / r = 5 %)."""
    m, P = np.array([0.3, 0.02]), np.diag([0.02**2, 0.001**2])
    ut = unscented_rul(Posterior(m, P), Ramp(), horizon=200.0)
    mc = monte_carlo_rul(Posterior(m, P), Ramp(), n_samples=40_000, horizon=200.0,
                         rng=np.random.default_rng(0))
    se = mc.std / math.sqrt(mc.n)
    assert abs(ut.mean - mc.mean) < 4 * se + 0.01 * mc.mean
    assert ut.std == pytest.approx(mc.std, rel=0.05)


def test_monte_carlo_rul_of_weighted_particles_keeps_their_weights() -> None:
    x = np.column_stack([np.zeros(3), [0.1, 0.2, 0.5]])
    w = np.array([0.2, 0.3, 0.5])
    dist = monte_carlo_rul(Posterior.from_samples(x, w), Ramp(), horizon=50.0,
                           rng=np.random.default_rng(0))
    np.testing.assert_allclose(dist.samples, [10.0, 5.0, 2.0])
    np.testing.assert_allclose(dist.weights, w)
    # a Gaussian posterior is sampled: n_samples draws, equally weighted
    g = monte_carlo_rul(Posterior(x.mean(axis=0), np.diag([0.0, 1e-4])), Ramp(),
                        n_samples=300, horizon=50.0, rng=np.random.default_rng(0))
    assert g.n == 300 and np.ptp(g.weights) == 0
    with pytest.raises(TypeError, match="expected a Posterior"):
        unscented_rul(x, Ramp(), horizon=50.0)
