"""The drive machine file: the defaults are the seed's drive and the reproduction's
consistent tuning; values checked with units and ranges."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rulkit.machine_file import MachineFileError, machine_file_template
from rulkit.systems.friction_drive.drive import DEFAULT_PARAMS, SEED_R, SEED_SIGMA_M2, SPEED_Q_RATE
from rulkit.systems.friction_drive.machine import (
    DRIVE_Q_RATE,
    DRIVE_SCHEMA,
    read_drive_machine,
)


def test_defaults_are_the_seeds_drive() -> None:
    m = read_drive_machine(None)
    assert m.params == DEFAULT_PARAMS
    np.testing.assert_allclose(m.R, SEED_R, rtol=1e-12)
    np.testing.assert_array_equal(m.q_rates, [*SPEED_Q_RATE, 0.0, DRIVE_Q_RATE])
    x0, P0 = m.prior(1.0, 2.0)
    np.testing.assert_array_equal(x0, [1.0, 2.0, 10.0, 0.01])
    np.testing.assert_allclose(np.diag(P0), [*np.diag(SEED_R), SEED_SIGMA_M2, SEED_SIGMA_M2],
                               rtol=1e-12)


def test_file_values_and_template_round_trip(tmp_path: Path) -> None:
    p = tmp_path / "drive.toml"
    p.write_text("[drive]\nr1 = 0.04\nJ2 = 0.5\n[failure]\nlevel = 0.9\n"
                 "[filter]\njacobian_at = 'start'\nq_m = 1e-7\n[rul]\ncurrent = 15\n")
    m = read_drive_machine(p)
    assert m.params.r1 == 0.04 and m.params.J2 == 0.5 and m.params.failure_level == 0.9
    assert m.params.r2 == DEFAULT_PARAMS.r2 and m.q_rates[3] == 1e-7
    q = tmp_path / "again.toml"
    q.write_text(machine_file_template(DRIVE_SCHEMA, values=m.values))
    assert read_drive_machine(q).values == m.values


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[drive]\nJ1 = 0\n", r"\[drive\] J1 = 0 \(kg m\^2\): outside its range"),
        ("[drive]\nKm = false\n", r"\[drive\] Km = False \(N m/A\): expected a number, not bool"),
        ("[failure]\nlevel = 1\n", r"\[failure\] level = 1: outside its range, expected 0 < "),
        ("[sensors]\nsigma_w1 = 0\n", r"\[sensors\] sigma_w1 = 0 \(rad/s\): outside its range"),
        ("[filter]\njacobian = 'start'\n", r"unknown key\(s\) 'jacobian'"),
        ("[filter]\nf44 = 100\n", r"\[filter\] f44 = 100 \(1/s\): outside its range"),
        ("[engine]\nx = 1\n", r"unknown section\(s\) \[engine\]"),
    ],
)
def test_bad_values_named(tmp_path: Path, text: str, message: str) -> None:
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(MachineFileError, match=message):
        read_drive_machine(p)


def test_the_command_page_shows_the_schema() -> None:
    from rulkit.machine_file import schema_table

    page = Path(__file__).resolve().parents[3] / "docs" / "commands" / "drive.md"
    assert schema_table(DRIVE_SCHEMA) in page.read_text()
