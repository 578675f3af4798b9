"""`softforce diagnose`: where the FE model and the recordings disagree, and which physics
the model leaves out."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from softforce_cli.cli.common import ForceOption, stderr, stdout
from softforce_cli.cli.interrupt import deferred_interrupt, signal_name


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
    cache: Annotated[Path | None, typer.Option(
        "--cache", help="Folder of cached FE solves (default ~/.cache/softforce/diagnose).",
        file_okay=False)] = None,
    no_cache: Annotated[bool, typer.Option(
        "--no-cache", help="Solve every state afresh and keep nothing.")] = False,
    settings_file: Annotated[Path | None, typer.Option(
        "--settings", help="TOML whose \\[vision] thresholds the point clouds are taken with, "
                           "as sense reads them (docs/vision.md).")] = None,
    force: ForceOption = False,
) -> None:
    """Locate the sim-vs-real mismatch, name the missing physics, fit it, show the gain."""
    from softforce_cli.diagnosis.run import DiagnoseInputs, default_cache, run_diagnosis

    folder = None if no_cache else (cache or default_cache())
    inputs = DiagnoseInputs(tuple(recordings), robot, calibration, output, frames, force, folder,
                            settings_file)
    columns = (TextColumn("{task.description:>14}"), BarColumn(), MofNCompleteColumn(),
               TimeElapsedColumn())
    # transient: a bad input found mid-run leaves its one line alone on stderr
    with deferred_interrupt() as stop, Progress(*columns, console=stderr,
                                                transient=True) as progress:
        tasks: dict[str, int] = {}

        def stage(name: str, done: int, total: int | None) -> None:
            if name not in tasks:
                tasks[name] = progress.add_task(name, total=total)
            progress.update(tasks[name], completed=done, total=total)

        diagnosis = run_diagnosis(inputs, stage, lambda: stop.requested)
    if diagnosis.interrupted:
        stderr.print(f"[yellow]interrupted ({signal_name()}) during {diagnosis.stage}:[/] "
                     f"what was done is in {escape(str(output))}/diagnosis.json "
                     '("interrupted": true)')
        raise typer.Exit(stop.exit_code)
    _summary(diagnosis)
    stderr.print(f"wrote {output}/ (diagnosis.json, robot.fitted.toml, residual_map.png, "
                 "signature.png)", markup=False)


def _summary(diagnosis) -> None:
    from softforce_cli.diagnosis.report import effect_entry, summary_lines

    floor = diagnosis.noise_floor_mm
    table = Table(title=f"verdict: [bold]{diagnosis.verdict}[/]   noise floor {floor:.2f} mm;"
                        " held-out residual RMS (mm)", title_justify="left")
    # names and values wrap (a parameter a line) rather than end in an ellipsis on a narrow
    # terminal or in a log
    for name in ("effect", "parameters"):
        table.add_column(name, overflow="fold")
    for name in ("before", "after"):
        table.add_column(name, justify="right", no_wrap=True)
    for name in ("mode", "accepted"):
        table.add_column(name, no_wrap=True)
    rows = list(diagnosis.selected) + [f for f in diagnosis.finals
                                       if f not in diagnosis.selected]
    rows += [s for s in diagnosis.screened[:6] if s.key not in {f.screened.key for f in rows}]
    for item in rows[:8]:
        entry = effect_entry(item, diagnosis.floor_for(item), item in diagnosis.selected,
                             diagnosis.with_mesh.get(item))
        shown = [f"{k}={v['value']:.3g}" for k, v in entry["parameters"].items()]
        values = "\n".join(shown[:2]) + (f"\n(+{len(shown) - 2})" if len(shown) > 2 else "")
        accepted = entry["evidence"]["accepted"]
        mode = "relative" if "relative" in entry["evidence"]["mode"] else "absolute"
        if entry["evidence"]["channel"] == "markers":
            mode += ", markers"
        # labels name their targets in brackets (cable_slack[north]): not rich markup
        table.add_row(escape(entry["label"]), escape(values),
                      f"{entry['heldout_rms_before_mm']:.3f}",
                      f"{entry['heldout_rms_after_mm']:.3f}", mode,
                      "screened" if accepted is None else ("yes" if accepted else "no"))
    stdout.print(table)
    where = diagnosis.location
    stdout.print(f"location: regions {', '.join(where['regions']) or '-'}; "
                 f"cables {', '.join(where['cables']) or '-'}")
    for line in summary_lines(diagnosis):
        stdout.print(line, markup=False)
