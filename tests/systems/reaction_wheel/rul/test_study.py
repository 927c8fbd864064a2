"""The Table 7 study from a small step-2 run."""

from __future__ import annotations

import numpy as np
import pytest

from rulkit.systems.reaction_wheel.degradation.shortcut import EstimateErrorProcess
from rulkit.systems.reaction_wheel.degradation.study import run_table6
from rulkit.systems.reaction_wheel.degradation.trackers import DegradationConfig
from rulkit.systems.reaction_wheel.rul.forecast import (
    RULConfig,
)
from rulkit.systems.reaction_wheel.rul.study import (
    plot_forecasts,
    plot_rul_densities,
    run_table7,
)

ST3 = RULConfig(failure_day=20.0, prediction_days=(1.0, 2.0), table7_day=2.0,
                    forecast_horizon_days=40.0)


def test_table7_from_a_small_step2_run(tmp_path) -> None:
    st2 = DegradationConfig(horizon_days=2.0, n_particles=40)
    err = EstimateErrorProcess(std_c=0.2, tau_s=20.0)
    t6 = run_table6(2, 0, st2, {"APF": err, "PF": err, "RBPF": err},
                    snapshot_windows=ST3.prediction_windows(st2.n_windows))
    res = run_table7(t6, ST3)
    tab = res.table
    assert set(tab["method"]) >= {"APF + two-step PF", "APF + one-step PF", "APF + RB-PF (ours)"}
    new = tab[tab["method"].isin(["RBPF + two-step PF (ours)", "RBPF + RB-PF (ours)"])]
    assert len(new) == 2  # the RBPF step-1 source's rows (ours): finite, not in the paper
    ours = [f"S{s} {k} ours" for s in (1, 2) for k in ("LB", "UB", "mean")]
    assert np.isfinite(new[ours].to_numpy()).all() and new["S1 LB paper"].isna().all()
    row = tab[tab["method"] == "APF + two-step PF"].iloc[0]
    assert row["S1 LB paper"] == 0.137 and row["S2 mean paper"] == 2.343
    assert row["S1 LB ours"] <= row["S1 mean ours"] <= row["S1 UB ours"]
    assert row["S1 day"] == 2.0 and row["S1 true RUL (d)"] == pytest.approx(18.0, abs=0.3)
    m = res.metrics
    assert ((m["interval_coverage"] >= 0) & (m["interval_coverage"] <= 1)).all()
    plot_rul_densities(res, tmp_path / "d.png")
    plot_forecasts(res, t6, 1, tmp_path / "f.png")
    assert (tmp_path / "d.png").stat().st_size > 1000 and (tmp_path / "f.png").exists()
