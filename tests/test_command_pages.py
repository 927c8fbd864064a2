"""Each page of docs/commands/ shows what its command prints: the ```text block after the
marker ``<!-- output of the block above -->`` must be the output of the python block before
it, line by line (the page may leave lines out, in particular those naming the run's temporary
directory ``d``). The docs tests run that block too; here its output is compared."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import pytest

PAGES = sorted((Path(__file__).resolve().parents[1] / "docs" / "commands").glob("*.md"))
MARKER = "<!-- output of the block above -->"
BLOCK = re.compile(r"```python\n(.*?)^```\s*\n(?:(?!```).)*?" + re.escape(MARKER)
                   + r"\s*\n```text\n(.*?)^```", flags=re.S | re.M)


def _shown_runs(page: Path) -> list[tuple[str, str]]:
    return [(m.group(1), m.group(2)) for m in BLOCK.finditer(page.read_text())]


def test_the_drive_motor_and_wheel_pages_show_a_run() -> None:
    shown = {p.stem for p in PAGES if _shown_runs(p)}
    assert shown >= {"drive", "motor-damping", "rw-estimate-temperature", "rw-degradation",
                     "rw-rul", "rw-pipeline", "rw-wheel-template"}


@pytest.mark.parametrize("page", [p for p in PAGES if MARKER in p.read_text()],
                         ids=lambda p: p.stem)
def test_printed_output_is_what_the_page_shows(page: Path) -> None:
    for code, shown in _shown_runs(page):
        out = io.StringIO()
        namespace: dict = {}
        with contextlib.redirect_stdout(out):
            exec(compile(code, str(page), "exec"), namespace)
        printed = [ln.rstrip() for ln in out.getvalue().splitlines()]
        tmp = str(namespace.get("d", "\0"))
        printed = [ln for ln in printed if tmp not in ln]
        expected = [ln.rstrip() for ln in shown.splitlines()]
        assert _subsequence(expected, printed), (
            f"{page}: the page's output block differs from the run:\n" + "\n".join(printed))


def _subsequence(expected: list[str], printed: list[str]) -> bool:
    it = iter(printed)
    return all(any(line == p for p in it) for line in expected)
