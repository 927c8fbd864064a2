"""The import graph keeps the architecture: a physics-free engine, systems independent, each
name with one home and one import path.

Read statically with ``ast`` over ``src/rulkit`` (every ``import``/``from ... import`` anywhere in
a module, including lazy imports inside functions and ``TYPE_CHECKING`` blocks), so an import
that only runs on one code path still counts.

- No engine module (model, integrate, metrics, tables, runner, reporting, plot, estimation.*,
  prognosis.*) imports ``rulkit.systems`` or ``rulkit.fleet``.
- No system package (``rulkit.systems.<name>``) imports another system.
- No import cycle between modules (imports that run: module level and inside functions; the
  ``TYPE_CHECKING`` ones never run). A lazy import that closes a cycle hides it until one code
  path runs first: it counts.
- No private name (``_x``) is imported from another package, by ``from m import _x`` or as
  ``m._x`` of an imported module: a helper another package needs gets a public name in its
  home.
- No module-level ``__getattr__`` re-exporting moved names, and no ``__all__`` listing a name the
  module only imports: each name has one home and one import path. The one exception is the
  curated top-level list of ``rulkit/__init__.py`` (loaded lazily so that the command line
  starts without scipy and numba).
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


# ------------------------------------------------------------------------------------------
# one home per name: import cycles, private names across packages, re-export shims
# ------------------------------------------------------------------------------------------

CURATED_EXPORTS = "rulkit"  # rulkit/__init__.py: the curated top-level list (module docstring)


def all_modules(src: Path | None = None) -> dict[str, Path]:
    root = (src or SRC) / "rulkit"
    return {module_name_in(p, src or SRC): p for p in sorted(root.rglob("*.py"))}


def module_name_in(path: Path, src: Path) -> str:
    parts = list(path.relative_to(src).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _type_checking_lines(tree: ast.AST) -> set[int]:
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and getattr(node.test, "id",
                                                getattr(node.test, "attr", "")) == "TYPE_CHECKING":
            for stmt in node.body:
                lines |= {n.lineno for n in ast.walk(stmt) if hasattr(n, "lineno")}
    return lines


def _package_of(mod: str, path: Path) -> str:
    return mod if path.name == "__init__.py" else mod.rpartition(".")[0]


def _resolve(node: ast.ImportFrom, package: str) -> str:
    if not node.level:
        return node.module or ""
    base = package.split(".")
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def runtime_import_graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the rulkit modules it imports at run time (not under ``TYPE_CHECKING``):
    ``from pkg import name`` goes to ``pkg.name`` when that is a module, else to ``pkg``."""
    graph: dict[str, set[str]] = {}
    for mod, path in modules.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        skip = _type_checking_lines(tree)
        package = _package_of(mod, path)
        out: set[str] = set()
        for node in ast.walk(tree):
            if getattr(node, "lineno", None) in skip:
                continue
            if isinstance(node, ast.Import):
                out |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom):
                src = _resolve(node, package)
                out |= {f"{src}.{a.name}" if f"{src}.{a.name}" in modules else src
                        for a in node.names}
        graph[mod] = {m for m in out if m in modules and m != mod}
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return cycles


