"""Tracking problems with known truth for the tests of step 2 (the trackers and the Table 6
study): the measured window losses of a lubricant-loss path and the quadrature of a synthetic
temperature estimate."""

from __future__ import annotations

import numpy as np

from rulkit.systems.reaction_wheel.degradation.quadrature import WindowQuadrature
from rulkit.systems.reaction_wheel.degradation.shortcut import (
    EstimateErrorProcess,
    synthetic_estimate_quadrature,
)
from rulkit.systems.reaction_wheel.degradation.trackers import DegradationConfig
from rulkit.systems.reaction_wheel.lubrication import (
    PATHS,
    SCENARIOS,
    LubricationSetup,
    simulate_measurements,
    true_window_increments,
)

BETA_REF = SCENARIOS[1].beta0_healthy


def tracking_problem(U: int, days: float, err_std: float = 0.0, seed: int = 0, sid: int = 1,
                     noise_rel: float = 0.01
                     ) -> tuple[DegradationConfig, LubricationSetup, np.ndarray, WindowQuadrature]:
    """U runs of scenario ``sid`` over ``days``: the settings (60 particles), the setup, the
    measured window losses (U, W) and the quadrature of a T^ with error std ``err_std`` C."""
    st = DegradationConfig(horizon_days=days, n_particles=60, noise_rel=noise_rel)
    setup = LubricationSetup(sid, days, noise_rel, PATHS[sid])
    W = st.n_windows
    y_true = true_window_increments(PATHS[sid], SCENARIOS[sid], W)
    y = simulate_measurements(y_true, setup.sigma_y,
                              [np.random.default_rng([seed, r]) for r in range(U)])
    q = synthetic_estimate_quadrature(PATHS[sid], EstimateErrorProcess(std_c=err_std, tau_s=30.0),
                                      W, [np.random.default_rng([seed, 50 + r]) for r in range(U)],
                                      n_nodes=4)
    return st, setup, y, q


def unit_rngs(tag: int, U: int) -> list[np.random.Generator]:
    """One generator per unit, ``default_rng([tag, r])``."""
    return [np.random.default_rng([tag, r]) for r in range(U)]
