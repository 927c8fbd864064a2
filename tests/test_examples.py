"""Every example script runs and every ```python block of docs/guide.md executes.

The examples print their own checks against independent oracles and exit with status 1 when
one fails (``check`` in each script, with Monte Carlo tolerances); here they must exit 0.
Each guide block runs in a fresh namespace and carries its own assertions, so the guide cannot
drift from the engine.
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
GUIDE = ROOT / "docs" / "guide.md"


def _guide_blocks() -> list[tuple[int, str]]:
    """(line number, code) of every ```python fenced block of the guide."""
    text = GUIDE.read_text()
    blocks = []
    for m in re.finditer(r"^```python\n(.*?)^```", text, flags=re.S | re.M):
        blocks.append((text.count("\n", 0, m.start()) + 1, m.group(1)))
    return blocks


BLOCKS = _guide_blocks()


def test_there_is_something_to_run() -> None:
    assert len(EXAMPLES) >= 4, EXAMPLES
    assert len(BLOCKS) >= 8, f"only {len(BLOCKS)} python blocks found in {GUIDE}"


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


@pytest.mark.parametrize("line, code", BLOCKS, ids=[f"guide_line_{ln}" for ln, _ in BLOCKS])
def test_guide_block_executes(line: int, code: str, tmp_path: Path,
                              monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {"__name__": f"guide_block_{line}"}
    exec(compile(code, f"{GUIDE}:{line}", "exec"), namespace)


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
