"""rulkit: model-based prognostics.

Telemetry of a degrading machine -> Bayesian state and parameter estimation -> a Remaining
Useful Life (RUL) distribution, with metrics and alerts. Physics lives in models (a
:class:`StateSpaceModel` subclass, or a system under :mod:`rulkit.systems`); the algorithms in
:mod:`rulkit.estimation` and :mod:`rulkit.prognosis` know no physics and take a model as is::

    import rulkit
    sim = model.simulate(x0, n_steps=60, rng=rng)
    pf = rulkit.ParticleFilter.from_model(model)
    profile = rulkit.prognosis_profile(model, sim.y, pf, particles0, times=[20, 30], rng=rng)

The engine's API is documented once in docs/engine-api.md.
"""

from importlib.metadata import PackageNotFoundError, version

from rulkit.estimation.ekf import ExtendedKalmanFilter
from rulkit.estimation.kalman import KalmanFilter, KalmanResult
from rulkit.estimation.particle import ParticleFilter, ParticleFilterResult
from rulkit.estimation.ukf import UnscentedKalmanFilter
from rulkit.integrate import euler_step, ode_step, rk4_step
from rulkit.metrics import (
    alpha_lambda,
    convergence,
    crps_rul,
    crps_samples,
    cumulative_relative_accuracy,
    interval_coverage,
    prognostic_horizon,
    relative_accuracy,
)
from rulkit.model import GaussianNoise, Simulation, StateSpaceModel
from rulkit.prognosis.learning import ParameterFit, fit_parameters
from rulkit.prognosis.predictors import monte_carlo_rul, unscented_rul
from rulkit.prognosis.profile import PrognosisProfile, prognosis_profile
from rulkit.prognosis.rul import RULDistribution, propagate_to_threshold

try:
    __version__ = version("rulkit")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0.0.0+unknown"

__all__ = [
    "ExtendedKalmanFilter",
    "GaussianNoise",
    "KalmanFilter",
    "KalmanResult",
    "ParameterFit",
    "ParticleFilter",
    "ParticleFilterResult",
    "PrognosisProfile",
    "RULDistribution",
    "Simulation",
    "StateSpaceModel",
    "UnscentedKalmanFilter",
    "__version__",
    "alpha_lambda",
    "convergence",
    "crps_rul",
    "crps_samples",
    "cumulative_relative_accuracy",
    "euler_step",
    "fit_parameters",
    "interval_coverage",
    "monte_carlo_rul",
    "ode_step",
    "prognosis_profile",
    "prognostic_horizon",
    "propagate_to_threshold",
    "relative_accuracy",
    "rk4_step",
    "unscented_rul",
]
