"""Particle filter against an exact Kalman filter (oracle written here, numpy only), plus the
contract: log-weights, degenerate updates, missing measurements, plug-ins, per-step API,
reproducibility and validation.

Monte Carlo comparisons run R independent filters (independent seeds) and z-test the mean
difference to the Kalman filter at every step; a precision bound makes sure a z-test cannot pass
merely because the filter is noisy.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import logsumexp

from rulkit.estimation.particle import ParticleFilter, ParticleState
from rulkit.estimation.resampling import systematic
from rulkit.estimation.weights import (
    DegenerateWeightsError,
    effective_sample_size,
    log_normalise,
    weighted_cov,
    weighted_mean,
    weighted_quantile,
)

Z_MAX = 5.0


# ---------------------------------------------------------------------------------------------
# Exact oracle and linear-Gaussian models
# ---------------------------------------------------------------------------------------------


def kalman_oracle(F, Q, H, R, m0, P0, ys):
    """Exact KF: predict then update for every row of ys (T, m); NaN rows: predict only.

    Returns filtered means (T, n), covariances (T, n, n) and the log marginal likelihood.
    """
    m, P = m0.astype(float), P0.astype(float)
    means, covs, ll = [], [], 0.0
    for y in ys:
        m = F @ m
        P = F @ P @ F.T + Q
        if not np.isnan(y).any():
            S = H @ P @ H.T + R
            nu = y - H @ m
            K = np.linalg.solve(S, H @ P).T
            m = m + K @ nu
            P = P - K @ S @ K.T
            _, logdet = np.linalg.slogdet(S)
            ll += -0.5 * (nu @ np.linalg.solve(S, nu) + logdet + len(y) * math.log(2 * math.pi))
        means.append(m)
        covs.append(P)
    return np.array(means), np.array(covs), ll


def lg_functions(F, Q, H, R):
    """Transition and normalised Gaussian log-likelihood of the model x' = F x + w, y = H x + v."""
    Lq = np.linalg.cholesky(Q)
    Rinv = np.linalg.inv(R)
    const = -0.5 * (R.shape[0] * math.log(2 * math.pi) + np.linalg.slogdet(R)[1])

    def transition(x, k, rng):
        return x @ F.T + rng.standard_normal(x.shape) @ Lq.T

    def log_likelihood(x, y, k):
        e = y - x @ H.T
        return const - 0.5 * np.einsum("ij,jk,ik->i", e, Rinv, e)

    return transition, log_likelihood


def simulate(F, Q, H, R, m0, P0, T, rng):
    n, my = F.shape[0], H.shape[0]
    x = m0 + np.linalg.cholesky(P0) @ rng.standard_normal(n)
    ys = np.empty((T, my))
    for k in range(T):
        x = F @ x + np.linalg.cholesky(Q) @ rng.standard_normal(n)
        ys[k] = H @ x + np.linalg.cholesky(R) @ rng.standard_normal(my)
    return ys


RANDOM_WALK = {
    "F": np.eye(1),
    "Q": np.array([[0.2]]),
    "H": np.eye(1),
    "R": np.array([[0.5]]),
    "m0": np.array([1.0]),
    "P0": np.array([[2.0]]),
}
DT = 0.5
CONST_VEL = {
    "F": np.array([[1.0, DT], [0.0, 1.0]]),
    "Q": 0.3 * np.array([[DT**3 / 3, DT**2 / 2], [DT**2 / 2, DT]]),
    "H": np.array([[1.0, 0.0]]),
    "R": np.array([[0.4]]),
    "m0": np.array([0.0, 1.0]),
    "P0": np.diag([1.0, 0.5]),
}


