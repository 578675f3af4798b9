"""Everything `softforce sense` checks and loads before the first frame is processed."""

from __future__ import annotations

import contextlib
import itertools
import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from softforce_cli import __version__
from softforce_cli.calibration.material import read_material, robot_with_material
from softforce_cli.calibration.result import read_calibration
from softforce_cli.camera.frame import robot_actuation
from softforce_cli.camera.intrinsics import CameraIntrinsics
from softforce_cli.errors import SensingError
from softforce_cli.estimation.sensing import ForceSensor, KnownContact
from softforce_cli.estimation.session import FrameRange
from softforce_cli.estimation.settings import load_settings
from softforce_cli.io.sense_files import check_output_folder
from softforce_cli.model.robot import load_robot
from softforce_cli.option_values import parse_numbers
from softforce_cli.vision.pipeline import robot_distance_mm
from softforce_cli.vision.settings import VisionSettings, settings_for_frame


class LockingWarning(UserWarning):
    """Sensing with linear tetrahedra and no material calibration: forces read low."""


@dataclass(frozen=True)
class SenseInputs:
    """The command line's inputs, as given (text for vectors, checked by prepare_sensing)."""

    recording: Path | None
    robot: Path
    calibration: Path
    output: Path
    frames: str | None = None
    contact_point: str | None = None
    direction: str | None = None
    settings_file: Path | None = None
    overrides: dict[str, Any] = field(default_factory=dict)
    robot_rgb: str | None = None
    record: Path | None = None
    tare_frames: int | None = None
    force: bool = False


@dataclass
class PreparedSensing:
    sensor: ForceSensor
    frames: Any
    header: dict[str, Any]
    output: Path
    force: bool
    frame_count: int | None
    resources: contextlib.ExitStack = field(default_factory=contextlib.ExitStack)


def parse_vector(text: str, option: str, count: int = 3) -> np.ndarray:
    """"1,2,3" -> array; SensingError naming the option otherwise."""
    values = parse_numbers(text)
    if values is None or values.shape != (count,):
        raise SensingError(f"{option} {text!r}: give {count} comma-separated numbers")
    return values


def _camera_entry(intrinsics: CameraIntrinsics, vision: VisionSettings,
                  sensor: ForceSensor) -> dict[str, Any]:
    """sense.json's "camera": the first frame's image and the vision thresholds the pipeline
    takes for it (vision.settings.settings_for_frame, at the robot's distance at rest)."""
    distance_mm = robot_distance_mm(sensor.crop_bounds_mm, sensor.transform)
    used = settings_for_frame(vision, intrinsics.fx, distance_mm)
    return {"width": intrinsics.width, "height": intrinsics.height, "fx": intrinsics.fx,
            "robot_distance_mm": round(distance_mm, 1), "decimation": used.decimation,
            "outlier_min_neighbours": used.outlier_min_neighbours,
            "contact_min_neighbours": used.contact_min_neighbours}


