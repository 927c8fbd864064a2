"""`rulkit.cli.main` builds only the command it runs: the same command, help and errors as
the whole app, which every other command line still gets."""

from __future__ import annotations

import pytest
from typer.main import get_command
from typer.testing import CliRunner

from rulkit.cli import _invoked_app, app

runner = CliRunner()


def test_one_command_app_holds_that_command_only() -> None:
    assert list(get_command(_invoked_app(["status", "--db", "x"])).commands) == ["status"]
    assert list(get_command(_invoked_app(["reproduce", "toy"])).commands) == ["reproduce"]
    for args in ([], ["--help"], ["--version"], ["--blas-threads", "1", "status"], ["nope"]):
        assert _invoked_app(args) is app
    assert len(get_command(app).commands) > 10  # the whole app is left as it was


@pytest.mark.parametrize("args", [["status", "--help"], ["track", "--help"],
                                  ["status", "--db", "x.db", "--format", "xml"],
                                  ["status", "--limit", "-1", "--db", "x.db"],
                                  ["reproduce", "--help"], ["demo", "--help"]])
def test_same_output_and_exit_code_as_the_whole_app(args: list[str]) -> None:
    whole = runner.invoke(app, args)
    one = runner.invoke(_invoked_app(args), args)
    assert (one.exit_code, one.output) == (whole.exit_code, whole.output)
    assert whole.exit_code in (0, 2)
