"""`softforce calibrate`: camera-to-robot transform and actuator inputs from observed markers."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape
from rich.table import Table

from softforce_cli.cli.common import ForceOption, JsonOption, print_json, stderr, stdout
from softforce_cli.errors import CalibrationError

PLOT_SUFFIXES = (".png", ".pdf", ".svg")


def calibrate(
    robot: Annotated[Path, typer.Option("--robot", help="Robot model file (TOML) with its "
                                        "[\\[marker]] list.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Calibration to write (JSON).")],
    markers: Annotated[Path | None, typer.Option(
        "--markers", help="Observed markers, CSV `id,x_mm,y_mm,z_mm` in the camera frame.")
    ] = None,
    recording: Annotated[Path | None, typer.Option(
        "--recording", help="A recording (.mcap) with a /markers topic.")] = None,
    frame: Annotated[int | None, typer.Option(
        help="With --recording: use this frame (0-based), not the average of the longest "
             "static stretch.")] = None,
    robust: Annotated[bool, typer.Option(
        "--robust", help="Exclude an outlier marker (always reported) and recalibrate.")
    ] = False,
    plot: Annotated[Path | None, typer.Option(
        help="Also save the residual per iteration (the paper's Fig. 6), .png/.pdf/.svg.")
    ] = None,
    iterations: Annotated[int, typer.Option(
        "--iterations", help="I1: at most this many outer iterations (SVD + QP).")] = 40,
    inner: Annotated[int, typer.Option(
        "--inner", help="I2: at most this many FE updates after each QP.")] = 4,
    material: Annotated[bool, typer.Option(
        "--material", help="Fit Young's modulus from a recording with a known load (needs "
        "--calibration, --recording, --load-point, --load-n); writes CALIB + material.")
    ] = False,
    calibration: Annotated[Path | None, typer.Option(
        "--calibration", help="With --material: the pose calibration to extend.")] = None,
    reference: Annotated[Path | None, typer.Option(
        "--reference", help="With --material: a recording of the robot unloaded.")] = None,
    load_point: Annotated[str | None, typer.Option(
        "--load-point", help="With --material: X,Y,Z where the load acts (mm, robot at rest).")
    ] = None,
    load_n: Annotated[str | None, typer.Option(
        "--load-n", help="With --material: FX,FY,FZ the load's force on the robot (N).")] = None,
    frames: Annotated[str | None, typer.Option(
        "--frames", help="With --material: the loaded frames START:STOP of --recording.")] = None,
    reference_frames: Annotated[str | None, typer.Option(
        "--reference-frames", help="With --material: the unloaded frames START:STOP of "
        "--reference (or of --recording when --reference is not given).")] = None,
    settings: Annotated[Path | None, typer.Option(
        "--settings", help="With --material: the settings file `sense --settings` reads "
        "(docs/sensing.md); the fit senses the loaded frames with it.")] = None,
    json_output: JsonOption = False,
    force: ForceOption = False,
) -> None:
    """Calibrate the camera-to-robot transform and the cables' inputs (paper Algorithm 1), or
    with --material the robot's Young's modulus from a known load."""
    if material:
        from softforce_cli.cli.material_command import calibrate_material

        calibrate_material(robot, output, calibration, recording, reference, load_point, load_n,
                           frames, reference_frames, settings, json_output, force)
        return
    if settings is not None:
        raise CalibrationError("--settings is for --material (the markers' calibration has "
                               "no vision settings)")
    from softforce_cli.calibration.calibrate import CalibrationSettings
    from softforce_cli.calibration.result import result_to_dict, result_to_json
    from softforce_cli.calibration.robust import calibrate_checked
    from softforce_cli.io.atomic import atomic_write_text, check_writable
    from softforce_cli.model.robot import load_robot

    if (markers is None) == (recording is None):
        raise CalibrationError("give the observed markers with exactly one of --markers M.csv "
                               "or --recording REC.mcap")
    if frame is not None and recording is None:
        raise CalibrationError("--frame selects a frame of --recording; it has no meaning with "
                               "--markers")
    if plot is not None and plot.suffix.lower() not in PLOT_SUFFIXES:
        raise CalibrationError(f"--plot {plot}: use a {', '.join(PLOT_SUFFIXES)} file name")
    check_writable(output, force)
    if plot is not None:
        check_writable(plot, force)
    settings = CalibrationSettings(outer_iterations=iterations, inner_iterations=inner)
    model = load_robot(robot)
    observed, source = _observed(markers, recording, frame)
    with stderr.status("calibrating...") as status:
        def report(step) -> None:
            status.update(f"calibrating: iteration {step.iteration}, residual "
                          f"{step.residual_rms_mm:.4g} mm")

        result = calibrate_checked(model, observed, settings, exclude_outliers=robust,
                                   progress=report, source=source)
    atomic_write_text(output, result_to_json(result), force=force)
    if plot is not None:
        from softforce_cli.calibration.plot import save_residual_plot

        save_residual_plot({f"{sum(m.used for m in result.markers)} markers":
                            result.residual_history_mm}, plot, force=force)
    if json_output:
        print_json(result_to_dict(result))
    else:
        _print_tables(result)
    for warning in result.warnings:
        stderr.print(f"[yellow]warning:[/] {escape(warning)}", soft_wrap=True)
    written = f" and [bold]{escape(str(plot))}[/]" if plot is not None else ""
    stderr.print(f"wrote [bold]{escape(str(output))}[/]{written}")


def _observed(markers: Path | None, recording: Path | None, frame: int | None):
    if markers is not None:
        from softforce_cli.calibration.markers_csv import read_markers_csv

        return read_markers_csv(markers), str(markers)
    from softforce_cli.calibration.recording_markers import markers_from_recording

    with stderr.status(f"reading markers from {recording}..."):
        taken = markers_from_recording(recording, frame)
    return taken.markers, f"{recording} ({taken.description})"


def _print_tables(result) -> None:
    import numpy as np

    transform = result.robot_from_camera
    pose = Table(title="robot_from_camera: p_robot = R p_cam + T", title_justify="left")
    for name in ("R", "", "", "T (mm)"):
        pose.add_column(name, justify="right")
    for row, t in zip(transform.rotation, transform.translation_mm, strict=True):
        pose.add_row(*(f"{v:+.5f}" for v in row), f"{t:+.3f}")
    stdout.print(pose)
    if result.pose_covariance is not None:
        spread = np.sqrt(np.clip(np.diag(result.pose_covariance), 0.0, None))
        turns = ", ".join(f"{v:.2f}" for v in np.degrees(spread[:3]))
        moves = ", ".join(f"{v:.2f}" for v in spread[3:])
        stdout.print(f"pose uncertainty (one standard deviation, robot frame x, y, z): turns "
                     f"{turns} deg, moves {moves} mm")

    if result.cable_names:  # a passive body has no actuation to show
        cables = Table(title="actuation", title_justify="left")
        for name in ("cable", "control", "input", "tension (N)", "state"):
            cables.add_column(name, justify="left" if name in ("cable", "control", "state")
                              else "right")
        for i, name in enumerate(result.cable_names):
            unit = "mm" if result.cable_controls[i] == "displacement" else "N"
            shown = round(float(result.actuation[i]), 4) + 0.0  # no "-0.0000" at a bound
            cables.add_row(name, result.cable_controls[i], f"{shown:.4f} {unit}",
                           f"{result.tensions_n[i]:.4f}", "slack" if result.slack[i] else "taut")
        stdout.print(cables)

    table = Table(title="markers", title_justify="left")
    for name in ("marker", "residual (mm)", "left out (mm)", "used", "outlier"):
        table.add_column(name, justify="right" if "mm" in name else "left")
    for m in result.markers:
        left_out = "" if m.left_out_mm is None else f"{m.left_out_mm:.2f}"
        table.add_row(m.id, f"{m.distance_mm:.3f}", left_out, "yes" if m.used else "no",
                      "[red]OUTLIER[/]" if m.outlier else "")
    stdout.print(table)
    status = "converged" if result.converged else "[yellow]not converged[/]"
    unobserved = f"; not observed: {', '.join(result.unobserved)}" if result.unobserved else ""
    stdout.print(f"residual RMS [bold]{result.residual_rms_mm:.4f} mm[/] over "
                 f"{sum(m.used for m in result.markers)} markers, "
                 f"{len(result.residual_history_mm)} iterations ({status}), "
                 f"{result.elapsed_s:.2f} s{unobserved}")
