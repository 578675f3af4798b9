"""A sense run replayed frame by frame for Foxglove (`softforce report --mcap`).

For each recording frame up to the last one sensed: the vision stage again (robot and object
points, as sense segmented them: same settings, calibration and learned robot colour), the
robot's shape rebuilt from the frame's sensed loads (reconstruction.py, warm-started from the
previous frame's), and the contact forces as arrows. Written by io.replay_writer.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from softforce_cli.calibration.result import read_calibration
from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.camera.frame import robot_actuation
from softforce_cli.errors import SensingError, SolverError
from softforce_cli.estimation.sensing import learned_robot_colour
from softforce_cli.estimation.settings import SenseSettings, load_settings
from softforce_cli.io.mcap_reader import iter_frames
from softforce_cli.io.replay_writer import FrameResults, ReplayWriter
from softforce_cli.model.mesh import vertex_normals
from softforce_cli.model.robot import Robot
from softforce_cli.report.loading import ReportError, SenseRun
from softforce_cli.report.reconstruction import (
    RobotShape,
    frame_cable_inputs,
    rest_shape,
    sensed_shape,
)
from softforce_cli.report.scene import LONGEST_ARROW_MM
from softforce_cli.vision.pipeline import process_frame


@dataclass(frozen=True)
class ReplayInputs:
    """recording and calibration files of the run (found or given), and the robot."""

    recording: Path
    calibration: Path
    robot: Robot


@dataclass(frozen=True)
class ReplayResult:
    path: Path
    frames: int
    interrupted: bool = False


def write_replay(run: SenseRun, inputs: ReplayInputs, path: Path, force: bool = False,
                 progress: Callable[[int, int], None] = lambda done, total: None,
                 stop_requested: Callable[[], bool] = lambda: False) -> ReplayResult:
    """Write the replay MCAP; a stop request ends it after the current frame, keeping the
    frames written (a finished, indexed MCAP)."""
    transform = read_calibration(inputs.calibration).robot_from_camera
    settings = _settings(run)
    robot = inputs.robot
    sensed = {int(f): str(s) for f, s in zip(run.frames["frame"], run.frames["status"],
                                             strict=True)}
    if not sensed:
        raise ReportError(f"{run.folder}: no frame was sensed; nothing to replay")
    last = max(sensed)
    forces = run.contacts["force_n"]
    scale = LONGEST_ARROW_MM / forces.max() if len(forces) and forces.max() > 0 else 0.0
    shape = rest_shape(robot)
    colour = table = None
    warm = False  # whether `shape` is a sensed shape to start the next solve from
    written = 0
    with ReplayWriter(path, transform.rotation, transform.translation_mm, force=force,
                      metadata={"source": "softforce report --mcap",
                                "sense_folder": str(run.folder)}) as writer:
        for index, frame in enumerate(iter_frames(inputs.recording)):
            if index > last:
                break
            if colour is None:
                nodes = shape.positions_mm[: robot.mesh.node_count]
                colour = learned_robot_colour(frame, transform, nodes,
                                              robot.mesh.surface_nodes, settings.vision)
            actuation = None if frame.actuation is None else robot_actuation(
                frame.actuation, robot.cable_specs, f"{inputs.recording}, frame {index}")
            shape, warm = _frame_shape(run, robot, index, actuation, shape, warm)
            vision = _vision(frame, transform, robot, shape, colour, settings, table)
            table = vision.table_plane
            rows = run.contacts["frame"] == index
            points = np.column_stack([run.contacts[k][rows] for k in ("x_mm", "y_mm", "z_mm")])
            vectors = scale * np.column_stack([run.contacts[k][rows]
                                               for k in ("fx_n", "fy_n", "fz_n")])
            known = index in sensed
            writer.write_replay_frame(frame, FrameResults(
                vision.segmentation.robot.points_mm, vision.segmentation.objects.points_mm,
                shape.positions_mm if known else None, shape.surface_faces if known else None,
                points.reshape(-1, 3) - vectors.reshape(-1, 3), vectors.reshape(-1, 3)))
            written += 1
            progress(written, last + 1)
            if stop_requested():
                return ReplayResult(Path(path), written, interrupted=True)
    return ReplayResult(Path(path), written)


def _frame_shape(run: SenseRun, robot: Robot, index: int, actuation: np.ndarray | None,
                 previous: RobotShape, warm: bool) -> tuple[RobotShape, bool]:
    """The frame's sensed shape, or the previous one when the frame has no tensions (not
    sensed, or skipped) or its loads cannot be solved; and whether the shape is sensed."""
    tensions = run.cable_tensions.get(index)
    if tensions is None or not np.all(np.isfinite(tensions)) or \
            len(tensions) != len(robot.cable_specs):
        return previous, warm
    rows = run.contacts["frame"] == index
    points = np.column_stack([run.contacts[k][rows] for k in ("x_mm", "y_mm", "z_mm")])
    forces = np.column_stack([run.contacts[k][rows] for k in ("fx_n", "fy_n", "fz_n")])
    start = previous.positions_mm if warm else None
    try:
        inputs = frame_cable_inputs(robot, actuation, tensions)
        return sensed_shape(robot, inputs, points, forces, start_mm=start), True
    except SolverError:
        return previous, warm


def _vision(frame, transform: RigidTransform, robot: Robot, shape: RobotShape,
            colour: np.ndarray, settings: SenseSettings, table):
    nodes = shape.positions_mm[: robot.mesh.node_count]
    normals = vertex_normals(nodes, robot.mesh.surface_faces)
    clamped = robot.mesh.nodes_mm[robot.fixed_nodes]
    return process_frame(frame.depth_mm, frame.color, frame.intrinsics, transform,
                         np.array([nodes.min(axis=0), nodes.max(axis=0)]),
                         nodes[robot.feature_nodes], normals[robot.feature_nodes], colour,
                         settings.vision, np.r_[clamped.min(axis=0), clamped.max(axis=0)],
                         table)


def _settings(run: SenseRun) -> SenseSettings:
    """The settings the run used (sense.json), so the points are segmented as sense did."""
    saved = run.header.get("settings")
    if not isinstance(saved, dict):
        return SenseSettings()
    overrides = {f"{table}.{key}": value for table, values in saved.items()
                 if isinstance(values, dict) for key, value in values.items()}
    try:
        return load_settings(None, overrides)
    except (SensingError, KeyError) as error:
        raise ReportError(f"{run.folder / 'sense.json'}: its settings are not this softforce's "
                          f"({error})") from error