def prepare_sensing(inputs: SenseInputs, live: bool = False) -> PreparedSensing:
    """Check every input (robot, calibration, recording, outputs) and build the sensor."""
    check_output_folder(inputs.output, inputs.force)
    settings = load_settings(inputs.settings_file, inputs.overrides)
    try:
        frame_range = FrameRange.parse(inputs.frames)
    except ValueError as error:
        raise SensingError(str(error)) from error
    known = _known_contact(inputs)
    robot = load_robot(inputs.robot)
    calibration = read_calibration(inputs.calibration)
    if calibration.robot_name and calibration.robot_name != robot.name:
        raise SensingError(f"{inputs.calibration} was made for robot {calibration.robot_name!r}, "
                           f"not {robot.name!r} ({inputs.robot}); calibrate this robot first")
    if len(calibration.actuation) not in (0, len(robot.cable_specs)):
        raise SensingError(f"{inputs.calibration} has {len(calibration.actuation)} cable inputs, "
                           f"the robot {len(robot.cable_specs)} cables; calibrate this robot")
    material = read_material(inputs.calibration)
    if material is not None:
        robot = robot_with_material(robot, material)
    rgb = None if inputs.robot_rgb is None else parse_vector(inputs.robot_rgb, "--robot-rgb")
    if rgb is not None and not np.all((rgb >= 0) & (rgb <= 255)):
        raise SensingError(f"--robot-rgb {inputs.robot_rgb!r}: each of R, G, B is 0-255")
    resources = contextlib.ExitStack()
    try:
        frames, count, source = _frame_source(inputs, live, resources)
        first = next(frames, None)
        if first is None:
            raise SensingError(f"{source}: no frame to process (check --frames)")
        # the FE model starts from the recording's own first inputs; the calibration's
        # describe the robot when it was calibrated (and a pose-only calibration has none);
        # live frames carry no actuation: the calibrated inputs are held
        start = (calibration.actuation if live and len(calibration.actuation)
                 else robot_actuation(first[1].actuation, robot.cable_specs, source))
    except BaseException:
        resources.close()
        raise
    if inputs.tare_frames is not None and inputs.tare_frames < 0:
        raise SensingError("--tare must be a number of frames >= 0")
    sensor = ForceSensor(robot, calibration.robot_from_camera, start, settings, known, rgb,
                         inputs.tare_frames)
    header = {
        "format": "softforce.sense",
        "version": 1,
        "softforce_version": __version__,
        "recording": source,
        "robot": {"name": robot.name, "file": str(inputs.robot),
                  "element": robot.element_name,
                  "young_modulus_mpa": robot.material.young_modulus_mpa},
        "calibration": {"file": str(inputs.calibration),
                        "residual_rms_mm": None if np.isnan(calibration.residual_rms_mm)
                        else calibration.residual_rms_mm,
                        "material": material},
        "settings": settings.to_dict(),
        "camera": _camera_entry(first[1].intrinsics, settings.vision, sensor),
        "known_contact": None if known is None else {
            "rest_point_mm": known.rest_point_mm.tolist(),
            "direction": known.direction.tolist()},
        "features": len(robot.feature_nodes),
        "tare_frames": "auto" if sensor.auto_tare else sensor.tare_left,
    }
    json.dumps(header)  # fail here, not mid-run, on a value JSON cannot hold
    remaining = None if count is None else max(
        0, min(count, frame_range.stop or count) - frame_range.start)
    if material is None and robot.element_name == "p1":
        # after every check, so that a bad input stays one line: a coarse P1 body is several
        # times too stiff where it bends (docs/locking.md), and which way its forces go wrong
        # depends on the recording (docs/sensing.md)
        warnings.warn(LockingWarning(
            f"{inputs.robot} uses linear tetrahedra (element p1), which lock on a coarse mesh "
            "and misread forces (on the Diamond: zero for the sample probes, 2-4 times too "
            "high on make bench's; docs/locking.md); sense with [mesh] element = \"p2\" or "
            "fit E for it with `softforce calibrate --material`"), stacklevel=2)
    return PreparedSensing(sensor, itertools.chain([first], frames), header, inputs.output,
                           inputs.force, remaining, resources)


def _known_contact(inputs: SenseInputs) -> KnownContact | None:
    if (inputs.contact_point is None) != (inputs.direction is None):
        raise SensingError("--contact-point and --direction go together: give both or neither")
    if inputs.contact_point is None:
        return None
    direction = parse_vector(inputs.direction, "--direction")
    if np.linalg.norm(direction) == 0:
        raise SensingError("--direction is zero; give the force's direction on the robot")
    return KnownContact(parse_vector(inputs.contact_point, "--contact-point"),
                        direction / np.linalg.norm(direction))


def _frame_source(inputs: SenseInputs, live: bool, resources: contextlib.ExitStack):
    """(frames (index, frame, decode_ms), frame count or None, a name for messages)."""
    frame_range = FrameRange.parse(inputs.frames)
    if live:
        from softforce_cli.camera.live_source import LiveSource
        from softforce_cli.camera.realsense import StreamSettings, iter_live_frames

        # capture (and --record) run on their own threads; sensing takes the newest frame
        source = resources.enter_context(LiveSource(
            iter_live_frames(StreamSettings()), record_to=inputs.record, force=inputs.force,
            metadata={"source": "softforce sense --live"}))
        return frame_range.select(source.latest()), None, "live RealSense"
    if inputs.record is not None:
        raise SensingError("--record keeps the frames of --live; a recording is already kept")
    from softforce_cli.io.mcap_reader import indexed_frame_count, iter_frames

    path = Path(inputs.recording)
    return frame_range.select(iter_frames(path)), indexed_frame_count(path), str(path)
