"""Exit codes and error reporting shared by every ``rulkit`` command (docs/guide.md, "Exit
codes"). One rule:

* ``0`` (:data:`EXIT_OK`): the command did what was asked;
* ``1`` (:data:`EXIT_INPUT`): an input file, database or value in it was refused, or the
  computation could not give a trustworthy answer; one ``error: ...`` line on stderr names the
  file, column and row, and nothing was written;
* ``2`` (:data:`EXIT_USAGE`): the command line itself was refused (unknown option, missing
  argument, an option value out of range); click's ``Usage: ... Error: ...`` message;
* ``75`` (:data:`EXIT_BUSY`, ``EX_TEMPFAIL`` of sysexits.h): a resource was busy (the database
  held by another writer past the wait); nothing was written, the same command can be retried;
* ``70`` (:data:`EXIT_INTERNAL`, ``EX_SOFTWARE``): a bug; a one-line message, the traceback
  only with ``RULKIT_DEBUG=1``;
* ``65`` (:data:`EXIT_CORRUPT`, ``EX_DATAERR``): SQLite reports the database damaged;
* ``74`` (:data:`EXIT_IO`, ``EX_IOERR``): the disk is full or failed; nothing was written;
* ``77`` (:data:`EXIT_NOPERM`, ``EX_NOPERM``): the database or its directory cannot be
  written (or read) by this user.
"""

from __future__ import annotations

from typing import NoReturn

import typer

EXIT_OK = 0
EXIT_INPUT = 1
EXIT_USAGE = 2
EXIT_INTERNAL = 70
EXIT_BUSY = 75
EXIT_CORRUPT = 65
EXIT_IO = 74
EXIT_NOPERM = 77


def fail(msg: str, code: int = EXIT_INPUT) -> NoReturn:
    """Print ``error: msg`` (made terminal-safe) on stderr and exit with ``code``."""
    from rulkit.tables import safe_text

    typer.echo(f"error: {safe_text(msg, 2000)}", err=True)
    raise typer.Exit(code=code)


def bad_option(option: str, msg: str) -> NoReturn:
    """A refused option value: click's usage error (exit code 2) naming the option."""
    raise typer.BadParameter(msg, param_hint=f"'{option}'")