def run_many(model, ys, n_particles, n_runs, seed, **pf_kwargs):
    tr, ll = lg_functions(model["F"], model["Q"], model["H"], model["R"])
    pf = ParticleFilter(tr, ll, **pf_kwargs)
    seeds = np.random.SeedSequence(seed).spawn(n_runs)
    out = []
    for s in seeds:
        rng = np.random.default_rng(s)
        x0 = (
            model["m0"]
            + rng.standard_normal((n_particles, model["m0"].size))
            @ np.linalg.cholesky(model["P0"]).T
        )
        out.append(pf.filter(ys, x0, rng, quantiles=None))
    return out


def max_z(samples: np.ndarray, target: np.ndarray) -> float:
    """Largest |t| statistic of mean(samples - target) over runs (axis 0)."""
    d = samples - target
    se = d.std(axis=0, ddof=1) / np.sqrt(d.shape[0])
    return float(np.max(np.abs(d.mean(axis=0)) / se))


# ---------------------------------------------------------------------------------------------
# Against the exact Kalman filter
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["random_walk", "constant_velocity"])
@pytest.mark.parametrize("resampler", ["systematic", "residual"])
def test_matches_kalman_filter(name, resampler):
    model = RANDOM_WALK if name == "random_walk" else CONST_VEL
    T, N, R_RUNS = 40, 4000, 30
    ys = simulate(**model, T=T, rng=np.random.default_rng(2024))
    ys[[7, 8, 25]] = np.nan  # missing measurements: the KF oracle predicts only
    kf_m, kf_P, kf_ll = kalman_oracle(**model, ys=ys)
    res = run_many(model, ys, N, R_RUNS, seed=1, resampler=resampler)

    means = np.stack([r.mean for r in res])  # (R, T, n)
    covs = np.stack([r.cov for r in res])
    lls = np.array([r.loglik for r in res])
    sd = np.sqrt(np.diagonal(kf_P, axis1=1, axis2=2))  # (T, n)

    # unbiased within Monte Carlo error, at every step and component
    assert max_z(means, kf_m) < Z_MAX
    assert max_z(covs, kf_P) < Z_MAX
    # and precise (loose sanity bounds, so a very noisy filter cannot pass on the z-test alone;
    # measured at N=4000: rms mean error <= ~0.15 sd, variance within ~35 %, loglik sd ~0.15)
    assert (np.sqrt(np.mean((means - kf_m) ** 2, axis=0)) / sd).max() < 0.25
    rel_var = np.diagonal(covs, axis1=2, axis2=3) / np.diagonal(kf_P, axis1=1, axis2=2)
    assert np.abs(rel_var - 1).max() < 0.5
    # the likelihood estimator exp(loglik) is unbiased for p(y_{1:T}): ratio to the exact one
    assert max_z(np.exp(lls - kf_ll)[:, None], np.ones(1)) < Z_MAX
    assert np.abs(lls - kf_ll).max() < 1.0 and (lls - kf_ll).std() < 0.3
    # missing measurements skipped and flagged, with a zero increment
    for r in res:
        np.testing.assert_array_equal(np.flatnonzero(r.skipped), [7, 8, 25])
        assert np.all(r.loglik_increments[[7, 8, 25]] == 0.0)
        assert r.loglik == pytest.approx(r.loglik_increments.sum())


def test_loglik_without_resampling_uses_previous_weights():
    """ess_threshold=0 (never resample): the increment must be log sum_i W_{k-1}^i p(y_k|x^i).

    The naive log mean_i p(y_k | x^i) ignores the carried weights; the same z-test that our
    estimate passes rejects it, so the test can tell the two apart.
    """
    model = RANDOM_WALK
    T, N, R_RUNS = 8, 500, 60
    ys = simulate(**model, T=T, rng=np.random.default_rng(5))
    _, _, kf_ll = kalman_oracle(**model, ys=ys)
    tr, ll = lg_functions(model["F"], model["Q"], model["H"], model["R"])
    recorded: list[np.ndarray] = []

    def ll_rec(x, y, k):
        v = ll(x, y, k)
        recorded.append(v)
        return v

    pf = ParticleFilter(tr, ll_rec, ess_threshold=0.0)
    ours, naive = [], []
    for s in np.random.SeedSequence(77).spawn(R_RUNS):
        rng = np.random.default_rng(s)
        recorded.clear()
        x0 = model["m0"] + math.sqrt(model["P0"][0, 0]) * rng.standard_normal((N, 1))
        r = pf.filter(ys, x0, rng, quantiles=None)
        assert not r.resampled.any()
        ours.append(r.loglik)
        naive.append(sum(logsumexp(v) - math.log(N) for v in recorded))
    ratio_ours = np.exp(np.array(ours) - kf_ll)[:, None]
    ratio_naive = np.exp(np.array(naive) - kf_ll)[:, None]
    assert max_z(ratio_ours, np.ones(1)) < Z_MAX
    assert max_z(ratio_naive, np.ones(1)) > 10


def test_loglik_increments_hand_computed():
    # deterministic transition (identity), two particles, known log-likelihoods per step
    lls = np.array([[0.0, math.log(3.0)], [math.log(2.0), 0.0], [0.0, 0.0]])
    pf = ParticleFilter(lambda x, k, rng: x, lambda x, y, k: lls[k].copy(), ess_threshold=0.0)
    r = pf.filter(np.zeros(3), np.zeros((2, 1)), np.random.default_rng(0), quantiles=None)
    # k=0: W=(1/2,1/2): log((1+3)/2); weights -> (1/4, 3/4)
    # k=1: log(1/4*2 + 3/4*1) = log(5/4); weights -> (2/5, 3/5); k=2: log 1 = 0
    np.testing.assert_allclose(r.loglik_increments, [math.log(2.0), math.log(1.25), 0.0])
    np.testing.assert_allclose(r.posterior().weights, [0.4, 0.6])
    np.testing.assert_allclose(r.ess, [1 / (1 / 16 + 9 / 16), 1 / (4 / 25 + 9 / 25), 1 / 0.52])


def test_reproducible_from_seed_and_kernel_equals_public_resampler():
    tr, ll = lg_functions(**{k: CONST_VEL[k] for k in "FQHR"})
    ys = simulate(**CONST_VEL, T=30, rng=np.random.default_rng(1))
    x0 = np.random.default_rng(2).standard_normal((300, 2))
    a = ParticleFilter(tr, ll).filter(ys, x0, np.random.default_rng(3), keep_particles=True)
    b = ParticleFilter(tr, ll).filter(ys, x0, np.random.default_rng(3), keep_particles=True)
    c = ParticleFilter(tr, ll, resampler=systematic).filter(
        ys, x0, np.random.default_rng(3), keep_particles=True
    )
    d = ParticleFilter(tr, ll).filter(ys, x0, np.random.default_rng(4), keep_particles=True)
    for other in (b, c):
        for field in ("mean", "cov", "quantiles", "ess", "resampled", "loglik_increments"):
            np.testing.assert_array_equal(getattr(a, field), getattr(other, field))
        np.testing.assert_array_equal(a.particle_history, other.particle_history)
    assert not np.array_equal(a.mean, d.mean)
    assert a.resampled.any() and not a.resampled.all()


def test_per_step_api_matches_filter():
    tr, ll = lg_functions(**{k: CONST_VEL[k] for k in "FQHR"})
    ys = simulate(**CONST_VEL, T=25, rng=np.random.default_rng(8))
    ys[4] = np.nan
    x0 = np.random.default_rng(2).standard_normal((200, 2))
    pf = ParticleFilter(tr, ll, resampler="stratified")
    ref = pf.filter(ys, x0, np.random.default_rng(6))
    state = pf.initialise(x0, np.random.default_rng(6))
    assert state.k == -1 and state.ess == pytest.approx(200)
    for k, y in enumerate(ys):
        pf.update(state, y)
        assert state.k == k
        np.testing.assert_array_equal(state.mean(), ref.mean[k])
        np.testing.assert_array_equal(state.cov(), ref.cov[k])
        np.testing.assert_array_equal(state.quantile([0.025, 0.5, 0.975]), ref.quantiles[k])
        assert state.skipped == ref.skipped[k]
        assert pf.fires(state) == ref.resampled[k]
        if k < len(ys) - 1:  # the final set is not resampled (nothing follows it)
            pf.resample_if_needed(state)
    assert state.loglik == pytest.approx(ref.loglik, rel=1e-12)
    final = ref.posterior()
    np.testing.assert_array_equal(state.particles, final.samples)
    np.testing.assert_allclose(state.weights, final.weights, rtol=1e-14)
    # step() = the resampling the previous step asked for, then update: the same draws
    s2 = pf.initialise(x0, np.random.default_rng(6))
    for k, y in enumerate(ys):
        pf.step(s2, y)
        np.testing.assert_array_equal(s2.mean(), ref.mean[k])
        assert s2.resample_pending == ref.resampled[k]
    np.testing.assert_array_equal(s2.particles, final.samples)
    np.testing.assert_array_equal(s2.posterior().mean, final.mean)


def test_keep_particles_history_consistent():
    tr, ll = lg_functions(**{k: RANDOM_WALK[k] for k in "FQHR"})
    ys = simulate(**RANDOM_WALK, T=12, rng=np.random.default_rng(0))
    r = ParticleFilter(tr, ll).filter(
        ys, np.zeros((100, 1)), np.random.default_rng(1), keep_particles=True
    )
    assert r.particle_history.shape == (12, 100, 1) and r.weight_history.shape == (12, 100)
    for k in range(12):
        np.testing.assert_allclose(r.mean[k], r.weight_history[k] @ r.particle_history[k])
        np.testing.assert_allclose(
            r.quantiles[k],
            weighted_quantile(r.particle_history[k], r.weight_history[k], r.quantile_levels),
        )
        post = r.posterior(k)  # the weighted set of step k, weights travelling with it
        np.testing.assert_array_equal(post.samples, r.particle_history[k])
        np.testing.assert_allclose(post.weights, r.weight_history[k], rtol=1e-14)
        np.testing.assert_allclose(post.mean, r.mean[k], rtol=1e-12)
    final = r.posterior()
    assert final.samples.shape == (100, 1) and final.weights.sum() == pytest.approx(1.0)
    np.testing.assert_array_equal(final.samples, r.particle_history[-1])
    none = ParticleFilter(tr, ll).filter(ys, np.zeros((100, 1)), np.random.default_rng(1))
    assert none.particle_history is None and none.weight_history is None
    np.testing.assert_array_equal(none.posterior(-1).samples, final.samples)
    with pytest.raises(ValueError, match="keep_particles=True"):
        none.posterior(3)


# ---------------------------------------------------------------------------------------------
# Resampling rule, trigger and weight-update plug-ins
# ---------------------------------------------------------------------------------------------


def _rw_setup(T=20, N=200):
    tr, ll = lg_functions(**{k: RANDOM_WALK[k] for k in "FQHR"})
    ys = simulate(**RANDOM_WALK, T=T, rng=np.random.default_rng(3))
    x0 = np.random.default_rng(4).normal(1.0, 1.4, (N, 1))
    return tr, ll, ys, x0


def test_ess_threshold_rule():
    tr, ll, ys, x0 = _rw_setup()
    never = ParticleFilter(tr, ll, ess_threshold=0.0).filter(ys, x0, np.random.default_rng(0))
    always = ParticleFilter(tr, ll, ess_threshold=1.0).filter(ys, x0, np.random.default_rng(0))
    half = ParticleFilter(tr, ll, ess_threshold=0.5).filter(ys, x0, np.random.default_rng(0))
    assert not never.resampled.any()
    assert always.resampled.all()
    np.testing.assert_array_equal(half.resampled, half.ess < 0.5 * 200)
    assert half.resampled.any() and not half.resampled.all()
    # without resampling the weights degenerate
    assert never.ess[-1] < 0.1 * 200


