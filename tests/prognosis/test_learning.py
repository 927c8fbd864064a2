"""Parameter learning (issue 10 item 5): known parameters recovered from simulated records."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from rulkit import FitError, FitWarning, GaussianNoise, StateSpaceModel, fit_parameters


@dataclass(frozen=True)
class Drift(StateSpaceModel):
    """[level, rate]: level += rate dt + N(0, q_l^2 dt); rate += N(0, q_r^2 dt); y = level + v."""

    q_l: float = 0.02
    q_r: float = 0.002
    sigma_y: float = 0.1
    dt: float = 1.0

    state_names = ("level", "rate")
    output_names = ("y",)

    @property
    def noise(self) -> GaussianNoise:
        return GaussianNoise(Q=np.diag([self.q_l**2, self.q_r**2]) * self.dt,
                             R=np.array([[self.sigma_y**2]]))

    def step(self, x, u, t, dt, rng=None):
        out = x.copy()
        out[:, 0] += x[:, 1] * dt
        if rng is not None:
            out += rng.standard_normal(x.shape) * np.array([self.q_l, self.q_r]) * math.sqrt(dt)
        return out

    def output(self, x, u=None):
        return x[:, :1].copy()

    def step_jacobian(self, x, u, t, dt):
        return np.broadcast_to(np.array([[1.0, dt], [0.0, 1.0]]), (x.shape[0], 2, 2))

    def output_jacobian(self, x, u=None):
        return np.broadcast_to(np.array([[1.0, 0.0]]), (x.shape[0], 1, 2))


TRUE = Drift()
M0, P0 = np.array([0.0, 0.05]), np.diag([0.1**2, 0.01**2])


def _records(n: int, T: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        x0 = M0 + np.sqrt(np.diag(P0)) * rng.standard_normal(2)
        out.append(TRUE.simulate(x0, T - 5 * i, rng).y)  # records of different lengths
    return out


def test_kalman_mle_recovers_known_noise_parameters_with_standard_errors() -> None:
    recs = _records(4, 100, 0)
    fit = fit_parameters(Drift(), recs, {"sigma_y": 0.3, "q_r": 0.01}, x0=M0, P0=P0,
                         method="ekf")
    assert fit.success
    for name in ("sigma_y", "q_r"):
        est, se, true = fit.params[name], fit.stderr[name], getattr(TRUE, name)
        assert 0 < se < 0.5 * true
        assert abs(est - true) < 3.5 * se, (name, est, se, true)
    assert fit.model.sigma_y == fit.params["sigma_y"]
    # the maximum is a maximum: moving off it lowers the likelihood
    from rulkit import ExtendedKalmanFilter

    def ll(**p):
        m = Drift(**{**fit.params, **p})
        return sum(float(ExtendedKalmanFilter.from_model(m).filter(y, M0, P0).loglik[0])
                   for y in recs)

    assert fit.loglik == pytest.approx(ll(), rel=1e-9)
    assert ll(sigma_y=fit.params["sigma_y"] * 1.1) < fit.loglik
    assert ll(sigma_y=fit.params["sigma_y"] * 0.9) < fit.loglik


def test_particle_filter_mle_with_common_random_numbers_agrees_with_kalman() -> None:
    recs = _records(2, 60, 1)
    kf = fit_parameters(Drift(), recs, {"sigma_y": 0.3}, x0=M0, P0=P0, method="ekf")
    pf = fit_parameters(Drift(), recs, {"sigma_y": 0.3}, x0=M0, P0=P0, method="pf",
                        n_particles=400, seed=3)
    assert pf.params["sigma_y"] == pytest.approx(kf.params["sigma_y"], rel=0.1)
    assert abs(pf.params["sigma_y"] - TRUE.sigma_y) < 3.5 * kf.stderr["sigma_y"]


def test_fit_parameters_errors() -> None:
    with pytest.raises(ValueError, match="log scale"):
        fit_parameters(Drift(), _records(1, 10, 0), {"sigma_y": -1.0}, x0=M0, P0=P0)
    with pytest.raises(ValueError, match=r"records\[1\]: ys: expected shape \(T, 1\)"):
        fit_parameters(Drift(), [np.zeros(5), np.zeros((5, 2))], {"sigma_y": 0.1}, x0=M0,
                       P0=P0)


# ---------------------------------------------------------------------------------------------
# Fits that say when they failed: a capacity-fade model with a knee
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Fade(StateSpaceModel):
    """Capacity fade with a knee: [loss, z = log fade rate]; loss += exp(z + beta loss) dt,
    z a slow random walk, the loss measured with noise; end of life at a loss of 0.2. Past
    end of life the loss runs away within a few steps (exp overflows): a filter predicting
    beyond a record's end fails there."""

    beta: float = 8.0
    q_z: float = 0.02
    sigma_y: float = 0.004
    dt: float = 1.0

    state_names = ("loss", "log_rate")
    output_names = ("loss_measured",)
    threshold = 0.2

    @property
    def noise(self) -> GaussianNoise:
        return GaussianNoise(Q=np.diag([1e-8, self.q_z**2]), R=np.array([[self.sigma_y**2]]))

    def step(self, x, u, t, dt, rng=None):
        out = x.copy()
        out[:, 0] += np.exp(x[:, 1] + self.beta * x[:, 0]) * dt
        if rng is not None:
            out += rng.standard_normal(x.shape) * np.array([1e-4, self.q_z])
        return out

    def output(self, x, u=None):
        return x[:, :1].copy()

    def health(self, x):
        return x[:, 0]


