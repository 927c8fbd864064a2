"""The T^ error process of the step-2 shortcut: fitting, synthetic estimates, the AR(1) kernel."""

from __future__ import annotations

import numpy as np
import pytest

from rulkit.systems.reaction_wheel.degradation.shortcut import (
    EstimateErrorProcess,
    fit_error_process,
    synthetic_estimate_quadrature,
)
from rulkit.systems.reaction_wheel.lubrication import (
    PATH_SCENARIO_1,
    TemperaturePath,
)


def _ar1_loop(n: int, rho: float, sd: float, bias: float, rng: np.random.Generator) -> np.ndarray:
    d = np.empty(n)
    prev = sd * rng.standard_normal()
    for i in range(n):
        prev = rho * prev + sd * np.sqrt(1 - rho * rho) * rng.standard_normal()
        d[i] = prev
    return bias + d


def test_fit_error_process_recovers_ar1() -> None:
    rng = np.random.default_rng(5)
    hold, tau, sd, bias = 20, 30.0, 0.7, -0.4
    rho = np.exp(-hold * 0.05 / tau)
    blocks = np.stack([_ar1_loop(3000, rho, sd, bias, rng) for _ in range(4)])
    e = np.repeat(blocks, hold, axis=1) + 0.01 * rng.standard_normal((4, 3000 * hold))
    fit = fit_error_process(e, hold_samples=hold)
    assert fit.bias_c == pytest.approx(bias, abs=0.15)
    assert fit.std_c == pytest.approx(sd, rel=0.15)
    assert fit.tau_s == pytest.approx(tau, rel=0.25)
    assert fit.white_std_c == pytest.approx(0.01, rel=0.05)
    with pytest.raises(ValueError, match="blocks"):
        fit_error_process(np.zeros((1, 30)), hold_samples=20)


def test_synthetic_estimate_statistics_and_batching() -> None:
    err = EstimateErrorProcess(bias_c=0.3, std_c=0.8, tau_s=40.0)
    rngs = [np.random.default_rng(i) for i in range(3)]
    T_hat, _ = err.estimate_blocks(TemperaturePath(orbit_amplitude_c=0.0, season_amplitude_c=0.0),
                                   0, 200, rngs)
    d = T_hat - 30.0
    assert d.mean() == pytest.approx(0.3, abs=0.1)
    assert d.std() == pytest.approx(0.8, rel=0.1)
    flat = d.reshape(3, -1) - d.mean()
    lag1 = (flat[:, 1:] * flat[:, :-1]).mean() / (flat * flat).mean()
    assert lag1 == pytest.approx(np.exp(-err.hold_s / 40.0), abs=0.015)
    # chunked streaming gives the same numbers as one chunk; run r depends on its rng only
    a = synthetic_estimate_quadrature(PATH_SCENARIO_1, err, 30, [np.random.default_rng(7)],
                                      chunk_windows=7)
    b = synthetic_estimate_quadrature(PATH_SCENARIO_1, err, 30,
                                      [np.random.default_rng(9), np.random.default_rng(7)])
    np.testing.assert_allclose(a.center[0], b.center[1], rtol=1e-14)
    np.testing.assert_allclose(a.nodes[0], b.nodes[1], atol=1e-12)


def test_ar1_kernel_matches_scipy_lfilter() -> None:
    from scipy.signal import lfilter

    from rulkit.systems.reaction_wheel.degradation.shortcut import _ar1

    rng = np.random.default_rng(8)
    x = rng.standard_normal((3, 500))
    d0 = rng.standard_normal(3)
    ref, _ = lfilter([1.0], [1.0, -0.93], x, axis=-1, zi=(0.93 * d0)[:, None])
    np.testing.assert_allclose(_ar1(x, 0.93, d0), ref, rtol=1e-12, atol=1e-14)
