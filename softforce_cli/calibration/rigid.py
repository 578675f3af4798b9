"""Rigid transforms between matched point sets: Kabsch/Umeyama by SVD, proper rotation only.

Transforms are named target-from-source: `robot_from_camera` maps camera-frame points to the
robot frame, p_robot = R p_cam + T (docs/robot_model.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Points whose RMS distance from their best-fit line is below this fraction of their RMS
# spread are collinear: the rotation about that line is then not determined.
COLLINEAR_RATIO = 1e-3


@dataclass(frozen=True)
class RigidTransform:
    """p_target = rotation @ p_source + translation_mm.

    rotation       : (3, 3) float64 proper rotation (R^T R = I, det R = +1).
    translation_mm : (3,) float64.
    """

    rotation: np.ndarray
    translation_mm: np.ndarray

    def apply(self, points_mm: np.ndarray) -> np.ndarray:
        """(p, 3) source-frame points -> (p, 3) float64 target-frame points."""
        return np.asarray(points_mm, dtype=float) @ self.rotation.T + self.translation_mm

    def inverse(self) -> RigidTransform:
        rotation_t = self.rotation.T
        return RigidTransform(rotation_t, -rotation_t @ self.translation_mm)

    def as_matrix(self) -> np.ndarray:
        """(4, 4) float64 homogeneous matrix [R T; 0 1]."""
        matrix = np.eye(4)
        matrix[:3, :3] = self.rotation
        matrix[:3, 3] = self.translation_mm
        return matrix


def check_points(points_mm: np.ndarray, name: str = "points") -> np.ndarray:
    """Return `points_mm` as (p, 3) float64; ValueError naming the shape otherwise."""
    points = np.asarray(points_mm, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name}: expected an array of shape (p, 3), got shape {points.shape}")
    return points


def collinearity(points_mm: np.ndarray) -> float:
    """RMS distance of the points from their best-fit line over their RMS spread, in [0, 1].

    0 for collinear (or coincident) points; below COLLINEAR_RATIO a rigid fit is degenerate.
    """
    centred = check_points(points_mm) - np.mean(points_mm, axis=0)
    singular = np.linalg.svd(centred, compute_uv=False)
    spread = float(np.sqrt(np.sum(singular**2)))
    if spread == 0.0:
        return 0.0
    return float(np.sqrt(np.sum(singular[1:] ** 2))) / spread


def rotation_from_covariance(covariance: np.ndarray) -> np.ndarray:
    """The proper rotation R maximising trace(R^T covariance) (3, 3) -> (3, 3).

    The SVD's last singular direction is flipped when U V^T would be a reflection (Umeyama
    1991), so det R = +1 even for noisy or planar point sets.
    """
    U, _, Vt = np.linalg.svd(covariance)
    sign = np.sign(np.linalg.det(U @ Vt)) or 1.0
    return U @ np.diag([1.0, 1.0, sign]) @ Vt


def fit_rigid_transform(
    source_mm: np.ndarray, target_mm: np.ndarray, weights: np.ndarray | None = None
) -> RigidTransform:
    """Least-squares rigid transform target-from-source for matched points (p, 3) each.

    Minimises sum_i w_i |R s_i + T - t_i|^2 (Kabsch, with Umeyama's reflection fix and no
    scale). weights (p,) >= 0, default all 1. ValueError for fewer than 3 points with weight,
    or collinear ones (collinearity() < COLLINEAR_RATIO), whose rotation is undetermined.
    """
    source = check_points(source_mm, "source_mm")
    target = check_points(target_mm, "target_mm")
    if source.shape != target.shape:
        raise ValueError(f"source has {len(source)} points and target {len(target)}")
    w = np.ones(len(source)) if weights is None else np.asarray(weights, dtype=float)
    used = w > 0
    if used.sum() < 3:
        raise ValueError(f"a rigid transform needs 3 points, got {int(used.sum())}")
    if collinearity(source[used]) < COLLINEAR_RATIO or collinearity(target[used]) < COLLINEAR_RATIO:
        raise ValueError("the points are collinear: the rotation about their line is undetermined")
    w = w / w.sum()
    source_mean, target_mean = w @ source, w @ target
    covariance = (target - target_mean).T @ (w[:, None] * (source - source_mean))
    rotation = rotation_from_covariance(covariance)
    return RigidTransform(rotation, target_mean - rotation @ source_mean)


def rigid_motion_basis(points_mm: np.ndarray, centre: np.ndarray | None = None) -> np.ndarray:
    """(3k, 6) columns: the motions of points (k, 3) under small rotations about the x, y, z
    axes through `centre` (default: their centroid), then unit translations along x, y, z."""
    centre = points_mm.mean(axis=0) if centre is None else centre
    centred = points_mm - centre
    basis = np.zeros((3 * len(points_mm), 6))
    for axis in range(3):
        basis[:, axis] = np.cross(np.eye(3)[axis], centred).ravel()
        basis[axis::3, 3 + axis] = 1.0
    return basis


def rigid_motion_projector(points_mm: np.ndarray) -> np.ndarray:
    """(3k, 3k) orthogonal projector onto the complement of the small rigid motions of points
    (k, 3): P v removes from a stacked displacement v (3k,) its best-fitting w x (p - c) + t."""
    q, _ = np.linalg.qr(rigid_motion_basis(points_mm))
    return np.eye(len(q)) - q @ q.T


def rotation_angle_deg(rotation: np.ndarray) -> float:
    """Angle (degrees) of a rotation (3, 3); the error between two is angle(R_a^T R_b)."""
    axis = np.array([rotation[2, 1] - rotation[1, 2], rotation[0, 2] - rotation[2, 0],
                     rotation[1, 0] - rotation[0, 1]])
    # atan2 of sine and cosine keeps small angles exact, where arccos alone loses half the digits.
    return float(np.degrees(np.arctan2(0.5 * np.linalg.norm(axis),
                                       0.5 * (np.trace(rotation) - 1.0))))


def rotation_from_euler_deg(angles_deg: np.ndarray) -> np.ndarray:
    """(3, 3) rotation about fixed x, then y, then z by angles_deg (3,) (the robot file's
    convention for mesh rotations)."""
    ax, ay, az = np.radians(np.asarray(angles_deg, dtype=float))
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx
