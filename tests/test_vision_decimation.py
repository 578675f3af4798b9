"""Depth decimation of fine frames (vision/decimation.py).

References: a sort of each block's valid depths, the camera module's back-projection of the
full frame (block-centre rays), and depth edges known by construction.
"""

from __future__ import annotations

import numpy as np
import pytest

from softforce_cli.camera.intrinsics import CameraIntrinsics, points_from_depth
from softforce_cli.vision.decimation import decimate_frame, decimation_factor, valid_median
from softforce_cli.vision.settings import (
    REFERENCE_FOCAL_PX,
    VisionSettings,
    settings_for_camera,
    settings_for_frame,
)

INTRINSICS = CameraIntrinsics(width=64, height=48, fx=50.0, fy=52.0, cx=31.2, cy=24.7)


@pytest.mark.parametrize("m", [4, 9, 16])
def test_valid_median_is_the_valid_depth_of_rank_half_their_number(m):
    rng = np.random.default_rng(m)
    depths = rng.integers(300, 320, (m, 5000)).astype(np.uint16)  # many ties
    depths[rng.random((m, 5000)) < 0.4] = 0
    depths[:, :50] = 0  # blocks with no valid pixel
    expected = []
    for column in depths.T:
        valid = np.sort(column[column > 0])
        expected.append(valid[len(valid) // 2] if len(valid) else 0)
    np.testing.assert_array_equal(valid_median(depths), expected)


def test_a_decimated_pixel_is_a_block_pixel_seen_along_the_block_centre_ray():
    """Constant depth: each decimated point is the mean of its block's full-resolution points
    (the block centre's ray at that depth), and its colour is one of the block's."""
    rng = np.random.default_rng(0)
    depth = np.full((48, 64), 500, dtype=np.uint16)
    color = rng.integers(0, 256, (48, 64, 3)).astype(np.uint8)
    for k in (2, 3, 4):
        small_depth, small_color, small = decimate_frame(depth, color, INTRINSICS, k)
        assert small_depth.shape == (48 // k, 64 // k) == (small.height, small.width)
        assert small.fx == pytest.approx(50.0 / k) and small.fy == pytest.approx(52.0 / k)
        full = points_from_depth(depth, INTRINSICS)[: 48 // k * k, : 64 // k * k]
        block_means = full.reshape(48 // k, k, 64 // k, k, 3).mean(axis=(1, 3))
        np.testing.assert_allclose(points_from_depth(small_depth, small), block_means,
                                   atol=1e-9)
        blocks = color[: 48 // k * k, : 64 // k * k].reshape(48 // k, k, 64 // k, k, 3)
        same = (blocks == small_color[:, None, :, None, :]).all(axis=-1).any(axis=(1, 3))
        assert same.all()


def test_a_block_across_a_depth_edge_takes_one_surface_never_a_point_between():
    depth = np.full((48, 64), 700, dtype=np.uint16)
    depth[:, 31:] = 400  # the edge runs through the blocks of columns 30-31
    depth[10, 30] = 0  # and a hole
    color = np.zeros((48, 64, 3), dtype=np.uint8)
    color[:, 31:] = 255
    small_depth, small_color, _ = decimate_frame(depth, color, INTRINSICS, 2)
    assert set(np.unique(small_depth)) == {400, 700}
    # the colour is the chosen pixel's: 400 mm is white, 700 mm black
    np.testing.assert_array_equal(small_color[..., 0] == 255, small_depth == 400)


def test_a_window_is_cut_from_the_whole_frame_grid():
    rng = np.random.default_rng(1)
    depth = rng.integers(400, 700, (48, 64)).astype(np.uint16)
    depth[rng.random((48, 64)) < 0.2] = 0
    color = rng.integers(0, 256, (48, 64, 3)).astype(np.uint8)
    whole_depth, whole_color, whole = decimate_frame(depth, color, INTRINSICS, 2)
    part_depth, part_color, part = decimate_frame(depth, color, INTRINSICS, 2, (11, 5, 40, 31))
    # widened to the grid: columns 10-39, rows 4-31 -> blocks 5-19 and 2-15
    np.testing.assert_array_equal(part_depth, whole_depth[2:16, 5:20])
    np.testing.assert_array_equal(part_color, whole_color[2:16, 5:20])
    np.testing.assert_allclose(points_from_depth(part_depth, part),
                               points_from_depth(whole_depth, whole)[2:16, 5:20])
    # at the far edges only whole blocks: 63 columns -> 31 blocks
    odd_depth, _, odd = decimate_frame(depth[:, :63], color[:, :63],
                                       CameraIntrinsics(63, 48, 50.0, 52.0, 31.2, 24.7), 2)
    assert odd_depth.shape == (24, 31) and (odd.width, odd.height) == (31, 24)


def test_the_factor_makes_a_pixel_about_one_voxel_leaf():
    leaf = VisionSettings().voxel_mm
    d415 = {424: 308.5, 640: REFERENCE_FOCAL_PX, 848: 616.9, 1280: 931.2}
    factors = {width: decimation_factor(fx, 536.0, leaf) for width, fx in d415.items()}
    assert factors == {424: 1, 640: 1, 848: 1, 1280: 2}
    assert decimation_factor(931.2, 250.0, leaf) == 4  # close up: 0.27 mm pixels
    assert decimation_factor(1e6, 536.0, leaf) == 8  # at most 8, as librealsense


def test_settings_for_a_fine_camera_fix_the_factor_and_count_its_coarser_pixels():
    """At 1280x720 the decimated image is the 640x480 D415's (fx 465.6 px): the counts stay
    the paper's. Forced to keep every pixel, they grow with the finer image's density."""
    hd = settings_for_camera(VisionSettings(), 931.2, 536.0)
    assert hd.decimation == 2 and not hd.scale_to_camera
    assert (hd.outlier_min_neighbours, hd.contact_min_neighbours) == (20, 3)
    every = settings_for_camera(VisionSettings(decimation=1), 931.2, 536.0)
    assert every.decimation == 1
    assert (every.outlier_min_neighbours, every.contact_min_neighbours) == (42, 6)
    # a frame is processed with these; counts taken as given still get the factor fixed
    assert settings_for_frame(VisionSettings(), 931.2, 536.0) == hd
    given = settings_for_frame(VisionSettings(outlier_min_neighbours=7, scale_to_camera=False),
                               931.2, 536.0)
    assert (given.decimation, given.outlier_min_neighbours) == (2, 7)


@pytest.mark.parametrize("value", [-1, 9])
def test_a_decimation_outside_0_to_8_is_refused(value):
    with pytest.raises(ValueError, match="decimation"):
        VisionSettings(decimation=value)
