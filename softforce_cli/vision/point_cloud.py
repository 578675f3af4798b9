"""Coloured point clouds in the robot frame, and their construction from an RGB-D frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.camera.intrinsics import CameraIntrinsics


@dataclass(frozen=True, eq=False)
class PointCloud:
    """Points with colours.

    points_mm : (n, 3) float64, robot frame.
    colors    : (n, 3) uint8 RGB.
    """

    points_mm: np.ndarray
    colors: np.ndarray

    def __post_init__(self) -> None:
        points = np.asarray(self.points_mm, dtype=float).reshape(-1, 3)
        colors = np.asarray(self.colors, dtype=np.uint8).reshape(-1, 3)
        if len(points) != len(colors):
            raise ValueError(f"{len(points)} points but {len(colors)} colours")
        object.__setattr__(self, "points_mm", points)
        object.__setattr__(self, "colors", colors)

    def __len__(self) -> int:
        return len(self.points_mm)

    def subset(self, selection: np.ndarray) -> PointCloud:
        """The points picked by a (n,) bool mask or an index array, in that order."""
        return PointCloud(self.points_mm[selection], self.colors[selection])

    @classmethod
    def empty(cls) -> PointCloud:
        return cls(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.uint8))


def cloud_from_frame(
    depth_mm: np.ndarray,
    color: np.ndarray,
    intrinsics: CameraIntrinsics,
    robot_from_camera: RigidTransform,
    box_mm: np.ndarray | None = None,
    *,
    above_plane: tuple[np.ndarray, float, float] | None = None,
    stride: int = 1,
) -> PointCloud:
    """Back-project the pixels with depth and move them to the robot frame.

    depth_mm (h, w) uint16 (0 = no data), color (h, w, 3) uint8 aligned to it -> PointCloud of
    the valid pixels in row-major order, p_robot = R p_cam + T: the points of
    softforce_cli.camera.intrinsics.points_from_depth, without building its full pixel grid.

    box_mm (6,) [xmin ymin zmin xmax ymax zmax], optional: keep only the points inside (the
    PassThrough filter). Only the pixels inside the box's image are back-projected then,
    about a fifth of a 640x480 frame for the Diamond at 0.58 m.
    above_plane (unit normal (3,), offset, clearance_mm), optional: keep only the points with
    normal . p + offset > clearance_mm (filters.remove_table), tested on the depth alone
    before the points are built: the table is most of the box's pixels.
    stride: every stride-th pixel row and column only (a cheap sample for fitting the table).
    """
    h, w = depth_mm.shape
    if (h, w) != (intrinsics.height, intrinsics.width) or color.shape[:2] != (h, w):
        raise ValueError(
            f"depth {depth_mm.shape}, colour {color.shape} and intrinsics "
            f"{intrinsics.width}x{intrinsics.height} disagree"
        )
    u0, v0, u1, v1 = (0, 0, w, h) if box_mm is None else box_pixels(
        box_mm, intrinsics, robot_from_camera
    )
    window = depth_mm[v0:v1:stride, u0:u1:stride]
    rows, columns = np.nonzero(window)
    z = window[rows, columns].astype(float)
    rows = rows * stride + v0
    columns = columns * stride + u0
    ray_x = (columns - intrinsics.cx) / intrinsics.fx
    ray_y = (rows - intrinsics.cy) / intrinsics.fy
    R, T = robot_from_camera.rotation, robot_from_camera.translation_mm
    if above_plane is not None:
        normal, offset, clearance = above_plane
        # n . (R p_cam + T) + offset, with p_cam = z (ray_x, ray_y, 1)
        normal_cam = R.T @ np.asarray(normal, dtype=float)
        height = z * (normal_cam[0] * ray_x + normal_cam[1] * ray_y + normal_cam[2])
        keep = height + (float(np.asarray(normal) @ T) + offset) > clearance
        rows, columns, z = rows[keep], columns[keep], z[keep]
        ray_x, ray_y = ray_x[keep], ray_y[keep]
    x, y = ray_x * z, ray_y * z
    # R (x, y, z) + T one axis at a time: no (n, 3) camera-frame copy, no (n, 3) matmul
    points = np.empty((len(z), 3))
    for axis in range(3):
        points[:, axis] = R[axis, 0] * x + R[axis, 1] * y + R[axis, 2] * z + T[axis]
    if box_mm is None:
        return PointCloud(points, color[rows, columns])
    inside = inside_box(points, box_mm)
    return PointCloud(points[inside], color[rows[inside], columns[inside]])


def box_pixels(
    box_mm: np.ndarray, intrinsics: CameraIntrinsics, robot_from_camera: RigidTransform
) -> tuple[int, int, int, int]:
    """The pixel rectangle (u0, v0, u1, v1), end exclusive, that holds the image of a box
    (6,) [xmin ymin zmin xmax ymax zmax] in the robot frame; the whole image when the box
    reaches behind the camera. A convex box projects inside the hull of its 8 corners."""
    box = np.asarray(box_mm, dtype=float)
    corners = np.stack(np.meshgrid(box[[0, 3]], box[[1, 4]], box[[2, 5]]), -1).reshape(-1, 3)
    camera = robot_from_camera.inverse().apply(corners)
    if np.any(camera[:, 2] <= 0):
        return 0, 0, intrinsics.width, intrinsics.height
    u = intrinsics.fx * camera[:, 0] / camera[:, 2] + intrinsics.cx
    v = intrinsics.fy * camera[:, 1] / camera[:, 2] + intrinsics.cy
    u0 = int(np.clip(np.floor(u.min()), 0, intrinsics.width))
    u1 = int(np.clip(np.ceil(u.max()) + 1, 0, intrinsics.width))
    v0 = int(np.clip(np.floor(v.min()), 0, intrinsics.height))
    v1 = int(np.clip(np.ceil(v.max()) + 1, 0, intrinsics.height))
    return u0, v0, u1, v1


def inside_box(points_mm: np.ndarray, box_mm: np.ndarray) -> np.ndarray:
    """(n, 3) points, box (6,) [xmin ymin zmin xmax ymax zmax] -> (n,) bool, inside or on it."""
    box = np.asarray(box_mm, dtype=float)
    if box.shape != (6,):
        raise ValueError(f"a box is (6,) [xmin ymin zmin xmax ymax zmax], got shape {box.shape}")
    inside = (points_mm[:, 0] >= box[0]) & (points_mm[:, 0] <= box[3])
    inside &= (points_mm[:, 1] >= box[1]) & (points_mm[:, 1] <= box[4])
    inside &= (points_mm[:, 2] >= box[2]) & (points_mm[:, 2] <= box[5])
    return inside
