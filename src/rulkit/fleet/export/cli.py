"""``rulkit export c`` (docs/rul-on-the-device.md); registered by rulkit.cli.

Heavy imports stay inside the command.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Annotated

import typer


def register(app: typer.Typer, reproduce: typer.Typer) -> None:
    """Add the ``export`` group with its command ``c``."""
    export = typer.Typer(help="Export a component type's prognosis chain for a device.",
                         no_args_is_help=True)
    app.add_typer(export, name="export")

    @export.command("c")
    def export_c(
        out: Annotated[Path, typer.Option("--out", help="Directory for <prefix>.h and "
                                                        "<prefix>.c (created).")],
        db: Annotated[Path | None, typer.Option(
            "--db", help="Fleet database (rulkit track / rulkit fit): its HI model, tracker "
                         "settings and learned model.")] = None,
        config: Annotated[Path | None, typer.Option(
            "--config", help="TOML configuration instead of a database (see "
                             "docs/rul-on-the-device.md).")] = None,
        number: str = typer.Option("double", "--number", help="double, float or fixed."),
        prefix: str = typer.Option("rk", "--prefix", help="Prefix of every C symbol."),
        name: str | None = typer.Option(None, "--name", help="Component type label."),
        no_learned: bool = typer.Option(False, "--no-learned",
                                        help="Leave the learned model out."),
        no_ci: bool = typer.Option(False, "--no-ci",
                                   help="Leave the CI -> HI map out (the device gets the HI)."),
        rul_one_measurement: bool = typer.Option(
            False, "--rul-one-measurement",
            help="The learned RUL of one measurement (eq. (5), closed form: no table, fewer "
                 "operations) instead of the server's first measured crossing over the "
                 "unit's cadence (eq. (5b), the default); the device's RUL then differs from "
                 "rulkit status."),
    ) -> None:
        """Write C99 sources of one component type's prognosis chain (no heap, <math.h> and
        <stdint.h> only).

        Exit codes: 0 written; 1 the input cannot be exported (nothing written); 2 a bad
        option.
        """
        from rulkit.cli.errors import bad_option, fail
        from rulkit.fleet.export.device_spec import (
            ExportError,
            spec_from_database,
            spec_from_file,
        )
        from rulkit.fleet.export.generator import NUMBER_FORMATS, check_prefix, write_c
        from rulkit.machine_file import MachineFileError

        if (db is None) == (config is None):
            bad_option("--db", "give either --db or --config")
        if number not in NUMBER_FORMATS:
            bad_option("--number", f"expected one of {', '.join(NUMBER_FORMATS)}, got "
                                   f"{number!r}")
        try:
            check_prefix(prefix)
        except ExportError as err:
            bad_option("--prefix", str(err).split(": ", 1)[-1])
        try:
            device = spec_from_database(db, name) if db is not None else spec_from_file(
                config)  # type: ignore[arg-type]
            if name:
                device = replace(device, name=name)
            if no_learned:
                device = replace(device, learned=None)
            if no_ci:
                device = replace(device, hi_model=None)
            device = replace(device, one_measurement=rul_one_measurement)
            paths = write_c(device, out, number, prefix)
        except (ExportError, MachineFileError) as err:
            fail(f"{err} (nothing written)")
        parts = ["tracker chain"]
        if device.hi_model is not None:
            parts.insert(0, f"HI from {device.hi_model.n} CIs")
        if device.learned is not None:
            event = ("RUL of one measurement" if rul_one_measurement else
                     "RUL of the first measured crossing")
            parts.append(f"learned {device.learned.name} model ({event})")
        typer.echo(f"wrote {', '.join(str(p) for p in paths)}: {', '.join(parts)} "
                   f"({number}) of {device.name!r} from {device.source}")
