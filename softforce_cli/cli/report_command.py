"""`softforce report`: what a sense or diagnose run found, for people to look at."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from softforce_cli.cli.common import ForceOption, progress_bar, stderr, stdout
from softforce_cli.cli.interrupt import deferred_interrupt, signal_name

FORMATS = ("html", "csv", "json")
FORMAT_HELP = ("html: the terminal summary, report.html and a PNG per figure (default); csv "
               "or json: one table (--table) re-exported, to -o FILE or standard output.")


def report(
    folder: Annotated[Path, typer.Argument(
        help="The -o folder of `softforce sense` or `softforce diagnose`.", file_okay=False)],
    format_: Annotated[str, typer.Option("--format", help=FORMAT_HELP)] = "html",
    table: Annotated[str | None, typer.Option(
        "--table", help="csv/json: contacts (default), frames, truth (located contacts against "
        "the ground truth) or effects (a diagnosis's fitted parameters).")] = None,
    columns: Annotated[str | None, typer.Option(
        "--columns", help="csv/json: the columns to keep, comma-separated, in that order.")
    ] = None,
    output: Annotated[Path | None, typer.Option(
        "-o", "--output", help="html: the folder for report.html and the PNGs (default "
        "FOLDER/report); csv/json: the file (default: standard output).")] = None,
    mcap: Annotated[Path | None, typer.Option(
        "--mcap", help="Also write the recording with the results (points, deformed surface, "
        "force arrows) as foxglove topics, to replay in Foxglove.", dir_okay=False)] = None,
    robot: Annotated[Path | None, typer.Option(
        "--robot", help="Robot file, instead of the one sense.json names.", dir_okay=False)
    ] = None,
    recording: Annotated[Path | None, typer.Option(
        "--recording", help="Recording, instead of the one sense.json names (its "
        "<name>.truth.json, when present, is compared).", dir_okay=False)] = None,
    calibration: Annotated[Path | None, typer.Option(
        "--calibration", help="Calibration, instead of the one sense.json names (--mcap).",
        dir_okay=False)] = None,
    force: ForceOption = False,
) -> None:
    """Summarise a sense or diagnose output: terminal summary, HTML page, PNGs, tables, MCAP."""
    # inputs are checked before the plotting libraries load: a mistake is reported at once
    from softforce_cli.report.loading import ReportError, load_run
    from softforce_cli.report.sources import ReportSources, robot_path, sense_truth

    if format_ not in FORMATS:
        raise ReportError(f"--format {format_!r}: use one of {', '.join(FORMATS)}")
    if format_ == "html" and (table or columns):
        raise ReportError("--table and --columns choose what --format csv or json exports; "
                          "add --format csv or --format json")
    run = load_run(folder)
    sources = ReportSources(robot=robot, recording=recording)
    if run.sense is not None and (format_ == "html" or mcap is not None):
        robot_path(run.sense, sources)  # a robot file named but missing: fail now
    if format_ == "html":
        from softforce_cli.io.atomic import check_writable
        from softforce_cli.report.paths import PAGE_NAME

        out_dir = output or folder / "report"
        check_writable(out_dir / PAGE_NAME, force)
        from softforce_cli.report.build import build_report

        with stderr.status("making the report...") as status:
            result = build_report(run, out_dir, sources, force=force,
                                  step=lambda text: status.update(f"{text}..."))
        _print_summary(run, result)
        stderr.print(f"wrote {result.page} and {len(result.pngs)} figures (PNG) beside it",
                     markup=False)
    else:
        truth = sense_truth(run.sense, sources) if run.sense is not None else None
        _export(run, truth, format_, table, columns, output, force)
    if mcap is not None:
        _write_mcap(run, sources, calibration, mcap, force)


def _print_summary(run, result) -> None:
    from softforce_cli.cli import report_terminal as terminal

    for note in result.notes:
        stderr.print(f"[yellow]note:[/] {escape(note)}", soft_wrap=True)
    if result.overview is not None:
        stdout.print(terminal.sense_summary(result.overview, result.truth))
    if run.diagnose is not None:
        stdout.print(terminal.diagnosis_summary(run.diagnose.diagnosis))


def _export(run, truth, format_: str, table: str | None, columns: str | None,
            output: Path | None, force: bool) -> None:
    import sys

    from softforce_cli.io.atomic import atomic_write_text
    from softforce_cli.report.export import available_tables, select_columns, table_text
    from softforce_cli.report.loading import ReportError

    tables = available_tables(run, truth)
    name = table or next(iter(tables))
    if name not in tables:
        raise ReportError(f"--table {name!r}: {run.folder} has the tables "
                          f"{', '.join(tables)}")
    chosen = [c.strip() for c in columns.split(",") if c.strip()] if columns else None
    text = table_text(select_columns(tables[name], name, chosen), format_)
    if output is None:
        sys.stdout.write(text)
        return
    atomic_write_text(output, text, force=force)
    stderr.print(f"wrote the {name} table to {output}", markup=False)


def _write_mcap(run, sources, calibration: Path | None, path: Path, force: bool) -> None:
    from softforce_cli.io.atomic import check_writable
    from softforce_cli.report.build import sense_robot
    from softforce_cli.report.loading import ReportError
    from softforce_cli.report.paths import resolve_input
    from softforce_cli.report.replay import ReplayInputs, write_replay

    sense = run.sense
    if sense is None:
        raise ReportError(f"--mcap replays a sense run; {run.folder} holds no sense output")
    check_writable(path, force)
    found = {}
    for key, given in (("recording", sources.recording), ("calibration", calibration)):
        found[key] = given or resolve_input(sense.input_path(key), sense.folder)
        if found[key] is None:
            raise ReportError(f"--mcap needs the run's {key}, which {sense.folder} does not name "
                              f"or which is not found ({sense.input_path(key)}); pass "
                              f"--{key} FILE")
    robot = sense_robot(sense, sources)
    if robot is None:
        raise ReportError("--mcap needs the run's robot; pass --robot ROBOT.toml")
    inputs = ReplayInputs(Path(found["recording"]), Path(found["calibration"]), robot)
    with deferred_interrupt() as stop, progress_bar("replay for Foxglove") as advance:
        result = write_replay(sense, inputs, path, force=force, progress=advance,
                              stop_requested=lambda: stop.requested)
    if result.interrupted:
        stderr.print(f"[yellow]interrupted ({signal_name()}):[/] {result.frames} frames are in "
                     f"{escape(str(result.path))}")
        raise typer.Exit(stop.exit_code)
    stderr.print(f"wrote {result.path} ({result.frames} frames with their results)",
                 markup=False)