def test_trigger_overrides_ess_rule():
    tr, ll, ys, x0 = _rw_setup()
    seen = []

    def every_third(state: ParticleState) -> bool:
        seen.append((state.k, state.ess))
        return state.k % 3 == 2

    r = ParticleFilter(tr, ll, trigger=every_third, ess_threshold=0.0).filter(
        ys, x0, np.random.default_rng(0)
    )
    np.testing.assert_array_equal(r.resampled, np.arange(20) % 3 == 2)
    assert [k for k, _ in seen] == list(range(20))
    np.testing.assert_allclose([e for _, e in seen], r.ess)  # trigger sees the updated ESS


def test_weight_update_plugin_tempering_and_state_contents():
    tr, ll, ys, x0 = _rw_setup()
    calls = []

    def tempered(logw, loglik, state):
        calls.append((state.k, state.y.copy(), state.particles.copy(), state.weights.copy()))
        assert isinstance(state.rng, np.random.Generator)
        return logw + 0.5 * loglik

    a = ParticleFilter(tr, ll, weight_update=tempered).filter(
        ys, x0, np.random.default_rng(0), keep_particles=True
    )
    b = ParticleFilter(tr, lambda x, y, k: 0.5 * ll(x, y, k)).filter(
        ys, x0, np.random.default_rng(0)
    )
    np.testing.assert_allclose(a.mean, b.mean, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(a.resampled, b.resampled)
    # the plug-in saw step k, its measurement, the propagated particles and the previous weights
    assert [c[0] for c in calls] == list(range(20))
    for k, (_, y, x, w_prev) in enumerate(calls):
        np.testing.assert_array_equal(y, ys[k])
        np.testing.assert_array_equal(x, a.particle_history[k])
        if k > 0 and not a.resampled[k - 1]:
            np.testing.assert_array_equal(w_prev, a.weight_history[k - 1])
    # loglik still reports log sum W_{k-1} p(y_k | x) with the untempered likelihood
    inc0 = logsumexp(ll(a.particle_history[0], ys[0], 0)) - math.log(200)
    assert a.loglik_increments[0] == pytest.approx(inc0, rel=1e-12)


# ---------------------------------------------------------------------------------------------
# Degenerate weights, missing data, validation
# ---------------------------------------------------------------------------------------------


def _ll_dead_at(step, value=-np.inf):
    def ll(x, y, k):
        out = -0.5 * (y - x[:, 0]) ** 2
        if k == step:
            out = np.full(x.shape[0], value)
        return out

    return ll


def _rw(x, k, rng):
    return x + 0.1 * rng.standard_normal(x.shape)


def test_degenerate_update_raises_naming_step():
    pf = ParticleFilter(_rw, _ll_dead_at(3))
    with pytest.raises(DegenerateWeightsError, match=r"step 3.*every log-weight is -inf") as ei:
        pf.filter(np.zeros(6), np.zeros((50, 1)), np.random.default_rng(0))
    assert ei.value.step == 3


def test_nan_loglik_raises():
    def ll(x, y, k):
        out = -0.5 * (y - x[:, 0]) ** 2
        if k == 2:
            out[5] = np.nan
        return out

    with pytest.raises(DegenerateWeightsError, match=r"step 2.*1 of 50 log-weights are NaN"):
        ParticleFilter(_rw, ll).filter(np.zeros(4), np.zeros((50, 1)), np.random.default_rng(0))


def test_reset_recovery_flags_step():
    pf = ParticleFilter(_rw, _ll_dead_at(3), recovery="reset")
    r = pf.filter(np.zeros(6), np.zeros((50, 1)), np.random.default_rng(0), keep_particles=True)
    np.testing.assert_array_equal(r.reset, np.arange(6) == 3)
    np.testing.assert_array_equal(r.weight_history[3], np.full(50, 1 / 50))
    assert r.loglik_increments[3] == -np.inf and r.loglik == -np.inf
    assert np.isfinite(r.loglik_increments[[0, 1, 2, 4, 5]]).all()
    assert np.isfinite(r.mean).all()


def test_failed_step_leaves_state_unchanged():
    pf = ParticleFilter(_rw, _ll_dead_at(1))
    state = pf.initialise(np.zeros((20, 1)), np.random.default_rng(0))
    pf.step(state, 0.0)
    before = (state.particles.copy(), state.weights.copy(), state.k, state.loglik)
    with pytest.raises(DegenerateWeightsError):
        pf.step(state, 0.0)
    np.testing.assert_array_equal(state.particles, before[0])
    np.testing.assert_array_equal(state.weights, before[1])
    assert (state.k, state.loglik) == before[2:]


def test_non_finite_transition_named_and_state_unchanged():
    def blow_up(x, k, rng):
        out = x + rng.standard_normal(x.shape)
        if k == 2:
            out[7, 0] = np.nan
        return out

    pf = ParticleFilter(blow_up, _ll_dead_at(-1))
    state = pf.initialise(np.zeros((20, 1)), np.random.default_rng(0))
    pf.step(state, 0.0)
    pf.step(state, 0.0)
    before = (state.particles.copy(), state.weights.copy(), state.k, state.loglik)
    with pytest.raises(ValueError, match=r"transition at step 2: non-finite value nan at "
                                         r"particle 7, state 0"):
        pf.step(state, 0.0)
    np.testing.assert_array_equal(state.particles, before[0])
    np.testing.assert_array_equal(state.weights, before[1])
    assert (state.k, state.loglik) == before[2:]


def test_missing_measurement_policies():
    ys = np.array([0.0, np.nan, 0.1])
    x0 = np.zeros((30, 1))
    ll = _ll_dead_at(-1)
    r = ParticleFilter(_rw, ll).filter(ys, x0, np.random.default_rng(0))
    np.testing.assert_array_equal(r.skipped, [False, True, False])
    assert r.loglik_increments[1] == 0.0
    with pytest.raises(ValueError, match="NaN in row 1"):
        ParticleFilter(_rw, ll, missing="raise").filter(ys, x0, np.random.default_rng(0))
    # "pass": the likelihood gets the NaN and here turns it into NaN log-weights -> loud error
    with pytest.raises(DegenerateWeightsError, match="step 1"):
        ParticleFilter(_rw, ll, missing="pass").filter(ys, x0, np.random.default_rng(0))
    with pytest.raises(ValueError, match="infinite value in row 2"):
        ParticleFilter(_rw, ll).filter([0.0, 1.0, np.inf], x0, np.random.default_rng(0))
    # per-step API applies the same policy
    pf = ParticleFilter(_rw, ll)
    s = pf.initialise(x0, np.random.default_rng(0))
    pf.step(s, np.nan)
    assert s.skipped and s.loglik == 0.0
    with pytest.raises(ValueError, match="step 1: infinite"):
        pf.step(s, np.inf)


@pytest.mark.parametrize(
    ("particles", "match"),
    [
        (np.zeros(10), r"expected shape \(N, n_x\).*reshape"),
        (np.zeros((0, 2)), "at least one row"),
        (np.array([[0.0], [np.nan]]), "particles0: non-finite value nan at row 1, column 0"),
        (np.array([[0.0, np.inf]]), "particles0: non-finite value inf at row 0, column 1"),
    ],
)
def test_invalid_particles(particles, match):
    with pytest.raises(ValueError, match=match):
        ParticleFilter(_rw, _ll_dead_at(-1)).filter(
            np.zeros(3), particles, np.random.default_rng(0)
        )


def test_invalid_configuration():
    ll = _ll_dead_at(-1)
    for thr in (-0.1, 1.5, np.nan):
        with pytest.raises(ValueError, match="ess_threshold"):
            ParticleFilter(_rw, ll, ess_threshold=thr)
    with pytest.raises(ValueError, match="unknown resampler"):
        ParticleFilter(_rw, ll, resampler="bogus")
    with pytest.raises(ValueError, match="recovery"):
        ParticleFilter(_rw, ll, recovery="ignore")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="missing"):
        ParticleFilter(_rw, ll, missing="zero")  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="rng"):
        ParticleFilter(_rw, ll).filter(np.zeros(2), np.zeros((5, 1)), 42)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="quantiles"):
        ParticleFilter(_rw, ll).filter(
            np.zeros(2), np.zeros((5, 1)), np.random.default_rng(0), quantiles=(0.5, 1.5)
        )
    with pytest.raises(ValueError, match="ys"):
        ParticleFilter(_rw, ll).filter(np.zeros(0), np.zeros((5, 1)), np.random.default_rng(0))


