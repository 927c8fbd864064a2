"""Machine files: a valid file read with defaults filled in, every kind of bad value refused
with the file, section, key, unit and what was expected."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import pytest

from rulkit.machine_file import (
    Field,
    Machine,
    MachineFileError,
    Schema,
    machine_file_template,
    read_machine_file,
    schema_table,
)

SCHEMA = {
    "wheel": (
        Field("J", "kg m^2", 0.0106, doc="rotor inertia", low=0.0, low_open=True, high=10.0),
        Field("poles", "", 8, doc="motor poles", low=2, high=64),
    ),
    "filter": (
        Field("method", "", "ekf", choices=("ekf", "rbpf"), doc="estimator"),
        Field("gate", "", True, doc="outlier gate on"),
        Field("q_T", "C per sample", 0.02, low=0.0),
    ),
}


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "m.toml"
    p.write_text(text)
    return p


def test_values_read_and_defaults_filled(tmp_path: Path) -> None:
    got = read_machine_file(write(tmp_path, "[wheel]\nJ = 2\n[filter]\nmethod = 'rbpf'\n"),
                            SCHEMA)
    assert got == {"wheel": {"J": 2.0, "poles": 8},
                   "filter": {"method": "rbpf", "gate": True, "q_T": 0.02}}
    assert isinstance(got["wheel"]["J"], float)  # an integer in the file is a float here


def test_template_reads_back_as_the_defaults(tmp_path: Path) -> None:
    text = machine_file_template(SCHEMA, "a wheel")
    assert "J = 0.0106  # kg m^2; 0 < J <= 10; rotor inertia" in text
    got = read_machine_file(write(tmp_path, text), SCHEMA)
    assert got == {s: {f.name: f.default for f in fs} for s, fs in SCHEMA.items()}


def test_schema_table_lists_every_field() -> None:
    table = schema_table(SCHEMA)
    assert table.count("\n") == 2 + 5
    assert "| wheel | `J` | kg m^2 | 0.0106 | 0 < J <= 10 | rotor inertia |" in table


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[wheel]\nJ = 0\n",
         r"\[wheel\] J = 0 \(kg m\^2\): outside its range, expected 0 < J <= 10"),
        ("[wheel]\nJ = -1.5\n", r"J = -1.5 \(kg m\^2\): outside its range"),
        ("[wheel]\nJ = 11\n", r"outside its range, expected 0 < J <= 10"),
        ("[wheel]\nJ = true\n", r"J = True \(kg m\^2\): expected a number, not bool"),
        ("[wheel]\nJ = 'big'\n", r"expected a number, not str"),
        ("[wheel]\nJ = [1, 2]\n", r"expected a number, not list"),
        ("[wheel]\nJ = nan\n", r"expected a finite number"),
        ("[wheel]\nJ = inf\n", r"expected a finite number"),
        ("[wheel]\npoles = 8.5\n", r"\[wheel\] poles = 8.5: expected a whole number"),
        ("[filter]\nmethod = 'pf'\n", r"\[filter\] method = 'pf': expected one of 'ekf', 'rbpf'"),
        ("[filter]\ngate = 1\n", r"\[filter\] gate = 1: expected true or false"),
        ("[wheel]\nj = 1\n",
         r"\[wheel\] unknown key\(s\) 'j' \(did you mean 'J'\?\); known keys: J, poles"),
        ("[wheel]\nJJ = 1\n", r"unknown key\(s\) 'JJ'"),
        ("[motor]\nR = 1\n", r"unknown section\(s\) \[motor\]; expected \[wheel\], \[filter\]"),
        ("wheel = 3\n", r"wheel must be a table \[wheel\], not int"),
        ("[wheel\nJ = 1\n", r"not valid TOML"),
    ],
)
def test_bad_values_name_file_section_key_and_expectation(tmp_path: Path, text: str,
                                                         message: str) -> None:
    p = write(tmp_path, text)
    with pytest.raises(MachineFileError, match=message) as err:
        read_machine_file(p, SCHEMA)
    assert str(err.value).startswith(str(p))


def test_file_problems(tmp_path: Path) -> None:
    with pytest.raises(MachineFileError, match="file not found"):
        read_machine_file(tmp_path / "none.toml", SCHEMA)
    with pytest.raises(MachineFileError, match="is a directory"):
        read_machine_file(tmp_path, SCHEMA)
    (tmp_path / "b.toml").write_bytes(b"[wheel]\nJ = 1 # \xff\n")
    with pytest.raises(MachineFileError, match="not UTF-8"):
        read_machine_file(tmp_path / "b.toml", SCHEMA)


def test_a_schema_whose_default_breaks_its_own_range_is_a_bug() -> None:
    bad = {"s": (Field("x", "m", -1.0, low=0.0),)}
    with pytest.raises(MachineFileError, match="default of \\[s\\] x"):
        read_machine_file("unused.toml", bad)
    with pytest.raises(ValueError, match="names a field twice"):
        machine_file_template({"s": (Field("x", "", 1.0), Field("x", "", 2.0))})


def test_range_text() -> None:
    assert Field("a", "", 1.0).range_text() == "a number"
    assert Field("a", "", 1).range_text() == "a whole number"
    assert Field("a", "", 1.0, low=0.0).range_text() == "0 <= a"
    assert Field("a", "", 1.0, high=math.pi, high_open=True).range_text() == "a < 3.14159"


def test_overrides_checked_and_named_by_their_label(tmp_path: Path) -> None:
    from rulkit.machine_file import apply_overrides

    values = read_machine_file(write(tmp_path, "[wheel]\nJ = 2\n"), SCHEMA)
    got = apply_overrides(values, SCHEMA, {"--j": ("wheel", "J", 3), "--poles": ("wheel",
                                                                                 "poles", None)})
    assert got["wheel"] == {"J": 3.0, "poles": 8} and values["wheel"]["J"] == 2.0
    with pytest.raises(MachineFileError, match=r"^--j = -1 \(kg m\^2\): outside its range"):
        apply_overrides(values, SCHEMA, {"--j": ("wheel", "J", -1)})
    with pytest.raises(ValueError, match=r"--x: \[wheel\] x is not in the schema"):
        apply_overrides(values, SCHEMA, {"--x": ("wheel", "x", 1)})


def test_template_with_values_reads_back_as_those_values(tmp_path: Path) -> None:
    values = read_machine_file(write(tmp_path, "[wheel]\nJ = 2\n[filter]\ngate = false\n"),
                               SCHEMA)
    text = machine_file_template(SCHEMA, values=values)
    assert "J = 2.0  # kg m^2" in text and "gate = false" in text
    assert read_machine_file(write(tmp_path, text), SCHEMA) == values


@dataclass(frozen=True)
class _Wheel(Machine):
    schema: ClassVar[Schema] = SCHEMA


def test_a_machine_subclass_reads_its_schema_and_keeps_its_type(tmp_path: Path) -> None:
    p = write(tmp_path, "[wheel]\npoles = 12\n")
    m = _Wheel.read(p)
    assert (m.source, m.values["wheel"]["poles"], m.values["wheel"]["J"]) == (str(p), 12, 0.0106)
    assert _Wheel.read(None) == _Wheel(read_machine_file(write(tmp_path, ""), SCHEMA))
    o = m.with_overrides({"--j": ("wheel", "J", 2.0), "--poles": ("wheel", "poles", None)})
    assert type(o) is _Wheel and o.source == str(p)
    assert (o.values["wheel"]["J"], o.values["wheel"]["poles"]) == (2.0, 12)
    assert m.values["wheel"]["J"] == 0.0106  # the original is unchanged
    with pytest.raises(MachineFileError, match=r"--j = -1 \(kg m\^2\): outside its range"):
        m.with_overrides({"--j": ("wheel", "J", -1)})
    with pytest.raises(MachineFileError, match=r"\[filter\] unknown key"):
        _Wheel.read(write(tmp_path, "[filter]\nmetod = 'ekf'\n"))
