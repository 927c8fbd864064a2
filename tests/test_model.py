"""The model contract helpers: as_batch, check_covariance, GaussianNoise sampling."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rulkit.model import GaussianNoise, StateSpaceModel, as_batch, check_covariance


def test_as_batch_shapes_and_errors() -> None:
    assert as_batch(np.array([1.0, 2.0]), 2).shape == (1, 2)
    x = np.arange(6.0).reshape(3, 2)
    np.testing.assert_array_equal(as_batch(x, 2), x)
    with pytest.raises(ValueError, match=r"x0: expected shape \(N, 3\) or \(3,\), got \(3, 2\)"):
        as_batch(x, 3, "x0")
    x[2, 1] = np.nan
    with pytest.raises(ValueError, match="x: non-finite value nan at row 2, column 1"):
        as_batch(x, 2)


@pytest.mark.parametrize(
    ("cov", "message"),
    [
        (np.array([[1.0, 0.5], [0.4, 1.0]]), "not symmetric"),
        (np.array([[1.0, 2.0], [2.0, 1.0]]), r"not positive semi-definite \(smallest eig"),
        (np.array([[1.0, np.nan], [np.nan, 1.0]]), "NaN or infinite"),
        (np.eye(3), r"expected shape \(2, 2\), got \(3, 3\)"),
    ],
)
def test_check_covariance_rejects(cov, message) -> None:
    with pytest.raises(ValueError, match=message):
        check_covariance(cov, 2, "Q")


def test_gaussian_noise_rejects_non_square() -> None:
    with pytest.raises(ValueError, match=r"Q: expected a square \(n, n\) matrix"):
        GaussianNoise(Q=np.ones(3), R=np.eye(1))
    with pytest.raises(ValueError, match=r"R: expected a square \(n, n\) matrix"):
        GaussianNoise(Q=np.eye(2), R=np.ones((2, 3)))


@pytest.mark.parametrize("rank_deficient", [False, True])
def test_noise_samples_have_the_stated_covariance(rank_deficient: bool) -> None:
    """Sample covariance of 200 000 draws against Q (and R); a singular Q (rank 1) is sampled
    in its range: the sample covariance is singular too."""
    rng = np.random.default_rng(3)
    if rank_deficient:
        v = np.array([1.0, -2.0, 0.5])
        Q = np.outer(v, v) * 1e-4
    else:
        A = rng.standard_normal((3, 3))
        Q = A @ A.T + 0.1 * np.eye(3)
    R = np.array([[0.25]])
    noise = GaussianNoise(Q=Q, R=R)
    n = 200_000
    w = noise.sample_process(n, rng)
    e = noise.sample_measurement(n, rng)
    assert w.shape == (n, 3) and e.shape == (n, 1)
    # the sample covariance entry C_ij has sd sqrt((Q_ii Q_jj + Q_ij^2) / n): 5 sd tolerance
    C = np.cov(w, rowvar=False)
    sd = np.sqrt((np.outer(np.diag(Q), np.diag(Q)) + Q**2) / n)
    assert np.all(np.abs(C - Q) < 5 * sd)
    assert np.all(np.abs(w.mean(axis=0)) < 5 * np.sqrt(np.diag(Q) / n))
    assert abs(e.var() - 0.25) < 5 * 0.25 * np.sqrt(2 / n)
    if rank_deficient:  # every draw is a multiple of v
        resid = w - np.outer(w @ v / (v @ v), v)
        assert np.abs(resid).max() < 1e-12 * np.abs(w).max()


# ------------------------------------------------------------------ simulate (stumble 6)
class _Drift(StateSpaceModel):
    """x += v dt (+ noise); y = x + N(0, R); failure at x >= 1."""

    state_names = ("x", "v")
    output_names = ("y",)
    threshold = 1.0
    dt = 0.5

    @property
    def noise(self) -> GaussianNoise:
        return GaussianNoise(Q=np.diag([1e-4, 0.0]), R=np.array([[0.1**2]]))

    def step(self, x, u, t, dt, rng=None):
        out = x.copy()
        out[:, 0] += x[:, 1] * dt
        if rng is not None:
            out += self.noise.sample_process(x.shape[0], rng)
        return out

    def output(self, x, u=None):
        return x[:, :1].copy()

    def health(self, x):
        return x[:, 0]


def test_simulate_one_unit_has_no_batch_axis_and_measures_the_next_state() -> None:
    model = _Drift()
    sim = model.simulate(np.array([0.0, 0.1]), 30, np.random.default_rng(0))
    assert sim.t.shape == (31,) and sim.x.shape == (31, 2) and sim.y.shape == (30, 1)
    np.testing.assert_allclose(sim.t, 0.5 * np.arange(31))
    t, x, y = sim  # unpacks
    assert t is sim.t and x is sim.x and y is sim.y
    resid = sim.y[:, 0] - sim.x[1:, 0]  # y[k] measures x[k+1]
    assert abs(resid.mean()) < 4 * 0.1 / math.sqrt(30) and 0.05 < resid.std() < 0.16
    df = sim.to_pandas()
    assert list(df.columns) == ["t", "x", "v", "y"] and len(df) == 31
    assert math.isnan(df["y"].iloc[0]) and df["y"].iloc[1] == sim.y[0, 0]


def test_simulate_batch_noise_covariance_and_event_time() -> None:
    model = _Drift()
    x0 = np.column_stack([np.zeros(4000), np.full(4000, 0.1)])
    sim = model.simulate(x0, 3, np.random.default_rng(1))
    assert sim.x.shape == (4, 4000, 2) and sim.y.shape == (3, 4000, 1)
    v = sim.y[:, :, 0] - sim.x[1:, :, 0]
    assert np.var(v) == pytest.approx(0.01, rel=0.05)  # R
    dx = np.diff(sim.x[:, :, 0], axis=0) - 0.05
    assert np.var(dx) == pytest.approx(1e-4, rel=0.05)  # Q
    # deterministic growth: crossing of 1 at t = 10 exactly (x = 0.05 per step)
    class Quiet(_Drift):
        @property
        def noise(self) -> GaussianNoise:
            return GaussianNoise(Q=np.zeros((2, 2)), R=np.array([[0.1**2]]))

    quiet = Quiet().simulate(np.array([0.0, 0.07]), 30, np.random.default_rng(0))
    assert quiet.event_time == pytest.approx(1.0 / 0.07, rel=1e-12)  # between steps: interpolated
    assert "unit" in sim.to_pandas().columns


def test_simulate_errors() -> None:
    with pytest.raises(ValueError, match=r"x0: expected shape \(N, 2\) or \(2,\)"):
        _Drift().simulate(np.zeros(3), 5, np.random.default_rng(0))
    with pytest.raises(ValueError, match="n_steps"):
        _Drift().simulate(np.zeros(2), 0, np.random.default_rng(0))
