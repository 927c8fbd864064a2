"""Onset model (docs/fleet-models.md eq. (9)-(10)): the mixture RUL against Monte Carlo and
against the single-Gaussian closed form; storage; online update."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ndtr

from rulkit.fleet.learned.degradation import UnitState, rul_quantiles
from rulkit.fleet.learned.hi_noise import HiNoiseModel
from rulkit.fleet.learned.onset import MixtureState, OnsetModel, mixture_columns


def _model(grid=(0.0, 0.5, 1.0, 1.5), walk=0.0):
    return OnsetModel(noise="additive", shape=0.0, mean=(-2.3, 2.0), cov=(1e-3, 0.0, 0.05),
                      hi_noise_sd=1e-9, log_noise_sd=0.0, walk_sd=walk, time_scale=100.0,
                      grid=grid, onset_mean=0.7, onset_sd=0.4)


def _state(model, w, x0=0.8):
    k = len(model.grid)
    return MixtureState(lw=np.log(np.asarray(w))[None, :],
                        m=np.tile([-0.9, 1.5], (1, k, 1)), p=np.tile([2e-3, 0.0, 0.02], (1, k, 1)),
                        t=np.array([x0 * model.time_scale]), hi=np.array([0.4]), n=np.array([5]))


def test_one_grid_value_equals_the_closed_form():
    """K = 1, onset 0: the mixture is one Gaussian; bisection = eq. (6)'s closed form."""
    m = _model(grid=(0.0,), walk=0.1)
    st = _state(m, [1.0])
    ref = HiNoiseModel(noise="additive", shape=0.0, mean=m.mean, cov=m.cov, hi_noise_sd=1e-9,
                       log_noise_sd=0.0, walk_sd=0.1, time_scale=100.0)
    g = UnitState(m=st.m[:, 0], p=st.p[:, 0], t=st.t, hi=st.hi, n=st.n)
    for a, b in zip(m.rul_quantiles(st), rul_quantiles(ref, g), strict=True):
        assert a[0] == pytest.approx(b[0], rel=1e-7)


def test_mixture_survival_against_monte_carlo():
    """eq. (10): draws of the onset (posterior weights), level and rate; the unit fails when
    level + rate * (time grown past the onset) reaches 0; P(RUL > r) by counting."""
    m = _model()
    w = np.array([0.1, 0.2, 0.3, 0.4])
    st = _state(m, w)
    rng = np.random.default_rng(0)
    n = 400_000
    k = rng.choice(4, size=n, p=w)
    lv = -0.9 + np.sqrt(2e-3) * rng.standard_normal(n)
    rate = 1.5 + np.sqrt(0.02) * rng.standard_normal(n)
    s = np.asarray(m.grid)[k]
    x0 = 0.8
    alive0 = lv < 0
    for r in (20.0, 50.0, 90.0):
        e = np.maximum(x0 + r / 100.0 - s, 0) - np.maximum(x0 - s, 0)
        surv = np.mean(lv + rate * e < 0) / np.mean(alive0)  # the exceedance form, marginal
        assert 1 - m.rul_cdf(st, np.array([[r]]))[0, 0] == pytest.approx(surv, abs=4e-3)


def test_quantiles_invert_the_cdf_and_censored_mass():
    m = _model()
    st = _state(m, [0.25, 0.25, 0.25, 0.25])
    med, lo, hi = m.rul_quantiles(st)
    f = m.rul_cdf(st, np.column_stack([lo, med, hi]))
    np.testing.assert_allclose(f[0], [0.05, 0.5, 0.95], atol=1e-6)
    # a rate mostly <= 0: the upper quantiles are in the never-failing mass
    neg = MixtureState(lw=st.lw, m=np.tile([-0.9, -0.2], (1, 4, 1)), p=st.p, t=st.t, hi=st.hi,
                       n=st.n)
    never = float(ndtr(0.2 / np.sqrt(0.02)))
    assert never > 0.5
    med, lo, hi = m.rul_quantiles(neg)
    assert np.isinf(med[0]) and np.isinf(hi[0]) and np.isfinite(lo[0])


def test_state_columns_round_trip_and_dict():
    m = _model()
    st = m.empty_state(3)
    cols = st.columns()
    assert tuple(cols) == mixture_columns(4) == m.state_columns
    back = m.state_from_columns(cols)
    np.testing.assert_array_equal(back.m, st.m)
    np.testing.assert_array_equal(back.lw, st.lw)
    assert OnsetModel.from_dict(m.to_dict()) == m
    st2 = m.update(st, np.array([10.0, np.nan, 30.0]), np.array([0.1, np.nan, 0.12]))
    assert list(st2.n) == [1, 0, 1] and np.isnan(m.rul_quantiles(st2)[0][1])


