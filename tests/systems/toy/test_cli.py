"""CLI test of ``rulkit example`` (typer CliRunner, tmp dir)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from rulkit.cli import app
from rulkit.prognosis.rul import RULDistribution


def test_example_writes_rul_json_summary_and_png(tmp_path):
    out = tmp_path / "ex"
    res = CliRunner().invoke(app, ["example", "--out", str(out), "--seed", "5",
                                   "--particles", "400"])
    assert res.exit_code == 0, res.output
    assert "true RUL" in res.output
    d = RULDistribution.from_json(out / "rul.json")
    assert d.n == 400
    summary = json.loads((out / "summary.json").read_text())
    assert summary["seed"] == 5
    last = summary["rows"][-1]
    assert last["rul_median"] == d.median
    assert last["rul_true"] == summary["metrics"]["t_eol"] - last["t_pred"]
    # relative accuracy of every row from its definition (Saxena et al. 2010), by hand
    for row in summary["rows"]:
        ra = 1.0 - abs(row["rul_true"] - row["rul_median"]) / row["rul_true"]
        assert row["relative_accuracy"] == pytest.approx(ra, rel=1e-12)
    png = (out / "toy_degradation.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    # report.md: one markdown row per prediction time, the median with 4 significant digits
    report = (out / "report.md").read_text().splitlines()
    header = next(i for i, line in enumerate(report) if line.startswith("| t_pred |"))
    body = report[header + 2 : header + 2 + len(summary["rows"])]
    assert len(body) == len(summary["rows"]) and all(line.startswith("| ") for line in body)
    assert f" {last['rul_median']:.4g} " in body[-1]
    # same seed -> same distribution
    out2 = tmp_path / "ex2"
    res2 = CliRunner().invoke(app, ["example", "--out", str(out2), "--seed", "5",
                                    "--particles", "400"])
    assert res2.exit_code == 0
    np.testing.assert_array_equal(RULDistribution.from_json(out2 / "rul.json").samples,
                                  d.samples)


def test_example_rejects_too_few_particles(tmp_path):
    res = CliRunner().invoke(app, ["example", "--out", str(tmp_path), "--particles", "1"])
    assert res.exit_code != 0
    assert "particles" in res.output.lower()


def test_example_rejects_negative_seed(tmp_path):
    res = CliRunner().invoke(app, ["example", "--out", str(tmp_path), "--seed", "-1"])
    assert res.exit_code != 0
    assert "seed" in res.output.lower()
    from rulkit.systems.toy.cli import run_example

    with pytest.raises(typer.BadParameter, match="seed"):
        run_example(tmp_path, seed=-3, n_particles=10)