def test_bad_callback_outputs_name_the_step():
    x0 = np.zeros((5, 2))
    with pytest.raises(ValueError, match=r"transition at step 0.*\(5, 1\)"):
        ParticleFilter(lambda x, k, rng: x[:, :1], lambda x, y, k: np.zeros(5)).filter(
            np.zeros(2), x0, np.random.default_rng(0)
        )
    with pytest.raises(ValueError, match=r"log_likelihood at step 0.*\(5,\)"):
        ParticleFilter(lambda x, k, rng: x, lambda x, y, k: np.zeros((5, 1))).filter(
            np.zeros(2), x0, np.random.default_rng(0)
        )
    with pytest.raises(ValueError, match="resampler returned shape"):
        ParticleFilter(
            lambda x, k, rng: x,
            lambda x, y, k: np.zeros(5),
            resampler=lambda w, rng: np.arange(3),
            ess_threshold=1.0,
        ).filter(np.zeros(2), x0, np.random.default_rng(0))


# ---------------------------------------------------------------------------------------------
# Weight utilities against independent references
# ---------------------------------------------------------------------------------------------


def test_log_normalise_matches_scipy_and_does_not_overflow():
    lw = np.array([1000.0, 1001.0, -np.inf, 999.5])
    w, lse = log_normalise(lw)
    assert lse == pytest.approx(logsumexp(lw), rel=1e-14)
    np.testing.assert_allclose(w, np.exp(lw - logsumexp(lw)), rtol=1e-12)
    assert w[2] == 0.0 and w.sum() == pytest.approx(1.0)
    with pytest.raises(DegenerateWeightsError, match="-inf"):
        log_normalise(np.full(3, -np.inf))
    with pytest.raises(DegenerateWeightsError, match="NaN"):
        log_normalise(np.array([0.0, np.nan]))
    with pytest.raises(DegenerateWeightsError, match=r"\+inf"):
        log_normalise(np.array([0.0, np.inf]))
    with pytest.raises(ValueError, match="1-D"):
        log_normalise(np.zeros((2, 2)))


