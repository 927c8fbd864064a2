"""Guards of the engine's public functions: a non-finite or absurd input is a ``ValueError``
that names the argument, before any work is done, and messages print plain numbers
(``250.0``, never ``np.float64(250.0)``).

Each case is one call with one bad argument; the check is the exception type, the argument
named at the start of the message (or the fragment given), and no numpy repr in it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

import rulkit
from rulkit import metrics, plot
from rulkit.integrate import integrate
from rulkit.model import GaussianNoise, StateSpaceModel

NAN, INF = math.nan, math.inf
RNG = np.random.default_rng(0)


class Ramp(StateSpaceModel):
    state_names, output_names, threshold, dt = ("d", "r"), ("y",), 1.0, 1.0

    @property
    def noise(self) -> GaussianNoise:
        return GaussianNoise(Q=np.diag([1e-6, 1e-8]), R=np.array([[1e-4]]))

    def step(self, x, u, t, dt, rng=None):
        return np.column_stack([x[:, 0] + x[:, 1] * dt, x[:, 1]])

    def output(self, x, u=None):
        return x[:, :1].copy()

    def health(self, x):
        return x[:, 0]


M = Ramp()
YS = 0.01 * np.arange(1.0, 21.0)[:, None]
X2 = np.column_stack([np.zeros(5), np.full(5, 0.01)])
DISTS = [rulkit.RULDistribution(np.array([5.0, 6.0, 7.0])) for _ in range(2)]


def _post(**kw: Any) -> Any:
    return rulkit.Posterior(**{"mean": np.zeros(2), "cov": np.eye(2), **kw})


def _profile(**kw: Any) -> Any:
    args = dict(times=[5.0, 10.0], horizon=50.0, rng=RNG, P0=np.eye(2) * 1e-4)
    return rulkit.prognosis_profile(M, YS, "ekf", np.array([0.0, 0.01]), **{**args, **kw})


def _propagate(**kw: Any) -> Any:
    args = dict(model=M, horizon=50.0, rng=RNG)
    return rulkit.propagate_to_threshold(kw.pop("x0", X2), **{**args, **kw})


def _fit(**kw: Any) -> Any:
    args = dict(x0=[0.0, 0.01], P0=np.eye(2) * 1e-4)
    return rulkit.fit_parameters(lambda r: Ramp(), [YS], kw.pop("params", {"r": 1.0}),
                                 **{**args, **kw})


CASES: list[tuple[str, Callable[[], Any]]] = [
    ("mean", lambda: _post(mean=np.array([0.0, NAN]))),
    ("cov", lambda: _post(cov=np.array([[1.0, 0.0], [0.0, INF]]))),
    ("cov", lambda: _post(cov=-np.eye(2))),
    ("weights", lambda: _post(samples=np.zeros((3, 2)), weights=np.array([1.0, -1.0, 1.0]))),
    ("samples", lambda: rulkit.Posterior.from_samples(np.array([[0.0, NAN]]))),
    ("n_samples", lambda: _post().with_samples(0, RNG)),
    ("particles0", lambda: rulkit.ParticleFilter.from_model(M).filter(
        YS, np.full((10, 2), NAN), RNG)),
    ("ys", lambda: rulkit.ParticleFilter.from_model(M).filter(np.full((3, 1), INF),
                                                              np.zeros((10, 2)), RNG)),
    ("quantiles", lambda: rulkit.ParticleFilter.from_model(M).filter(
        YS, np.zeros((10, 2)), RNG, quantiles=[np.float64(1.5)])),
    ("ess_threshold", lambda: rulkit.ParticleFilter.from_model(M, ess_threshold=NAN)),
    ("x0", lambda: rulkit.ExtendedKalmanFilter.from_model(M).filter(YS, [NAN, 0.0],
                                                                    np.eye(2))),
    ("P0", lambda: rulkit.UnscentedKalmanFilter.from_model(M).filter(YS, [0.0, 0.0],
                                                                     np.eye(2) * NAN)),
    ("Q", lambda: rulkit.ExtendedKalmanFilter.from_model(M, Q=np.diag([INF, 1.0]))),
    ("alpha", lambda: rulkit.UnscentedKalmanFilter.from_model(M, alpha=NAN)),
    ("x0", lambda: _propagate(x0=np.array([[0.0, NAN]]))),
    ("dt", lambda: _propagate(dt=NAN)),
    ("dt", lambda: _propagate(dt=np.float64(1e-9))),
    ("horizon", lambda: _propagate(horizon=INF)),
    ("t0", lambda: _propagate(t0=NAN)),
    ("threshold", lambda: _propagate(threshold=NAN)),
    ("kappa", lambda: rulkit.unscented_rul(_post(), M, horizon=10.0, kappa=NAN)),
    ("n_samples", lambda: rulkit.monte_carlo_rul(_post(), M, horizon=10.0, rng=RNG,
                                                 n_samples=-5)),
    ("samples", lambda: rulkit.RULDistribution(np.array([1.0, NAN]))),
    ("weights", lambda: rulkit.RULDistribution(np.array([1.0, 2.0]), weights=[1.0, INF])),
    ("horizon", lambda: rulkit.RULDistribution(np.array([1.0]), horizon=np.float64(NAN))),
    ("times", lambda: _profile(times=[5.0, NAN])),
    ("times", lambda: _profile(times=[np.float64(5.5)])),
    ("P0", lambda: _profile(P0=np.eye(2) * NAN)),
    ("prior", lambda: rulkit.prognosis_profile(M, YS, "ekf", np.array([NAN, 0.0]),
                                               P0=np.eye(2), times=[5.0], horizon=5.0,
                                               rng=RNG)),
    ("params", lambda: _fit(params={"r": NAN})),
    ("params", lambda: _fit(params={"r": np.float64(-2.0)})),
    ("x0", lambda: _fit(x0=[INF, 0.0])),
    ("P0", lambda: _fit(P0=np.eye(2) * NAN)),
    ("n_particles", lambda: _fit(method="pf", n_particles=0)),
    ("bounds", lambda: _fit(bounds={"r": (2.0, 1.0)})),
    ("records[0]", lambda: rulkit.fit_parameters(lambda r: Ramp(), [np.full((4, 1), NAN)],
                                                 {"r": 1.0}, x0=[0.0, 0.01], P0=np.eye(2))),
    ("t_eol", lambda: rulkit.alpha_lambda([1.0, 2.0], DISTS, np.float64(NAN))),
    ("alpha", lambda: rulkit.alpha_lambda([1.0, 2.0], DISTS, 10.0, alpha=NAN)),
    ("lam", lambda: rulkit.alpha_lambda([1.0, 2.0], DISTS, 10.0, lam=np.float64(2.0))),
    ("beta", lambda: rulkit.prognostic_horizon([1.0, 2.0], DISTS, 10.0, beta=NAN)),
    ("times", lambda: rulkit.prognostic_horizon([1.0, NAN], DISTS, 10.0)),
    ("rul_pred", lambda: rulkit.relative_accuracy(NAN, 10.0)),
    ("rul_true", lambda: rulkit.crps_rul(DISTS[0], np.float64(INF))),
    ("samples", lambda: rulkit.crps_samples([1.0, NAN], 2.0)),
    ("truth", lambda: rulkit.interval_coverage([0.0], [1.0], [NAN])),
    ("metric", lambda: rulkit.convergence([0.0, 1.0], [1.0, NAN])),
    ("weights", lambda: rulkit.cumulative_relative_accuracy([9.0, 8.0], [10.0, 9.0],
                                                            weights=[1.0, NAN])),
    ("mu", lambda: metrics.crps_normal(NAN, 1.0, 0.0)),
    ("x0", lambda: M.simulate(np.array([NAN, 0.0]), 5, RNG)),
    ("n_steps", lambda: M.simulate(np.zeros(2), 0, RNG)),
    ("dt", lambda: M.simulate(np.zeros(2), 5, RNG, dt=NAN)),
    ("Q", lambda: GaussianNoise(Q=np.array([[NAN]]), R=np.eye(1))),
    ("dt", lambda: integrate(lambda x, t, u: x, np.zeros((2, 1)), 0.0, NAN, 3)),
    ("t", lambda: plot.state_estimates([0.0, NAN], np.zeros(2))),
    ("alpha", lambda: plot.alpha_lambda_cone([0.0, 1.0], [9.0, 8.0], 10.0, alpha=NAN)),
]


@pytest.mark.parametrize(("name", "call"), CASES,
                         ids=[f"{i}-{n}" for i, (n, _) in enumerate(CASES)])
def test_bad_input_is_a_value_error_naming_the_argument(name: str, call: Callable[[], Any]
                                                        ) -> None:
    with pytest.raises(ValueError) as err:
        call()
    message = str(err.value)
    assert message.startswith(f"{name}:") or f" {name}:" in message, message
    for numpy_repr in ("np.float64(", "np.int64(", "array(", "np.True_", "np.False_"):
        assert numpy_repr not in message, message
