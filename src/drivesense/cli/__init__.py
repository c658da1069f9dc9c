"""The ``drivesense`` command line: a thin layer over the Python API.

Every command prints human-readable output (Rich tables), can write
machine-readable JSON with ``--json PATH``, and turns bad input into a one-line
message and exit code 2 (no traceback).  Commands live in one module per group.
"""

from __future__ import annotations

from typing import Annotated

import typer

from drivesense.cli import (archive, batch, core, detect, feedpower, identify_frf, identify_linear, identify_nc, learn,
                            monitor, mtconnect, plot_cmd, sensor, wear, xml_cmd)

__all__ = ["app", "identify_app", "main"]

# rich_markup_mode=None: help texts name units in brackets ("time [s]"), which Rich markup would swallow
app = typer.Typer(add_completion=False, no_args_is_help=True, rich_markup_mode=None,
                  help="drivesense: process force from a machine tool's own drive signals.")


def _package_version() -> str:
    """The installed package's version (pyproject.toml), else the source tree's ``drivesense.__version__``."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("drivesense")
    except PackageNotFoundError:
        from drivesense import __version__

        return __version__


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"drivesense {_package_version()}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[bool, typer.Option("--version", callback=_print_version, is_eager=True,
                                          help="Print the version (drivesense X.Y.Z) and exit.")] = False,
) -> None:
    """drivesense: process force from a machine tool's own drive signals."""


core.register(app)

identify_app = typer.Typer(no_args_is_help=True,
                           help="Identify axis parameters from measurements and write the parameter file.")
identify_frf.register(identify_app)
identify_linear.register(identify_app)
identify_nc.register(identify_app)
app.add_typer(identify_app, name="identify")
for module in (detect, monitor, batch, learn, wear, feedpower, sensor, xml_cmd, archive, mtconnect,
               plot_cmd):
    module.register(app)


def main() -> None:
    """Entry point of the ``drivesense`` script."""
    app()
