"""Window sums of step 2 by Gauss quadrature against the direct sum (numba and numpy paths)."""

from __future__ import annotations

import numpy as np
import pytest

from rulkit.systems.reaction_wheel.degradation.quadrature import (
    direct_log_sums,
    path_quadrature,
    window_quadrature,
)
from rulkit.systems.reaction_wheel.lubrication import (
    PATH_SCENARIO_1,
)

T_WIN = np.arange(4800) * 0.05


B_GRID = np.linspace(5.0, 120.0, 47)


def _rel_err(u: np.ndarray, n: int, backend: str = "numba", b: np.ndarray = B_GRID) -> float:
    q = window_quadrature(u, n, backend=backend)
    ref = direct_log_sums(u, b)
    got = np.stack([q.log_sums(b, k) for k in range(u.shape[0])])
    return float(np.max(np.abs(np.expm1(got - ref))))


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


def test_path_quadrature_matches_dense_sum() -> None:
    q = path_quadrature(PATH_SCENARIO_1, 3600.0, 4, 6 * 3600.0, points_per_window=720)
    b = np.array([25.0, 37.0])
    t = 3600.0 + (np.arange(4 * 720) + 0.5) * 30.0
    ref = np.exp(-b[None, :] / PATH_SCENARIO_1(t)[:, None]).reshape(4, 720, 2).mean(axis=1)
    got = np.stack([q.sums(b, j) for j in range(4)]) / q.count
    np.testing.assert_allclose(got, ref, rtol=1e-12)
