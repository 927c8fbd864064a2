"""CLI test of ``rulkit reproduce friction-drive`` on small settings."""

from __future__ import annotations

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
    assert len(cons) == 9  # nine (filter, scenario) pairs, one run each


def test_reproduce_friction_drive_rejects_bad_options(tmp_path):
    res = CliRunner().invoke(app, ["reproduce", "friction-drive", "--runs", "0",
                                   "--out", str(tmp_path)])
    assert res.exit_code != 0
    res = CliRunner().invoke(app, ["reproduce", "friction-drive", "--duration", "1",
                                   "--out", str(tmp_path)])
    assert res.exit_code != 0
