"""Pinhole intrinsics of a colour (and aligned depth) image, and back-projection to points."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softforce_cli.camera.lens import LensDistortion


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole model of the RealSense optical frame (x right, y down, z forward).

    width, height : image size in pixels.
    fx, fy        : focal lengths in pixels.
    cx, cy        : principal point in pixels (pixel centres at integer coordinates).
    distortion    : the lens' distortion (camera.lens), None for a pinhole image. The vision
                    stage takes pinhole images only: a frame with distortion is rectified
                    first (camera.rectification).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: LensDistortion | None = None

    @property
    def matrix(self) -> np.ndarray:
        """(3, 3) float64 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_fov(cls, width: int, height: int, horizontal_fov_deg: float) -> CameraIntrinsics:
        """Square pixels, centred principal point, given horizontal field of view."""
        fx = 0.5 * width / np.tan(np.radians(horizontal_fov_deg) / 2.0)
        return cls(width, height, fx, fx, (width - 1) / 2.0, (height - 1) / 2.0)


def points_from_depth(depth_mm: np.ndarray, intrinsics: CameraIntrinsics) -> np.ndarray:
    """Back-project a depth image into camera-frame points.

    depth_mm (h, w) uint16 or float, 0 = no data -> (h, w, 3) float64 mm, NaN where depth is 0.
    """
    h, w = depth_mm.shape
    v, u = np.mgrid[0:h, 0:w]
    z = np.where(depth_mm > 0, depth_mm, np.nan).astype(float)
    x = (u - intrinsics.cx) / intrinsics.fx * z
    y = (v - intrinsics.cy) / intrinsics.fy * z
    return np.stack([x, y, z], axis=-1)
