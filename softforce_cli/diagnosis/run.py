"""`softforce diagnose` as a library call: check inputs, observe, diagnose, write outputs."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from softforce_cli.calibration.pose_covariance import calibration_pose_covariance
from softforce_cli.calibration.result import read_calibration
from softforce_cli.diagnosis.figures import save_residual_map, save_signature_plot
from softforce_cli.diagnosis.observations import DiagnosisError, observe_recordings
from softforce_cli.diagnosis.pipeline import Diagnosis, diagnose_observations
from softforce_cli.diagnosis.report import diagnosis_document, fitted_robot_toml
from softforce_cli.diagnosis.solves import SolveCache
from softforce_cli.estimation.session import FrameRange
from softforce_cli.estimation.settings import load_settings
from softforce_cli.io.atomic import (
    atomic_write_text,
    check_can_write,
    check_writable,
    writable_folder,
)
from softforce_cli.model.robot import load_robot, robot_with_effects

OUTPUTS = ("diagnosis.json", "robot.fitted.toml", "residual_map.png", "signature.png")
# A recording needs this many usable frames: two states with repeats at the least.
MIN_FRAMES = 4
Stage = Callable[[str, int, int | None], None]


def default_cache() -> Path:
    """$XDG_CACHE_HOME/softforce/diagnose (~/.cache/softforce/diagnose by default)."""
    root = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(root) / "softforce" / "diagnose"


@dataclass(frozen=True)
class DiagnoseInputs:
    """What `softforce diagnose` was given; cache None: solve everything afresh;
    settings_file: a sense settings file, whose [vision] thresholds the clouds are taken with."""

    recordings: tuple[Path, ...]
    robot: Path
    calibration: Path
    output: Path
    frames: str | None = None
    force: bool = False
    cache: Path | None = None
    settings_file: Path | None = None


def run_diagnosis(inputs: DiagnoseInputs, stage: Stage,
                  stop_requested: Callable[[], bool] = lambda: False) -> Diagnosis:
    """Everything: DiagnosisError (one line) on bad input; outputs written atomically. An
    interrupted run writes diagnosis.json marked `interrupted` with the stage it reached."""
    for name in OUTPUTS:
        check_writable(inputs.output / name, inputs.force)
    for path in inputs.recordings:
        if not Path(path).is_file():
            raise DiagnosisError(f"recording {path} not found; give an .mcap made by "
                                 "`softforce record` or `softforce simulate`")
    try:
        frame_range = FrameRange.parse(inputs.frames)
    except ValueError as error:
        raise DiagnosisError(str(error)) from error
    vision = load_settings(inputs.settings_file).vision
    # the diagnosis compares the robot file's nominal model with the recordings: effects the
    # file already carries (a robot.fitted.toml) are left out, and said so
    given = load_robot(inputs.robot)
    robot = robot_with_effects(given, ()) if given.effects else given
    calibration = read_calibration(inputs.calibration)
    if calibration.robot_name and calibration.robot_name != robot.name:
        raise DiagnosisError(f"{inputs.calibration} was made for robot "
                             f"{calibration.robot_name!r}, not {robot.name!r} ({inputs.robot});"
                             " calibrate this robot first")
    # a folder that cannot be written is found before the minutes of work, not after them
    check_can_write(inputs.output / "diagnosis.json")
    observations = observe_recordings(
        list(inputs.recordings), robot, calibration.robot_from_camera,
        (frame_range.start, frame_range.stop),
        progress=lambda done, total: stage("vision", done, total),
        stop_requested=stop_requested, vision=vision)
    if len(observations.frames) < MIN_FRAMES and not stop_requested():
        raise DiagnosisError(f"only {len(observations.frames)} usable frames in "
                             f"{', '.join(map(str, inputs.recordings))}; diagnosis needs "
                             f"{MIN_FRAMES} or more with varied actuation (loading, unloading, "
                             "holds)")
    if stop_requested():
        from softforce_cli.diagnosis.pipeline import Diagnosis as Partial

        diagnosis = Partial(robot, observations, interrupted=True, stage="observations")
    else:
        diagnosis = diagnose_observations(robot, observations, SolveCache(inputs.cache), stage,
                                          stop_requested,
                                          calibration_pose_covariance(calibration))
        if given.effects and diagnosis.verdict is not None:
            diagnosis.evidence["robot_file_effects_left_out"] = [e.label for e in given.effects]
    write_outputs(inputs, diagnosis, stage)
    return diagnosis


def write_outputs(inputs: DiagnoseInputs, diagnosis: Diagnosis, stage: Stage) -> None:
    """diagnosis.json always; the fitted robot and the figures once there is a verdict."""
    output = writable_folder(inputs.output)
    document = diagnosis_document(diagnosis, {
        "recordings": [str(p) for p in inputs.recordings], "robot": str(inputs.robot),
        "calibration": str(inputs.calibration), "frames": inputs.frames,
        "settings": None if inputs.settings_file is None else str(inputs.settings_file)})
    atomic_write_text(output / "diagnosis.json", json.dumps(document, indent=1) + "\n",
                      force=inputs.force)
    if diagnosis.verdict is None:
        return
    atomic_write_text(output / "robot.fitted.toml",
                      fitted_robot_toml(inputs.robot, diagnosis, output), force=inputs.force)
    stage("figures", 0, 2)
    save_residual_map(diagnosis, output / "residual_map.png", inputs.force)
    save_signature_plot(diagnosis, output / "signature.png", inputs.force)
    stage("figures", 2, 2)
