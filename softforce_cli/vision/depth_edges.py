"""Pixels that carry one side of a depth edge's depth in the other side's colour.

A stereo depth camera's correlation window bleeds the nearer surface's depth a pixel or two
past a depth edge ("edge fattening"), and a colour image registered a pixel or two off the
depth paints each side of an edge in the other's colour. Either puts points in space in the
wrong colour: the table's along the robot's outline, the robot's along a probe's, the
probe's on the robot's skin beside it. Such a pixel lies by a depth edge, and its colour is
the other side's, not its own side's: it is dropped before the cloud is made
(docs/vision.md, "Edges").
"""

from __future__ import annotations

import numpy as np


def bled_pixels(depth_mm: np.ndarray, color: np.ndarray, reach_px: int, jump_mm: float,
                margin: float, window: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """(h, w) bool: the pixels by a depth edge whose colour is the other side's.

    depth_mm (h, w) uint16 (0: no data), color (h, w, 3) uint8 aligned to it. Within reach_px
    of a pixel, its side is the pixels less than jump_mm / 2 from its depth, the other side
    those more than jump_mm from it. A pixel with both is dropped when its colour is at least
    `margin` (RGB levels) closer to the other side's mean colour than to its own side's. Only
    the pixels of window (u0, v0, u1, v1), end exclusive, are looked at (all: None).
    """
    h, w = depth_mm.shape
    u0, v0, u1, v1 = (0, 0, w, h) if window is None else window
    bled = np.zeros((h, w), dtype=bool)
    if reach_px < 1 or u1 <= u0 or v1 <= v0:
        return bled
    # the window grown by the reach, so that its border pixels see their neighbours
    top, left = max(v0 - reach_px, 0), max(u0 - reach_px, 0)
    patch = depth_mm[top:min(v1 + reach_px, h), left:min(u1 + reach_px, w)]
    valid = patch > 0
    # no data is 0 to the maximum and the largest depth to the minimum
    nearest = _window_extreme(np.where(valid, patch, np.iinfo(np.uint16).max), reach_px,
                              np.minimum)
    farthest = _window_extreme(patch, reach_px, np.maximum)
    edge = valid & (farthest.astype(np.int32) - nearest > jump_mm)
    # the window's pixels only, not those of its grown border
    edge[:v0 - top] = edge[v1 - top:] = False
    edge[:, :u0 - left] = edge[:, u1 - left:] = False
    rows, columns = np.nonzero(edge)
    if not len(rows):
        return bled
    depth = patch.astype(float)
    colors = color[top:top + depth.shape[0], left:left + depth.shape[1]].astype(float)
    dy, dx = np.mgrid[-reach_px:reach_px + 1, -reach_px:reach_px + 1].reshape(2, -1)
    others = (dy != 0) | (dx != 0)
    around_rows = np.clip(rows[:, None] + dy[others], 0, depth.shape[0] - 1)
    around_columns = np.clip(columns[:, None] + dx[others], 0, depth.shape[1] - 1)
    around = depth[around_rows, around_columns]  # (m, k) 0 where no data
    step = np.abs(around - depth[rows, columns][:, None])
    own_side = (around > 0) & (step < 0.5 * jump_mm)
    other_side = (around > 0) & (step > jump_mm)
    seen = own_side.any(axis=1) & other_side.any(axis=1)
    around_colors = colors[around_rows, around_columns]  # (m, k, 3)

    def side_mean(side: np.ndarray) -> np.ndarray:
        return (np.einsum("mk,mkc->mc", side, around_colors)
                / np.maximum(side.sum(axis=1), 1)[:, None])

    own = colors[rows, columns]
    to_other = np.linalg.norm(own - side_mean(other_side), axis=1)
    to_own = np.linalg.norm(own - side_mean(own_side), axis=1)
    dropped = seen & (to_other + margin < to_own)
    bled[rows[dropped] + top, columns[dropped] + left] = True
    return bled


def _window_extreme(values: np.ndarray, reach: int, extreme: np.ufunc) -> np.ndarray:
    """(h, w) the extreme (np.minimum or np.maximum) of values (h, w) over each pixel's
    (2 reach + 1)^2 window, the image's edge pixels repeated beyond it (as scipy.ndimage's
    filters with mode "nearest", whose 1D passes took 3 ms on a 640x480 frame's crop: these
    whole-array steps take a fraction)."""
    rows = np.pad(values, [(reach, reach), (0, 0)], mode="edge")
    h = values.shape[0]
    down = rows[:h]
    for offset in range(1, 2 * reach + 1):
        down = extreme(down, rows[offset:offset + h])
    columns = np.pad(down, [(0, 0), (reach, reach)], mode="edge")
    w = values.shape[1]
    result = columns[:, :w]
    for offset in range(1, 2 * reach + 1):
        result = extreme(result, columns[:, offset:offset + w])
    return result
