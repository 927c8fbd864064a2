"""The estimator contract: Posterior (against numpy's weighted moments and Gaussian sampling),
every filter returning FilterResult posteriors and running the same per-step API (against the
exact Kalman filter on a linear-Gaussian model, and against each filter's own ``filter``)."""

from __future__ import annotations

import numpy as np
import pytest

from rulkit.estimation import particle
from rulkit.estimation.base import Estimator, FilterResult, Posterior, gaussian_samples
from rulkit.estimation.ekf import ExtendedKalmanFilter
from rulkit.estimation.kalman import KalmanFilter
from rulkit.estimation.particle import ParticleFilter
from rulkit.estimation.ukf import UnscentedKalmanFilter
from rulkit.model import GaussianNoise, StateSpaceModel


class Walk(StateSpaceModel):
    """Linear-Gaussian [level, rate]: the exact Kalman filter is every filter's oracle."""

    state_names, output_names, dt = ("level", "rate"), ("y",), 1.0
    F = np.array([[1.0, 1.0], [0.0, 1.0]])

    @property
    def noise(self) -> GaussianNoise:
        return GaussianNoise(Q=np.diag([1e-3, 1e-5]), R=np.array([[0.05]]))

    def step(self, x, u, t, dt, rng=None):
        out = x @ self.F.T
        return out if rng is None else out + self.noise.sample_process(len(x), rng)

    def output(self, x, u=None):
        return x[:, :1].copy()


MODEL = Walk()
PRIOR = Posterior(np.array([0.0, 0.1]), np.diag([0.5, 0.01]))


def _data(seed: int = 0, T: int = 25) -> np.ndarray:
    return MODEL.simulate(np.array([0.2, 0.12]), T, np.random.default_rng(seed)).y


def test_posterior_from_samples_matches_numpy_and_validates() -> None:
    rng = np.random.default_rng(1)
    x = rng.standard_normal((500, 3)) @ np.array([[1.0, 0.2, 0.0], [0, 1, 0.3], [0, 0, 2]])
    w = rng.random(500)
    post = Posterior.from_samples(x, w)
    np.testing.assert_allclose(post.mean, np.average(x, axis=0, weights=w), rtol=1e-12)
    np.testing.assert_allclose(post.cov, np.cov(x.T, aweights=w, bias=True), rtol=1e-10)
    np.testing.assert_allclose(post.weights, w / w.sum(), rtol=1e-14)
    np.testing.assert_allclose(post.std, np.sqrt(np.diag(post.cov)))
    assert not post.samples.flags.writeable and not post.weights.flags.writeable
    assert post.with_samples(10, rng) is post  # samples already there: themselves
    with pytest.raises(ValueError, match="weights: given without samples"):
        Posterior(np.zeros(2), np.eye(2), weights=np.ones(2))
    with pytest.raises(ValueError, match=r"samples: expected shape \(N, 2\)"):
        Posterior(np.zeros(2), np.eye(2), samples=np.zeros((4, 3)))
    with pytest.raises(ValueError, match="weights: all zero"):
        Posterior.from_samples(x[:2], [0.0, 0.0])


def test_gaussian_posterior_samples_have_its_moments() -> None:
    cov = np.array([[2.0, 0.6], [0.6, 0.5]])
    post = Posterior(np.array([1.0, -3.0]), cov)
    drawn = post.with_samples(200_000, np.random.default_rng(2))
    assert drawn.samples.shape == (200_000, 2) and np.ptp(drawn.weights) == 0
    se = np.sqrt(np.diag(cov) / 200_000)
    assert np.all(np.abs(drawn.mean - post.mean) < 5 * se)
    np.testing.assert_allclose(drawn.cov, cov, rtol=0.02, atol=0.01)
    singular = gaussian_samples([0.0, 0.0], [[1.0, 1.0], [1.0, 1.0]], 1000,
                                np.random.default_rng(3))
    np.testing.assert_allclose(singular[:, 0], singular[:, 1], atol=1e-12)  # in the range


def _filters() -> dict[str, Estimator]:
    return {"kf": KalmanFilter(MODEL.F, [[1.0, 0.0]], MODEL.noise.Q, MODEL.noise.R),
            "ekf": ExtendedKalmanFilter.from_model(MODEL),
            "ukf": UnscentedKalmanFilter.from_model(MODEL),
            "pf": ParticleFilter.from_model(MODEL)}


