"""`softforce record`: RGB-D (+ actuation) from a RealSense, a RealSense .bag/.db3 file or a
ROS 2 bag of one into MCAP.

softforce record (--live | --from FILE.db3|.bag|.mcap) -o REC.mcap [--actuation ACT.csv] ...
softforce record info REC.mcap [--json]
"""

from __future__ import annotations

import enum
import json
import signal
import time
import warnings
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
from rich.table import Table

from softforce_cli.camera.actuation_timeline import read_actuation_csv, with_actuation
from softforce_cli.camera.live_source import record_live
from softforce_cli.camera.realsense import (
    PRESETS,
    CaptureProgress,
    StreamSettings,
    iter_file_frames,
    iter_live_frames,
)
from softforce_cli.cli.common import key_value_table
from softforce_cli.cli.interrupt import interrupted_exit_code, received_signal, signal_name
from softforce_cli.errors import RecordingError
from softforce_cli.io.atomic import check_writable
from softforce_cli.io.mcap_reader import RecordingSummary, read_summary
from softforce_cli.io.mcap_writer import write_recording
from softforce_cli.io.ros2_bag import is_ros2_bag, iter_bag_frames

app = typer.Typer(
    help="Record RGB-D frames and actuation inputs into an MCAP recording.",
    subcommand_metavar="[info RECORDING]",
    add_completion=False,
)
stderr = Console(stderr=True)
Preset = enum.Enum("Preset", {name: name for name in sorted(PRESETS)}, type=str)


@app.callback(invoke_without_command=True)
def record(
    ctx: typer.Context,
    live: Annotated[
        bool, typer.Option("--live", help="Record from the connected RealSense.")
    ] = False,
    from_file: Annotated[
        Path | None,
        typer.Option(
            "--from",
            help="Convert a RealSense recording (.bag or .db3) or a ROS 2 bag of one (its "
                 "folder, or its .db3 or .mcap file: realsense-ros with aligned depth).",
        ),
    ] = None,
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="The MCAP recording to write.")
    ] = None,
    actuation: Annotated[
        Path | None,
        typer.Option(help="CSV of actuator inputs over time (see docs/recordings.md)."),
    ] = None,
    width: Annotated[int | None, typer.Option(help="Live image width (default 640).")] = None,
    height: Annotated[int | None, typer.Option(help="Live image height (default 480).")] = None,
    fps: Annotated[int | None, typer.Option(help="Live frame rate (default 30).")] = None,
    preset: Annotated[Preset | None, typer.Option(help="Live depth visual preset.")] = None,
    duration: Annotated[
        float | None, typer.Option(help="Stop after this many seconds of frames.", min=0.0)
    ] = None,
    force: Annotated[
        bool, typer.Option("--force", help="Overwrite the output if it exists.")
    ] = False,
) -> None:
    """Record RGB-D frames (and actuation inputs) into an MCAP recording.

    Live recording runs until --duration or Ctrl-C; Ctrl-C keeps the frames recorded so far.
    """
    if ctx.invoked_subcommand is not None:
        return
    if live == (from_file is not None):
        raise typer.BadParameter(
            "choose one source: --live or --from FILE", ctx, param_hint="source"
        )
    if output is None:
        raise typer.BadParameter("required to record", ctx, param_hint="'-o' / '--output'")
    live_options = {"--width": width, "--height": height, "--fps": fps, "--preset": preset}
    if from_file is not None and any(v is not None for v in live_options.values()):
        given = ", ".join(name for name, value in live_options.items() if value is not None)
        raise typer.BadParameter("only for --live recording", ctx, param_hint=given)
    timeline = read_actuation_csv(actuation) if actuation is not None else None
    check_writable(output, force)
    metadata = {"source": "realsense live" if live else f"file {from_file.name}"}
    if actuation is not None:
        metadata["actuation_file"] = actuation.name

    display = _CaptureDisplay(live)
    if live:
        preset_name = preset.value if preset is not None else None
        settings = StreamSettings(width or 640, height or 480, fps or 30, preset_name)
        frames = iter_live_frames(settings, duration_s=duration, on_progress=display.update)
    else:
        read = iter_bag_frames if is_ros2_bag(from_file) else iter_file_frames
        frames = read(from_file, duration_s=duration, on_progress=display.update)
    if timeline is not None:
        frames = with_actuation(frames, timeline)
    with display:
        if live:  # written off the capture thread: no frame is dropped while zstd compresses
            result = record_live(
                frames, output, force=force, metadata=metadata, stop_on_interrupt=True
            )
        else:
            result = write_recording(
                frames, output, force=force, metadata=metadata, stop_on_interrupt=True
            )
    queue_dropped = result.stats.dropped if live else 0  # the writer's queue overflowed
    if result.frames == 0:
        if result.interrupted:
            raise KeyboardInterrupt
        source = "the RealSense" if live else str(from_file)
        raise RecordingError(f"no frame was recorded from {source}; {output} was not written")
    summary = _read_with_warnings(output)
    note = f" (stopped by {signal_name()})" if result.interrupted else ""
    # Ctrl-C is how a live recording ends; a file's conversion, or SIGTERM, cut a run short:
    # then the line goes to stderr with the run's other diagnostics and the status is non-zero.
    cut_short = result.interrupted and (not live or received_signal() == signal.SIGTERM)
    Console(soft_wrap=True, stderr=cut_short).print(
        f"wrote {output}: {summary.frame_count} frames, {summary.duration_s:.2f} s, "
        f"{summary.intrinsics.width}x{summary.intrinsics.height}, "
        f"{display.dropped + queue_dropped} dropped{note}",
        highlight=False,
    )
    if cut_short:
        raise typer.Exit(interrupted_exit_code())


