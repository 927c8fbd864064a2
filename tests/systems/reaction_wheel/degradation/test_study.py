"""The Table 6 study: grouping-independent cases, the truth per window, the shortcut validation
and the error statistics measured on real step-1 runs."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rulkit.systems.reaction_wheel.degradation.shortcut import (
    EstimateErrorProcess,
)
from rulkit.systems.reaction_wheel.degradation.study import (
    CaseTask,
    run_case,
    run_table6,
    truth_parameters,
)
from rulkit.systems.reaction_wheel.degradation.trackers import (
    DegradationConfig,
    rbpf,
    unit_rng,
)

from .conftest import BETA_REF, tracking_problem, unit_rngs


def test_run_case_independent_of_grouping_and_table6() -> None:
    st = DegradationConfig(horizon_days=0.5, n_particles=40)
    err = EstimateErrorProcess(std_c=0.3, tau_s=20.0)
    a = run_case(CaseTask(2, "PF", (0, 1), 3, st, err, (50,)))
    b = run_case(CaseTask(2, "PF", (1,), 3, st, err, (50,)))
    assert a.rmspe_b["rbpf"][1] == b.rmspe_b["rbpf"][0]
    assert a.rmspe_beta0["two_step"][1] == b.rmspe_beta0["two_step"][0]
    np.testing.assert_array_equal(a.snapshots["rbpf"][50][0][1], b.snapshots["rbpf"][50][0][0])
    res = run_table6(2, 3, st, {"APF": err, "PF": err}, scenarios=(2,))
    tab = res.table
    assert list(tab["method"])[:3] == ["APF + two-step PF", "PF + two-step PF",
                                      "APF + one-step PF"]
    assert tab.loc[0, "S2 b paper"] == 1.920 and tab.loc[2, "S2 beta paper"] == 24.303
    assert tab.loc[1, "S2 b ours"] == pytest.approx(res.case(2, "PF").rmspe_b["two_step"].mean())
    # the RBPF step-1 source (ours) adds two rows and leaves the APF/PF rows unchanged
    res3 = run_table6(2, 3, st, {"APF": err, "PF": err, "RBPF": err}, scenarios=(2,))
    t3 = res3.table
    assert list(t3["method"]) == [*tab["method"], "RBPF + two-step PF (ours)",
                                  "RBPF + RB-PF (ours)"]
    import pandas as pd

    pd.testing.assert_frame_equal(t3.iloc[:len(tab)], tab)
    new = t3.iloc[len(tab):]
    assert np.isfinite(new[["S2 b ours", "S2 beta ours"]].to_numpy()).all()
    assert new["S2 b paper"].isna().all()  # not in the paper
    assert t3.iloc[-1]["S2 b ours"] == pytest.approx(res3.case(2, "RBPF").rmspe_b["rbpf"].mean())
    # the same error process under another source gives other T^ draws (own streams)
    assert res3.case(2, "RBPF").rmspe_b["rbpf"][0] != res3.case(2, "PF").rmspe_b["rbpf"][0]
    with pytest.raises(ValueError, match="unknown T\\^ source"):
        run_table6(1, 3, st, {"EKF": err}, scenarios=(2,))


def test_truth_per_window_and_bad_inputs() -> None:
    b, beta0 = truth_parameters(1, 45)
    assert b[38] == 37.0 and b[39] == 25.0  # window 39 ends at 160 min > 159 min
    assert beta0[39] == 8.054e-6  # window 39 ends at 160 min > 159 min
    st, setup, y, q = tracking_problem(2, 0.1)
    with pytest.raises(ValueError, match="generators"):
        rbpf(y, q, setup.sigma_y, st, unit_rngs(0, 1), beta_ref=BETA_REF)
    y2 = y.copy()
    y2[1, 3] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        rbpf(y2, q, setup.sigma_y, st, unit_rngs(0, 2), beta_ref=BETA_REF)
    with pytest.raises(ValueError, match="backend"):
        rbpf(y, q, setup.sigma_y, st, unit_rngs(0, 2), beta_ref=BETA_REF, backend="cuda")
    with pytest.raises(ValueError, match="method"):
        run_case(CaseTask(1, "APF", (0,), 0, replace(st, horizon_days=0.05),
                          EstimateErrorProcess(), methods=("kalman",)))
    assert unit_rng(1, "rbpf", 1, 0, 2).random() == unit_rng(1, "rbpf", 1, 0, 2).random()


@pytest.mark.parametrize("source", ["PF", "RBPF"])
def test_validate_shortcut_runs_the_real_step1_estimator(source: str) -> None:
    from rulkit.systems.reaction_wheel.degradation.study import validate_shortcut

    err = EstimateErrorProcess(bias_c=-1.0, std_c=0.5, tau_s=100.0)
    v = validate_shortcut(err, source, hours=0.14, n_runs=1, seed=0,
                          settings=DegradationConfig(n_particles=30), n_particles_step1=30)
    assert v.n_runs == 1 and v.rmspe_b_real["rbpf"].shape == (1,)
    assert np.isfinite(v.window_error_std_real) and v.window_error_std_real > 0
    assert np.isfinite(v.fitted_on_path.std_c) and "step-2 path" in v.fitted_on_path.source
    for d in (v.rmspe_b_real, v.rmspe_b_synth):
        assert set(d) == {"two_step", "rbpf"} and all(np.isfinite(x).all() for x in d.values())


def test_rbpf_error_statistics_are_measured_from_real_rbj_runs(monkeypatch) -> None:
    """The RBPF source's T^ error process is fitted to real step-1 runs of the RBJ RBPF: equal
    to a fit of errors of run_rbpf called directly on the same simulated data, and it follows
    the estimator's output (a shifted estimator shifts the measured bias)."""
    from rulkit.systems.reaction_wheel.degradation.shortcut import fit_error_process
    from rulkit.systems.reaction_wheel.degradation.study import (
        RBPF_STEP1_DESIGN,
        SOURCES,
        measure_temperature_errors,
    )
    from rulkit.systems.reaction_wheel.temperature import rbpf
    from rulkit.systems.reaction_wheel.wheel import NOISE_LEVELS, simulate_table3

    seed, N = 4, 30
    e = measure_temperature_errors("RBPF", 2, seed, n_particles=N, on="table3", hold_samples=40)
    assert "rbpf RBJ" in e.source and "2 step-1 runs" in e.source
    errs = []  # independent reconstruction: the RBJ design called directly
    for r in range(2):
        g = unit_rng(seed, "estimate", 0, SOURCES.index("RBPF"), 1000 + r)
        run = simulate_table3(g, "low")
        cfg = replace(rbpf.RBPF_DESIGNS[RBPF_STEP1_DESIGN], n_particles=N)
        T_hat = rbpf.run_rbpf(run.y, run.V, g, cfg, sigma=NOISE_LEVELS["low"],
                                       quantiles=False).T_mean
        keep = run.t >= 100.0
        errs.append(T_hat[keep] - run.T[keep])
    ref = fit_error_process(np.stack(errs), hold_samples=40)
    assert (e.bias_c, e.std_c, e.tau_s) == pytest.approx((ref.bias_c, ref.std_c, ref.tau_s))
    assert e.std_c > 0 and abs(e.bias_c) < 1.0
    alt = measure_temperature_errors("RBPF", 2, seed + 1, n_particles=N, on="table3")
    assert alt.std_c != e.std_c

    real = rbpf.run_rbpf

    def shifted(*a, **k):
        out = real(*a, **k)
        return replace(out, T_mean=out.T_mean + 3.0)

    monkeypatch.setattr(rbpf, "run_rbpf", shifted)
    e3 = measure_temperature_errors("RBPF", 2, seed, n_particles=N, on="table3", hold_samples=40)
    assert e3.bias_c == pytest.approx(e.bias_c + 3.0)