def _onset_fleet(n_units):
    """A small fleet of the onset kind (flat at 0.1 for about 180 time units, then exponential
    growth over about 300) and the generator's parameters in scaled age."""
    from rulkit.fleet.learned.datasets import synthetic_growth_fleet
    from rulkit.fleet.learned.degradation import time_scale_of
    from rulkit.fleet.learned.growth_filter import GrowthParams
    from rulkit.fleet.learned.histories import histories_from_frame

    df, _ = synthetic_growth_fleet(np.random.default_rng(3), n_units, n_acq=25, onset_frac=0.6)
    hist = histories_from_frame(df, "onset fleet")
    tau = time_scale_of(hist)
    rate = np.log(10.0) / 300.0 * tau
    truth = GrowthParams(mean=(np.log(0.1), rate), cov=(1e-6, 0.0, (0.25 * rate) ** 2),
                         r_log=0.0, r_hi=0.02**2, q=1e-8, onset_mean=180.0 / tau,
                         onset_sd=54.0 / tau)
    return hist, tau, truth


def _log_lik(hist, tau, theta, lam, grid):
    from rulkit.fleet.learned.filter_kernels import negative_log_likelihood

    return -negative_log_likelihood(theta, hist.t / tau, hist.hi, hist.start.astype(np.int64),
                                    lam, np.asarray(grid))


def test_halved_keeps_the_grid_and_halves_its_step():
    from rulkit.fleet.learned.onset import halved

    assert halved((0.0, 1.0, 2.0)) == (0.0, 0.5, 1.0, 1.5, 2.0)


def test_twelve_onsets_are_too_coarse_and_halving_converges_to_the_quadrature():
    """Eq. (9) at the generator's own parameters: the sum over 12 onsets misses the
    brute-force quadrature (385 onsets) by several ONSET_GRID_TOL, which grid_error sees;
    halving the step until grid_error is below the tolerance lands within it of the reference."""
    from rulkit.fleet.learned.onset import ONSET_GRID_TOL, grid_error, halved, onset_grid

    hist, tau, truth = _onset_fleet(8)
    theta = truth.theta()
    grid = onset_grid(hist, tau)
    ref = _log_lik(hist, tau, theta, 0.0, np.linspace(0.0, grid[-1], 12 * 32 + 1))
    assert abs(_log_lik(hist, tau, theta, 0.0, grid) - ref) > 3 * ONSET_GRID_TOL
    assert grid_error(theta, hist, hist.t / tau, 0.0, grid) > ONSET_GRID_TOL
    while grid_error(theta, hist, hist.t / tau, 0.0, grid) > ONSET_GRID_TOL:
        grid = halved(grid)
    assert len(grid) < 12 * 32
    assert abs(_log_lik(hist, tau, theta, 0.0, grid) - ref) < 2 * ONSET_GRID_TOL


def test_a_grid_stopped_at_its_cap_before_converging_is_a_stored_warning(monkeypatch):
    """With the refinement capped at the starting 12 values (a fleet whose onsets the largest
    grid cannot resolve), fit_onset reports the quadrature error it stopped at, and check_fit
    turns it into a warning that says what to do."""
    import rulkit.fleet.learned.onset as onset
    from rulkit.fleet.learned.checks import check_fit

    hist, _, _ = _onset_fleet(6)
    monkeypatch.setattr(onset, "ONSET_GRID_MAX", 12)
    model = onset.fit_onset(hist)
    assert len(model.grid) == 12
    assert model.diagnostics.grid_error > onset.ONSET_GRID_TOL
    assert model.diagnostics.grid_error == pytest.approx(onset.grid_error(
        model.params().theta(), hist, hist.t / model.time_scale, model.shape, model.grid))
    warnings = [w for w in check_fit(model) if "onset grid" in w]
    assert len(warnings) == 1 and "12 values" in warnings[0]


@pytest.mark.slow
def test_the_fitted_grid_resolves_the_true_onset_distribution():
    """The grid fit_onset keeps is a converged quadrature of eq. (9): at the generator's own
    parameters its log-likelihood is within 2 ONSET_GRID_TOL of the brute-force one (the
    12-value grid is more than 5 nats off, test above), and at the fitted parameters too."""
    from rulkit.fleet.learned.onset import ONSET_GRID_TOL, fit_onset

    hist, tau, truth = _onset_fleet(8)
    model = fit_onset(hist)
    assert model.time_scale == tau and len(model.grid) > 12
    assert model.diagnostics.grid_error == 0.0  # converged: no warning
    brute = np.linspace(0.0, model.grid[-1], 12 * 32 + 1)
    for theta, lam in ((truth.theta(), 0.0), (model.params().theta(), model.shape)):
        err = _log_lik(hist, tau, theta, lam, model.grid) - _log_lik(hist, tau, theta, lam, brute)
        assert abs(err) < 2 * ONSET_GRID_TOL
