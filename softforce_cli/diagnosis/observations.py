"""Recordings -> the robot's observed points per frame, in the robot frame.

The vision stage of `sense` (softforce_cli.vision.pipeline) without its contact and force
parts: table removal, VoxelGrid, RadiusOutlier and colour segmentation keep the robot's points
X_r. Diagnosis needs recordings without unknown contact, so every robot point is evidence of
the robot's shape. Markers (topic /markers), where recorded, are kept in the robot frame.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.camera.frame import RgbdFrame, robot_actuation
from softforce_cli.errors import SoftforceError
from softforce_cli.estimation.sensing import learned_robot_colour
from softforce_cli.model.robot import Robot
from softforce_cli.vision.pipeline import process_frame
from softforce_cli.vision.settings import VisionSettings

# Points kept per frame after the VoxelGrid: a random subset this large still puts ~10 points
# on every visible surface node of the coarse Diamond, and bounds the residual work per frame.
MAX_POINTS_PER_FRAME = 6000
# A frame with fewer robot points than this shows too little of the robot to be evidence.
MIN_ROBOT_POINTS = 200

Progress = Callable[[int, int | None], None]


class DiagnosisError(SoftforceError):
    """Diagnosis cannot run on these inputs (no frames, no actuation variety, ...)."""


@dataclass(frozen=True, eq=False)
class FrameObservation:
    """What one frame shows of the robot.

    index       : frame index in its recording.
    recording   : index of the recording among those diagnosed.
    time_s      : seconds since the recording's first frame.
    actuation   : (a,) cable inputs (mm or N, the robot file's control).
    points_mm   : (p, 3) robot points, robot frame.
    depth_mm    : (p,) each point's depth along the camera's optical axis.
    markers_mm  : (k, 3) observed markers in the robot frame, NaN where not seen; k = the
                  robot's markers (empty (0, 3) when the recording has none).
    table_plane : (unit normal (3,), offset) of the table in the robot frame, or None.
    """

    index: int
    recording: int
    time_s: float
    actuation: np.ndarray
    points_mm: np.ndarray
    depth_mm: np.ndarray
    markers_mm: np.ndarray
    table_plane: tuple[np.ndarray, float] | None


@dataclass(frozen=True, eq=False)
class Observations:
    """The frames of every diagnosed recording, in order, and the camera pose used."""

    frames: tuple[FrameObservation, ...]
    robot_from_camera: RigidTransform
    recordings: tuple[str, ...]
    skipped: int

    @property
    def actuations(self) -> np.ndarray:
        """(t, a) cable inputs per frame."""
        return np.array([f.actuation for f in self.frames])

    @property
    def times_s(self) -> np.ndarray:
        """(t,) frame times; each recording continues after the previous one's end (+1 s), so
        that holds and loading directions never span two recordings."""
        return np.array([f.time_s for f in self.frames])


def observe_frame(frame: RgbdFrame, robot: Robot, robot_from_camera: RigidTransform,
                  robot_rgb: np.ndarray, rng: np.random.Generator,
                  settings: VisionSettings = VisionSettings()) -> tuple[np.ndarray, tuple | None]:
    """Robot points (p, 3) mm in the robot frame of one frame, and the table plane found.

    The crop box is the rest shape's bounds grown by the vision margin; the features passed to
    the vision stage only serve its matching step, which diagnosis does not use. The table is
    fitted in every frame (sensing reuses the first frame's plane, for speed): one frame's
    plane tilts by its noise, and diagnosis.background averages them.
    """
    nodes = robot.mesh.nodes_mm
    bounds = np.array([nodes.min(axis=0), nodes.max(axis=0)])
    features = robot.feature_nodes
    clamped = nodes[robot.fixed_nodes]
    result = process_frame(frame.depth_mm, frame.color, frame.intrinsics, robot_from_camera,
                           bounds, nodes[features], robot.feature_normals, robot_rgb, settings,
                           np.r_[clamped.min(axis=0), clamped.max(axis=0)])
    points = result.segmentation.robot.points_mm
    if len(points) > MAX_POINTS_PER_FRAME:
        points = points[np.sort(rng.choice(len(points), MAX_POINTS_PER_FRAME, replace=False))]
    return points, result.table_plane


def observe_recordings(
    paths: list[Path], robot: Robot, robot_from_camera: RigidTransform,
    frame_range: tuple[int, int | None] = (0, None), progress: Progress | None = None,
    stop_requested: Callable[[], bool] = lambda: False, seed: int = 0,
    vision: VisionSettings = VisionSettings(),
) -> Observations:
    """Every frame of `paths` in `frame_range` (start, stop) through the vision stage, with
    the thresholds `vision`.

    DiagnosisError when a frame's actuation does not fit the robot's cables, or when no
    frame shows the robot. Frames that show too little of the robot are skipped and counted.
    """
    from softforce_cli.io.mcap_reader import indexed_frame_count, iter_frames

    rng = np.random.default_rng(seed)
    camera_from_robot = robot_from_camera.inverse()
    totals = [indexed_frame_count(p) for p in paths]
    total = None if any(t is None for t in totals) else sum(
        _range_count(t, frame_range) for t in totals)
    frames: list[FrameObservation] = []
    skipped = 0
    offset_s = 0.0
    done = 0
    for number, path in enumerate(paths):
        robot_rgb = None
        first_ns = None
        last_s = 0.0
        for index, frame in _frames_in(iter_frames(Path(path)), frame_range):
            if stop_requested():
                break
            actuation = robot_actuation(frame.actuation, robot.cable_specs,
                                        f"{path}, frame {index}")
            if robot_rgb is None:
                robot_rgb = learned_robot_colour(frame, robot_from_camera, robot.mesh.nodes_mm,
                                                 robot.mesh.surface_nodes, vision)
            first_ns = frame.time_ns if first_ns is None else first_ns
            points, table = observe_frame(frame, robot, robot_from_camera, robot_rgb, rng,
                                          vision)
            done += 1
            if progress is not None:
                progress(done, total)
            if len(points) < MIN_ROBOT_POINTS or frame.actuation is None:
                skipped += 1
                continue
            last_s = (frame.time_ns - first_ns) * 1e-9
            depth = (camera_from_robot.apply(points))[:, 2]
            frames.append(FrameObservation(
                index=index, recording=number, time_s=offset_s + last_s,
                actuation=actuation,
                points_mm=points, depth_mm=depth,
                markers_mm=_markers(frame, robot, robot_from_camera), table_plane=table))
        offset_s += last_s + 1.0
    if not frames:
        raise DiagnosisError(f"no frame of {', '.join(map(str, paths))} shows the robot "
                             f"(at least {MIN_ROBOT_POINTS} robot points); check the "
                             "calibration and --frames")
    return Observations(tuple(frames), robot_from_camera, tuple(map(str, paths)), skipped)


def _range_count(count: int, frame_range: tuple[int, int | None]) -> int:
    start, stop = frame_range
    return max(0, min(count, count if stop is None else stop) - start)


def _frames_in(frames: Iterator[RgbdFrame],
               frame_range: tuple[int, int | None]) -> Iterator[tuple[int, RgbdFrame]]:
    start, stop = frame_range
    for index, frame in enumerate(frames):
        if stop is not None and index >= stop:
            return
        if index >= start:
            yield index, frame


def _markers(frame: RgbdFrame, robot: Robot, robot_from_camera: RigidTransform) -> np.ndarray:
    """(k, 3) the robot's markers as observed in this frame (robot frame), NaN if unseen."""
    observed = np.full((len(robot.marker_ids), 3), np.nan)
    if frame.markers is None or not len(robot.marker_ids):
        return observed if frame.markers is not None else np.zeros((0, 3))
    where = {marker_id: i for i, marker_id in enumerate(robot.marker_ids)}
    for marker_id, position in zip(frame.markers.ids, frame.markers.positions_mm, strict=True):
        if marker_id in where:
            observed[where[marker_id]] = robot_from_camera.apply(position[None])[0]
    return observed
