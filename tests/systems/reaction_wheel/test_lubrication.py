"""Lubricant-loss model: loss law, scenarios, quadrature window sums vs the direct sum,
Euler-Maclaurin truth vs the direct 0.05 s sum, the T^ error process."""

from __future__ import annotations

import numpy as np
import pytest

from rulkit.systems.reaction_wheel.lubrication import (
    PATH_SCENARIO_1,
    PATHS,
    SCENARIO_1,
    SCENARIO_2,
    WINDOW_S,
    EstimateErrorProcess,
    TemperaturePath,
    direct_log_sums,
    fit_error_process,
    loss_rate,
    path_quadrature,
    synthetic_estimate_quadrature,
    true_window_increments,
    window_quadrature,
)

T_WIN = np.arange(4800) * 0.05
B_GRID = np.linspace(5.0, 120.0, 47)


def _rel_err(u: np.ndarray, n: int, backend: str = "numba", b: np.ndarray = B_GRID) -> float:
    q = window_quadrature(u, n, backend=backend)
    ref = direct_log_sums(u, b)
    got = np.stack([q.log_sums(b, k) for k in range(u.shape[0])])
    return float(np.max(np.abs(np.expm1(got - ref))))


def test_loss_rate_closed_form_and_singularity() -> None:
    assert loss_rate(30.0, 37.0, 7.494e-6) == pytest.approx(7.494e-6 * np.exp(-37.0 / 30.0),
                                                             rel=1e-15)
    # sensitivity ~4 % per C at 30 C in deg C units (spec section 4)
    r = loss_rate(np.array([30.0, 31.0]), 37.0, 1.0)
    assert r[1] / r[0] - 1 == pytest.approx(np.exp(37 / 30 - 37 / 31) - 1, rel=1e-12)
    assert 0.035 < r[1] / r[0] - 1 < 0.045
    with pytest.raises(ValueError, match="below 5"):
        loss_rate(np.array([20.0, 2.0]), 37.0, 1.0)
    with pytest.raises(ValueError, match="non-finite"):
        loss_rate(np.array([np.nan]), 37.0, 1.0)


