"""Machines described as data: a TOML file of a machine's constants, noise levels and filter
settings, validated against a schema with units and ranges.

A system declares its schema as sections of :class:`Field` (name, unit, allowed range or
choices, default, one line of meaning); :func:`read_machine_file` reads a user's file against it
and returns every value, the defaults filled in. Nothing is guessed: an unknown section or key,
a value of the wrong type (``true`` where a number is expected, a string, an array), a number
outside its range, or a choice not in its list is refused with the file, the ``[section]``, the
key, the unit and what was expected. :func:`machine_file_template` writes the defaults as a
commented TOML file to start from, and :func:`schema_table` the markdown table a docs page
shows. Units are part of the schema, not of the file: a value is read in the unit its field
names (SI unless the field says otherwise).

Example::

    WHEEL = {"wheel": (Field("J", "kg m^2", 0.0106, low=1e-5, high=10.0,
                             doc="rotor inertia"),)}
    values = read_machine_file("my-wheel.toml", WHEEL)   # {"wheel": {"J": 0.0106}}
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Self

__all__ = ["Field", "Machine", "MachineFileError", "apply_overrides", "machine_file_template",
           "machine_values", "read_machine_file", "schema_table"]

Schema = Mapping[str, Sequence["Field"]]


class MachineFileError(ValueError):
    """A machine file that cannot be used; the message names the file, section and key."""


@dataclass(frozen=True)
class Field:
    """One value of a machine file.

    ``default`` fixes the kind: a float (ints in the file are accepted), an int (a whole
    number), a string (one of ``choices``) or a bool. ``low``/``high`` bound a number
    (inclusive unless ``low_open``/``high_open``); ``unit`` is printed with every message.
    """

    name: str
    unit: str
    default: float | int | str | bool
    doc: str = ""
    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] = ()

    def range_text(self) -> str:
        """The allowed values in words: ``0 < x <= 10``, ``one of 'a', 'b'``, ``true or
        false``."""
        if isinstance(self.default, bool):
            return "true or false"
        if isinstance(self.default, str):
            return "one of " + ", ".join(repr(c) for c in self.choices)
        lo = "" if self.low == -math.inf else f"{self.low:g} {'<' if self.low_open else '<='} "
        hi = "" if self.high == math.inf else f" {'<' if self.high_open else '<='} {self.high:g}"
        kind = "a whole number" if isinstance(self.default, int) else "a number"
        return f"{lo}{self.name}{hi}" if lo or hi else kind

    def check(self, value: Any, where: str) -> float | int | str | bool:
        """``value`` converted to the field's kind, or :class:`MachineFileError` naming
        ``where``."""
        unit = f" ({self.unit})" if self.unit else ""
        got = f"{where} = {value!r}{unit}"
        if isinstance(self.default, bool):
            if not isinstance(value, bool):
                raise MachineFileError(f"{got}: expected true or false")
            return value
        if isinstance(self.default, str):
            if not isinstance(value, str) or (self.choices and value not in self.choices):
                raise MachineFileError(f"{got}: expected {self.range_text()}")
            return value
        if isinstance(value, bool) or not isinstance(value, int | float):
            kind = "a whole number" if isinstance(self.default, int) else "a number"
            raise MachineFileError(f"{got}: expected {kind}, not {type(value).__name__}")
        if isinstance(self.default, int) and not isinstance(value, int):
            raise MachineFileError(f"{got}: expected a whole number")
        if not math.isfinite(value):
            raise MachineFileError(f"{got}: expected a finite number")
        too_low = value < self.low or (self.low_open and value == self.low)
        too_high = value > self.high or (self.high_open and value == self.high)
        if too_low or too_high:
            raise MachineFileError(f"{got}: outside its range, expected {self.range_text()}")
        return value if isinstance(self.default, int) else float(value)


def _check_schema(schema: Schema) -> None:
    for section, fields in schema.items():
        names = [f.name for f in fields]
        if len(set(names)) != len(names):
            raise ValueError(f"schema section [{section}] names a field twice: {names}")
        for f in fields:
            f.check(f.default, f"default of [{section}] {f.name}")


def read_machine_file(path: str | Path, schema: Schema) -> dict[str, dict[str, Any]]:
    """Every value of ``schema`` from the TOML file ``path`` (defaults where the file is
    silent), checked. Raises :class:`MachineFileError` naming the file, section and key."""
    _check_schema(schema)
    p = Path(path)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise MachineFileError(f"{p}: file not found") from None
    except IsADirectoryError:
        raise MachineFileError(f"{p}: is a directory, expected a TOML file") from None
    except OSError as err:
        raise MachineFileError(f"{p}: cannot be read ({err.strerror})") from None
    try:
        doc = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as err:
        raise MachineFileError(f"{p}: not UTF-8 text (byte {err.start})") from None
    except tomllib.TOMLDecodeError as err:
        raise MachineFileError(f"{p}: not valid TOML: {err}") from None
    return machine_values(doc, schema, str(p))


def machine_values(doc: Mapping[str, Any], schema: Schema, source: str = "<dict>"
                   ) -> dict[str, dict[str, Any]]:
    """:func:`read_machine_file` for an already parsed document (a dict of sections)."""
    _check_schema(schema)
    unknown = sorted(set(doc) - set(schema))
    if unknown:
        raise MachineFileError(
            f"{source}: unknown section(s) {', '.join(f'[{u}]' for u in unknown)}; "
            f"expected {', '.join(f'[{s}]' for s in schema)}")
    out: dict[str, dict[str, Any]] = {}
    for section, fields in schema.items():
        given = doc.get(section, {})
        if not isinstance(given, Mapping):
            raise MachineFileError(f"{source}: {section} must be a table [{section}], "
                                   f"not {type(given).__name__}")
        known = {f.name: f for f in fields}
        extra = sorted(set(given) - set(known))
        if extra:
            close = {k: _closest(k, known) for k in extra}
            hints = "; ".join(f"{k!r}" + (f" (did you mean {c!r}?)" if c else "")
                              for k, c in close.items())
            raise MachineFileError(f"{source}: [{section}] unknown key(s) {hints}; "
                                   f"known keys: {', '.join(known)}")
        out[section] = {f.name: f.check(given[f.name], f"{source}: [{section}] {f.name}")
                        if f.name in given else f.default for f in fields}
    return out


def apply_overrides(values: dict[str, dict[str, Any]], schema: Schema,
                    overrides: Mapping[str, tuple[str, str, Any]]) -> dict[str, dict[str, Any]]:
    """``values`` (as :func:`read_machine_file` returns them) with single values replaced:
    ``overrides`` maps a label (how the user gave it, e.g. a command-line flag ``"--j"``) to
    ``(section, key, value)``; ``None`` values are skipped. Each value is checked by its field,
    and an error names the label: ``--j = -0.003 (kg m^2): outside its range, ...``."""
    out = {s: dict(v) for s, v in values.items()}
    fields = {(s, f.name): f for s, fs in schema.items() for f in fs}
    for label, (section, key, value) in overrides.items():
        if value is None:
            continue
        if (section, key) not in fields:
            raise ValueError(f"{label}: [{section}] {key} is not in the schema")
        out[section][key] = fields[section, key].check(value, label)
    return out


@dataclass(frozen=True)
class Machine:
    """A machine file, read and checked against the subclass's :attr:`schema`: ``values`` holds
    every section's values (the defaults filled in), ``source`` the file (or ``"defaults"``).

    A system subclasses it with its schema and typed views of the values, e.g.
    :class:`rulkit.systems.friction_drive.machine.DriveMachine`.
    """

    schema: ClassVar[Schema] = {}
    values: dict[str, dict[str, Any]]
    source: str = "defaults"

    @classmethod
    def read(cls, path: str | Path | None = None) -> Self:
        """The machine file at ``path`` checked against :attr:`schema`, the defaults filled in
        (``None``: the defaults alone). Raises :class:`MachineFileError` naming the file,
        section and key."""
        if path is None:
            return cls(machine_values({}, cls.schema, "defaults"))
        return cls(read_machine_file(path, cls.schema), str(path))

    def with_overrides(self, overrides: Mapping[str, tuple[str, str, Any]]) -> Self:
        """This machine with single values replaced (:func:`apply_overrides`: ``{label:
        (section, key, value)}``, ``None`` values skipped, errors naming the label)."""
        return type(self)(apply_overrides(self.values, self.schema, overrides), self.source)


def _closest(name: str, known: Mapping[str, Field]) -> str | None:
    low = {k.lower(): k for k in known}
    if name.lower() in low:
        return low[name.lower()]
    import difflib

    hit = difflib.get_close_matches(name, list(known), n=1, cutoff=0.75)
    return hit[0] if hit else None


def _toml_value(v: float | int | str | bool) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, int):
        return str(v)
    return repr(float(v))


def machine_file_template(schema: Schema, title: str = "",
                          values: Mapping[str, Mapping[str, Any]] | None = None) -> str:
    """The defaults of ``schema`` (or ``values``, as :func:`read_machine_file` returns them)
    as a TOML file, each key with its unit, range and meaning as a comment (reading it back
    gives the same values)."""
    _check_schema(schema)
    lines = [f"# {title}", ""] if title else []
    for section, fields in schema.items():
        lines.append(f"[{section}]")
        for f in fields:
            note = "; ".join(x for x in (f.unit, f.range_text(), f.doc) if x)
            v = f.default if values is None else values[section][f.name]
            lines.append(f"{f.name} = {_toml_value(v)}  # {note}")
        lines.append("")
    return "\n".join(lines)


def schema_table(schema: Schema) -> str:
    """A markdown table of every field (section, key, unit, default, allowed values, meaning)."""
    rows = ["| section | key | unit | default | allowed | meaning |",
            "| --- | --- | --- | --- | --- | --- |"]
    for section, fields in schema.items():
        for f in fields:
            rows.append(f"| {section} | `{f.name}` | {f.unit} | {_toml_value(f.default)} | "
                        f"{f.range_text()} | {f.doc} |")
    return "\n".join(rows) + "\n"
