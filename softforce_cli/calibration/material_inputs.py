"""The frames a material calibration uses: a static state selected from a recording."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from softforce_cli.camera.frame import RgbdFrame, robot_actuation
from softforce_cli.errors import CalibrationError
from softforce_cli.estimation.session import FrameRange
from softforce_cli.io.mcap_reader import iter_frames
from softforce_cli.model.robot import Robot


def static_frames(recording: Path, frames: str | None, robot: Robot) -> list[RgbdFrame]:
    """The frames START:STOP of a recording (all by default), checked to hold one actuation
    of the robot's cables (their names in the robot file's order, their control modes)."""
    try:
        selection = FrameRange.parse(frames)
    except ValueError as error:
        raise CalibrationError(str(error)) from error
    chosen = [frame for _, frame, _ in selection.select(iter_frames(recording))]
    if not chosen:
        raise CalibrationError(f"{recording}: no frame in {frames or 'the recording'}")
    # a frame without its own message holds the last one; the first must have one
    actuations = [robot_actuation(f.actuation, robot.cable_specs, str(recording))
                  for k, f in enumerate(chosen) if k == 0 or f.actuation is not None]
    if any(not np.allclose(a, actuations[0]) for a in actuations):
        raise CalibrationError(f"{recording}: the actuation changes within the selected frames "
                               f"{frames or ''}; select the frames of one static state")
    return chosen