def private_imports_across_packages(modules: dict[str, Path]) -> list[str]:
    """``path:line: name from module`` for every private name taken from another package."""
    bad = []
    for mod, path in modules.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        package = _package_of(mod, path)
        aliases: dict[str, str] = {}  # local name -> imported rulkit module
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                src = _resolve(node, package)
                for a in node.names:
                    full = f"{src}.{a.name}"
                    if full in modules:
                        aliases[a.asname or a.name] = full
                        continue
                    home = _package_of(src, modules[src]) if src in modules else src
                    if _private(a.name) and home != package and src.startswith("rulkit"):
                        bad.append(f"{path.relative_to(SRC)}:{node.lineno}: {a.name} from {src}")
            elif isinstance(node, ast.Import):
                aliases |= {a.asname: a.name for a in node.names if a.asname and
                            a.name in modules}
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                    and node.value.id in aliases and _private(node.attr)):
                src = aliases[node.value.id]
                if _package_of(src, modules[src]) != package:
                    bad.append(f"{path.relative_to(SRC)}:{node.lineno}: {node.attr} of {src}")
    return bad


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def reexport_shims(modules: dict[str, Path]) -> list[str]:
    """Module-level ``__getattr__`` and ``__all__`` entries a module does not define itself."""
    bad = []
    for mod, path in modules.items():
        if mod == CURATED_EXPORTS:
            continue
        tree = ast.parse(path.read_text(), filename=str(path))
        defined: set[str] = set()
        exported: list[str] = []
        for node in tree.body:
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                defined.add(node.name)
                if node.name == "__getattr__":
                    bad.append(f"{path.relative_to(SRC)}:{node.lineno}: module __getattr__")
            elif isinstance(node, ast.Assign | ast.AnnAssign):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                for t in targets:
                    for n in ast.walk(t):
                        if isinstance(n, ast.Name):
                            defined.add(n.id)
                            if n.id == "__all__" and isinstance(node.value, ast.List | ast.Tuple):
                                exported = [e.value for e in node.value.elts
                                            if isinstance(e, ast.Constant)]
        bad += [f"{path.relative_to(SRC)}: __all__ lists {name!r}, defined elsewhere"
                for name in exported if name not in defined]
    return bad


def test_no_import_cycles() -> None:
    modules = all_modules()
    graph = runtime_import_graph(modules)
    assert sum(map(len, graph.values())) > 100  # the reader sees the imports (not vacuous)
    cycles = import_cycles(graph)
    assert not cycles, "import cycles (modules importing each other, lazily or not):\n" + \
        "\n".join(" <-> ".join(c) for c in cycles)


def test_no_private_names_imported_across_packages() -> None:
    bad = private_imports_across_packages(all_modules())
    assert not bad, ("private names imported from another package (give the helper a public "
                     "name in its home):\n" + "\n".join(bad))


def test_no_reexport_shims() -> None:
    bad = reexport_shims(all_modules())
    assert not bad, "each name has one home and one import path:\n" + "\n".join(bad)


@pytest.mark.parametrize(
    ("files", "check", "expected"),
    [
        ({"a.py": "from rulkit.b import f\n", "b.py": "def f():\n    from rulkit import a\n"},
         "cycles", [["rulkit.a", "rulkit.b"]]),
        ({"a.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from rulkit import b\n",
          "b.py": "from rulkit import a\n"}, "cycles", []),
        ({"p/__init__.py": "", "p/m.py": "_h = 1\n", "q/__init__.py": "",
          "q/n.py": "from rulkit.p.m import _h\n"}, "private", ["rulkit/q/n.py:1: _h"]),
        ({"p/__init__.py": "", "p/m.py": "_h = 1\n", "q/__init__.py": "",
          "q/n.py": "from rulkit.p import m\nx = m._h\n"}, "private", ["rulkit/q/n.py:2: _h"]),
        ({"p/__init__.py": "", "p/m.py": "_h = 1\n", "p/n.py": "from rulkit.p.m import _h\n"},
         "private", []),
        ({"m.py": "def __getattr__(name):\n    return 1\n"}, "shims", ["module __getattr__"]),
        ({"m.py": "from os import path\n__all__ = ['path']\n"}, "shims", ["'path'"]),
        ({"m.py": "def f():\n    pass\n__all__ = ['f']\n"}, "shims", []),
    ],
)
def test_one_home_readers_find_what_the_rules_forbid(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, files: dict[str, str], check: str,
    expected: list,
) -> None:
    """The readers behind the three rules above report a made-up offence (so they can fail)
    and nothing for the allowed forms."""
    src = tmp_path / "src"
    for name, text in {"__init__.py": "", **files}.items():
        path = src / "rulkit" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    monkeypatch.setitem(globals(), "SRC", src)
    modules = all_modules(src)
    if check == "cycles":
        assert import_cycles(runtime_import_graph(modules)) == expected
        return
    found = (private_imports_across_packages(modules) if check == "private"
             else reexport_shims({k: v for k, v in modules.items() if k != "rulkit"}))
    assert len(found) == len(expected)
    assert all(e in f for e, f in zip(expected, found, strict=True)), found
