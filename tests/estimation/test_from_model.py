"""From a model to any filter (issue 10 items 1, stumbles 2 and 6): ``from_model`` on the PF,
EKF and UKF against the exact Kalman filter of a linear-Gaussian model, analytic vs
finite-difference Jacobians, one unit without a batch axis, and wrong shapes caught before any
model code runs."""

from __future__ import annotations

import math

import numpy as np
import pytest

import rulkit
from rulkit import (
    ExtendedKalmanFilter,
    GaussianNoise,
    KalmanFilter,
    ParticleFilter,
    StateSpaceModel,
    UnscentedKalmanFilter,
)


class Linear(StateSpaceModel):
    """x_{k+1} = F x_k + w, y = H x + v (F = [[1, dt], [0, 1]]); ``calls`` counts model calls."""

    state_names = ("level", "slope")
    output_names = ("level_measured",)

    def __init__(self, dt: float = 1.0, analytic: bool = True) -> None:
        self.dt = dt
        self.analytic = analytic
        self.F = np.array([[1.0, dt], [0.0, 1.0]])
        self.calls = 0
        self._noise = GaussianNoise(Q=np.diag([1e-3, 1e-4]) * dt, R=np.array([[0.05**2]]))

    @property
    def noise(self) -> GaussianNoise:
        return self._noise

    def step(self, x, u, t, dt, rng=None):
        self.calls += 1
        F = np.array([[1.0, dt], [0.0, 1.0]])
        out = x @ F.T
        if rng is not None:
            out = out + self._noise.sample_process(x.shape[0], rng)
        return out

    def output(self, x, u=None):
        self.calls += 1
        return x[:, :1].copy()

    def health(self, x):
        return x[:, 0]

    threshold = 1.0


class LinearJac(Linear):
    def step_jacobian(self, x, u, t, dt):
        return np.broadcast_to(np.array([[1.0, dt], [0.0, 1.0]]), (x.shape[0], 2, 2))

    def output_jacobian(self, x, u=None):
        return np.broadcast_to(np.array([[1.0, 0.0]]), (x.shape[0], 1, 2))


M0, P0 = np.array([0.0, 0.01]), np.diag([0.02**2, 0.005**2])


def _data(model, T=30, seed=0):
    sim = model.simulate(np.array([0.0, 0.012]), T, np.random.default_rng(seed))
    return sim


def _kf(model, ys):
    return KalmanFilter(model.F, [[1.0, 0.0]], model.noise.Q, model.noise.R).filter(
        ys[:, None, :], M0[None], P0)


