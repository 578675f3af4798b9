"""`softforce sense`: where external forces act on the robot and how hard, frame by frame."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape
from rich.table import Table

from softforce_cli.cli.common import ForceOption, stderr, stdout
from softforce_cli.cli.interrupt import deferred_interrupt, interrupted_exit_code, signal_name
from softforce_cli.errors import SensingError

FORCE_MODELS = ("axis", "normal", "cone", "3d")
# Below this rate with a full quadratic model, the end of a run points to its reduced model.
SLOW_FPS = 15.0


def sense(
    recording: Annotated[Path | None, typer.Argument(
        help="The recording (.mcap) to process; omit with --live.", dir_okay=False)] = None,
    robot: Annotated[Path, typer.Option("--robot", help="Robot model file (TOML).")] = ...,
    calibration: Annotated[Path, typer.Option(
        "--calibration", help="Calibration JSON from `softforce calibrate` (its material, "
        "when present, replaces the robot file's Young's modulus).")] = ...,
    output: Annotated[Path, typer.Option("-o", "--output", help="Output folder.")] = ...,
    live: Annotated[bool, typer.Option("--live", help="Sense from the connected RealSense "
                                       "until Ctrl-C.")] = False,
    frames: Annotated[str | None, typer.Option(
        "--frames", help="Process frames START:STOP (0-based, STOP excluded).")] = None,
    contact_point: Annotated[str | None, typer.Option(
        "--contact-point", help="X,Y,Z (mm, robot frame, robot at rest): a known contact; "
        "only its intensity is estimated (needs --direction).")] = None,
    direction: Annotated[str | None, typer.Option(
        "--direction", help="DX,DY,DZ: the known contact's force direction on the robot.")
    ] = None,
    settings_file: Annotated[Path | None, typer.Option(
        "--settings", help="TOML with \\[vision] and \\[estimation] thresholds (docs/sensing.md).")
    ] = None,
    force_model: Annotated[str | None, typer.Option(
        "--force-model", help="axis (default): one push per contact along the pushing "
        "object's axis (the normal where it has none); normal: along the inward normal (the "
        "paper); cone: within the friction cone around the normal; 3d: a free force vector "
        "per contact.")] = None,
    updates: Annotated[int | None, typer.Option(
        "--updates", help="FE updates per frame, at most (default 6; a frame stops "
        "updating once the model stops moving).")] = None,
    record: Annotated[Path | None, typer.Option(
        "--record", help="With --live: also keep every camera frame in this MCAP recording.",
        dir_okay=False)] = None,
    tare: Annotated[int | None, typer.Option(
        "--tare", help="Take the first N frames as free of external force and zero the "
        "observations on them (the cables' inputs should not change much after); 0: no "
        "zeroing. Default: the first 3 frames in which no contact is seen, none once one "
        "is; a recording that starts touched, on the first 3 frames it shows free (none "
        "with --contact-point).")] = None,
    robot_rgb: Annotated[str | None, typer.Option(
        "--robot-rgb", help="R,G,B of the robot (0-255); default: learned on the first frame.")
    ] = None,
    force: ForceOption = False,
) -> None:
    """Estimate contact locations and force intensities per frame (paper section V)."""
    from softforce_cli.estimation.setup import SenseInputs, prepare_sensing

    if live == (recording is not None):
        raise SensingError("give exactly one of a recording REC.mcap or --live")
    overrides = {}
    if force_model is not None:
        overrides["estimation.force_model"] = force_model
    if updates is not None:
        overrides["estimation.updates_per_frame"] = updates
    inputs = SenseInputs(
        recording=recording, robot=robot, calibration=calibration, output=output,
        frames=frames, contact_point=contact_point, direction=direction,
        settings_file=settings_file, overrides=overrides, robot_rgb=robot_rgb, record=record,
        tare_frames=tare,
        force=force,
    )
    with stderr.status("loading the robot and the first frame..."):
        prepared = prepare_sensing(inputs, live=live)
    # the interrupt is deferred outside the live source, so that a Ctrl-C ends the loop and
    # the source still drains and finishes the --record recording
    with deferred_interrupt() as stop, prepared.resources:
        summary = _run(prepared, lambda: stop.requested)
    _print_summary(summary)
    if summary.poor_fit_frames:
        from softforce_cli.estimation.summary import poor_fit_text

        stderr.print(f"[yellow]warning:[/] {poor_fit_text(summary.poor_fit_frames)} "
                     "(docs/sensing.md)", soft_wrap=True)
    if prepared.sensor.started_touched:
        tared = summary.skipped.get("tare", 0)
        zeroed = (f"the sensor zeroed itself on the first {tared} frame(s) it showed free, "
                  "and the frames before the first of them" if tared else
                  "it never shows the robot free, so nothing was zeroed, and its frames")
        stderr.print(f"note: the recording starts touched: {zeroed} read the model's rest "
                     "offset as force (--tare N zeroes on the first N frames; docs/sensing.md, "
                     "Zeroing)", soft_wrap=True)
    robot_config = prepared.sensor.robot.config
    if (robot_config.mesh.element != "p1" and robot_config.mesh.reduced is None
            and summary.frames_per_s < SLOW_FPS):
        stderr.print(f"[dim]tip: {summary.frames_per_s:.1f} fps with the full "
                     f"{robot_config.mesh.element} model; its reduced model senses at camera "
                     "rate (`softforce model reduce`, docs/reduced_model.md)[/]")
    where = f"{output}/ (contacts.csv, frames.csv, sense.json)"
    if summary.interrupted:
        stderr.print(f"[yellow]interrupted ({signal_name()}):[/] the {summary.frames} frames "
                     f"processed are in {escape(where)}")
        raise typer.Exit(stop.exit_code if stop.requested else interrupted_exit_code())
    stderr.print(f"wrote {where}", markup=False)


def _run(prepared, stop_requested):
    from rich.console import Group
    from rich.live import Live
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from softforce_cli.estimation.session import run_sensing

    columns = (TextColumn("sensing"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TextColumn("{task.fields[rate]}"))
    progress = Progress(*columns, console=stderr)
    task = progress.add_task("sensing", total=prepared.frame_count, rate="")
    # the progress bar and, under it, the contacts of the frame just sensed
    try:
        with Live(Group(progress, _contacts_table(())), console=stderr,
                  refresh_per_second=10) as live:

            def on_frame(estimate, summary) -> None:
                progress.update(task, completed=summary.frames,
                                rate=f"{summary.frames_per_s:.1f} fps")
                live.update(Group(progress, _contacts_table(estimate.contacts)))

            return run_sensing(prepared.frames, prepared.sensor, prepared.output,
                               prepared.header, force=prepared.force, on_frame=on_frame,
                               stop_requested=stop_requested)
    finally:
        if not stderr.is_interactive:
            # off a terminal Live ends its last render without a newline (rich's Progress
            # adds one itself): the next line would join the table's last
            stderr.line()


def _contacts_table(contacts) -> Table:
    """The contacts (estimation.results.ContactEstimate) of one frame, one row each."""
    table = Table(title="contacts in the latest frame", title_justify="left",
                  caption=None if contacts else "none")
    for name in ("contact", "feature", "x (mm)", "y (mm)", "z (mm)", "force (N)",
                 "residual (mm)"):
        table.add_column(name, justify="right")
    for c in contacts:
        table.add_row(str(c.contact), str(c.feature), *(f"{v:.1f}" for v in c.position_mm),
                      f"{c.force_n:.3f}", f"{c.residual_mm:.2f}")
    return table


def _print_summary(summary) -> None:
    data = summary.to_dict()
    table = Table(title="contacts", title_justify="left")
    for name in ("contact", "frames", "min (N)", "mean (N)", "max (N)"):
        table.add_column(name, justify="right")
    for c in data["contacts"]:
        table.add_row(str(c["contact"]), str(c["frames"]), f"{c['force_min_n']:.4f}",
                      f"{c['force_mean_n']:.4f}", f"{c['force_max_n']:.4f}")
    if data["contacts"]:
        stdout.print(table)
    # one line per thread: the vision of the next frame runs beside the model of this one
    medians = {k: v for k, v in data["median_stage_ms"].items() if v >= 0.05}
    from softforce_cli.vision.pipeline import OBSERVED_STAGES

    ahead = ("decode", *OBSERVED_STAGES)  # decoded and observed by the look-ahead's thread
    for title, names in (("vision (next frame)", ahead),
                         ("model (this frame)", [k for k in medians if k not in ahead])):
        parts = ", ".join(f"{k} {medians[k]:.1f}" for k in names if k in medians)
        stdout.print(f"median ms per frame, {title}: {parts}")
    skipped = ", ".join(f"{n} {reason}" for reason, n in data["skipped"].items()) or "none"
    fps, interval = data["frames_per_s"], data["median_interval_ms"]
    rate = "" if fps is None else f"{fps:.1f} fps"
    if interval:
        rate += f" ({1e3 / interval:.1f} fps median, {interval:.1f} ms between frames)"
    stdout.print(f"{data['frames']} frames, {data['ok']} ok, skipped: {skipped}; "
                 f"{len(data['contacts'])} contacts; {rate}")
