"""The wheel file: the defaults are the seed's wheel, the template reads back to them, another
wheel's values arrive in the model and the filters, and every bad value is refused naming the
file, section and key."""

from __future__ import annotations

from pathlib import Path

import pytest

from rulkit.machine_file import MachineFileError
from rulkit.systems.reaction_wheel.temperature.ekf import EKFConfig
from rulkit.systems.reaction_wheel.wheel import IthacoParams
from rulkit.systems.reaction_wheel.wheel_file import (
    read_wheel_file,
    step1_config,
    wheel_file_template,
)


def test_defaults_are_the_seed_wheel_and_the_template_reads_back(tmp_path: Path) -> None:
    w = read_wheel_file(None)
    assert w.params == IthacoParams() and w.sigma == (3e-3, 3e-2)
    assert w.ekf == EKFConfig() and w.method == "imm"
    f = tmp_path / "wheel.toml"
    f.write_text(wheel_file_template())
    back = read_wheel_file(f)
    assert back.params == w.params and back.ekf == w.ekf and back.degradation == w.degradation
    assert back.sigma == w.sigma and back.limits == w.limits and back.rul == w.rul


def test_another_wheel_reaches_model_filter_and_limits(tmp_path: Path) -> None:
    f = tmp_path / "w.toml"
    f.write_text('[wheel]\nJ = 0.0106\nfriction_law = "linear"\nviscous_at_0C = 5e-5\n'
                 'viscous_per_C = -2.5e-7\n[noise]\nsigma_I = 0.13\n[telemetry]\n'
                 'max_speed_rad_s = 600\n[temperature]\nmethod = "ekf"\nmodels = 1\n'
                 'q_T_low = 0.01\nq_T_high = 0.01\n')
    w = read_wheel_file(f)
    assert w.params.J == 0.0106 and w.params.friction_law == "linear"
    assert w.sigma == (3e-3, 0.13) and w.limits.speed_rad_s == 600.0
    assert w.ekf.q_T == (0.01,)
    assert step1_config(w).q_T == (0.02,)  # method "ekf": the plain EKF's step
    assert step1_config(w, "imm") is w.ekf and step1_config(w, "pf") is None


@pytest.mark.parametrize(("text", "match"), [
    ("[wheel]\nJ = -1.0\n", r"\[wheel\] J = -1.0 \(kg m\^2\): outside its range"),
    ("[wheel]\nJ = true\n", r"\[wheel\] J = True .*expected a number"),
    ("[wheel]\nj = 0.01\n", r"unknown key\(s\) 'j' \(did you mean 'J'\?\)"),
    ("[whee]\nJ = 0.01\n", r"unknown section\(s\) \[whee\]"),
    ("[temperature]\nmethod = \"magic\"\n", r"method = 'magic'.*expected one of 'imm'"),
    ("[temperature]\nT_prior_low = 50.0\n", r"T_prior_low must be below T_prior_high"),
    ("[degradation]\nb_prior_low = 90.0\n", r"b_prior_low must be below b_prior_high"),
    ("[wheel]\nfriction_law = \"seed_literal\"\n", r"b_v\(15 C\) = .* not positive"),
    ("[wheel]\nfriction_law = \"linear\"\nviscous_per_C = -1e-5\n", r"not positive"),
    ("[temperature]\nparticles = 2.5\n", r"particles = 2.5.*whole number"),
])
def test_bad_values_are_refused_naming_file_section_and_key(tmp_path: Path, text: str,
                                                          match: str) -> None:
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(MachineFileError, match=match) as err:
        read_wheel_file(f)
    assert str(f) in str(err.value)


def test_the_command_page_shows_every_key() -> None:
    from rulkit.machine_file import schema_table
    from rulkit.systems.reaction_wheel.wheel_file import WHEEL_SCHEMA

    page = Path(__file__).resolve().parents[3] / "docs" / "commands" / "rw-wheel-template.md"
    assert schema_table(WHEEL_SCHEMA) in page.read_text()
