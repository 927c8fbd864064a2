"""Step 2 of the reaction-wheel study: batched trackers against oracles (exact Kalman filter,
the engine's resampler and ParticleFilter), numba == numpy, batching invariance."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rulkit.systems.reaction_wheel.degradation.trackers import (
    one_step_pf,
    rbpf,
    rbpf_engine,
    two_step_pf,
)
from rulkit.systems.reaction_wheel.lubrication import SAMPLE_DT

from .conftest import BETA_REF, tracking_problem, unit_rngs


@pytest.mark.parametrize("tracker", ["one_step", "two_step", "rbpf"])
def test_numba_kernels_equal_numpy_path(tracker: str) -> None:
    # 300 windows cross a noise-block boundary (256); a snapshot splits a segment
    st, setup, y, q = tracking_problem(3, 300 * 240 / 86400, err_std=0.5)
    out = {}
    for be in ("numba", "numpy"):
        kw = dict(beta_ref=BETA_REF, snapshot_windows=(100,), backend=be)
        if tracker == "one_step":
            out[be] = one_step_pf(y, q, setup.sigma_y, st, unit_rngs(1, 3), **kw)
        elif tracker == "two_step":
            out[be] = two_step_pf(y, q, setup.sigma_y, st, unit_rngs(1, 3), unit_rngs(2, 3), **kw)
        else:
            out[be] = rbpf(y, q, setup.sigma_y, st, unit_rngs(1, 3), **kw)
    a, b = out["numba"], out["numpy"]
    for name in ("b_mean", "b_std", "beta0_mean", "beta0_std"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-9, atol=1e-20)
    assert a.n_resampled == b.n_resampled > 0
    np.testing.assert_allclose(a.snapshots[100][0], b.snapshots[100][0], rtol=1e-9)


def test_rbpf_with_known_b_is_the_exact_kalman_filter() -> None:
    from rulkit.estimation.kalman import kf_predict, kf_update

    st, setup, y, q = tracking_problem(1, 1.0)
    W = st.n_windows
    b_true = 37.0
    st = replace(st, q_b=0.0, b_prior=(b_true, b_true), n_particles=8)
    # scenario 1 changes beta0 at window 39: the random walk has to absorb it
    out = rbpf(y, q, setup.sigma_y, st, unit_rngs(3, 1), beta_ref=BETA_REF)
    plo, phi = st.beta0_prior_rel
    x = np.array([[0.5 * (plo + phi) * BETA_REF]])
    P = np.array([[[((phi - plo) * BETA_REF) ** 2 / 12.0]]])
    Qb = np.array([[(st.q_beta0_rel * BETA_REF) ** 2]])
    Rm = np.array([[setup.sigma_y**2]])
    ref_m, ref_s = np.empty(W), np.empty(W)
    for k in range(W):
        x, P = kf_predict(x, P, np.eye(1), Qb)
        H = q.sums(np.array([[b_true]]), k)[0, 0] * SAMPLE_DT
        x, P, _ = kf_update(x, P, y[:, k:k + 1], np.array([[H]]), Rm)
        ref_m[k], ref_s[k] = x[0, 0], np.sqrt(P[0, 0, 0])
    np.testing.assert_allclose(out.beta0_mean[0], ref_m, rtol=1e-9)
    np.testing.assert_allclose(out.beta0_std[0], ref_s, rtol=1e-7)


def test_pf2_with_known_b_approaches_the_kalman_posterior() -> None:
    # two-step PF2 alone (PF1's b forced to the truth by a degenerate prior) vs the exact KF,
    # before the fault (38 windows, constant parameters)
    st, setup, y, q = tracking_problem(1, 38 * 240 / 86400)
    st = replace(st, q_b=0.0, b_prior=(37.0, 37.0), n_particles=4000, q_beta0_rel=0.01)
    two = two_step_pf(y, q, setup.sigma_y, st, unit_rngs(4, 1), unit_rngs(5, 1), beta_ref=BETA_REF)
    rb = rbpf(y, q, setup.sigma_y, replace(st, n_particles=4), unit_rngs(6, 1), beta_ref=BETA_REF)
    # after the uniform prior is forgotten (10 windows) the PF mean is within ~MC error of KF
    err = np.abs(two.beta0_mean[0, 10:] - rb.beta0_mean[0, 10:]) / rb.beta0_std[0, 10:]
    assert np.median(err) < 0.15 and err.max() < 0.5
    np.testing.assert_allclose(two.beta0_std[0, 10:], rb.beta0_std[0, 10:], rtol=0.15)
    np.testing.assert_allclose(two.b_mean[0], 37.0, rtol=1e-12)


def test_rbpf_engine_path_agrees_with_batched_rbpf() -> None:
    st, setup, y, q = tracking_problem(1, 1.0)
    st = replace(st, n_particles=400)
    bat = rbpf(y, q, setup.sigma_y, st, unit_rngs(7, 1), beta_ref=BETA_REF)
    from rulkit.systems.reaction_wheel.degradation.quadrature import WindowQuadrature

    q1 = WindowQuadrature(q.center[0], q.scale[0], q.nodes[0], q.weights[0], q.count)
    b_eng, beta_eng = rbpf_engine(y[0], q1, setup.sigma_y, st, np.random.default_rng(8),
                                  beta_ref=BETA_REF)
    # different random streams: compare late-window estimates within posterior spread
    late = slice(200, None)
    assert abs(b_eng[late].mean() - bat.b_mean[0, late].mean()) < 3 * bat.b_std[0, late].mean()
    rel = abs(beta_eng[late].mean() / bat.beta0_mean[0, late].mean() - 1)
    assert rel < 0.1


def test_trackers_recover_b_with_exact_temperature() -> None:
    # exact T^: b (25 after the fault) is identifiable from the orbital cycle. The two-step
    # PF re-converges within hours; the RB-PF, whose beta0 random walk is small, within days.
    st, setup, y, q = tracking_problem(2, 5.0, err_std=0.0, noise_rel=0.01)
    st = replace(st, n_particles=200)
    two = two_step_pf(y, q, setup.sigma_y, st, unit_rngs(10, 2), unit_rngs(11, 2),
                      beta_ref=BETA_REF)
    rb = rbpf(y, q, setup.sigma_y, st, unit_rngs(9, 2), beta_ref=BETA_REF)
    assert np.abs(two.b_mean[:, 300:400].mean(axis=1) / 25.0 - 1).max() < 0.05
    for out in (rb, two):
        assert np.abs(out.b_mean[:, -100:].mean(axis=1) / 25.0 - 1).max() < 0.1
        assert np.abs(out.beta0_mean[:, -100:].mean(axis=1) / 8.054e-6 - 1).max() < 0.1


def test_biased_temperature_biases_b() -> None:
    # errors-in-variables: a T^ biased 3 C low biases b low (what drives our Table 6)
    st, setup, y, q0 = tracking_problem(1, 2.0, noise_rel=0.003)
    _, _, _, qb = tracking_problem(1, 2.0, noise_rel=0.003)
    qb = replace(qb, center=1.0 / (1.0 / q0.center - 3.0))
    st = replace(st, n_particles=200)
    ok = rbpf(y, q0, setup.sigma_y, st, unit_rngs(12, 1), beta_ref=BETA_REF)
    bad = rbpf(y, qb, setup.sigma_y, st, unit_rngs(12, 1), beta_ref=BETA_REF)
    assert bad.b_mean[0, -100:].mean() < 0.9 * ok.b_mean[0, -100:].mean()