FADE_M0, FADE_P0 = np.array([0.0, math.log(0.003)]), np.diag([1e-6, 0.25**2])


def _fade_records(n: int = 6) -> list[np.ndarray]:
    """Run-to-failure records (each up to its end of life): 29 to 46 steps."""
    rng = np.random.default_rng(0)
    out = []
    for _ in range(n):
        x0 = FADE_M0 + np.sqrt(np.diag(FADE_P0)) * rng.standard_normal(2)
        with np.errstate(over="ignore", invalid="ignore"):  # the simulation runs past failure
            sim = Fade().simulate(x0, 80, rng)
        out.append(sim.y[: int(sim.event_time)])
    return out


@pytest.mark.parametrize(("method", "start"), [("ekf", 4.0), ("ukf", 6.0)])
def test_records_of_different_lengths_give_the_knee_parameter(method: str, start: float) -> None:
    """Six records of 29-46 steps: the fit reaches the true beta = 8 within its standard error
    (it used to return its start as a success with a NaN standard error: the shorter records
    were padded and predicted past their end of life, where the model overflows)."""
    recs = _fade_records()
    assert len({len(y) for y in recs}) == 6
    fit = fit_parameters(Fade(), recs, {"beta": start}, x0=FADE_M0, P0=FADE_P0, method=method)
    assert fit.success, fit.message
    se = fit.stderr["beta"]
    assert 0 < se < 1.0 and abs(fit.params["beta"] - 8.0) < 3 * se, (fit.params, se)


def test_each_records_likelihood_stops_at_its_own_end() -> None:
    """Oracle: the fit's log-likelihood is the sum of each record's own EKF log-likelihood
    (filtered alone, no padding), at the true parameter where padding would overflow."""
    from rulkit import ExtendedKalmanFilter

    recs = _fade_records()
    with pytest.warns(FitWarning, match="ITERATIONS REACHED LIMIT"):  # one step: enough here
        fit = fit_parameters(Fade(), recs, {"beta": 8.0}, x0=FADE_M0, P0=FADE_P0,
                             method="ekf", options={"maxiter": 1})
    alone = sum(float(ExtendedKalmanFilter.from_model(fit.model).filter(y, FADE_M0, FADE_P0)
                      .loglik[0]) for y in recs)
    assert fit.loglik == pytest.approx(alone, rel=1e-10)


