"""Step 2 on a user's windows: the constant-law fit recovers a known law, the trackers recover
b and beta0 of a simulated fault, and what step 3 needs survives a save and a load."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rulkit.systems.reaction_wheel.degradation.track import (
    fit_constant_law,
    load_step2,
    save_step2,
    track_degradation,
)
from rulkit.systems.reaction_wheel.degradation.trackers import DegradationConfig
from rulkit.systems.reaction_wheel.degradation.windows import LossRecord, WindowAccumulator
from rulkit.systems.reaction_wheel.lubrication import (
    PATHS,
    SCENARIOS,
    WINDOW_S,
    true_window_increments,
)


def _scenario(days: float, noise_rel: float, seed: int = 0):
    W = round(days * 86400 / WINDOW_S)
    y_true = true_window_increments(PATHS[1], SCENARIOS[1], W)
    sig = noise_rel * y_true[:20].mean()
    y = y_true + sig * np.random.default_rng(seed).standard_normal(W)
    end = (np.arange(W) + 1) * WINDOW_S
    lr = LossRecord(end - WINDOW_S, end, y, "loss", "simulated")
    acc = WindowAccumulator(lr, 4)
    t = np.arange(1, round(days * 86400 / 0.5) + 1) * 0.5  # the true path as the estimate
    acc.add(t, np.asarray(PATHS[1](t)), 0.5)
    return lr, acc.finish(), sig


def test_constant_law_fit_recovers_a_noise_free_law() -> None:
    lr, sums, _ = _scenario(0.5, 0.0)
    fit = fit_constant_law(lr.loss_mL, sums.quad, (10.0, 80.0), n_fit=39)  # before the fault
    assert fit.b == pytest.approx(37.0, abs=0.2)
    assert fit.beta0 == pytest.approx(SCENARIOS[1].beta0_healthy, rel=0.01)


def test_trackers_recover_the_fault_and_report_intervals() -> None:
    lr, sums, sig = _scenario(2.0, 0.01)
    res = track_degradation(lr, sums, DegradationConfig(n_particles=150), seed=1, level=0.9)
    tab = res.table
    assert len(tab) == lr.n_windows and res.n_missing == 0
    late = tab["end_s"].to_numpy() > 86400.0  # a day after the fault
    for name in ("two_step", "rbpf"):
        b = tab[f"b_{name}"].to_numpy()[late]
        assert np.mean(np.abs(b - 25.0)) < 2.5, name
        assert np.all(tab[f"b_lo_{name}"] <= tab[f"b_{name}"])
    assert res.sigma_y == pytest.approx(sig, rel=1.0)  # estimated, same order
    p, w = res.posteriors["one_step"]
    assert p.shape == (150, 2) and w.sum() == pytest.approx(1.0)


def test_step2_saves_what_step3_needs(tmp_path: Path) -> None:
    lr, sums, _ = _scenario(0.3, 0.01)
    res = track_degradation(lr, sums, DegradationConfig(n_particles=40), seed=2,
                            trackers=("two_step",))
    save_step2(tmp_path, res, lr, sums)
    st = load_step2(tmp_path)
    np.testing.assert_array_equal(st.posteriors["two_step"][0], res.posteriors["two_step"][0])
    assert st.X_end == pytest.approx(res.X_end) and st.t_end == res.t_end
    np.testing.assert_array_equal(st.sums.quad.nodes, sums.quad.nodes)
    with pytest.raises(ValueError, match="not the output of step 2"):
        load_step2(tmp_path / "nowhere")
