"""A record filtered chunk by chunk (issue 13: ``rw estimate-temperature`` in bounded memory)
gives the numbers of one pass over the whole record, its checks find a bad row at a chunk
boundary as anywhere else, and a failure leaves no output behind."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from rulkit.cli import app
from rulkit.systems.reaction_wheel.telemetry import (
    TelemetryError,
    iter_wheel_telemetry,
    read_wheel_telemetry,
    table3_telemetry,
)
from rulkit.systems.reaction_wheel.temperature.estimator import (
    EstimationError,
    TemperatureEstimator,
    estimate_temperature,
)

runner = CliRunner()


@pytest.fixture(scope="module")
def record() -> pd.DataFrame:
    """60 s of the Table 3 path with a +1 V command glitch at row 40 (the outlier gate and its
    rollback ring act across the chunk boundaries below)."""
    df = table3_telemetry(np.random.default_rng(4), "low", t_end=60.0).drop(columns="T_lub_C")
    df.loc[40, "v_comm_V"] += 1.0
    return df


def _chunked(df: pd.DataFrame, method: str, sizes: list[int], **kw) -> pd.DataFrame:
    clean = read_clean(df)
    est = TemperatureEstimator(method, 40, np.random.default_rng(7), dt=clean.attrs["dt"], **kw)
    parts, start = [], 0
    for n in sizes:
        part = clean.iloc[start:start + n]
        part.attrs["row0"] = start
        parts.append(est.update(part))
        start += n
    assert start == len(clean)
    return pd.concat(parts, ignore_index=True)


def read_clean(df: pd.DataFrame) -> pd.DataFrame:
    from rulkit.systems.reaction_wheel.telemetry import validate_wheel_telemetry

    return validate_wheel_telemetry(df)


@pytest.mark.parametrize(("method", "design"), [
    ("adaptive", "F2"), ("pf", "F1"), ("apf_eq28", "F2"), ("apf_tempered", "F1"), ("ekf", "F2"),
    ("rbpf", "F2"), ("imm", "F2"), ("apf", "F2")])
def test_chunks_give_the_numbers_of_one_pass(record, method: str, design: str) -> None:
    whole = estimate_temperature(record, method, 40, np.random.default_rng(7), design=design)
    # boundaries at the glitch, inside the gate's run of untrusted samples, and 1-row chunks
    sizes = [2, 1, 38, 1, 5, 300, 1, len(record) - 348]
    parts = _chunked(record, method, sizes, design=design)
    pd.testing.assert_frame_equal(parts, whole, check_exact=True)
    if method == "adaptive":
        assert whole["untrusted"].any()  # the gate did act in this record


def test_chunks_must_follow_each_other(record) -> None:
    est = TemperatureEstimator("ekf", dt=0.05)
    clean = read_clean(record)
    est.update(clean.iloc[:10])
    with pytest.raises(ValueError, match="starts at row 0, expected row 10"):
        est.update(clean.iloc[10:20])  # row0 0: the frame's own attrs


@pytest.mark.parametrize("chunk", [2, 3, 8, 1000])
def test_streamed_validation_equals_whole_file(tmp_path: Path, record, chunk: int,
                                               monkeypatch) -> None:
    """The first chunk is extended to the sampling-step window (here 23 steps: 24 rows)."""
    from rulkit.systems.reaction_wheel import telemetry

    monkeypatch.setattr(telemetry, "DT_WINDOW", 23)
    f = tmp_path / "t.csv"
    record.iloc[:50].to_csv(f, index=False)
    whole = read_wheel_telemetry(f)
    parts = list(iter_wheel_telemetry(f, chunk_rows=chunk))
    assert [p.attrs["row0"] for p in parts] == [0, *range(24, 50, chunk)][:len(parts)]
    got = pd.concat(parts)
    np.testing.assert_array_equal(got.to_numpy(), whole.to_numpy())


@pytest.mark.parametrize("chunk", [5, 6, 1000])
@pytest.mark.parametrize(("edit", "match"), [
    (lambda d: d.assign(time_s=d["time_s"].where(d.index != 5, d["time_s"][4])),
     r"column 'time_s', row 5 \(file line 7\): repeated time"),
    (lambda d: d.assign(time_s=d["time_s"].where(d.index != 5, d["time_s"][4] - 1.0)),
     r"column 'time_s', row 5 \(file line 7\): time .* is before"),
    (lambda d: d.assign(time_s=d["time_s"] + (d.index >= 5) * 0.02),
     r"column 'time_s', row 5 \(file line 7\): step 0.07 s differs"),
    (lambda d: d.assign(speed_rad_s=d["speed_rad_s"] + (d.index >= 5) * 5.0),
     r"column 'speed_rad_s', row 5 \(file line 7\): speed jumps"),
    (lambda d: d.assign(current_A=d["current_A"].astype(object).where(d.index != 5, "x")),
     r"column 'current_A', row 5 \(file line 7\): 'x' is not a number"),
])
def test_a_bad_row_at_a_chunk_boundary_is_named(tmp_path: Path, record, chunk, edit, match,
                                                monkeypatch):
    """Row 5 is the first row of a chunk (chunk 5), the last (6) or inside the only one."""
    from rulkit.systems.reaction_wheel import telemetry

    monkeypatch.setattr(telemetry, "DT_WINDOW", 2)
    f = tmp_path / "t.csv"
    edit(record.iloc[:30].copy()).to_csv(f, index=False)
    with pytest.raises(TelemetryError, match=match):
        list(iter_wheel_telemetry(f, chunk_rows=chunk))


def test_cli_streams_the_same_numbers_and_leaves_nothing_on_failure(tmp_path: Path,
                                                                    record) -> None:
    f = tmp_path / "t.csv"
    record.to_csv(f, index=False)
    outs = {}
    for chunk in ("7", "100000"):
        dest = tmp_path / f"e{chunk}.csv"
        res = runner.invoke(app, ["rw", "estimate-temperature", str(f), "--out", str(dest),
                                  "--particles", "40", "--chunk-rows", chunk])
        assert res.exit_code == 0, res.output
        outs[chunk] = pd.read_csv(dest)
    pd.testing.assert_frame_equal(outs["7"], outs["100000"], check_exact=True)
    whole = estimate_temperature(record)  # the default: imm
    pd.testing.assert_frame_equal(outs["7"], whole, check_exact=True, check_dtype=False)
    pq = tmp_path / "e.parquet"
    assert runner.invoke(app, ["rw", "estimate-temperature", str(f), "--out", str(pq),
                               "--particles", "40", "--chunk-rows", "9"]).exit_code == 0
    pd.testing.assert_frame_equal(pd.read_parquet(pq), whole, check_exact=True)

    # a bad row in the last chunk: exit 1 naming it, the old output untouched, no partial file
    bad = record.astype({"speed_rad_s": object})
    bad.loc[len(bad) - 3, "speed_rad_s"] = "fast"
    bad.to_csv(f, index=False)
    dest = tmp_path / "e7.csv"
    before = dest.read_bytes()
    res = runner.invoke(app, ["rw", "estimate-temperature", str(f), "--out", str(dest),
                              "--particles", "40", "--chunk-rows", "7"])
    assert res.exit_code == 1
    assert f"row {len(bad) - 3}" in res.output and "speed_rad_s" in res.output
    assert dest.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e.parquet", "e100000.csv", "e7.csv",
                                                           "t.csv"]


def test_a_filter_failure_names_the_file_row_and_time(record, monkeypatch) -> None:
    """Issue 13: an error from inside a filter step becomes a message naming the source, the
    record row and its time (the step index mapped through the chunking)."""
    from rulkit.estimation.kalman import FilterStepError
    from rulkit.systems.reaction_wheel.temperature import estimator as te

    real = te.ekf_steps

    def failing(t, V, y, *a):
        if len(t) > 3:
            raise FilterStepError(3, ValueError("innovation covariance is not positive"))
        return real(t, V, y, *a)

    monkeypatch.setattr(te, "ekf_steps", failing)
    clean = read_clean(record)
    est = TemperatureEstimator("imm", dt=clean.attrs["dt"], source="wheel.csv")
    with pytest.raises(EstimationError, match=r"^wheel.csv: row 3 \(time_s = 0.15\): the imm "
                                              r"filter failed \(step 3: innovation covariance"):
        est.update(clean.iloc[:10])
    est = TemperatureEstimator("imm", dt=clean.attrs["dt"], source="wheel.csv")
    est.update(clean.iloc[:3])
    later = clean.iloc[3:13]
    later.attrs["row0"] = 3
    with pytest.raises(EstimationError, match=r"^wheel.csv: row 6 \(time_s = 0.3\)"):
        est.update(later)


def test_a_record_the_model_cannot_explain_is_refused(tmp_path: Path) -> None:
    """Full command, full speed and full negative current all along: no wheel does that. The
    gated PF trusts no sample (its output would be the prior), nor does the IMM's outlier gate:
    both exit 1 with a message, and nothing is written."""
    K = 400
    f = tmp_path / "t.csv"
    pd.DataFrame({"time_s": 0.05 * np.arange(K), "v_comm_V": np.full(K, 5.0),
                  "speed_rad_s": np.full(K, 999.0), "current_A": np.full(K, -5.0)}).to_csv(
        f, index=False)
    for method, match in (("adaptive", "only 1 of 400 speed samples could be used"),
                          ("imm", "only 1 of 400 speed samples could be used")):
        res = runner.invoke(app, ["rw", "estimate-temperature", str(f), "--out",
                                  str(tmp_path / "e.csv"), "--method", method,
                                  "--particles", "40"])
        assert res.exit_code == 1 and match in res.output, res.output
        assert sorted(p.name for p in tmp_path.iterdir()) == ["t.csv"]


def test_a_file_without_any_wanted_column_says_so(tmp_path: Path) -> None:
    """Not "no data rows": the rows are there, the columns are not (CSV and Parquet)."""
    for name in ("m.csv", "m.parquet"):
        f = tmp_path / name
        df = pd.DataFrame({"a": [1.0, 3.0], "b": [2.0, 4.0]})
        df.to_csv(f, index=False) if name.endswith(".csv") else df.to_parquet(f)
        with pytest.raises(TelemetryError, match="missing column 'time_s'.*columns found: "
                                                 r"\['a', 'b'\]"):
            list(iter_wheel_telemetry(f))
