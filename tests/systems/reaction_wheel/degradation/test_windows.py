"""Loss measurements and the window sums of a streamed step-1 estimate: the three file kinds,
their refusals, and an accumulator that gives the Gauss rules of the direct computation
whatever the chunking, thinning long windows, leaving empty ones out, through a checkpoint."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from rulkit.systems.reaction_wheel.degradation.quadrature import window_quadrature
from rulkit.systems.reaction_wheel.degradation.windows import (
    LossFileError,
    LossRecord,
    WindowAccumulator,
    iter_temperature_estimate,
    read_losses,
)


def test_the_three_kinds_of_loss_file(tmp_path: Path) -> None:
    t = [100.0, 340.0, 580.0]
    pd.DataFrame({"time_s": t, "loss_mL": [1.0, 2.0, 3.0]}).to_csv(tmp_path / "a.csv", index=False)
    a = read_losses(tmp_path / "a.csv", record_start=0.0)
    np.testing.assert_array_equal(a.start_s, [0.0, 100.0, 340.0])
    np.testing.assert_array_equal(a.loss_mL, [1.0, 2.0, 3.0])
    pd.DataFrame({"time_s": t, "cumulative_mL": [5.0, 7.0, 10.0]}).to_csv(tmp_path / "c.csv",
                                                                         index=False)
    c = read_losses(tmp_path / "c.csv", record_start=0.0)
    np.testing.assert_array_equal(c.start_s, [100.0, 340.0])
    np.testing.assert_array_equal(c.loss_mL, [2.0, 3.0])
    stamps = pd.to_datetime(np.array(t) + 1.7e9, unit="s", utc=True)
    pd.DataFrame({"time_s": stamps, "injected_mL": [0.1, 0.2, 0.3]}).to_parquet(tmp_path / "i.pq")
    i = read_losses(tmp_path / "i.pq", record_start=1.7e9)
    assert i.kind == "injections" and i.end_s[-1] == pytest.approx(1.7e9 + 580.0)


@pytest.mark.parametrize(("frame", "start", "match"), [
    ({"time_s": [1.0, 2.0], "loss": [1.0, 2.0]}, 0.0, "exactly one of"),
    ({"time_s": [1.0, 2.0], "loss_mL": [1.0, 2.0], "injected_mL": [1.0, 2.0]}, 0.0,
     "exactly one of"),
    ({"time_s": [1.0, 1.0], "loss_mL": [1.0, 2.0]}, 0.0, "row 2: time 1 is not after"),
    ({"time_s": [1.0, 2.0], "loss_mL": [1.0, "x"]}, 0.0, "'x' is not a number"),
    ({"time_s": [1.0, 2.0], "loss_mL": [True, False]}, 0.0, "booleans"),
    ({"time_s": [1.0, 2.0], "loss_mL": [1.0, 2.0]}, 5.0, "not after the record's first sample"),
    ({"time_s": [1.0], "cumulative_mL": [1.0]}, 0.0, "at least 2 rows"),
])
def test_bad_loss_files_are_refused_naming_what(tmp_path: Path, frame, start, match) -> None:
    f = tmp_path / "l.csv"
    pd.DataFrame(frame).to_csv(f, index=False)
    with pytest.raises(LossFileError, match=match):
        read_losses(f, record_start=start)


def _record(n_windows: int = 6, length: float = 240.0) -> LossRecord:
    end = (np.arange(n_windows) + 1.0) * length
    return LossRecord(end - length, end, np.ones(n_windows), "loss", "test")


def test_accumulator_equals_direct_rules_whatever_the_chunks() -> None:
    lr = _record()
    t = np.arange(1, 28801) * 0.05  # 1440 s at 20 Hz: six windows
    T = 30.0 + 2.0 * np.sin(t / 300.0)
    sums = []
    for cuts in ([t.size], [7, 4800, 5000, 17000, t.size], [*range(1000, t.size, 1000), t.size]):
        acc = WindowAccumulator(lr, 4)
        a = 0
        for b in cuts:
            acc.add(t[a:b], T[a:b], 0.05)
            a = b
        sums.append(acc.finish())
    for s in sums[1:]:
        np.testing.assert_array_equal(s.quad.nodes, sums[0].quad.nodes)
        np.testing.assert_array_equal(s.quad.center, sums[0].quad.center)
    k = 2
    inside = (t > lr.start_s[k]) & (t <= lr.end_s[k])
    ref = window_quadrature(1.0 / T[inside][None], 4)
    np.testing.assert_allclose(sums[0].quad.nodes[0, k], ref.nodes[0], rtol=1e-12)
    np.testing.assert_allclose(sums[0].T_mean[k], np.mean(T[inside]), rtol=1e-12)
    assert sums[0].n_samples[k] == 4800
    assert np.asarray(sums[0].quad.count)[0, k] == pytest.approx(4800.0)


def test_empty_windows_are_marked_and_long_ones_thinned(monkeypatch) -> None:
    from rulkit.systems.reaction_wheel.degradation import windows

    lr = _record()
    t = np.concatenate([np.arange(1, 4801), np.arange(9601, 28801)]) * 0.05  # window 1 empty
    acc = WindowAccumulator(lr, 4)
    acc.add(t, np.full(t.size, 30.0), 0.05)
    s = acc.finish()
    assert list(s.present) == [True, False, True, True, True, True]
    monkeypatch.setattr(windows, "MAX_WINDOW_SAMPLES", 1000)
    acc = WindowAccumulator(lr, 4)
    acc.add(t, 30.0 + 0.001 * t, 0.05)
    thin = acc.finish()
    assert thin.n_samples[0] == 4800  # counted, though 1 in 5 was kept
    assert thin.T_mean[0] == pytest.approx(s.T_mean[0] + 0.001 * 120.0, rel=1e-3)


def test_checkpoint_state_continues_the_same_sums() -> None:
    lr = _record()
    t = np.arange(1, 28801) * 0.05
    T = 30.0 + np.cos(t / 200.0)
    whole = WindowAccumulator(lr, 4)
    whole.add(t, T, 0.05)
    part = WindowAccumulator(lr, 4)
    part.add(t[:7000], T[:7000], 0.05)
    back = WindowAccumulator.from_state(lr, 4, part.state())
    back.add(t[7000:], T[7000:], 0.05)
    np.testing.assert_array_equal(back.finish().quad.weights, whole.finish().quad.weights)


def test_a_cold_estimate_is_refused_and_estimate_files_read(tmp_path: Path) -> None:
    acc = WindowAccumulator(_record(), 4)
    with pytest.raises(ValueError, match="singular at 0 C"):
        acc.add(np.array([10.0, 20.0]), np.array([30.0, 2.0]), 0.05)
    pd.DataFrame({"time_s": [0.0, 0.05, 0.1], "T_mean": [30.0, 30.1, 30.2]}).to_csv(
        tmp_path / "T.csv", index=False)
    (_, T, dt), = list(iter_temperature_estimate(tmp_path / "T.csv"))
    assert dt == pytest.approx(0.05) and T[-1] == 30.2