def test_effective_sample_size():
    assert effective_sample_size(np.full(8, 1 / 8)) == pytest.approx(8)
    assert effective_sample_size(np.eye(1, 8)[0]) == pytest.approx(1)
    assert effective_sample_size(np.array([0.5, 0.5, 0.0])) == pytest.approx(2)


def test_weighted_moments_match_numpy():
    rng = np.random.default_rng(0)
    x = rng.standard_normal((50, 3))
    w = rng.dirichlet(np.ones(50))
    np.testing.assert_allclose(weighted_mean(x, w), np.average(x, axis=0, weights=w))
    np.testing.assert_allclose(weighted_cov(x, w), np.cov(x.T, aweights=w, bias=True))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_weighted_quantile_matches_numpy_inverted_cdf(seed):
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((40, 2))
    w = rng.dirichlet(np.ones(40))
    w[[3, 17]] = 0.0
    w /= w.sum()
    q = np.array([0.0, 0.025, 0.3, 0.5, 0.975, 1.0])
    got = weighted_quantile(x, w, q)
    for j in range(2):
        ref = np.quantile(x[:, j], q, weights=w, method="inverted_cdf")
        np.testing.assert_array_equal(got[:, j], ref)
        # never a zero-weight particle
        assert not np.isin(got[:, j], x[[3, 17], j]).any()
    # equal weights: the classical inverted-CDF sample quantile; integer weights: repetition
    np.testing.assert_array_equal(
        weighted_quantile(x[:, 0], np.ones(40), q), np.quantile(x[:, 0], q, method="inverted_cdf")
    )
    reps = rng.integers(1, 4, 40)
    np.testing.assert_array_equal(
        weighted_quantile(x[:, 1], reps.astype(float), q),
        np.quantile(np.repeat(x[:, 1], reps), q, method="inverted_cdf"),
    )
    assert np.ndim(weighted_quantile(x[:, 0], w, 0.5)) == 0
    assert weighted_quantile(x, w, 0.5).shape == (2,)
    with pytest.raises(ValueError, match="q must be"):
        weighted_quantile(x, w, 1.5)
    bad_w = w.copy()
    bad_w[5] = -bad_w[5]
    for ww in (bad_w, np.zeros_like(w), np.where(np.arange(w.size) == 0, np.nan, w)):
        with pytest.raises(ValueError, match="weights must be finite, non-negative"):
            weighted_quantile(x, ww, 0.5)
    with pytest.raises(ValueError, match="values contain NaN"):
        weighted_quantile(np.where(np.arange(x.shape[0])[:, None] == 2, np.nan, x), w, 0.5)


