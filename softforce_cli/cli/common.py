"""Options and output helpers shared by several commands."""

from __future__ import annotations

import json
import sys
from typing import Annotated, Any

import typer
from rich.console import Console

stderr = Console(stderr=True, highlight=False)
stdout = Console(highlight=False)

ForceOption = Annotated[
    bool, typer.Option("--force", help="Overwrite existing output files.")
]
JsonOption = Annotated[
    bool, typer.Option("--json", help="Print one JSON document on standard output, nothing else.")
]


def print_json(document: Any) -> None:
    """The whole of standard output for --json."""
    sys.stdout.write(json.dumps(document, indent=2) + "\n")
