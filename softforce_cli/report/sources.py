"""Which robot and recording a report uses: those given on the command line, else those the
sense run names in sense.json (found again from where it was run)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from softforce_cli.camera.frame import robot_actuation
from softforce_cli.io.mcap_reader import iter_frames
from softforce_cli.model.config import CableSpec
from softforce_cli.report.loading import ReportError, SenseRun
from softforce_cli.report.paths import resolve_input, truth_path
from softforce_cli.report.truth import TruthReport, compare_run_with_truth


@dataclass(frozen=True)
class ReportSources:
    """Files given on the command line instead of those the run names (None: the run's)."""

    robot: Path | None = None
    recording: Path | None = None


def robot_path(run: SenseRun, sources: ReportSources) -> Path | None:
    """The robot file the run used (or --robot); None when sense.json names none; ReportError
    when the file it names is not found."""
    if sources.robot is not None:
        return Path(sources.robot)
    named = run.input_path("robot")
    if named is None:
        return None
    path = resolve_input(named, run.folder)
    if path is None:
        raise ReportError(f"the robot file {named} that {run.folder / 'sense.json'} names is not "
                          f"found (from here or above {run.folder}); pass --robot ROBOT.toml")
    return path


def recording_path(run: SenseRun, sources: ReportSources) -> Path | None:
    """The run's recording (or --recording), None when it is not found."""
    if sources.recording is not None:
        return Path(sources.recording)
    return resolve_input(run.input_path("recording"), run.folder)


def recorded_actuation(recording: Path | None, index: int,
                       cables: Sequence[CableSpec]) -> np.ndarray | None:
    """(a,) the /robot/actuation values of frame `index` of the recording (the last one sent
    before it, as sense holds them), in the order of the robot's `cables`; None without a
    recording or an actuation; RecordingError when they are another robot's."""
    if recording is None:
        return None
    values = None
    for number, frame in enumerate(iter_frames(recording)):
        if frame.actuation is not None:
            values = robot_actuation(frame.actuation, cables, f"{recording}, frame {number}")
        if number == index:
            break
    return values


def truth_file(run: SenseRun, sources: ReportSources) -> Path | None:
    """`<recording>.truth.json` beside the run's recording (or --recording), if it exists."""
    recording = recording_path(run, sources)
    if recording is None:
        return None
    path = truth_path(Path(recording))
    return path if path.is_file() else None


def sense_truth(run: SenseRun, sources: ReportSources) -> TruthReport | None:
    """The comparison with the recording's ground truth, when it has one."""
    path = truth_file(run, sources)
    return None if path is None else compare_run_with_truth(run, path)
