"""Synthetic calibration data: known transforms, truth robots and observed markers.

Used by the tests, the accuracy study (scripts/calibration_study.py) and the benchmark. The
truth is generated on a chosen robot (the fine mesh with another material law, to avoid the
"inverse crime" of estimating with the model that made the data) and seen by a camera whose
pose is known.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from softforce_cli.calibration.rigid import RigidTransform, rotation_from_covariance
from softforce_cli.camera.frame import Markers
from softforce_cli.model.mesh import TetMesh
from softforce_cli.model.robot import Robot, build_robot
from softforce_cli.sim.camera_pose import look_at

# Table I of the paper (actual values, AV): R printed to 3 decimals, so re-orthonormalised by
# the nearest rotation; T in mm; the cable forces in N.
PAPER_ROTATION = np.array([[-0.147, 0.941, 0.305],
                           [-0.485, 0.200, -0.851],
                           [-0.862, -0.273, 0.427]])
PAPER_TRANSLATION_MM = np.array([-264.956, 263.885, 12.767])
PAPER_FORCES_N = np.array([1.2, 1.0, 1.0, 1.2])
# The paper's five-marker case uses the white dots of its Fig. 5: here the apex and elbows.
FIVE_MARKERS = ("apex", "elbow_north", "elbow_west", "elbow_south", "elbow_east")


def paper_transform() -> RigidTransform:
    """robot_from_camera of the paper's Table I (p_robot = R p_cam + T)."""
    return RigidTransform(rotation_from_covariance(PAPER_ROTATION), PAPER_TRANSLATION_MM.copy())


def overhead_transform(eye_mm=(40.0, -60.0, 580.0), target_mm=(0.0, 0.0, 60.0)
                       ) -> RigidTransform:
    """robot_from_camera of a camera at eye_mm (robot frame) looking at target_mm: by default
    about 580 mm above the Diamond and slightly off its axis (docs/virtual_camera.md)."""
    pose = look_at(np.asarray(eye_mm, float), np.asarray(target_mm, float))
    return RigidTransform(pose[:3, :3], pose[:3, 3])


def with_law(robot: Robot, law: str, mesh: TetMesh | None = None) -> Robot:
    """The robot with another material law, on another mesh if given (its markers, cables and
    supports from `robot`'s file are re-attached to that mesh)."""
    config = robot.config
    config = dataclasses.replace(config, material=dataclasses.replace(config.material, law=law))
    return build_robot(config, robot.mesh if mesh is None else mesh)


def with_controls(robot: Robot, controls: tuple[str, ...], lower: float = 0.0,
                  upper: float = 20.0) -> Robot:
    """The robot with each cable's control mode (and bounds) replaced."""
    config = robot.config
    cables = tuple(dataclasses.replace(c, control=mode, min=lower, max=upper)
                   for c, mode in zip(config.cables, controls, strict=True))
    return build_robot(dataclasses.replace(config, cables=cables), robot.mesh)


def observed_markers(robot: Robot, positions_mm: np.ndarray, robot_from_camera: RigidTransform,
                     ids: tuple[str, ...] | None = None, sigma_mm: float = 0.0,
                     rng: np.random.Generator | None = None) -> Markers:
    """The robot's markers at node positions (n, 3), in the camera frame, with isotropic
    Gaussian noise sigma_mm (rng required when > 0)."""
    ids = robot.marker_ids if ids is None else ids
    robot_mm = robot.marker_points.positions(positions_mm)
    chosen = np.array([robot.marker_ids.index(marker_id) for marker_id in ids])
    camera_mm = robot_from_camera.inverse().apply(robot_mm[chosen])
    if sigma_mm > 0:
        camera_mm = camera_mm + sigma_mm * rng.standard_normal(camera_mm.shape)
    return Markers(tuple(ids), camera_mm)
