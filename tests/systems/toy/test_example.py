"""Tests of the toy degradation model and the engine's end-to-end example.

Oracles: a hand-written 2-state Kalman filter (the model is linear-Gaussian), scipy's normal
log-density, and the closed-form noise-free failure time (1 - damage) / rate.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from rulkit.systems.toy.example import ToyConfig, run, simulate_truth
from rulkit.systems.toy.model import ToyDegradation


def hand_kalman(ys, m0, P0, F, Q, sigma_y):
    """Plain textbook Kalman filter for y = damage + v (independent of rulkit.estimation)."""
    x, P = np.asarray(m0, float), np.asarray(P0, float)
    means, stds = [], []
    for y in ys:
        x = F @ x
        P = F @ P @ F.T + Q
        S = P[0, 0] + sigma_y**2
        K = P[:, 0] / S
        x = x + K * (y - x[0])
        P = P - np.outer(K, P[0, :])
        means.append(x.copy())
        stds.append(np.sqrt(np.diag(P)))
    return np.array(means), np.array(stds)


# ------------------------------------------------------------------ the model
def test_model_step_mean_and_noise_covariance():
    m = ToyDegradation(sigma_d=2e-3, sigma_r=3e-4, sigma_y=0.05)
    x = np.tile([0.3, 0.01], (200_000, 1))
    dt = 0.25
    nxt = m.step(x, None, 0.0, dt, np.random.default_rng(0))
    np.testing.assert_allclose(m.step(x[:1], None, 0.0, dt), [[0.3 + 0.01 * dt, 0.01]])
    np.testing.assert_allclose(nxt.mean(axis=0), [0.3 + 0.01 * dt, 0.01], atol=2e-5)
    c = np.cov(nxt.T)
    np.testing.assert_allclose(np.diag(c), np.diag(m.process_cov(dt)), rtol=0.02)
    assert abs(c[0, 1] / math.sqrt(c[0, 0] * c[1, 1])) < 0.01  # independent components
    np.testing.assert_allclose(m.noise.Q, np.diag([4e-6, 9e-8]))
    assert m.output(x[:2]).shape == (2, 1)


def test_model_log_likelihood_and_closed_form_rul():
    m = ToyDegradation(sigma_y=0.03)
    x = np.array([[0.1, 0.01], [0.5, 0.02], [1.1, 0.0], [0.5, -0.01]])
    np.testing.assert_allclose(m.log_likelihood(x, 0.12),
                               stats.norm(x[:, 0], 0.03).logpdf(0.12))
    np.testing.assert_allclose(m.rul_noise_free(x), [90.0, 25.0, 0.0, np.inf])
    with pytest.raises(ValueError, match="sigma_y"):
        ToyDegradation(sigma_y=0.0)
    with pytest.raises(ValueError, match="sigma_d"):
        ToyDegradation(sigma_d=np.nan)
    with pytest.raises(ValueError, match="x"):
        m.step(np.zeros((3, 3)), None, 0.0, 1.0)


def test_truth_without_noise_fails_at_the_closed_form_time():
    m = ToyDegradation(sigma_d=0.0, sigma_r=0.0, sigma_y=0.01, dt=0.7)
    _, x, ys, t_eol = simulate_truth(m, np.array([0.1, 0.013]), 20, np.random.default_rng(0))
    assert t_eol == pytest.approx(0.9 / 0.013, rel=1e-12)
    assert x.shape == (21, 2) and ys.shape == (20,)
    # the measurement noise is the model's
    assert np.std(ys - x[1:, 0]) == pytest.approx(0.01, rel=0.5)


# ------------------------------------------------------------------ the example
@pytest.fixture(scope="module")
def small_run():
    return run(ToyConfig(n_particles=1500, seed=4))


def test_particle_filter_matches_exact_kalman_filter(small_run):
    r = small_run
    cfg = r.config
    m = cfg.model()
    means, stds = hand_kalman(r.ys, cfg.prior_mean, np.diag(np.square(cfg.prior_std)),
                              m.transition_matrix(), m.noise.Q, cfg.sigma_y)
    # the experiment's own Kalman filter is the exact one
    np.testing.assert_allclose(r.kf_mean, means, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(r.kf_std, stds, rtol=1e-9)
    # particle filter within Monte Carlo error of it over the last 20 steps
    sl = slice(-20, None)
    assert np.all(np.abs(r.pf_mean[sl] - means[sl]) < 0.3 * stds[sl])
    np.testing.assert_allclose(r.pf_std[sl], stds[sl], rtol=0.2)


def test_rul_predictions_consistent_with_posterior(small_run):
    r = small_run
    assert len(r.ruls) == len(r.prediction_times) == 5
    np.testing.assert_allclose(r.rul_true, r.t_eol - r.prediction_times)
    for d in r.ruls:
        assert d.n == r.config.n_particles
        assert d.fraction_censored == 0.0
    # at the last step, the median RUL is close to the noise-free time from the posterior mean
    # (process noise on the rate is small; the ratio is nearly linear there)
    m = r.config.model()
    d_mean = r.pf_mean[-1]
    approx = m.rul_noise_free(d_mean[None, :])[0]
    assert r.ruls[-1].median == pytest.approx(approx, rel=0.05)
    table = r.table()
    assert [row["t_pred"] for row in table] == r.prediction_times.tolist()
    assert all(math.isfinite(row["crps"]) for row in table)
    assert {"alpha_lambda", "prognostic_horizon", "cumulative_relative_accuracy"} <= set(
        r.metrics
    )


def test_example_is_reproducible_from_seed():
    cfg = ToyConfig(n_particles=300, n_steps=30, prediction_steps=(20, 30), seed=11)
    a, b = run(cfg), run(cfg)
    np.testing.assert_array_equal(a.ruls[-1].samples, b.ruls[-1].samples)
    np.testing.assert_array_equal(a.pf_mean, b.pf_mean)
    c = run(ToyConfig(n_particles=300, n_steps=30, prediction_steps=(20, 30), seed=12))
    assert not np.array_equal(a.ys, c.ys)
    with pytest.raises(ValueError, match="prediction_steps"):
        run(ToyConfig(n_steps=10, prediction_steps=(20,)))


def test_rul_intervals_are_calibrated_over_seeds():
    # 90 % predictive intervals at t = 40 should cover the true RUL of ~90 % of independent
    # units (PF ~ exact posterior, future process noise propagated). 200 seeds: binomial
    # SE 0.021; the band is +-2.4 SE. Ignoring the rate uncertainty or the future noise
    # would drop the coverage far below it.
    hits = []
    for s in range(200):
        r = run(ToyConfig(n_particles=500, n_steps=40, prediction_steps=(40,), seed=100 + s))
        lo, hi = r.ruls[0].interval(0.9)
        hits.append(lo <= r.rul_true[0] <= hi)
    assert 0.85 <= np.mean(hits) <= 0.95


@pytest.mark.parametrize("dt", [1.0, 0.1, 0.37])
def test_model_step_is_f_x_plus_scaled_standard_normals(dt):
    """The column-wise step equals ``F x + diag(sigma sqrt(dt)) z`` with the same N(0, 1)
    draws ``z`` (N x 2, row-major) as an independent matrix form (noise law unchanged)."""
    m = ToyDegradation(sigma_d=2e-3, sigma_r=3e-4)
    x = np.random.default_rng(5).normal([0.4, 0.01], [0.1, 0.002], (300, 2))
    x_before = x.copy()
    got = m.step(x, None, 0.0, dt, np.random.default_rng(6))
    z = np.random.default_rng(6).standard_normal((300, 2))
    want = x @ m.transition_matrix(dt).T + z * np.sqrt(np.diag(m.process_cov(dt)))
    np.testing.assert_allclose(got, want, rtol=1e-14, atol=1e-17)
    np.testing.assert_array_equal(x, x_before)  # the input batch is not modified
