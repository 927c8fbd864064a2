"""Prognosis profile (issue 10 item 3; stumble 4: RUL at several times in one call)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rulkit import (
    GaussianNoise,
    KalmanFilter,
    ParticleFilter,
    StateSpaceModel,
    crps_samples,
    prognosis_profile,
    propagate_to_threshold,
    relative_accuracy,
)


class Ramp(StateSpaceModel):
    """[damage, rate]: damage += rate dt + w; y = damage + v; failure at damage >= 1."""

    state_names = ("damage", "rate")
    output_names = ("y",)
    threshold = 1.0

    def __init__(self, q: float = 1e-3, dt: float = 1.0) -> None:
        self.q, self.dt = q, dt

    @property
    def noise(self) -> GaussianNoise:
        return GaussianNoise(Q=np.diag([self.q**2 * self.dt, 0.0]), R=np.array([[0.02**2]]))

    def step(self, x, u, t, dt, rng=None):
        out = x.copy()
        out[:, 0] += x[:, 1] * dt
        if rng is not None:
            out[:, 0] += self.q * math.sqrt(dt) * rng.standard_normal(x.shape[0])
        return out

    def output(self, x, u=None):
        return x[:, :1].copy()

    def health(self, x):
        return x[:, 0]


def _record(seed: int = 0):
    model = Ramp()
    sim = model.simulate(np.array([0.0, 0.015]), 100, np.random.default_rng(seed))
    return model, sim


def test_profile_equals_the_filter_and_propagation_composed_by_hand() -> None:
    """The one call gives bit-for-bit what the hand-written composition gives: the weighted
    particles of the filter at each time (no off-by-one: measurement k is at (k + 1) dt)
    propagated from that time, in order, with the same generator."""
    model, sim = _record()
    times = [10.0, 25.0, 40.0]
    p0 = np.column_stack([np.zeros(500), np.random.default_rng(1).normal(0.01, 0.004, 500)])
    prof = prognosis_profile(model, sim.y, "pf", p0, times=times, t_eol=sim.event_time,
                             horizon=300.0, rng=np.random.default_rng(2))
    rng = np.random.default_rng(2)
    res = ParticleFilter.from_model(model).filter(sim.y, p0, rng, keep_particles=True)
    for t, d in zip(times, prof.distributions, strict=True):
        k = int(t) - 1
        ref = propagate_to_threshold(res.posterior(k), model=model, t0=t, horizon=300.0,
                                     rng=rng, after_crossing="drop")
        np.testing.assert_array_equal(d.samples, ref.samples)
        np.testing.assert_array_equal(d.weights, ref.weights)
    df = prof.to_pandas()
    assert len(df) == 3 and list(df["t"]) == times
    np.testing.assert_allclose(df["rul_true"], sim.event_time - np.array(times))
    np.testing.assert_allclose(prof.relative_accuracy,
                               relative_accuracy(prof.median, prof.rul_true))
    for i, d in enumerate(prof.distributions):  # nothing censored: the ordinary CRPS
        assert prof.crps[i] == pytest.approx(
            crps_samples(d.samples, prof.rul_true[i], d.weights), rel=1e-9)
    assert prof.cra == pytest.approx(np.mean(prof.relative_accuracy))


def test_unscented_profile_from_an_ekf_matches_the_closed_form() -> None:
    """Known rate, no process noise: the time of event is linear in the damage, so the
    unscented RUL at each time is (1 - m_k) / r with sd sd_k / r from the Kalman posterior."""
    model = Ramp(q=0.0)
    sim = model.simulate(np.array([0.0, 0.012]), 70, np.random.default_rng(3))
    m0, P0 = np.array([0.0, 0.012]), np.diag([0.05**2, 0.0])
    times = np.array([5.0, 20.0, 50.0])
    prof = prognosis_profile(model, sim.y, "ekf", m0, P0=P0, times=times, horizon=400.0,
                             t_eol=sim.event_time, rng=np.random.default_rng(0),
                             predictor="unscented")
    kr = KalmanFilter([[1.0, 1.0], [0.0, 1.0]], [[1.0, 0.0]], model.noise.Q,
                      model.noise.R).filter(sim.y, m0, P0)
    k = times.astype(int) - 1
    np.testing.assert_allclose(prof.mean, (1 - kr.x[k, 0, 0]) / 0.012, rtol=1e-9)
    np.testing.assert_allclose([d.std for d in prof.distributions],
                               np.sqrt(kr.P[k, 0, 0, 0]) / 0.012, rtol=1e-7)


def test_censored_record_and_metrics_that_need_the_truth() -> None:
    model, sim = _record(4)
    p0 = np.column_stack([np.zeros(300), np.full(300, 0.012)])
    prof = prognosis_profile(model, sim.y[:30], "pf", p0, times=[10.0, 20.0, 30.0], t_eol=30.0,
                             failed=False, horizon=300.0, rng=np.random.default_rng(0))
    assert np.all(np.isnan(prof.relative_accuracy)) and math.isnan(prof.coverage)
    assert np.all(np.isnan(prof.alpha_lambda_mass[:2]))
    assert np.all(np.isfinite(prof.crps[:2]))  # the censored CRPS needs only a lower bound
    with pytest.raises(ValueError, match="needs the true end of life"):
        prof.prognostic_horizon()
    with pytest.raises(ValueError, match="not a measurement time"):
        prognosis_profile(model, sim.y, "pf", p0, times=[10.5], horizon=10.0,
                          rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="P0"):
        prognosis_profile(model, sim.y, "ekf", np.zeros(2), times=[10.0], horizon=10.0,
                          rng=np.random.default_rng(0))


def test_profile_metrics_against_the_metric_functions() -> None:
    from rulkit import alpha_lambda, prognostic_horizon

    model, sim = _record(5)
    p0 = np.column_stack([np.zeros(400), np.random.default_rng(1).normal(0.012, 0.003, 400)])
    times = np.arange(5.0, 65.0, 5.0)
    times = times[times < sim.event_time]
    prof = prognosis_profile(model, sim.y, "pf", p0, times=times, t_eol=sim.event_time,
                             horizon=300.0, rng=np.random.default_rng(6))
    ph = prognostic_horizon(times, list(prof.distributions), sim.event_time, alpha=0.2,
                            bounds="relative")
    assert prof.prognostic_horizon().horizon == ph.horizon or (
        math.isnan(ph.horizon) and math.isnan(prof.prognostic_horizon().horizon))
    al = alpha_lambda(times, list(prof.distributions), sim.event_time, alpha=0.2, lam=0.5)
    assert prof.alpha_lambda(0.5) == al
    lo, hi = prof.lower, prof.upper
    r = prof.rul_true
    assert prof.coverage == pytest.approx(np.mean((lo <= r) & (r <= hi)))


def test_profile_plot_hands_its_data_to_rulkit_plot() -> None:
    """The figure itself is tested in tests/test_plot.py; here: the profile is accepted."""
    pytest.importorskip("matplotlib")
    model, sim = _record(7)
    p0 = np.column_stack([np.zeros(200), np.full(200, 0.015)])
    prof = prognosis_profile(model, sim.y, "pf", p0, times=[10.0, 20.0], t_eol=sim.event_time,
                             horizon=300.0, rng=np.random.default_rng(0))
    assert prof.dists is prof.distributions
    fig = prof.plot()
    assert len(fig.axes) >= 2
