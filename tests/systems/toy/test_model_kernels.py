"""The toy model's compiled step and likelihood round exactly as the numpy expressions of its
docstring (bit for bit, so seeded results do not move when the implementation changes)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rulkit.systems.toy.model import ToyDegradation


@pytest.mark.parametrize("dt", [1.0, 0.1, 0.37])
def test_step_equals_the_numpy_expression_bit_for_bit(dt: float) -> None:
    m = ToyDegradation(sigma_d=1e-3, sigma_r=1e-4, sigma_y=0.02)
    x = np.random.default_rng(1).normal([0.3, 0.01], [0.1, 0.004], size=(257, 2))
    got = m.step(x, None, 0.0, dt, np.random.default_rng(5))
    z = np.random.default_rng(5).standard_normal((257, 2))
    s = math.sqrt(dt)
    d = z[:, 0] * (m.sigma_d * s) + x[:, 0] + x[:, 1] * dt
    r = z[:, 1] * (m.sigma_r * s) + x[:, 1]
    np.testing.assert_array_equal(got, np.column_stack([d, r]))
    xs = x[::2]  # a strided batch gives the same rows
    np.testing.assert_array_equal(m.step(xs, None, 0.0, dt, np.random.default_rng(5)),
                                  m.step(xs.copy(), None, 0.0, dt, np.random.default_rng(5)))


def test_log_likelihood_equals_the_numpy_expression_bit_for_bit() -> None:
    m = ToyDegradation(sigma_y=0.03)
    x = np.random.default_rng(2).normal(0.5, 0.2, size=(301, 2))
    r = (0.47 - x[:, 0]) / 0.03
    want = r * -0.5 * r - math.log(0.03 * math.sqrt(2.0 * math.pi))
    np.testing.assert_array_equal(m.log_likelihood(x, np.array([0.47])), want)
    np.testing.assert_allclose(
        np.exp(m.log_likelihood(x, 0.47)),
        np.exp(-0.5 * r**2) / (0.03 * math.sqrt(2 * math.pi)), rtol=1e-13)
