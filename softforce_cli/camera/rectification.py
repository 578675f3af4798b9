"""Rectification: a frame through a distorting lens resampled into the pinhole image of its K.

softforce's vision back-projects pixel (u, v) along ((u - cx) / fx, (v - cy) / fy, 1). A
frame whose intrinsics carry a lens distortion (camera.lens) is first resampled so that this
holds: each pixel of the rectified image (same size and K) takes the raw pixel nearest to
where its ray meets the raw image. Nearest, not interpolated: a depth between a robot's edge
and the table behind it would be a point in mid-air, and colour keeps its pixel's depth.
Pixels whose ray meets the raw image outside it are empty (depth 0, black). Depth is the z
of the surface point and does not change with where its pixel lies, so it is copied as is.
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import numpy as np

from softforce_cli.camera.frame import RgbdFrame
from softforce_cli.camera.intrinsics import CameraIntrinsics
from softforce_cli.camera.lens import distort, undistort


def rectified(frame: RgbdFrame) -> RgbdFrame:
    """The frame as a pinhole camera with its K would see it (distortion None); the frame
    itself when it has no distortion."""
    intrinsics = frame.intrinsics
    if intrinsics.distortion is None:
        return frame
    source, empty = rectification_map(intrinsics)
    h, w = frame.depth_mm.shape
    depth = np.take(frame.depth_mm.reshape(-1), source)
    depth[empty] = 0
    color = np.take(frame.color.reshape(h * w, 3), source, axis=0)
    color[empty] = 0
    return replace(frame, depth_mm=depth.reshape(h, w), color=color.reshape(h, w, 3),
                   intrinsics=replace(intrinsics, distortion=None))


@lru_cache(maxsize=4)
def rectification_map(intrinsics: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """(h * w,) int64 for each pixel of the rectified image (row by row) the flat index of
    the raw pixel nearest to where its ray meets the raw image (0 where it meets none), and
    (e,) int64 the pixels whose ray meets none (read-only)."""
    v, u = np.mgrid[0:intrinsics.height, 0:intrinsics.width]
    xd, yd = distort(intrinsics.distortion, (u - intrinsics.cx) / intrinsics.fx,
                     (v - intrinsics.cy) / intrinsics.fy)
    column = np.rint(intrinsics.fx * xd + intrinsics.cx)
    row = np.rint(intrinsics.fy * yd + intrinsics.cy)
    inside = ((column >= 0) & (column < intrinsics.width)
              & (row >= 0) & (row < intrinsics.height)).reshape(-1)
    source = (np.where(inside.reshape(row.shape), row * intrinsics.width + column, 0)
              .astype(np.int64).reshape(-1))
    empty = np.flatnonzero(~inside)
    for array in (source, empty):
        array.setflags(write=False)
    return source, empty


def pixel_rays(intrinsics: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """(h, w) x and (h, w) y of the ray (x, y, 1) each raw pixel sees, through the lens'
    distortion when the intrinsics have one (NaN where it maps none)."""
    v, u = np.mgrid[0:intrinsics.height, 0:intrinsics.width]
    x = (u - intrinsics.cx) / intrinsics.fx
    y = (v - intrinsics.cy) / intrinsics.fy
    if intrinsics.distortion is None:
        return x, y
    return undistort(intrinsics.distortion, x, y)
