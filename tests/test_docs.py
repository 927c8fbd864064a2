"""The documentation site: every page is in the navigation, the API reference covers every
module and names only modules that import, docstrings cite docs/systems/ sections that exist,
and (slow, needs the `docs` extra) `mkdocs build --strict` succeeds.

The code blocks of the pages are executed by tests/test_examples.py.
"""

from __future__ import annotations

import importlib
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
SRC = ROOT / "src" / "rulkit"
MKDOCS = ROOT / "mkdocs.yml"


def _nav_pages() -> set[str]:
    return set(re.findall(r"([\w./-]+\.md)\s*$", MKDOCS.read_text(), flags=re.M))


def _api_targets() -> list[str]:
    return [m for page in sorted((DOCS / "api").glob("*.md"))
            for m in re.findall(r"^::: ([\w.]+)\s*$", page.read_text(), flags=re.M)]


def test_every_page_is_in_the_navigation_and_every_nav_entry_exists() -> None:
    pages = {p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md")}
    nav = _nav_pages()
    assert pages - nav == set(), f"pages missing from mkdocs.yml nav: {sorted(pages - nav)}"
    assert nav - pages == set(), f"nav entries without a page: {sorted(nav - pages)}"


def test_api_reference_covers_every_module() -> None:
    """Packages are rendered with their submodules (new modules appear by themselves); every
    top-level module and every package under rulkit/ and rulkit/systems/ needs a page."""
    targets = _api_targets()
    for name in targets:
        importlib.import_module(name)  # a renamed module fails here, not only in `make docs`
    wanted = {f"rulkit.{p.stem}" for p in SRC.glob("*.py") if p.name != "__init__.py"}
    wanted |= {f"rulkit.{p.parent.name}" for p in SRC.glob("*/__init__.py")}
    wanted |= {f"rulkit.systems.{p.parent.name}" for p in SRC.glob("systems/*/__init__.py")}
    wanted -= {"rulkit.cli", "rulkit.systems"}  # the commands: `rulkit --help`; a namespace
    missing = sorted(wanted - set(targets))
    assert not missing, f"no API page renders these (add a '::: name' line): {missing}"


# "docs/systems/<page>.md section N" or "... (EQ-n)" in docstrings and comments
_CITE = re.compile(r"docs/systems/([\w-]+)\.md(?:,? (?:section|§)\s?(\d+)(?:\.(\d+))?)?")


def test_docstring_citations_of_system_pages_resolve() -> None:
    headings: dict[str, set[str]] = {}
    equations: dict[str, set[str]] = {}
    for page in (DOCS / "systems").glob("*.md"):
        text = page.read_text()
        headings[page.stem] = set(re.findall(r"^#{2,3} (\d+(?:\.\d+)?)\.? ", text, flags=re.M))
        equations[page.stem] = set(re.findall(r"\(([A-Z]{2}-\d+)\)", text))
    cited = 0
    for path in SRC.rglob("*.py"):
        text = path.read_text()
        for m in _CITE.finditer(text):
            page, sec, sub = m.groups()
            assert page in headings, f"{path}: cites docs/systems/{page}.md, which does not exist"
            if sec:
                key = f"{sec}.{sub}" if sub else sec
                assert key in headings[page], f"{path}: {page}.md has no section {key}"
            cited += 1
        for eq in re.findall(r"\(([A-Z]{2}-\d+)\)", text):
            assert any(eq in e for e in equations.values()), f"{path}: no equation ({eq})"
    assert cited > 0


SYSTEM_PACKAGES = {
    "reaction-wheel": "rulkit.systems.reaction_wheel",
    "motor-damping": "rulkit.systems.motor_damping",
    "friction-drive": "rulkit.systems.friction_drive",
    "embedded-rul": "rulkit.fleet",
}


_OUTSIDE = re.compile(
    r"\(spec\b|\bspec (section|§|rw-|motor-|friction-|embedded-)|\bspec: \"|\bthe spec\b"
    r"|\bspec's\b|(^|[^\w/.])§\s?\d|\b(rw-lubrication|architecture|style)\.md"
    r"|(?<![\w/])(motor-damping|friction-drive|embedded-rul|reaction-wheel)\.md",
    flags=re.I,
)


_VALID = re.compile(r"docs/systems/[\w-]+\.md(?:,? ?§\s?[\d.]+(?:-\d+)?)*(?:, §[\d.]+)*")


def test_no_source_cites_a_spec_outside_the_repository() -> None:
    """Docstrings, comments and report texts cite docs/systems/<page>.md (in the repository),
    never the project's spec files, which are not shipped. A section sign must follow a
    docs/systems page name (on the same line or at the end of the previous one)."""
    offenders = []
    for path in sorted(SRC.rglob("*.py")):
        lines = path.read_text().splitlines()
        for i, line in enumerate(lines):
            rest = _VALID.sub("", line)
            before = lines[i - 1].rstrip() if i else ""
            if re.search(r"docs/systems/[\w-]+\.md(?:,? ?§[\d.]+)*,?$", before):
                rest = re.sub(r"^\s*(?:§[\d.]+(?:-\d+)?(?:, )?)+", "", rest)
            if _OUTSIDE.search(rest):
                offenders.append(f"{path.relative_to(ROOT)}:{i + 1}: {line.strip()}")
    assert not offenders, "cite docs/systems/<page>.md instead:\n" + "\n".join(offenders)


@pytest.mark.parametrize("page", sorted(SYSTEM_PACKAGES))
def test_system_pages_name_code_that_exists(page: str) -> None:
    """`module.name` references of a model page (e.g. `wheel.table3_temperature`) resolve in
    its package (or the engine), so a rename cannot leave the page pointing nowhere."""
    text = (DOCS / "systems" / f"{page}.md").read_text()
    pkg = SYSTEM_PACKAGES[page]
    checked = 0
    for ref in sorted(set(re.findall(r"`([a-z_]+(?:\.[A-Za-z_]\w*)+)`", text))):
        head, *rest = ref.split(".")
        if rest[-1] in ("py", "md"):
            continue  # a file name
        for base in (f"{pkg}.{head}", f"rulkit.{head}", f"rulkit.estimation.{head}"):
            try:
                obj = importlib.import_module(base)
            except ModuleNotFoundError:
                continue
            for attr in rest:
                if not hasattr(obj, attr) and hasattr(obj, "__path__"):  # a submodule
                    importlib.import_module(f"{obj.__name__}.{attr}")
                assert hasattr(obj, attr), f"{page}.md: `{ref}`: {base} has no {attr!r}"
                obj = getattr(obj, attr)
            checked += 1
            break
    assert checked >= 3, f"{page}.md: only {checked} code references found"


def test_crack_growth_tutorial_is_at_most_45_lines_of_user_code() -> None:
    """Issue 10: model, simulation, PF and EKF, a profile at 10 times, metrics and plots in at
    most 45 lines (blank lines and comment-only lines not counted). The code itself runs in
    tests/test_examples.py."""
    text = (DOCS / "tutorials" / "crack-growth.md").read_text()
    blocks = re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)
    lines = [ln for b in blocks for ln in b.splitlines()
             if ln.strip() and not ln.strip().startswith("#")]
    assert len(blocks) >= 4 and 25 <= len(lines) <= 45, len(lines)
    code = "\n".join(blocks)
    for needed in ("simulate(", '"pf"', '"ekf"', "prognosis_profile", "summary()",
                   "plot_profile", "state_estimates"):
        assert needed in code, needed


@pytest.mark.slow
def test_mkdocs_build_strict(tmp_path: Path) -> None:
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings_handlers.python")
    exe = shutil.which("mkdocs", path=str(Path(sys.executable).parent))
    assert exe, "mkdocs is installed but its script is not beside the interpreter"
    proc = subprocess.run([exe, "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={"NO_MKDOCS_2_WARNING": "1", "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    html = (tmp_path / "site" / "index.html").read_text()
    assert "fonts.googleapis" not in html and "fonts.gstatic" not in html
    api = (tmp_path / "site" / "api" / "metrics-plot.html").read_text()
    assert "alpha_lambda_cone" in api
