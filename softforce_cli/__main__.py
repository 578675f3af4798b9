"""`python -m softforce_cli`: the same as the `softforce` command."""

from softforce_cli.cli.main import main

main()