def test_every_filter_returns_posteriors_of_one_kind() -> None:
    """One call shape per filter, one result contract: the posterior of step k is a Posterior
    that agrees with the exact Kalman filter (EKF/UKF to round-off, PF within Monte Carlo
    error); only the particle filter's carries weighted samples."""
    ys = _data()
    rng = np.random.default_rng(4)
    exact = KalmanFilter(MODEL.F, [[1.0, 0.0]], MODEL.noise.Q, MODEL.noise.R).filter(ys, PRIOR)
    for name, f in _filters().items():
        prior = PRIOR.with_samples(20_000, rng) if name == "pf" else PRIOR
        res = (f.filter(ys, prior, rng, keep_particles=True) if name == "pf"
               else f.filter(ys, prior))
        assert isinstance(res, FilterResult) and res.n_steps == len(ys)
        means, _ = res.moments()
        for k in (4, None):
            post, ref = res.posterior(k), exact.posterior(k)
            assert isinstance(post, Posterior)
            if name == "pf":
                assert post.samples is not None and post.weights is not None
                sd = np.sqrt(np.diag(ref.cov))
                assert np.all(np.abs(post.mean - ref.mean) < 0.1 * sd)
            else:
                assert post.samples is None
                np.testing.assert_allclose(post.mean, ref.mean, rtol=1e-9, atol=1e-12)
                np.testing.assert_allclose(post.cov, ref.cov, rtol=1e-7, atol=1e-12)
        np.testing.assert_array_equal(means[-1], res.posterior().mean)


@pytest.mark.parametrize("name", ["kf", "ekf", "ukf", "pf"])
def test_per_step_api_is_the_filter(name: str) -> None:
    """``initialise`` / ``step`` / ``posterior`` give what ``filter`` gives, step by step (the
    same numbers: one loop), for every filter."""
    ys = _data(5, 15)
    ys[6] = np.nan  # a missing measurement: the update is skipped in both
    f = _filters()[name]
    prior = PRIOR.with_samples(300, np.random.default_rng(6)) if name == "pf" else PRIOR
    ref = (f.filter(ys, prior, np.random.default_rng(7)) if name == "pf"
           else f.filter(ys, prior))
    state = f.initialise(prior, np.random.default_rng(7))
    np.testing.assert_allclose(state.posterior().mean, prior.mean, rtol=1e-14)
    for k, y in enumerate(ys):
        f.step(state, y)
        assert state.k == k
        np.testing.assert_array_equal(state.posterior().mean, ref.moments()[0][k])
    np.testing.assert_array_equal(state.posterior().cov, ref.posterior().cov)


def test_kalman_results_give_each_units_posterior() -> None:
    ys = np.stack([_data(8), _data(9)], axis=1)  # (T, 2 units, 1)
    res = KalmanFilter(MODEL.F, [[1.0, 0.0]], MODEL.noise.Q, MODEL.noise.R).filter(
        ys, np.stack([PRIOR.mean] * 2), PRIOR.cov)
    for b in (0, 1):
        one = KalmanFilter(MODEL.F, [[1.0, 0.0]], MODEL.noise.Q, MODEL.noise.R).filter(
            ys[:, b], PRIOR)
        np.testing.assert_allclose(res.posterior(3, unit=b).mean, one.posterior(3).mean,
                                   rtol=1e-12)
    with pytest.raises(ValueError, match=r"unit: expected a unit in \[0, 1\], got 2"):
        res.posterior(unit=2)
    with pytest.raises(ValueError, match="P0: the prior posterior carries its own covariance"):
        KalmanFilter(MODEL.F, [[1.0, 0.0]], MODEL.noise.Q, MODEL.noise.R).filter(
            ys[:, 0], PRIOR, np.eye(2))


def test_weights_travel_with_particles_not_in_a_registry() -> None:
    """Which weights belong to a particle array is never guessed from the array's identity:
    there is no registry, and a particle filter's result hands out its particles only inside
    a Posterior together with their weights."""
    assert not hasattr(particle, "weights_of") and not hasattr(particle, "_WEIGHTED")
    pf = ParticleFilter.from_model(MODEL)
    with pytest.raises(ValueError, match=r"prior: a Gaussian posterior has no particles"):
        pf.filter(_data(), PRIOR, np.random.default_rng(0))
    res = pf.filter(_data(), PRIOR.with_samples(200, np.random.default_rng(0)),
                    np.random.default_rng(0))
    assert not hasattr(res, "particles") and not hasattr(res, "weights")
    final = res.posterior()
    assert final.samples.shape == (200, 2) and final.weights.shape == (200,)
