"""Every example script runs and every ```python block of docs/ (the site's pages) executes.

The examples print their own checks against independent oracles and exit with status 1 when
one fails (``check`` in each script, with Monte Carlo tolerances); here they must exit 0.
Each docs block runs in a fresh namespace and carries its own assertions, so the docs cannot
drift from the code. Every fenced block must name its language: ```python runs, the others
(```text for equations, ```console for shell commands) are declared as not Python. A python
block right after a line ``<!-- slow -->`` (invisible on the site) runs only with
``-m slow`` (`make test-slow`): longer tutorial steps stay out of the default run. A python
block right after ``<!-- continue -->`` continues the previous python block of its page: the
chain runs as one test in one namespace (line numbers in tracebacks are the page's). A block
whose printed output a page shows (``<!-- output of the block above -->`` after it) runs in
tests/test_command_pages.py, which also compares what it prints; not a second time here.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples").glob("*.py"))
DOCS = ROOT / "docs"
GUIDE = DOCS / "guide.md"
#: Languages of fenced blocks that are deliberately not executed.
NOT_PYTHON = {"text", "console", "c"}  # C: compiled by tests/fleet/export
FENCE = re.compile(r"^```([^\n`]*)\n(.*?)^```[ \t]*$", flags=re.S | re.M)


SLOW = "<!-- slow -->"
CONTINUE = "<!-- continue -->"
SHOWN = "<!-- output of the block above -->"


def _fences(page: Path) -> list[tuple[int, str, str]]:
    """(line number, language, code) of every fenced block of a markdown page."""
    text = page.read_text()
    return [(text.count("\n", 0, m.start()) + 1, m.group(1).strip(), m.group(2))
            for m in FENCE.finditer(text)]


def _marker(page: Path, line: int) -> str:
    """The last non-blank line before the fence at ``line`` (a marker comment or text)."""
    before = page.read_text().splitlines()[: line - 1]
    previous = [ln for ln in before if ln.strip()]
    return previous[-1].strip() if previous else ""


def _is_slow(page: Path, line: int) -> bool:
    return _marker(page, line) == SLOW


def _output_shown(page: Path, line: int, code: str) -> bool:
    """Whether the page shows the output of the block at ``line``: the output marker comes
    after the block and before the next fence."""
    after = page.read_text().splitlines()[line + code.count("\n") + 1:]
    for ln in after:
        if ln.startswith("```"):
            return False
        if ln.strip() == SHOWN:
            return True
    return False


def _python_blocks(page: Path) -> list[tuple[Path, int, str]]:
    """(page, first fence line, code) per test: a <!-- continue --> block joins the previous
    one, padded with blank lines so that the code sits at its line numbers in the page."""
    out: list[tuple[Path, int, str]] = []
    for line, lang, code in _fences(page):
        if lang != "python" or _output_shown(page, line, code):
            continue
        if _marker(page, line) == CONTINUE:
            assert out, f"{page}:{line}: {CONTINUE} without a python block before it"
            first, so_far = out[-1][1], out[-1][2]
            pad = line - (first + so_far.count("\n"))
            out[-1] = (page, first, so_far + "\n" * pad + code)
        else:
            out.append((page, line, code))
    return [(p, ln, "\n" * ln + code) for p, ln, code in out]


PAGES = sorted(DOCS.rglob("*.md"))
BLOCKS = [block for page in PAGES for block in _python_blocks(page)]
GUIDE_BLOCKS = [b for b in BLOCKS if b[0] == GUIDE]


def test_there_is_something_to_run() -> None:
    assert len(EXAMPLES) >= 4, EXAMPLES
    assert len(GUIDE_BLOCKS) >= 8, f"only {len(GUIDE_BLOCKS)} python blocks found in {GUIDE}"


def test_every_docs_block_names_its_language() -> None:
    unmarked = [f"{page.relative_to(ROOT)}:{line} ({lang or 'no language'})"
                for page in PAGES for line, lang, _ in _fences(page)
                if lang != "python" and lang not in NOT_PYTHON]
    assert not unmarked, f"mark these blocks python, text or console: {unmarked}"


def test_fence_parser_sees_every_fence() -> None:
    # an odd number of ``` lines means a block the parser would silently skip
    for page in PAGES:
        fences = [ln for ln in page.read_text().splitlines() if ln.startswith("```")]
        assert len(fences) % 2 == 0 and len(fences) == 2 * len(_fences(page)), page


@pytest.mark.parametrize("script", EXAMPLES, ids=lambda p: p.name)
def test_example_runs(script: Path, tmp_path: Path) -> None:
    env = dict(os.environ, MPLBACKEND="Agg", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    proc = subprocess.run(
        [sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
        timeout=60,
    )
    assert proc.returncode == 0, f"{script.name} failed:\n{proc.stdout}\n{proc.stderr}"
    assert proc.stdout.strip(), f"{script.name} printed nothing"


def test_example_writes_figure_with_out(tmp_path: Path) -> None:
    script = ROOT / "examples" / "01_pf_vs_kalman.py"
    out = tmp_path / "figs"
    env = dict(os.environ, MPLBACKEND="Agg", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run(
        [sys.executable, str(script), "--particles", "500", "--out", str(out)],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert (out / "pf_vs_kalman.png").stat().st_size > 0


@pytest.mark.parametrize(
    "page, line, code",
    [pytest.param(p, ln, code, id=f"{p.relative_to(DOCS).with_suffix('')}:{ln}",
                  marks=[pytest.mark.slow] if _is_slow(p, ln) else [])
     for p, ln, code in BLOCKS],
)
def test_docs_block_executes(page: Path, line: int, code: str, tmp_path: Path,
                             monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    namespace: dict[str, object] = {"__name__": f"docs_block_{line}"}
    exec(compile(code, str(page), "exec"), namespace)


def test_example_checks_can_fail(tmp_path: Path) -> None:
    # 10 particles cannot match the exact Kalman posterior: the script's own check must stop it
    script = ROOT / "examples" / "01_pf_vs_kalman.py"
    env = dict(os.environ, MPLBACKEND="Agg", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, str(script), "--particles", "10"], cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1 and "CHECK FAILED" in proc.stderr, proc.stderr


def test_guide_names_only_installed_reproductions() -> None:
    from typer.testing import CliRunner

    from rulkit.cli import app

    text = GUIDE.read_text()
    listed = re.search(r"lists them\): (.*?), one per seed paper", text, flags=re.S)
    assert listed, "the guide's list of reproductions moved; update this test"
    names = re.findall(r"`([a-z-]+)`", listed.group(1))
    out = CliRunner().invoke(app, ["reproduce", "--help"], env={"COLUMNS": "200"}).output
    assert names and all(n in out for n in names), (names, out)
