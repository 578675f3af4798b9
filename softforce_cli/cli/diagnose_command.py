"""`softforce diagnose`: where the FE model and the recordings disagree, and which physics
the model leaves out."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from softforce_cli.cli.common import ForceOption, stderr, stdout
from softforce_cli.cli.interrupt import deferred_interrupt


def diagnose(
    recordings: Annotated[list[Path], typer.Argument(
        help="Recordings (.mcap) without unknown contact, with varied actuation.",
        dir_okay=False)],
    robot: Annotated[Path, typer.Option("--robot", help="Robot model file (TOML).")] = ...,
    calibration: Annotated[Path, typer.Option(
        "--calibration", help="Calibration JSON (the camera pose).")] = ...,
    output: Annotated[Path, typer.Option("-o", "--output", help="Output folder.")] = ...,
    frames: Annotated[str | None, typer.Option(
        "--frames", help="Use frames START:STOP of each recording.")] = None,
    force: ForceOption = False,
) -> None:
    """Locate the sim-vs-real mismatch, name the missing physics, fit it, show the gain."""
    from softforce_cli.diagnosis.run import DiagnoseInputs, run_diagnosis

    inputs = DiagnoseInputs(tuple(recordings), robot, calibration, output, frames, force)
    columns = (TextColumn("{task.description:>16}"), BarColumn(), MofNCompleteColumn(),
               TimeElapsedColumn())
    with deferred_interrupt() as stop, Progress(*columns, console=stderr) as progress:
        tasks: dict[str, int] = {}

        def stage(name: str, done: int, total: int | None) -> None:
            if name not in tasks:
                tasks[name] = progress.add_task(name, total=total)
            progress.update(tasks[name], completed=done, total=total)

        diagnosis = run_diagnosis(inputs, stage, lambda: stop.requested)
    _summary(diagnosis)
    stderr.print(f"wrote {output}/ (diagnosis.json, robot.fitted.toml, residual_map.png, "
                 "signature.png)")


def _summary(diagnosis) -> None:
    table = Table(title=f"verdict: {diagnosis.verdict}   noise floor "
                        f"{diagnosis.noise_floor_mm:.2f} mm", title_justify="left")
    for name in ("effect", "target", "parameters", "held-out before (mm)",
                 "held-out after (mm)", "accepted"):
        table.add_column(name)
    for c in diagnosis.ranked[:6]:
        h = c.fit.hypothesis
        values = ", ".join(f"{n}={v:.3g}" for n, v in zip(h.free, c.fit.values, strict=True))
        table.add_row(h.name, h.target or "", values, f"{c.heldout.rms_before_mm:.3f}",
                      f"{c.heldout.rms_after_mm:.3f}", "yes" if c.accepted else "no")
    stdout.print(table)
    where = diagnosis.location
    stdout.print(f"location: regions {', '.join(where['regions']) or '-'}; "
                 f"cables {', '.join(where['cables']) or '-'}")
