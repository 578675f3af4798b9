"""The `softforce` command: sub-command groups, and errors printed as one line."""

from __future__ import annotations

import os
import sys
import warnings

import typer
from rich.console import Console
from rich.markup import escape

from softforce_cli import __version__
from softforce_cli.cli.interrupt import install_signal_handlers, interrupted_exit_code
from softforce_cli.errors import SoftforceError
from softforce_cli.fem.allocator import keep_freed_memory

app = typer.Typer(
    name="softforce",
    help="An RGB-D camera and a finite element model as a force sensor for soft robots.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
stderr = Console(stderr=True)


def _register_commands() -> None:
    if app.registered_groups:  # main() may run more than once in a process (tests)
        return
    from softforce_cli.cli import (
        calibrate_command,
        diagnose_command,
        model_commands,
        record_commands,
        report_command,
        sense_command,
        simulate_command,
    )

    app.add_typer(model_commands.app, name="model")
    app.add_typer(record_commands.app, name="record")
    app.command("simulate")(simulate_command.simulate)
    app.command("calibrate")(calibrate_command.calibrate)
    app.command("sense")(sense_command.sense)
    app.command("diagnose")(diagnose_command.diagnose)
    app.command("report")(report_command.report)


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


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings (a damaged recording, skipped frames) as one yellow line on stderr each."""
    text = " ".join(str(message).split())
    stderr.print(f"[yellow]warning:[/] {escape(text)}", highlight=False, soft_wrap=True)


def main() -> None:
    """Entry point: run the app; a SoftforceError (or an OSError: the machine's, not the
    input's) becomes one red line and exit status 1.

    Usage errors are typer's (a usage line, exit status 2). Set SOFTFORCE_DEBUG=1 to see the
    traceback of such an error instead. SIGTERM stops a run like Ctrl-C (see interrupt.py)
    and the exit status is 128 + the signal: 130 for Ctrl-C, 143 for SIGTERM.
    """
    install_signal_handlers()
    # every command allocates and frees large arrays (FE tangents, snapshots, frames): glibc
    # returning each to the OS made `model reduce` spend 2.5 of its 13 minutes in the kernel
    keep_freed_memory()
    if not os.environ.get("SOFTFORCE_DEBUG"):
        warnings.showwarning = _show_warning
    try:
        _register_commands()
        app()
    except (SoftforceError, OSError) as error:
        # an OSError that no reader or writer turned into a SoftforceError (a disk that fills
        # up mid-run, a file vanishing under a reader) is the machine's, not a bug: one line too
        if os.environ.get("SOFTFORCE_DEBUG"):
            raise
        message = " ".join(str(error).split())  # one line, whatever the message holds
        stderr.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)
        sys.exit(1)
    except SystemExit as exit_:
        # typer turns a KeyboardInterrupt (hence SIGTERM's Terminated) into exit status 130.
        if exit_.code == 130:
            sys.exit(interrupted_exit_code())
        raise
    except KeyboardInterrupt:  # one that escaped typer (while importing commands)
        sys.exit(interrupted_exit_code())