def test_per_step_accepts_non_numeric_measurement():
    # system code may pass e.g. (measurement, input) pairs through the per-step API
    def ll(x, y, k):
        return -0.5 * (y["z"] - x[:, 0]) ** 2

    pf = ParticleFilter(_rw, ll)
    s = pf.initialise(np.zeros((10, 1)), np.random.default_rng(0))
    pf.step(s, {"z": 0.3})
    assert s.k == 0 and not s.skipped and np.isfinite(s.loglik)


def test_per_step_covariance_matches_numpy_weighted_cov():
    """The filter's per-step covariance (computed on the transpose) against numpy's weighted
    covariance of the kept weighted particle sets, for a 2-state model."""
    f = np.array([[1.0, 1.0], [0.0, 1.0]])

    def tr(x, k, rng):
        return x @ f.T + rng.standard_normal(x.shape) * [0.1, 0.01]

    def ll(x, y, k):
        return -0.5 * ((y[0] - x[:, 0]) / 0.5) ** 2

    ys = np.cumsum(np.full(8, 0.3))[:, None] + np.random.default_rng(0).normal(0, 0.5, (8, 1))
    x0 = np.random.default_rng(1).normal([0.0, 0.3], [1.0, 0.1], (500, 2))
    r = ParticleFilter(tr, ll).filter(ys, x0, np.random.default_rng(2), keep_particles=True)
    for k in range(8):
        x, w = r.particle_history[k], r.weight_history[k]
        np.testing.assert_allclose(r.cov[k], np.cov(x.T, aweights=w, bias=True),
                                   rtol=1e-10, atol=1e-15)
        np.testing.assert_allclose(r.cov[k], weighted_cov(x, w), rtol=1e-12, atol=1e-17)


def test_weight_update_plugin_array_is_not_modified():
    """A weight_update that returns an array it keeps (here: the log-likelihood itself) must
    not see it changed by the filter's normalisation."""
    kept = []

    def wu(logw, ll, state):
        kept.append((ll, ll.copy()))
        return ll

    def tr(x, k, rng):
        return x + rng.standard_normal(x.shape)

    def ll(x, y, k):
        return -0.5 * (y[0] - x[:, 0]) ** 2

    ParticleFilter(tr, ll, weight_update=wu).filter(
        np.zeros((3, 1)), np.zeros((50, 1)), np.random.default_rng(0)
    )
    assert len(kept) == 3
    for arr, copy in kept:
        np.testing.assert_array_equal(arr, copy)
