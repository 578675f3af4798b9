"""The `softforce` command: sub-command groups, and errors printed as one line."""

from __future__ import annotations

import os
import sys

import typer
from rich.console import Console
from rich.markup import escape

from softforce_cli import __version__
from softforce_cli.errors import SoftforceError

app = typer.Typer(
    name="softforce",
    help="An RGB-D camera and a finite element model as a force sensor for soft robots.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
stderr = Console(stderr=True)


def _register_commands() -> None:
    from softforce_cli.cli import (
        calibrate_command,
        model_commands,
        record_commands,
        simulate_command,
    )

    app.add_typer(model_commands.app, name="model")
    app.add_typer(record_commands.app, name="record")
    app.command("simulate")(simulate_command.simulate)
    app.command("calibrate")(calibrate_command.calibrate)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"softforce {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """An RGB-D camera and a finite element model as a force sensor for soft robots."""


def main() -> None:
    """Entry point: run the app; a SoftforceError becomes one red line and exit status 1.

    Usage errors are typer's (a usage line, exit status 2). Set SOFTFORCE_DEBUG=1 to see the
    traceback of a SoftforceError instead.
    """
    _register_commands()
    try:
        app()
    except SoftforceError as error:
        if os.environ.get("SOFTFORCE_DEBUG"):
            raise
        stderr.print(f"[bold red]error:[/] {escape(str(error))}", highlight=False, soft_wrap=True)
        sys.exit(1)
