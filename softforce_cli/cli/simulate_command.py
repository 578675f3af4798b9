"""`softforce simulate`: a synthetic recording with known ground truth from a scenario."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from softforce_cli.cli.common import ForceOption, progress_bar, stderr


def simulate(
    scenario: Annotated[Path, typer.Argument(help="Scenario file (TOML, see docs/scenarios.md).")],
    output: Annotated[
        Path,
        typer.Option(
            "-o",
            "--output",
            help="Recording to write (.mcap); the ground truth goes beside it as .truth.json.",
        ),
    ],
    force: ForceOption = False,
) -> None:
    """Solve the scenario on its truth robot and film it with a virtual D415."""
    from softforce_cli.sim.simulate import prepare_simulation, run_simulation

    simulation = prepare_simulation(scenario, output, force=force)
    with progress_bar("simulating") as advance:
        result = run_simulation(simulation, progress=advance)
    note = " (interrupted: the frames done are kept)" if result.interrupted else ""
    stderr.print(
        f"wrote {result.frames} frames to [bold]{escape(str(result.recording))}[/] and the "
        f"ground truth to [bold]{escape(str(result.truth))}[/]{note}"
    )
    if result.interrupted:
        from softforce_cli.cli.interrupt import interrupted_exit_code

        raise typer.Exit(interrupted_exit_code())
