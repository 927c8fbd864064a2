"""CLI test of ``rulkit reproduce friction-drive`` on small settings."""

from __future__ import annotations

import numpy as np
import pandas as pd
from typer.testing import CliRunner

from rulkit.cli import app


def test_reproduce_friction_drive_small(tmp_path):
    out = tmp_path / "fd"
    res = CliRunner().invoke(
        app,
        ["reproduce", "friction-drive", "--runs", "1", "--seed", "7", "--n-rul", "20",
         "--duration", "3", "--out", str(out)],
    )
    assert res.exit_code == 0, res.output
    assert "seed: 106.09 h" in res.output
    rep = (out / "report.md").read_text()
    assert "106.09" in rep and "3.36" in rep and "93.9" in rep
    for name in ("consistency", "verdicts", "ellipsoid", "observability", "rul"):
        assert (out / f"{name}.csv").exists()
    for fig in ("fig3_estimates.png", "fig5_deterioration.png", "fig7_bundle_tuned.png",
                "fig8_rul_tuned.png"):
        assert (out / fig).stat().st_size > 1000
    rul = pd.read_csv(out / "rul.csv")
    assert set(rul["config"]) == {"tuned", "seed", "seed-f44"}
    assert (rul["N"] == 20).all()
    cons = pd.read_csv(out / "consistency.csv")
    assert len(cons) == 12  # twelve (filter, scenario) pairs, one run each
    # the NEES-cause sentence quotes this run's largest post-switch NEES of each group
    fixed = cons["config"].str.startswith("tuned-consistent")
    assert fixed.sum() == 3
    for name, sel in (("no speed noise", cons[~fixed]), ("tuned-consistent*", cons[fixed])):
        assert (f"{name}: largest NEES within 50 steps after a current switch "
                f"{sel['max_NEES_switch'].max():.3g}") in rep
    # the report's text describes this run, not the 20 s default: at t_pred = 3 s the jump of
    # m (at 10 s) has not happened, so the truth's RUL is computed with m = 0.01
    assert "(LSODA, m = 0.01, alpha = " in rep
    truth_h = float(res.output.split("from the truth state at 3 s: ")[1].split(" h")[0])
    assert f"**{truth_h:.2f} h**" in rep
    np.testing.assert_allclose(rul["true_rul_h"], truth_h, atol=0.005)
    assert truth_h > 250  # m = 0.01 from alpha ~ 9.7: ~290 h, not the ~105 h of m = 0.02
    n_steps = 3000
    assert f"{n_steps} steps make them sensitive" in rep
    # the LSODA check sentence quotes the measured maximum, in seconds
    worst_s = rul["lsoda_check_max_abs_h"].max() * 3600.0
    assert f"max |fast - LSODA| {worst_s:.1f} s over {rul['lsoda_check_n'].sum()} samples" in rep


def test_reproduce_friction_drive_rejects_bad_options(tmp_path):
    res = CliRunner().invoke(app, ["reproduce", "friction-drive", "--runs", "0",
                                   "--out", str(tmp_path)])
    assert res.exit_code != 0
    res = CliRunner().invoke(app, ["reproduce", "friction-drive", "--duration", "1",
                                   "--out", str(tmp_path)])
    assert res.exit_code != 0
    res = CliRunner().invoke(app, ["reproduce", "friction-drive", "--seed", "-1",
                                   "--out", str(tmp_path)])
    assert res.exit_code == 2 and "seed" in res.output.lower()