@app.command("info")
def info(
    recording: Annotated[Path, typer.Argument(help="An MCAP recording.")],
    json_output: Annotated[
        bool, typer.Option("--json", help="Print one JSON document on stdout.")
    ] = False,
) -> None:
    """Show a recording's topics, frames, duration, resolution and intrinsics."""
    summary = _read_with_warnings(recording)
    if json_output:
        typer.echo(json.dumps(summary.to_dict(), indent=2))
    else:
        Console().print(_summary_table(summary))


def _read_with_warnings(path: Path) -> RecordingSummary:
    """read_summary, with its warnings as one yellow line each on stderr."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            return read_summary(path)
        finally:  # also before an error: what was lost explains it
            for warning in caught:
                stderr.print(
                    f"[yellow]warning:[/] {escape(str(warning.message))}",
                    highlight=False,
                    soft_wrap=True,
                )


def _summary_table(summary: RecordingSummary) -> Table:
    k = summary.intrinsics
    rate = summary.frame_rate_hz
    rows = [
        ("frames", str(summary.frame_count)),
        ("duration", f"{summary.duration_s:.3f} s" + (f" ({rate:.2f} fps)" if rate else "")),
        ("resolution", f"{k.width}x{k.height}"),
        ("intrinsics", f"fx {k.fx:.3f}  fy {k.fy:.3f}  cx {k.cx:.3f}  cy {k.cy:.3f}"),
    ]
    if k.distortion is not None:
        values = " ".join(f"{c:.6g}" for c in k.distortion.coefficients)
        rows.append(("lens", f"{k.distortion.model} {values} (rectified when read)"))
    if summary.actuation_names is not None:
        unit = "mm" if summary.actuation_control == "displacement" else "N"
        names = ", ".join(summary.actuation_names)
        rows.append(("actuation", f"{names} ({summary.actuation_control}, {unit})"))
    if summary.marker_ids is not None:
        rows.append(("markers", ", ".join(summary.marker_ids)))
    rows += [(f"metadata {name}", ", ".join(f"{k}={v}" for k, v in values.items()))
             for name, values in summary.metadata.items()]
    rows += [("topic", f"{topic.topic}  {topic.schema or topic.message_encoding}  "
                       f"{topic.message_count} messages") for topic in summary.topics]
    if not summary.indexed:
        rows.append(("index", "missing: the file was scanned (was the recording cut short?)"))
    return key_value_table(str(summary.path), rows)


class _CaptureDisplay:
    """A progress line on stderr: frames, frame rate, dropped frames, and for files a bar."""

    def __init__(self, live: bool) -> None:
        columns = [SpinnerColumn(), TextColumn("{task.description}")]
        if not live:
            columns.append(BarColumn())
        columns += [
            TextColumn("{task.fields[frames]} frames  {task.fields[rate]:.1f} fps"),
            TextColumn("{task.fields[dropped]} dropped"),
            TimeElapsedColumn(),
        ]
        self.progress = Progress(*columns, console=stderr, transient=False)
        self.task = self.progress.add_task(
            "recording" if live else "converting", total=None, frames=0, rate=0.0, dropped=0
        )
        self.dropped = 0
        self._start = time.monotonic()

    def __enter__(self) -> _CaptureDisplay:
        self.progress.start()
        self._start = time.monotonic()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.progress.stop()

    def update(self, progress: CaptureProgress) -> None:
        self.dropped = progress.dropped
        wall_s = max(time.monotonic() - self._start, 1e-9)
        fields = {"frames": progress.frames, "rate": progress.frames / wall_s}
        if progress.total_s:
            fields.update(
                total=progress.total_s, completed=min(progress.elapsed_s, progress.total_s)
            )
        self.progress.update(self.task, dropped=progress.dropped, **fields)