@pytest.mark.parametrize("cls", [ExtendedKalmanFilter, UnscentedKalmanFilter])
def test_kalman_from_model_equals_exact_kf_one_unit_without_batch_axis(cls) -> None:
    model = LinearJac()
    sim = _data(model)
    kr = _kf(model, sim.y)
    res = cls.from_model(model).filter(sim.y[:, 0], M0, P0)  # ys (T,), x0 (n,)
    assert res.x.shape == kr.x.shape
    np.testing.assert_allclose(res.x, kr.x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(res.P, kr.P, rtol=1e-7, atol=1e-14)
    np.testing.assert_allclose(res.loglik, kr.loglik, rtol=1e-9)
    res2 = cls.from_model(model).filter(sim.y, M0[None], P0)  # (T, n_y) and (1, n)
    np.testing.assert_array_equal(res2.x, res.x)


def test_ekf_from_model_uses_the_analytic_jacobian_else_finite_differences() -> None:
    ana = ExtendedKalmanFilter.from_model(LinearJac())
    num = ExtendedKalmanFilter.from_model(Linear())
    forced = ExtendedKalmanFilter.from_model(LinearJac(), jacobian="numerical")
    assert ana.jac_f is not None and ana.jac_h is not None
    assert num.jac_f is None and forced.jac_f is None
    sim = _data(Linear())
    a = ana.filter(sim.y, M0, P0)
    b = num.filter(sim.y, M0, P0)
    np.testing.assert_allclose(a.x, b.x, atol=1e-8)  # FD error O(h^2) on a linear model


def test_pf_from_model_matches_exact_kalman_posterior() -> None:
    model = Linear()
    sim = _data(model, T=40, seed=3)
    kr = _kf(model, sim.y)
    rng = np.random.default_rng(4)
    n = 4000
    p0 = M0 + np.sqrt(np.diag(P0)) * rng.standard_normal((n, 2))
    res = ParticleFilter.from_model(model).filter(sim.y[:, 0], p0, rng)
    sd = np.sqrt(np.diagonal(kr.P[:, 0], axis1=1, axis2=2))
    z = np.abs(res.mean - kr.x[:, 0]) / sd
    assert z.max() < 6 / math.sqrt(res.ess.min()) + 0.05
    np.testing.assert_allclose(np.sqrt(np.diagonal(res.cov, axis1=1, axis2=2))[-1], sd[-1],
                               rtol=0.15)
    # the Gaussian likelihood built from noise.R is the normalised density
    ll = ParticleFilter.from_model(model).log_likelihood(np.array([[0.1, 0.0]]), [0.15], 0)
    expected = -0.5 * (0.05 / 0.05) ** 2 - math.log(0.05 * math.sqrt(2 * math.pi))
    assert ll[0] == pytest.approx(expected)


def test_from_model_adapter_time_and_input_convention() -> None:
    """Step k runs from t0 + k dt; the input u(t) reaches step and output at their times."""
    seen: list[tuple[str, float, float]] = []

    class Logged(Linear):
        input_names = ("load",)

        def step(self, x, u, t, dt, rng=None):
            seen.append(("step", t, float(np.asarray(u))))
            return super().step(x, None, t, dt, rng)

        def output(self, x, u=None):
            seen.append(("output", math.nan, float(np.asarray(u))))
            return super().output(x)

    model = Logged(dt=0.5)
    pf = ParticleFilter.from_model(model, t0=2.0, u=lambda t: 10 * t)
    pf.filter(np.zeros(2), np.zeros((5, 2)), np.random.default_rng(0), quantiles=None)
    assert [s for s in seen if s[0] == "step"] == [("step", 2.0, 20.0), ("step", 2.5, 25.0)]
    assert [s[2] for s in seen if s[0] == "output"] == [25.0, 30.0]  # at t_{k+1}


@pytest.mark.parametrize(
    ("make", "ys", "x0", "message"),
    [
        (lambda m: ParticleFilter.from_model(m), np.zeros((5, 2)), np.zeros((10, 2)),
         r"ys: expected shape \(T, 1\) or \(T,\)"),
        (lambda m: ParticleFilter.from_model(m), np.zeros(5), np.zeros((10, 3)),
         r"particles0: expected shape \(N, 2\)"),
        (lambda m: ParticleFilter.from_model(m), np.zeros((5, 1, 1)), np.zeros((10, 2)),
         r"ys: expected shape \(T, 1\)"),
        (lambda m: ExtendedKalmanFilter.from_model(m), np.zeros((5, 2)), np.zeros(2),
         r"ys: expected shape \(T, 1, 1\) \(or \(T, 1\) for one unit\)"),
        (lambda m: UnscentedKalmanFilter.from_model(m), np.zeros(5), np.zeros(3),
         r"x0: expected 2 states"),
    ],
)
def test_wrong_shapes_are_named_errors_before_any_model_code(make, ys, x0, message) -> None:
    model = Linear()
    filt = make(model)
    with pytest.raises(ValueError, match=message):
        if isinstance(filt, ParticleFilter):
            filt.filter(ys, x0, np.random.default_rng(0))
        else:
            filt.filter(ys, x0, np.eye(x0.shape[-1]))
    assert model.calls == 0


@pytest.mark.parametrize("cls", [ParticleFilter, ExtendedKalmanFilter, UnscentedKalmanFilter])
def test_passing_a_model_or_its_step_to_a_constructor_names_from_model(cls) -> None:
    """Stumble 2: the user passed ``model.step`` and got 'missing 1 required positional
    argument: dt' from deep inside the filter."""
    model = Linear()
    for obj in (model, model.step):
        with pytest.raises(TypeError, match=rf"{cls.__name__}\.from_model\(model"):
            if cls is ParticleFilter:
                cls(obj, lambda x, y, k: np.zeros(x.shape[0]))
            else:
                cls(obj, lambda x, u, k: x[:, :1], np.eye(2), np.eye(1))


def test_a_dt_other_than_the_models_needs_an_explicit_q() -> None:
    with pytest.raises(ValueError, match=r"Q: model.noise.Q is the covariance of one step"):
        ExtendedKalmanFilter.from_model(Linear(dt=1.0), dt=0.5)
    ekf = ExtendedKalmanFilter.from_model(Linear(dt=1.0), dt=0.5, Q=np.diag([5e-4, 5e-5]))
    assert ekf.Q.value is not None


def test_import_rulkit_exports_the_engine() -> None:
    """Stumble 7: ``import rulkit`` exported nothing."""
    for name in ("StateSpaceModel", "ParticleFilter", "ExtendedKalmanFilter",
                 "UnscentedKalmanFilter", "KalmanFilter", "propagate_to_threshold",
                 "RULDistribution", "alpha_lambda", "prognostic_horizon", "Simulation",
                 "unscented_rul", "monte_carlo_rul", "prognosis_profile", "PrognosisProfile"):
        assert name in rulkit.__all__, name
        assert getattr(rulkit, name) is not None
