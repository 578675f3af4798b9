"""Rigid camera poses for the virtual camera: look-at construction, inversion, point transforms.

A pose is a (4, 4) float64 homogeneous matrix named target-from-source: `world_from_cam` maps
points from the camera's optical frame (x right, y down, z forward; docs/robot_model.md) into
the world frame, which for the simulator is the robot frame, in millimetres.
"""

from __future__ import annotations

import numpy as np

# docs/virtual_camera.md: the camera is about 0.58 m above the Diamond, looking down.
DIAMOND_CAMERA_HEIGHT_MM = 580.0


def check_pose(pose: np.ndarray) -> np.ndarray:
    """Return `pose` as a (4, 4) float64 array; ValueError if the shape is not (4, 4)."""
    pose = np.asarray(pose, dtype=float)
    if pose.shape != (4, 4):
        raise ValueError(f"expected a (4, 4) pose matrix, got shape {pose.shape}")
    return pose


def pose_from_rotation_translation(rotation: np.ndarray, translation_mm: np.ndarray) -> np.ndarray:
    """(3, 3) rotation and (3,) translation in mm -> (4, 4) float64 pose [R t; 0 1]."""
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = translation_mm
    return pose


def invert_pose(pose: np.ndarray) -> np.ndarray:
    """Inverse of a rigid pose: a_from_b (4, 4) -> b_from_a (4, 4) float64, via R^T."""
    pose = check_pose(pose)
    rotation_t = pose[:3, :3].T
    return pose_from_rotation_translation(rotation_t, -rotation_t @ pose[:3, 3])


def transform_points(pose: np.ndarray, points_mm: np.ndarray) -> np.ndarray:
    """Apply b_from_a (4, 4) to points (n, 3) in frame a -> (n, 3) float64 in frame b."""
    pose = check_pose(pose)
    points_mm = np.asarray(points_mm, dtype=float)
    if points_mm.ndim != 2 or points_mm.shape[1] != 3:
        raise ValueError(f"expected points of shape (n, 3), got shape {points_mm.shape}")
    return points_mm @ pose[:3, :3].T + pose[:3, 3]


def look_at(
    eye_mm: np.ndarray, target_mm: np.ndarray, up_hint: np.ndarray = (0.0, 1.0, 0.0)
) -> np.ndarray:
    """Pose of an optical-frame camera at `eye_mm` looking at `target_mm`.

    eye_mm, target_mm : (3,) world positions in mm.
    up_hint           : (3,) world direction that should point toward the top of the image;
                        only its part orthogonal to the viewing direction matters.

    Returns world_from_cam (4, 4) float64 whose columns are the camera axes in the world:
    z forward (eye -> target), y down in the image (opposite the projected `up_hint`) and
    x = y cross z to the right. Looking straight down (-z world) with up_hint +y, world +y
    is toward the image top and world +x to the right: a map-like top view.
    """
    eye = np.asarray(eye_mm, dtype=float)
    forward = np.asarray(target_mm, dtype=float) - eye
    distance = np.linalg.norm(forward)
    if distance == 0.0:
        raise ValueError("look_at: eye and target are the same point")
    forward /= distance
    up = np.asarray(up_hint, dtype=float)
    up_orthogonal = up - (up @ forward) * forward
    norm = np.linalg.norm(up_orthogonal)
    if norm < 1e-9 * max(np.linalg.norm(up), 1.0):
        raise ValueError("look_at: up_hint is parallel to the viewing direction; choose another")
    down = -up_orthogonal / norm
    right = np.cross(down, forward)
    return pose_from_rotation_translation(np.column_stack([right, down, forward]), eye)


def overhead_pose(
    height_mm: float = DIAMOND_CAMERA_HEIGHT_MM,
    target_mm: np.ndarray = (0.0, 0.0, 0.0),
    up_hint: np.ndarray = (0.0, 1.0, 0.0),
) -> np.ndarray:
    """world_from_cam (4, 4) of a camera `height_mm` straight above `target_mm`, looking down.

    The default is the Diamond set-up of docs/virtual_camera.md: 580 mm above the robot's base
    centre (the robot-frame origin), world +y toward the image top, world +x to the right.
    """
    target = np.asarray(target_mm, dtype=float)
    return look_at(target + np.array([0.0, 0.0, height_mm]), target, up_hint)