def test_scenarios_table4() -> None:
    t = np.array([158.9 * 60, 159.0 * 60, 159.1 * 60])
    b, beta0 = SCENARIO_1.parameters(t)
    assert list(b) == [37.0, 37.0, 25.0]
    assert list(beta0) == [7.494e-6, 7.494e-6, 8.054e-6]
    b2, beta2 = SCENARIO_2.parameters(t)
    assert list(b2) == [37.0, 37.0, 49.0] and beta2[-1] == 7.0e-6
    # 159 min falls inside window 40 (index 39)
    assert int(SCENARIO_1.fault_time_s // WINDOW_S) == 39


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_quadrature_smooth_paths_need_4_nodes(backend: str) -> None:
    # orbital + seasonal path: smooth; noisy AR(1)-like T^; Table 3-like exponential ramp
    rng = np.random.default_rng(1)
    smooth = np.stack([PATH_SCENARIO_1(T_WIN + k * 7919.0) for k in range(6)])
    walk = 30.0 + 0.05 * np.cumsum(rng.standard_normal((4, 4800)), axis=1)
    ramp = np.where(T_WIN < 50, 31.0, 31 * np.exp(3e-4 * (T_WIN - 50)))[None]
    u = 1.0 / np.concatenate([smooth, walk, ramp])
    assert _rel_err(u, 4, backend) < 1e-9
    assert _rel_err(u, 5, backend) < 1e-12


def test_quadrature_worst_case_windows() -> None:
    rng = np.random.default_rng(2)
    step = np.where(T_WIN < 120.0, 23.0, 31.0)  # the Table 3 temperature step inside a window
    noisy = 30.0 + 1.0 * rng.standard_normal(4800)  # white noise of 1 C on T^
    step_noisy = step + 0.5 * rng.standard_normal(4800)
    wide = np.linspace(10.0, 60.0, 4800)  # far wider than any real window
    u = 1.0 / np.stack([step, noisy, step_noisy, wide])
    assert _rel_err(u[:3], 6) < 1e-9
    assert _rel_err(u[:3], 4) > 1e-12  # it is a worst case: 4 nodes are visibly less exact
    # the extreme 10..60 C window still needs few nodes for moderate b
    assert _rel_err(u[3:], 6, b=np.linspace(5.0, 60.0, 12)) < 1e-6


def test_quadrature_constant_and_two_valued_windows_are_exact() -> None:
    u = 1.0 / np.stack([np.full(4800, 30.0), np.where(T_WIN < 100, 23.0, 31.0)])
    for n in (1, 2, 5):
        q = window_quadrature(u, n)
        assert abs(q.weights[0].sum() - 1) < 1e-14
    assert _rel_err(u, 5) < 1e-13  # round-off of the 4800-term reference sum
    assert _rel_err(u[:1], 1) < 1e-13


def test_gauss_rule_reproduces_empirical_moments() -> None:
    # an n-point Gauss rule integrates polynomials up to degree 2n - 1 exactly
    rng = np.random.default_rng(3)
    u = 1.0 / (30.0 + rng.gamma(2.0, 1.0, size=(3, 2400)))
    n = 5
    q = window_quadrature(u, n)
    for k in range(3):
        x = (u[k] - q.center[k]) / q.scale[k]
        for p in range(2 * n):
            assert (q.weights[k] * q.nodes[k] ** p).sum() == pytest.approx(
                np.mean(x**p), rel=1e-9, abs=1e-11)


def test_numba_and_numpy_quadrature_agree() -> None:
    rng = np.random.default_rng(4)
    u = 1.0 / (30.0 + np.cumsum(rng.standard_normal((50, 240)), axis=1) * 0.1)
    u[7] = 1 / 29.0
    a = window_quadrature(u, 5, backend="numpy")
    b = window_quadrature(u, 5, backend="numba")
    np.testing.assert_allclose(a.center, b.center, rtol=1e-14)
    np.testing.assert_allclose(a.scale, b.scale, rtol=1e-12)
    np.testing.assert_allclose(a.nodes, b.nodes, atol=1e-11)
    np.testing.assert_allclose(a.weights, b.weights, atol=1e-12)


def test_quadrature_bad_input() -> None:
    with pytest.raises(ValueError, match="non-finite"):
        window_quadrature(np.array([[0.1, np.nan]]))
    with pytest.raises(ValueError, match="shape"):
        window_quadrature(np.ones(5))
    with pytest.raises(ValueError, match="n_nodes"):
        window_quadrature(np.ones((1, 5)), 0)
    with pytest.raises(ValueError, match="backend"):
        window_quadrature(np.ones((1, 5)), 2, backend="fortran")


@pytest.mark.parametrize("sid", [1, 2])
def test_euler_maclaurin_truth_matches_direct_sum(sid: int) -> None:
    from rulkit.systems.reaction_wheel.lubrication import SCENARIOS

    direct = true_window_increments(PATHS[sid], SCENARIOS[sid], 120, method="direct")
    em = true_window_increments(PATHS[sid], SCENARIOS[sid], 120)
    np.testing.assert_allclose(em, direct, rtol=1e-12)
    # a path with a much faster orbit still agrees (window far from the fault)
    fast = TemperaturePath(orbit_period_s=1800.0, orbit_amplitude_c=8.0)
    np.testing.assert_allclose(true_window_increments(fast, SCENARIOS[sid], 60),
                               true_window_increments(fast, SCENARIOS[sid], 60, method="direct"),
                               rtol=1e-11)


def test_path_quadrature_matches_dense_sum() -> None:
    q = path_quadrature(PATH_SCENARIO_1, 3600.0, 4, 6 * 3600.0, points_per_window=720)
    b = np.array([25.0, 37.0])
    t = 3600.0 + (np.arange(4 * 720) + 0.5) * 30.0
    ref = np.exp(-b[None, :] / PATH_SCENARIO_1(t)[:, None]).reshape(4, 720, 2).mean(axis=1)
    got = np.stack([q.sums(b, j) for j in range(4)]) / q.count
    np.testing.assert_allclose(got, ref, rtol=1e-12)


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

    from rulkit.systems.reaction_wheel.lubrication import _ar1

    rng = np.random.default_rng(8)
    x = rng.standard_normal((3, 500))
    d0 = rng.standard_normal(3)
    ref, _ = lfilter([1.0], [1.0, -0.93], x, axis=-1, zi=(0.93 * d0)[:, None])
    np.testing.assert_allclose(_ar1(x, 0.93, d0), ref, rtol=1e-12, atol=1e-14)
