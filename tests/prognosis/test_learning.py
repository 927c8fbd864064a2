"""Parameter learning (issue 10 item 5): known parameters recovered from simulated records."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from rulkit import GaussianNoise, StateSpaceModel, fit_parameters


@dataclass(frozen=True)
class Drift(StateSpaceModel):
    """[level, rate]: level += rate dt + N(0, q_l^2 dt); rate += N(0, q_r^2 dt); y = level + v."""

    q_l: float = 0.02
    q_r: float = 0.002
    sigma_y: float = 0.1
    dt: float = 1.0

    state_names = ("level", "rate")
    output_names = ("y",)

    @property
    def noise(self) -> GaussianNoise:
        return GaussianNoise(Q=np.diag([self.q_l**2, self.q_r**2]) * self.dt,
                             R=np.array([[self.sigma_y**2]]))

    def step(self, x, u, t, dt, rng=None):
        out = x.copy()
        out[:, 0] += x[:, 1] * dt
        if rng is not None:
            out += rng.standard_normal(x.shape) * np.array([self.q_l, self.q_r]) * math.sqrt(dt)
        return out

    def output(self, x, u=None):
        return x[:, :1].copy()

    def step_jacobian(self, x, u, t, dt):
        return np.broadcast_to(np.array([[1.0, dt], [0.0, 1.0]]), (x.shape[0], 2, 2))

    def output_jacobian(self, x, u=None):
        return np.broadcast_to(np.array([[1.0, 0.0]]), (x.shape[0], 1, 2))


TRUE = Drift()
M0, P0 = np.array([0.0, 0.05]), np.diag([0.1**2, 0.01**2])


def _records(n: int, T: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        x0 = M0 + np.sqrt(np.diag(P0)) * rng.standard_normal(2)
        out.append(TRUE.simulate(x0, T - 5 * i, rng).y)  # records of different lengths
    return out


def test_kalman_mle_recovers_known_noise_parameters_with_standard_errors() -> None:
    recs = _records(4, 100, 0)
    fit = fit_parameters(Drift(), recs, {"sigma_y": 0.3, "q_r": 0.01}, x0=M0, P0=P0,
                         method="ekf")
    assert fit.success
    for name in ("sigma_y", "q_r"):
        est, se, true = fit.params[name], fit.stderr[name], getattr(TRUE, name)
        assert 0 < se < 0.5 * true
        assert abs(est - true) < 3.5 * se, (name, est, se, true)
    assert fit.model.sigma_y == fit.params["sigma_y"]
    # the maximum is a maximum: moving off it lowers the likelihood
    from rulkit import ExtendedKalmanFilter

    def ll(**p):
        m = Drift(**{**fit.params, **p})
        return sum(float(ExtendedKalmanFilter.from_model(m).filter(y, M0, P0).loglik[0])
                   for y in recs)

    assert fit.loglik == pytest.approx(ll(), rel=1e-9)
    assert ll(sigma_y=fit.params["sigma_y"] * 1.1) < fit.loglik
    assert ll(sigma_y=fit.params["sigma_y"] * 0.9) < fit.loglik


def test_particle_filter_mle_with_common_random_numbers_agrees_with_kalman() -> None:
    recs = _records(2, 60, 1)
    kf = fit_parameters(Drift(), recs, {"sigma_y": 0.3}, x0=M0, P0=P0, method="ekf")
    pf = fit_parameters(Drift(), recs, {"sigma_y": 0.3}, x0=M0, P0=P0, method="pf",
                        n_particles=400, seed=3)
    assert pf.params["sigma_y"] == pytest.approx(kf.params["sigma_y"], rel=0.1)
    assert abs(pf.params["sigma_y"] - TRUE.sigma_y) < 3.5 * kf.stderr["sigma_y"]


def test_fit_parameters_errors() -> None:
    with pytest.raises(ValueError, match="log scale"):
        fit_parameters(Drift(), _records(1, 10, 0), {"sigma_y": -1.0}, x0=M0, P0=P0)
    with pytest.raises(ValueError, match=r"records\[1\]: ys: expected shape \(T, 1\)"):
        fit_parameters(Drift(), [np.zeros(5), np.zeros((5, 2))], {"sigma_y": 0.1}, x0=M0,
                       P0=P0)
