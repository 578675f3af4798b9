"""Every command's --help shows its text as written: TOML tables in brackets ([vision],
[[marker]]) are not taken for rich markup and dropped."""

from __future__ import annotations

import re

import click
import pytest
import typer.main
from typer.testing import CliRunner

from softforce_cli.cli import main

main._register_commands()
ROOT = typer.main.get_command(main.app)
# what rich would read as a markup tag: "[" and a letter, "#", "/" or "@" (rich.markup)
TAG_LIKE = re.compile(r"\[+[a-z#/@][^\[\]]*\]+")


def _commands(command: click.Command, path: tuple[str, ...] = ()):
    yield path, command
    for name, sub in getattr(command, "commands", {}).items():
        yield from _commands(sub, (*path, name))


def _meant(text: str) -> str:
    """The help text as its author meant it to read: escaped brackets unescaped."""
    return text.replace("\\[", "[")


COMMANDS = list(_commands(ROOT))


def test_the_commands_have_help_with_bracketed_tables():
    # the check below has something to check: these help texts name TOML tables
    bracketed = {tag for _, command in COMMANDS
                 for text in [command.help or "", *(getattr(p, "help", "") or ""
                                                    for p in command.params)]
                 for tag in TAG_LIKE.findall(_meant(text))}
    assert {"[vision]", "[estimation]", "[[marker]]", "[mesh]", "[min, max]"} <= bracketed


@pytest.mark.parametrize("path", [path for path, _ in COMMANDS], ids=" ".join)
def test_help_keeps_bracketed_words(path):
    command = dict(COMMANDS)[path]
    texts = [command.help or "", *(getattr(p, "help", "") or "" for p in command.params)]
    result = CliRunner().invoke(main.app, [*path, "--help"], env={"COLUMNS": "250"},
                                terminal_width=250)
    assert result.exit_code == 0, result.output
    shown = " ".join(result.output.split())
    for text in texts:
        for tag in TAG_LIKE.findall(_meant(text)):
            assert tag in shown, f"{' '.join(path)}: {tag!r} missing from its --help"
