"""Depth decimation: a fine RGB-D frame reduced to pixels about one VoxelGrid leaf wide.

At 1280x720 a D415's pixel spans 0.58 mm on a robot 0.54 m away, half the VoxelGrid leaf
(1.1 mm): the cloud holds four times the pixels of 640x480 and, after the grid, about twice
the points (the depth noise spreads a leaf's pixels over leaves along the view), so the
radius searches that follow cost three to four times as much for a surface no better
resolved than the feature points need. Decimating k x k blocks of pixels first gives the
cloud of a camera with focal length f / k and the same field of view, as librealsense's own
decimation filter does for a RealSense stream.

A block's depth is the valid depth of rank n // 2 among its n valid ones (0 = none), the
choice of librealsense's median filter on non-zero pixels: always a depth one pixel
measured, so a block straddling a depth edge gives a point on one of the two surfaces, never
one in the air between them; its colour is that pixel's.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from softforce_cli.camera.intrinsics import CameraIntrinsics

# librealsense's decimation filter accepts factors 1-8
MAX_DECIMATION = 8


def decimation_factor(focal_px: float, distance_mm: float, voxel_mm: float) -> int:
    """The k whose decimated pixel spans about one VoxelGrid leaf at distance_mm: round(v / p)
    with p = distance_mm / focal_px the pixel's footprint, between 1 and MAX_DECIMATION. 1 (no
    decimation) for the 424x240 to 848x480 D415 at 0.5-0.6 m; 2 at 1280x720."""
    footprint = max(distance_mm, 1e-9) / focal_px
    return int(np.clip(round(voxel_mm / footprint), 1, MAX_DECIMATION))


def decimate_frame(
    depth_mm: np.ndarray,
    color: np.ndarray,
    intrinsics: CameraIntrinsics,
    factor: int,
    window: tuple[int, int, int, int] | None = None,
) -> tuple[np.ndarray, np.ndarray, CameraIntrinsics]:
    """The frame's pixels (or those of window (u0, v0, u1, v1), end exclusive) in blocks of
    factor x factor, each one pixel: depth (H, W) uint16, colour (H, W, 3) uint8 and the
    intrinsics of that smaller image (fx / k, and the principal point moved to the block
    grid, so each output pixel back-projects along its block's centre ray).

    depth_mm (h, w) uint16 (0 = no data), color (h, w, 3) uint8 aligned to it. The blocks lie
    on the whole image's grid (the window is widened to it, and trimmed at the image's far
    edges to whole blocks), so one pixel falls in the same block whatever the window.
    """
    k = int(factor)
    h, w = depth_mm.shape
    u0, v0, u1, v1 = (0, 0, w, h) if window is None else window
    u0, v0 = (u0 // k) * k, (v0 // k) * k
    u1 = min(-(-u1 // k) * k, (w // k) * k)
    v1 = min(-(-v1 // k) * k, (h // k) * k)
    rows, columns = max(v1 - v0, 0) // k, max(u1 - u0, 0) // k
    scaled = replace(intrinsics, width=columns, height=rows, fx=intrinsics.fx / k,
                     fy=intrinsics.fy / k, cx=(intrinsics.cx - u0 - (k - 1) / 2) / k,
                     cy=(intrinsics.cy - v0 - (k - 1) / 2) / k)
    if k == 1:
        return depth_mm[v0:v1, u0:u1], color[v0:v1, u0:u1], scaled
    # (k * k, rows * columns): a block's pixels down a column, row by row within the block
    tiles = depth_mm[v0:v1, u0:u1].reshape(rows, k, columns, k).transpose(1, 3, 0, 2)
    blocks = tiles.reshape(k * k, rows * columns)
    depth = valid_median(blocks)
    # the pixel that measured it, for its colour: the first in the block with that depth
    within = np.argmax(blocks == depth, axis=0)
    corner = (v0 + k * np.arange(rows))[:, None] * w + (u0 + k * np.arange(columns))
    pixel = corner.ravel() + (within // k) * w + within % k
    colour = np.take(color.reshape(h * w, 3), pixel, axis=0)
    return depth.reshape(rows, columns), colour.reshape(rows, columns, 3), scaled


def valid_median(depths: np.ndarray) -> np.ndarray:
    """(m, b) uint16 depths (0 = none) -> (b,) uint16 each column's valid depth of rank n // 2
    among its n valid ones; 0 when it has none.

    An odd-even transposition sorting network, m rounds of np.minimum / np.maximum over
    whole rows: at m = 4 three to four times faster than np.sort along a short last axis,
    which pays a cost per block."""
    m = len(depths)
    values = np.where(depths > 0, depths, np.iinfo(np.uint16).max)  # invalid ones sort last
    for first in (index % 2 for index in range(m)):
        lower, upper = values[first:m - 1:2], values[first + 1:m:2]
        lower[...], upper[...] = np.minimum(lower, upper), np.maximum(lower, upper)
    valid = np.count_nonzero(depths, axis=0)
    median = np.take_along_axis(values, (valid // 2)[None], axis=0)[0]
    return np.where(valid > 0, median, 0).astype(np.uint16)
