"""`softforce diagnose` as a library call: check inputs, observe, diagnose, write outputs."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from softforce_cli.calibration.result import read_calibration
from softforce_cli.diagnosis.figures import save_residual_map, save_signature_plot
from softforce_cli.diagnosis.observations import DiagnosisError, observe_recordings
from softforce_cli.diagnosis.pipeline import Diagnosis, diagnose_observations
from softforce_cli.diagnosis.report import diagnosis_document, fitted_robot_toml
from softforce_cli.estimation.session import FrameRange
from softforce_cli.io.atomic import atomic_write_text, check_writable
from softforce_cli.model.robot import load_robot

OUTPUTS = ("diagnosis.json", "robot.fitted.toml", "residual_map.png", "signature.png")
Stage = Callable[[str, int, int | None], None]


@dataclass(frozen=True)
class DiagnoseInputs:
    recordings: tuple[Path, ...]
    robot: Path
    calibration: Path
    output: Path
    frames: str | None = None
    force: bool = False


def run_diagnosis(inputs: DiagnoseInputs, stage: Stage,
                  stop_requested: Callable[[], bool] = lambda: False) -> Diagnosis:
    """Everything: DiagnosisError (one line) on bad input; outputs written atomically."""
    for name in OUTPUTS:
        check_writable(inputs.output / name, inputs.force)
    for path in inputs.recordings:
        if not Path(path).is_file():
            raise DiagnosisError(f"recording {path} not found")
    try:
        frame_range = FrameRange.parse(inputs.frames)
    except ValueError as error:
        raise DiagnosisError(str(error)) from error
    robot = load_robot(inputs.robot)
    calibration = read_calibration(inputs.calibration)
    transform = calibration.robot_from_camera
    observations = observe_recordings(
        list(inputs.recordings), robot, transform, (frame_range.start, frame_range.stop),
        progress=lambda done, total: stage("vision", done, total), stop_requested=stop_requested)
    if len(observations.frames) < 4:
        raise DiagnosisError(f"only {len(observations.frames)} usable frames; diagnosis needs "
                             "recordings with varied actuation (loading, unloading, holds)")
    diagnosis = diagnose_observations(robot, observations, transform, stage)
    document = diagnosis_document(diagnosis, {
        "recordings": [str(p) for p in inputs.recordings], "robot": str(inputs.robot),
        "calibration": str(inputs.calibration), "frames": inputs.frames})
    output = inputs.output
    output.mkdir(parents=True, exist_ok=True)
    atomic_write_text(output / "diagnosis.json", json.dumps(document, indent=1),
                      force=inputs.force)
    atomic_write_text(output / "robot.fitted.toml",
                      fitted_robot_toml(inputs.robot, diagnosis, output), force=inputs.force)
    stage("figures", 0, 2)
    save_residual_map(robot, diagnosis, output / "residual_map.png", inputs.force)
    save_signature_plot(diagnosis, output / "signature.png", inputs.force)
    stage("figures", 2, 2)
    return diagnosis
