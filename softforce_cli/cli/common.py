"""Options and output helpers shared by several commands."""

from __future__ import annotations

import contextlib
import json
import sys
from collections.abc import Callable, Iterable, Iterator
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table
from rich.text import Text

stderr = Console(stderr=True, highlight=False)
stdout = Console(highlight=False)

ForceOption = Annotated[bool, typer.Option("--force", help="Overwrite existing output files.")]
JsonOption = Annotated[
    bool, typer.Option("--json", help="Print one JSON document on standard output, nothing else.")
]


def print_json(document: Any) -> None:
    """The whole of standard output for --json."""
    sys.stdout.write(json.dumps(document, indent=2) + "\n")


def key_value_table(title: str, rows: Iterable[tuple[str, str]]) -> Table:
    """A table of (key, value) rows for the terminal, in plain text: a file's names and an
    effect's [target] are not rich markup. A long value (a path) wraps whole."""
    table = Table(title=Text(title), show_header=False, box=None, title_justify="left")
    table.add_column(style="bold")
    table.add_column(overflow="fold")
    for key, value in rows:
        table.add_row(Text(key), Text(value))
    return table


@contextlib.contextmanager
def progress_bar(label: str) -> Iterator[Callable[[int, int], None]]:
    """A rich progress bar on stderr; yields the (done, total) callback library code takes."""
    columns = (TextColumn(label), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=stderr) as progress:
        task = progress.add_task(label, total=None)

        def advance(done: int, total: int) -> None:
            progress.update(task, completed=done, total=total)

        yield advance