def test_a_particle_fit_stalled_in_monte_carlo_noise_says_so() -> None:
    """With 100 particles the particle log-likelihood is too noisy to optimise (its spread over
    fresh random numbers is tens of nats at the stall): a fit that reports success must be near
    the truth; this one stalls and says so, naming the remedy (it used to report the stall,
    beta about 4, as a success with a standard error of 0.02)."""
    import warnings

    recs = _fade_records(3)
    kw = dict(x0=FADE_M0, P0=FADE_P0, method="pf", n_particles=100, seed=1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit = fit_parameters(Fade(), recs, {"beta": 4.0}, **kw)
    if fit.success:
        assert abs(fit.params["beta"] - 8.0) < 3 * fit.stderr["beta"]
    else:
        assert "n_particles" in fit.message and fit.loglik_sd > 1.0
        assert any(issubclass(w.category, FitWarning) for w in caught)
        with pytest.raises(FitError, match="n_particles") as err:
            fit_parameters(Fade(), recs, {"beta": 4.0}, strict=True, **kw)
        assert err.value.fit.params == fit.params
    assert not fit.success  # with 100 particles: the stall is detected


def test_records_without_measurements_and_absurd_starts_are_refused() -> None:
    """All-NaN records used to give success with the untouched start; a start of 1e300 an
    OverflowError from the model: both are ValueErrors naming the argument."""
    recs = _records(2, 20, 0)
    with pytest.raises(ValueError, match=r"records\[0\]: no measurement"):
        fit_parameters(Drift(), [np.full((10, 1), np.nan)], {"sigma_y": 0.3}, x0=M0, P0=P0)
    with pytest.raises(ValueError, match=r"records\[1\]: no measurement"):
        fit_parameters(Drift(), [recs[0], np.full(8, np.nan)], {"sigma_y": 0.3}, x0=M0, P0=P0)
    with pytest.raises(ValueError, match=r"params: the log-likelihood is not finite at the "
                                         r"starting values .*OverflowError"):
        fit_parameters(Drift(), recs, {"q_l": 1e300}, x0=M0, P0=P0)
    for bad in (math.inf, math.nan):
        with pytest.raises(ValueError, match="params: 'q_l' must be finite"):
            fit_parameters(Drift(), recs, {"q_l": bad}, x0=M0, P0=P0)
    with pytest.raises(ValueError, match=r"x0: expected a finite prior mean"):
        fit_parameters(Drift(), recs, {"q_l": 0.1}, x0=[0.0, math.nan], P0=P0)


def test_a_parameter_the_records_do_not_determine_fails_loudly() -> None:
    """A parameter the model ignores leaves the likelihood flat in its direction: no positive
    definite Hessian, so no success, a warning (or with strict=True an error)."""
    recs = _records(2, 40, 3)

    def make(sigma_y: float, spare: float) -> Drift:
        return Drift(sigma_y=sigma_y)

    with pytest.warns(FitWarning, match="not determined by these records"):
        fit = fit_parameters(make, recs, {"sigma_y": 0.3, "spare": 1.0}, x0=M0, P0=P0)
    assert not fit.success and math.isnan(fit.stderr["spare"])
    with pytest.raises(FitError, match="not determined"):
        fit_parameters(make, recs, {"sigma_y": 0.3, "spare": 1.0}, x0=M0, P0=P0, strict=True)


def test_an_estimate_on_its_bound_fails_and_multi_start_keeps_the_best() -> None:
    recs = _records(2, 50, 4)
    with pytest.warns(FitWarning, match="'sigma_y' is at its bound 0.2"):
        fit = fit_parameters(Drift(), recs, {"sigma_y": 0.3}, x0=M0, P0=P0,
                             bounds={"sigma_y": (0.2, 1.0)})  # the truth, 0.1, is outside
    assert not fit.success and fit.params["sigma_y"] == pytest.approx(0.2)
    multi = fit_parameters(Drift(), recs, {"sigma_y": 0.3}, x0=M0, P0=P0,
                           starts=[{"sigma_y": 0.05}, {"sigma_y": 1.0}])
    assert multi.success and len(multi.attempts) == 3
    assert multi.loglik == pytest.approx(max(a.loglik for a in multi.attempts), abs=1e-6)
    assert [a.start["sigma_y"] for a in multi.attempts] == pytest.approx([0.3, 0.05, 1.0])
