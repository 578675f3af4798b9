"""The observed states a material calibration compares: frames of recordings -> LoadCases."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from softforce_cli.calibration.material import KnownLoad, LoadCase
from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.errors import CalibrationError
from softforce_cli.estimation.sensing import observed_robot_points
from softforce_cli.estimation.session import FrameRange
from softforce_cli.io.mcap_reader import iter_frames
from softforce_cli.model.robot import Robot
from softforce_cli.vision.settings import VisionSettings


def load_case(
    robot: Robot,
    robot_from_camera: RigidTransform,
    recording: Path,
    frames: str | None,
    load: KnownLoad | None,
    vision: VisionSettings,
) -> LoadCase:
    """A static state from the selected frames of a recording: their actuation (which must not
    change) and their pooled robot points."""
    try:
        selection = FrameRange.parse(frames)
    except ValueError as error:
        raise CalibrationError(str(error)) from error
    chosen = [frame for _, frame, _ in selection.select(iter_frames(recording))]
    if not chosen:
        raise CalibrationError(f"{recording}: no frame in {frames or 'the recording'}")
    actuations = [f.actuation.values for f in chosen if f.actuation is not None]
    if robot.cable_specs and not actuations:
        raise CalibrationError(f"{recording}: no /robot/actuation in the selected frames; the "
                               "cables' inputs are needed to model the state")
    actuation = np.asarray(actuations[0] if actuations else np.zeros(0), dtype=float)
    if any(not np.allclose(a, actuation) for a in actuations):
        raise CalibrationError(f"{recording}: the actuation changes within the selected frames; "
                               "select frames of one static state with --frames/"
                               "--reference-frames")
    return LoadCase(actuation, load,
                    observed_robot_points(chosen, robot_from_camera, robot, vision))
