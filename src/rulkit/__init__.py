"""rulkit: model-based prognostics.

Telemetry of a degrading machine -> Bayesian state and parameter estimation -> a Remaining
Useful Life (RUL) distribution, with metrics and alerts. Physics lives in models (a
:class:`StateSpaceModel` subclass, or a system under :mod:`rulkit.systems`); the algorithms in
:mod:`rulkit.estimation` and :mod:`rulkit.prognosis` know no physics and take a model as is::

    import rulkit
    sim = model.simulate(x0, n_steps=60, rng=rng)
    prior = rulkit.Posterior(mean0, cov0)             # every filter's prior and posterior
    res = rulkit.ExtendedKalmanFilter.from_model(model).filter(sim.y, prior)
    rul = rulkit.monte_carlo_rul(res.posterior(), model, horizon=100.0, rng=rng)
    profile = rulkit.prognosis_profile(model, sim.y, "pf", prior.with_samples(2000, rng),
                                       times=[20, 30], horizon=100.0, rng=rng)

The engine's API is documented once in docs/engine-api.md.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from rulkit.estimation.base import Posterior
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
    from rulkit.prognosis.learning import FitError, FitWarning, ParameterFit, fit_parameters
    from rulkit.prognosis.predictors import monte_carlo_rul, unscented_rul
    from rulkit.prognosis.profile import PrognosisProfile, prognosis_profile
    from rulkit.prognosis.rul import RULDistribution, propagate_to_threshold

# The engine's names are imported on first use (PEP 562): the command line and the fleet
# commands, which need none of them, start without loading scipy and the filters.
_EXPORTS = {
    "Posterior": "rulkit.estimation.base",
    "ExtendedKalmanFilter": "rulkit.estimation.ekf",
    "KalmanFilter": "rulkit.estimation.kalman",
    "KalmanResult": "rulkit.estimation.kalman",
    "ParticleFilter": "rulkit.estimation.particle",
    "ParticleFilterResult": "rulkit.estimation.particle",
    "UnscentedKalmanFilter": "rulkit.estimation.ukf",
    "euler_step": "rulkit.integrate",
    "ode_step": "rulkit.integrate",
    "rk4_step": "rulkit.integrate",
    "alpha_lambda": "rulkit.metrics",
    "convergence": "rulkit.metrics",
    "crps_rul": "rulkit.metrics",
    "crps_samples": "rulkit.metrics",
    "cumulative_relative_accuracy": "rulkit.metrics",
    "interval_coverage": "rulkit.metrics",
    "prognostic_horizon": "rulkit.metrics",
    "relative_accuracy": "rulkit.metrics",
    "GaussianNoise": "rulkit.model",
    "Simulation": "rulkit.model",
    "StateSpaceModel": "rulkit.model",
    "FitError": "rulkit.prognosis.learning",
    "FitWarning": "rulkit.prognosis.learning",
    "ParameterFit": "rulkit.prognosis.learning",
    "fit_parameters": "rulkit.prognosis.learning",
    "monte_carlo_rul": "rulkit.prognosis.predictors",
    "unscented_rul": "rulkit.prognosis.predictors",
    "PrognosisProfile": "rulkit.prognosis.profile",
    "prognosis_profile": "rulkit.prognosis.profile",
    "RULDistribution": "rulkit.prognosis.rul",
    "propagate_to_threshold": "rulkit.prognosis.rul",
}


def __getattr__(name: str) -> Any:
    if name == "__version__":  # lazily: importlib.metadata costs ~40 ms of every CLI start
        from importlib.metadata import PackageNotFoundError, version

        try:
            value = version("rulkit")
        except PackageNotFoundError:  # pragma: no cover - a source tree without install
            value = "0.0.0+unknown"
        globals()[name] = value
        return value
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'rulkit' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))


__all__ = [
    "ExtendedKalmanFilter",
    "FitError",
    "FitWarning",
    "GaussianNoise",
    "KalmanFilter",
    "KalmanResult",
    "ParameterFit",
    "ParticleFilter",
    "ParticleFilterResult",
    "Posterior",
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
