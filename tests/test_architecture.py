"""The import graph keeps the architecture: a physics-free engine, systems independent.

Read statically with ``ast`` over ``src/rulkit`` (every ``import``/``from ... import`` anywhere in
a module, including lazy imports inside functions and ``TYPE_CHECKING`` blocks), so an import
that only runs on one code path still counts.

- No engine module (model, integrate, metrics, tables, runner, reporting, plot, estimation.*,
  prognosis.*) imports ``rulkit.systems`` or ``rulkit.fleet``.
- No system package (``rulkit.systems.<name>``) imports another system.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = SRC / "rulkit"

ENGINE_MODULES = ("model", "integrate", "metrics", "tables", "runner", "reporting", "plot")
ENGINE_PACKAGES = ("estimation", "prognosis")
FORBIDDEN_FOR_ENGINE = ("rulkit.systems", "rulkit.fleet")


def module_name(path: Path) -> str:
    """``src/rulkit/a/b.py`` -> ``rulkit.a.b``; ``src/rulkit/a/__init__.py`` -> ``rulkit.a``."""
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in the file, relative ones resolved.

    ``from pkg import name`` yields both ``pkg`` and ``pkg.name`` (``name`` may be a module)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    me = module_name(path)
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            found.append((node.lineno, mod))
            found += [(node.lineno, f"{mod}.{a.name}") for a in node.names if a.name != "*"]
    # importlib.import_module("rulkit....") with a literal argument counts too
    for node in ast.walk(tree):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute | ast.Name)
                and getattr(node.func, "attr", getattr(node.func, "id", "")) == "import_module"
                and node.args and isinstance(node.args[0], ast.Constant)
                and isinstance(node.args[0].value, str)):
            found.append((node.lineno, node.args[0].value))
    return found


def _within(mod: str, prefix: str) -> bool:
    return mod == prefix or mod.startswith(prefix + ".")


def engine_files() -> list[Path]:
    files = [PACKAGE / f"{m}.py" for m in ENGINE_MODULES if (PACKAGE / f"{m}.py").exists()]
    for pkg in ENGINE_PACKAGES:
        files += sorted((PACKAGE / pkg).rglob("*.py"))
    return files


def system_names() -> list[str]:
    return sorted(p.name for p in (PACKAGE / "systems").iterdir()
                  if p.is_dir() and (p / "__init__.py").exists())


def test_engine_imports_no_system_nor_fleet() -> None:
    files = engine_files()
    # the engine is there (a renamed folder would make this test vacuous)
    assert {module_name(f) for f in files} >= {"rulkit.model", "rulkit.estimation.particle",
                                               "rulkit.prognosis.rul"}
    bad = [f"{f.relative_to(SRC)}:{line}: imports {mod}"
           for f in files for line, mod in imported_modules(f)
           if any(_within(mod, p) for p in FORBIDDEN_FOR_ENGINE)]
    assert not bad, "the engine must not import systems or the fleet layer:\n" + "\n".join(bad)


def test_no_system_imports_another_system() -> None:
    names = system_names()
    assert {"reaction_wheel", "motor_damping", "friction_drive", "toy"} <= set(names)
    bad = []
    for name in names:
        own = f"rulkit.systems.{name}"
        for f in sorted((PACKAGE / "systems" / name).rglob("*.py")):
            for line, mod in imported_modules(f):
                if _within(mod, "rulkit.systems") and not _within(mod, own) \
                        and mod != "rulkit.systems":
                    bad.append(f"{f.relative_to(SRC)}:{line}: imports {mod}")
    assert not bad, "a system must not import another system:\n" + "\n".join(bad)


@pytest.mark.parametrize(
    ("source", "module", "expected"),
    [
        ("import rulkit.systems.toy.model\n", "rulkit.metrics", "rulkit.systems.toy.model"),
        ("def f():\n    from rulkit.fleet import store\n", "rulkit.metrics", "rulkit.fleet.store"),
        ("from ..systems.toy import model\n", "rulkit.estimation.particle",
         "rulkit.systems.toy.model"),
        ("from . import kernels\n", "rulkit.systems.toy.model", "rulkit.systems.toy.kernels"),
        ("import importlib\nimportlib.import_module('rulkit.fleet.store.cli')\n", "rulkit.plot",
         "rulkit.fleet.store.cli"),
    ],
)
def test_import_reader_sees_lazy_relative_and_dynamic_imports(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, source: str, module: str, expected: str
) -> None:
    """The reader finds the imports the rules above must catch (so those tests can fail)."""
    src = tmp_path / "src"
    path = src / Path(*module.split(".")).with_suffix(".py")
    path.parent.mkdir(parents=True)
    path.write_text(source)
    monkeypatch.setitem(globals(), "SRC", src)
    assert expected in {m for _, m in imported_modules(path)}
