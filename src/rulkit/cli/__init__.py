"""The ``rulkit`` command line (typer + rich).

Each system (and the fleet layer) contributes its commands from its own ``cli`` module, which
defines ``register(app, reproduce)``: ``app`` is the top-level typer app and ``reproduce`` the
``rulkit reproduce`` group. Heavy imports stay inside the command functions so that
``rulkit --help`` stays fast.
"""

from __future__ import annotations

import importlib
from pathlib import Path

import typer

app = typer.Typer(
    name="rulkit",
    pretty_exceptions_enable=False,
    help="Model-based prognostics: Bayesian filters and Remaining Useful Life distributions.",
    no_args_is_help=True,
    add_completion=False,
    # help texts are plain text: "[c, a]" must not be read as rich markup and vanish
    rich_markup_mode=None,
)
reproduce = typer.Typer(help="Reproduce a seed paper's tables and figures.", no_args_is_help=True)
app.add_typer(reproduce, name="reproduce")

# Modules that add commands; each defines register(app, reproduce).
COMMAND_MODULES = (
    "rulkit.systems.reaction_wheel.cli",
    "rulkit.systems.motor_damping.cli",
    "rulkit.systems.friction_drive.cli",
    "rulkit.systems.embedded_rul.cli",
    "rulkit.fleet.store.cli",
    "rulkit.fleet.learned.cli",
    "rulkit.fleet.service.cli",
    "rulkit.fleet.export.cli",
    "rulkit.systems.toy.cli",
)


def _version_callback(value: bool) -> None:
    if value:
        from rulkit import __version__

        typer.echo(f"rulkit {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_version_callback, is_eager=True, help="Print the version."
    ),
    blas_threads: int = typer.Option(
        1, "--blas-threads", min=1, help="Threads for BLAS/LAPACK (numpy, scipy)."
    ),
) -> None:
    """rulkit: telemetry -> state and parameter estimates -> RUL distribution."""
    limit_blas_threads(blas_threads)


def limit_blas_threads(n: int) -> None:
    """Cap the BLAS thread pools of numpy and scipy for the rest of the process.

    The filters here do many small batched linear-algebra calls (e.g. ``expm`` on (B, 8, 8)
    stacks each step), where BLAS threads only add synchronisation: on a 2-core machine one
    such call took ~0.8 ms with OpenBLAS threads against ~0.06 ms with one thread. Independent
    runs are parallelised by processes instead (``--workers``).
    """
    import os
    import sys

    # BLAS libraries loaded later (most commands import numpy only when they run) read their
    # thread count from the environment when they load; threadpoolctl caps the loaded ones
    for var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS",
                "VECLIB_MAXIMUM_THREADS"):
        os.environ[var] = str(n)
    if "numpy" in sys.modules or "scipy" in sys.modules:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=n, user_api="blas")


@app.command()
def demo(
    out: Path = typer.Option(Path("demo-out"), help="Directory for the tables and figures."),
    seed: int = typer.Option(0, min=0, help="Seed of the run."),
) -> None:
    """Short end-to-end run of the reaction-wheel pipeline (what `make demo` runs)."""
    from rulkit.systems.reaction_wheel.cli import run_quick

    run_quick(out=out, seed=seed)


for _name in COMMAND_MODULES:
    importlib.import_module(_name).register(app, reproduce)


def _invoked_app(args: list[str]) -> typer.Typer:
    """``app`` with only the command that ``args`` start with, when they start with the name
    of one (``rulkit status --db f``): typer reads the signature of every registered command
    to build the group before it runs one, and a run needs only its own. The same app
    otherwise (no command, an option first, an unknown name, ``--help``)."""
    import copy

    from typer.main import get_command_name

    if not args:
        return app
    name = args[0]
    commands = [c for c in app.registered_commands
                if (c.name or get_command_name(getattr(c.callback, "__name__", ""))) == name]
    groups = [g for g in app.registered_groups if g.name == name]
    if len(commands) + len(groups) != 1:
        return app
    one = copy.copy(app)  # the root callback and settings; the lists below are new ones
    one.registered_commands, one.registered_groups = commands, groups
    return one


def main() -> None:
    """Entry point of the ``rulkit`` console script.

    An exception no command turned into a message is a bug: one line on stderr and exit code
    70 (:mod:`rulkit.cli.errors`), the traceback only with ``RULKIT_DEBUG=1``.
    """
    import os
    import sys

    from rulkit.cli.errors import EXIT_INTERNAL

    try:
        _invoked_app(sys.argv[1:])()
    except SystemExit:
        raise
    except KeyboardInterrupt:
        sys.exit(130)
    except Exception as err:
        if os.environ.get("RULKIT_DEBUG"):
            raise
        from rulkit.tables import safe_text

        sys.stderr.write(
            f"rulkit: internal error (a bug; please report it with the command line): "
            f"{type(err).__name__}: {safe_text(err, 500)}; RULKIT_DEBUG=1 shows the traceback\n")
        sys.exit(EXIT_INTERNAL)