def test_one_step_beside_two_step_on_every_source() -> None:
    from rulkit.systems.reaction_wheel.degradation.shortcut import EstimateErrorProcess
    from rulkit.systems.reaction_wheel.degradation.study import one_vs_two_step, run_table6
    from rulkit.systems.reaction_wheel.degradation.trackers import DegradationConfig

    err = {s: EstimateErrorProcess(std_c=0.1, tau_s=10.0) for s in ("APF", "RBPF", "IMM")}
    t6 = run_table6(1, 0, DegradationConfig(n_particles=30, horizon_days=0.3), err)
    t = one_vs_two_step(t6)
    assert list(t["T^ source"]) == ["APF", "RBPF", "IMM"]
    assert {"S1 b one-step", "S1 b two-step", "S2 beta two-step"} <= set(t.columns)
    assert t.loc[0, "S1 b paper one/two"] == "136.999 / 3.947"
    # Table 6 keeps the rows of the seeds' methods and ours (no one-step row on RBPF, IMM)
    assert not t6.table["method"].str.contains("IMM").any()


def test_real_step1_over_the_horizon_against_the_shortcut() -> None:
    from rulkit.systems.reaction_wheel.degradation.real_step1 import compare_real_and_shortcut
    from rulkit.systems.reaction_wheel.degradation.shortcut import EstimateErrorProcess
    from rulkit.systems.reaction_wheel.degradation.trackers import DegradationConfig

    t = compare_real_and_shortcut(1, 0, DegradationConfig(n_particles=30, horizon_days=0.05),
                                  EstimateErrorProcess(std_c=0.05, tau_s=5.0))
    assert set(t["scenario"]) == {1, 2} and set(t["tracker"]) == {"two_step", "one_step", "rbpf"}
    assert np.isfinite(t[["b real", "b shortcut", "beta real", "beta shortcut"]]).all().all()
    assert (t["step-1 s per run"] > 0).all()
