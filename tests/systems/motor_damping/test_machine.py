"""The motor machine file: defaults are the synthetic motor, values read with units and
ranges, command-line overrides checked against the same schema."""

from __future__ import annotations

from pathlib import Path

import pytest

from rulkit.machine_file import MachineFileError, machine_file_template
from rulkit.systems.motor_damping.machine import MOTOR_SCHEMA, read_motor_machine
from rulkit.systems.motor_damping.micro import MicroEKFSettings
from rulkit.systems.motor_damping.motor import MotorConstants
from rulkit.systems.motor_damping.pullup import PullupLimits


def test_defaults_are_the_synthetic_motor() -> None:
    m = read_motor_machine(None)
    assert m.source == "defaults"
    synthetic = MotorConstants()
    assert (m.constants.K, m.constants.J, m.constants.T_L) == (synthetic.K, synthetic.J,
                                                               synthetic.T_L)
    assert m.micro == MicroEKFSettings(gate=100.0)  # the reproduction runs without the gate
    assert m.limits == PullupLimits()
    kw = m.analysis_kwargs()
    # 0 in the file means "estimate" / "from the design point"
    assert kw["c_fail"] is None and kw["sigma_w"] is None and kw["sigma_dw"] is None


def test_file_values_and_template_round_trip(tmp_path: Path) -> None:
    p = tmp_path / "motor.toml"
    p.write_text("[motor]\nK = 0.05\nJ = 0.004\n[noise]\nsigma_w = 0.1\n"
                 "[limits]\nmax_speed = 2000\n[macro]\nmodel = 'quadratic'\n")
    m = read_motor_machine(p)
    assert m.constants.K == 0.05 and m.constants.J == 0.004 and m.constants.T_L == 1.4e-3
    assert m.limits.max_speed == 2000.0 and m.analysis_kwargs()["sigma_w"] == 0.1
    assert m.analysis_kwargs()["macro_model"] == "quadratic"
    q = tmp_path / "again.toml"
    q.write_text(machine_file_template(MOTOR_SCHEMA, values=m.values))
    assert read_motor_machine(q).values == m.values


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[motor]\nK = -0.03\n", r"\[motor\] K = -0.03 \(N m/A\): outside its range"),
        ("[motor]\nJ = true\n", r"\[motor\] J = True \(kg m\^2\): expected a number, not bool"),
        ("[motor]\nk = 0.03\n", r"\[motor\] unknown key\(s\) 'k' \(did you mean 'K'\?\)"),
        ("[limits]\nmax_current = 0\n", r"\[limits\] max_current = 0 \(A\): outside its range"),
        ("[micro]\nscheme = 'euler'\n", r"expected one of 'rk4', 'seed-euler'"),
    ],
)
def test_bad_values_named(tmp_path: Path, text: str, message: str) -> None:
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(MachineFileError, match=message):
        read_motor_machine(p)


def test_overrides_take_precedence_and_name_their_label() -> None:
    m = read_motor_machine(None).with_overrides({"--j": ("motor", "J", 2e-3),
                                                 "--k": ("motor", "K", None)})
    assert m.constants.J == 2e-3 and m.constants.K == MotorConstants().K
    with pytest.raises(MachineFileError, match=r"--j = 0 \(kg m\^2\): outside its range"):
        m.with_overrides({"--j": ("motor", "J", 0)})


def test_the_command_page_shows_the_schema() -> None:
    from rulkit.machine_file import schema_table

    page = Path(__file__).resolve().parents[3] / "docs" / "commands" / "motor-damping.md"
    assert schema_table(MOTOR_SCHEMA) in page.read_text()
