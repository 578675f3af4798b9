"""Vision filters: back-projection, PassThrough, VoxelGrid, RadiusOutlier, table removal.

References: the camera module's own back-projection, brute-force voxel means, open3d's
radius outlier removal, and planes known by construction.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from softforce_cli.calibration.rigid import RigidTransform, rotation_from_euler_deg
from softforce_cli.camera.intrinsics import CameraIntrinsics, points_from_depth
from softforce_cli.vision.filters import (
    TABLE_MAX_TILT_DEG,
    crop_box,
    crop_box_from_bounds,
    fit_table_plane,
    neighbour_counts,
    radius_pairs,
    remove_radius_outliers,
    remove_radius_outliers_with_pairs,
    remove_table,
    voxel_downsample,
)
from softforce_cli.vision.point_cloud import PointCloud, cloud_from_frame

INTRINSICS = CameraIntrinsics(width=64, height=48, fx=50.0, fy=52.0, cx=31.2, cy=24.7)
POSE = RigidTransform(rotation_from_euler_deg([170.0, 10.0, 30.0]), np.array([5.0, -8.0, 580.0]))


def _frame(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    depth = rng.integers(400, 700, (48, 64)).astype(np.uint16)
    depth[rng.random((48, 64)) < 0.2] = 0  # holes
    color = rng.integers(0, 256, (48, 64, 3)).astype(np.uint8)
    return depth, color


def test_cloud_from_frame_matches_the_camera_back_projection():
    rng = np.random.default_rng(0)
    depth, color = _frame(rng)
    cloud = cloud_from_frame(depth, color, INTRINSICS, POSE)
    reference = points_from_depth(depth, INTRINSICS).reshape(-1, 3)
    valid = depth.ravel() > 0
    assert len(cloud) == valid.sum()
    np.testing.assert_allclose(cloud.points_mm, POSE.apply(reference[valid]), atol=1e-9)
    np.testing.assert_array_equal(cloud.colors, color.reshape(-1, 3)[valid])


def test_cloud_cropped_while_built_equals_cropping_after():
    rng = np.random.default_rng(1)
    depth, color = _frame(rng)
    full = cloud_from_frame(depth, color, INTRINSICS, POSE)
    # a box around part of the scene, so that the pixel window excludes much of the image
    centre = np.median(full.points_mm, axis=0)
    box = np.concatenate([centre - np.array([60, 40, 80]), centre + np.array([30, 50, 80])])
    cropped = cloud_from_frame(depth, color, INTRINSICS, POSE, box)
    expected = crop_box(full, box)
    assert 0 < len(expected) < len(full)
    order = lambda c: np.lexsort(c.points_mm.T)  # noqa: E731
    np.testing.assert_allclose(
        cropped.points_mm[order(cropped)], expected.points_mm[order(expected)], atol=1e-9
    )
    np.testing.assert_array_equal(cropped.colors[order(cropped)], expected.colors[order(expected)])


def test_crop_box_from_bounds_grows_every_side():
    box = crop_box_from_bounds(np.array([[-1.0, -2.0, -3.0], [4.0, 5.0, 6.0]]), 20.0)
    np.testing.assert_array_equal(box, [-21.0, -22.0, -23.0, 24.0, 25.0, 26.0])


def test_voxel_downsample_gives_the_mean_of_each_occupied_voxel():
    rng = np.random.default_rng(2)
    points = rng.uniform(-5.0, 5.0, (400, 3))
    colors = rng.integers(0, 256, (400, 3)).astype(np.uint8)
    result = voxel_downsample(PointCloud(points, colors), 1.1)
    # brute force: group by integer voxel coordinates
    groups: dict[tuple, list[int]] = {}
    for i, cell in enumerate(map(tuple, np.floor(points / 1.1).astype(int))):
        groups.setdefault(cell, []).append(i)
    expected = np.array([points[g].mean(axis=0) for g in groups.values()])
    expected_colors = np.array([np.rint(colors[g].mean(axis=0)) for g in groups.values()])
    assert len(result) == len(groups)
    mine, theirs = np.lexsort(result.points_mm.T), np.lexsort(expected.T)
    np.testing.assert_allclose(result.points_mm[mine], expected[theirs], atol=1e-12)
    np.testing.assert_array_equal(result.colors[mine], expected_colors[theirs])


def test_radius_outliers_keep_the_same_points_as_open3d():
    rng = np.random.default_rng(3)
    # a dense patch and scattered speckles
    patch = rng.uniform(0, 20, (2000, 3)) * [1, 1, 0.05]
    points = np.vstack([patch, rng.uniform(-40, 60, (80, 3))])
    colors = np.zeros((len(points), 3), dtype=np.uint8)
    kept = remove_radius_outliers(PointCloud(points, colors), 5.0, 20)
    o3d_cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    _, o3d_kept = o3d_cloud.remove_radius_outlier(nb_points=20, radius=5.0)
    np.testing.assert_array_equal(kept.points_mm, points[np.sort(o3d_kept)])
    assert 1900 < len(kept) < 2010  # the speckles go, the patch stays


def test_outlier_pairs_are_the_close_pairs_of_the_kept_points():
    rng = np.random.default_rng(4)
    points = rng.uniform(0, 15, (600, 3))
    cloud = PointCloud(points, np.zeros((600, 3), dtype=np.uint8))
    kept, pairs = remove_radius_outliers_with_pairs(cloud, 5.0, 25, 3.0)
    assert len(kept) == np.count_nonzero(neighbour_counts(points, 5.0) >= 25)
    distance = np.linalg.norm(kept.points_mm[:, None] - kept.points_mm[None], axis=2)
    i, j = np.nonzero(np.triu(distance <= 3.0, k=1))
    np.testing.assert_array_equal(np.sort(pairs, axis=1)[np.lexsort(pairs.T[::-1])],
                                  np.stack([i, j], axis=1))


TABLE, BLOCK = 1, 2  # colours used as labels


def _table_scene(rng: np.random.Generator, tilt_deg: float) -> tuple[PointCloud, np.ndarray]:
    """A noisy tilted table through (0, 0, -37.5) under a block standing on it; colour red
    channel = TABLE or BLOCK."""
    xy = rng.uniform(-120, 120, (6000, 2))
    normal = rotation_from_euler_deg([tilt_deg, 0.0, 0.0]) @ [0.0, 0.0, 1.0]
    z = -37.5 - (normal[0] * xy[:, 0] + normal[1] * xy[:, 1]) / normal[2]
    table = np.column_stack([xy, z + rng.normal(0.0, 1.8, len(xy))])  # D415 noise, 424x240
    block = rng.uniform([-15, -15, -37.5], [15, 15, 120], (3000, 3))
    colors = np.zeros((9000, 3), dtype=np.uint8)
    colors[:6000, 0], colors[6000:, 0] = TABLE, BLOCK
    return PointCloud(np.vstack([table, block]), colors), normal


def test_table_plane_is_found_and_removed_with_the_base_clear_of_it():
    rng = np.random.default_rng(5)
    cloud, normal = _table_scene(rng, tilt_deg=3.0)
    plane = fit_table_plane(cloud, -37.5, np.array([0, 0, 40.0]), 30.0, 4.0, 200)
    assert plane is not None
    assert np.degrees(np.arccos(plane[0] @ normal)) < 0.5
    assert abs(plane[0] @ [0, 0, -37.5] + plane[1]) < 0.3  # through the table's centre
    left = remove_table(cloud, plane, 8.0)
    assert not np.any(left.colors[:, 0] == TABLE)
    # the block keeps exactly its points clear of the table by the clearance: between those
    # 8 mm above z = -37.5 give or take the tilt's rise across its footprint (15 tan 3 deg)
    rise = 15.0 * np.sqrt(2) * np.tan(np.radians(3.0)) + 0.3
    block_z = cloud.points_mm[6000:, 2]
    kept_z = left.points_mm[left.colors[:, 0] == BLOCK, 2]
    assert kept_z.min() > -37.5 + 8.0 - rise
    assert np.count_nonzero(block_z > -37.5 + 8.0 + rise) <= len(kept_z)
    assert len(kept_z) <= np.count_nonzero(block_z > -37.5 + 8.0 - rise)


def test_no_table_in_the_slab_means_nothing_removed():
    rng = np.random.default_rng(6)
    points = rng.uniform([-15, -15, 20], [15, 15, 120], (500, 3))
    cloud = PointCloud(points, np.zeros((500, 3), dtype=np.uint8))
    plane = fit_table_plane(cloud, -37.5, np.array([0, 0, 40.0]), 30.0, 4.0, 200)
    assert plane is None
    assert len(remove_table(cloud, plane, 8.0)) == 500


def _hanging_skin(rng: np.random.Generator, count: int = 3000) -> np.ndarray:
    """(count, 3) points on the side of a vertical cylinder (radius 10 mm, z 0-60 mm), the
    half a camera sees: the lower end of a robot that hangs in the air."""
    angle = rng.uniform(-np.pi, 0.0, count)
    z = rng.uniform(0.0, 60.0, count)
    return np.column_stack([10 * np.cos(angle), 10 * np.sin(angle), z]) + rng.normal(
        0.0, 0.5, (count, 3))


def test_a_band_of_a_hanging_robot_is_no_table():
    """A robot whose lowest part hangs in the air has only its own skin, and what touches
    it, in the slab: the plane through most of it is a band of the skin, or the skin and a
    probe's rod, which is no table: none is found, where one had been taken and cut the
    robot away (a trunk's frames were all `norobot`) or the rod (no contact found)."""
    rng = np.random.default_rng(7)
    skin = _hanging_skin(rng)
    footprint = np.array([[-15.0, -15.0], [15.0, 15.0]])
    x = rng.uniform(10.0, 50.0, 1500)  # a rod along +x touching the skin 20 mm up
    angle = rng.uniform(0.0, 2 * np.pi, len(x))
    rod = np.column_stack([x, 5 * np.cos(angle), 20 + 5 * np.sin(angle)])
    for points in (skin, np.vstack([skin, rod])):
        cloud = PointCloud(points, np.zeros((len(points), 3), dtype=np.uint8))
        assert fit_table_plane(cloud, 0.0, np.array([0, 0, 75.0]), 30.0, 4.0, 200,
                               footprint_mm=footprint) is None
    # a table 30 mm below the tip, around it, is found through the skin beside it
    xy = rng.uniform(-55, 55, (4000, 2))
    table = np.column_stack([xy, np.full(len(xy), -30.0) + rng.normal(0.0, 1.0, len(xy))])
    both = PointCloud(np.vstack([table, skin]), np.zeros((len(table) + len(skin), 3),
                                                          dtype=np.uint8))
    plane = fit_table_plane(both, -30.0, np.array([0, 0, 75.0]), 60.0, 4.0, 200,
                            footprint_mm=footprint)
    assert plane is not None and plane[0][2] > 0.999 and abs(plane[1] - 30.0) < 0.3


def test_a_table_seen_above_the_robots_lowest_point_is_still_the_table():
    """A camera whose depth scale is 2% short sees the table 12 mm higher than the robot's
    lowest point (the model's, in the calibrated frame); it is still the table, which
    diagnose reads the camera's error from (diagnosis.background)."""
    rng = np.random.default_rng(9)
    cloud, _ = _table_scene(rng, tilt_deg=0.0)
    plane = fit_table_plane(cloud, -37.5 - 12.0, np.array([0, 0, 40.0]), 30.0, 4.0, 200,
                            footprint_mm=np.array([[-15.0, -15.0], [15.0, 15.0]]))
    assert plane is not None and abs(plane[1] - 37.5) < 0.3


def test_a_wall_beside_the_robot_is_no_table():
    """The best plane of the slab tilted more than TABLE_MAX_TILT_DEG (a wall behind the
    robot with more points than the table in view) is passed over for the table."""
    rng = np.random.default_rng(8)
    xy = rng.uniform(-60, 60, (1500, 2))
    table = np.column_stack([xy, np.full(len(xy), -37.5) + rng.normal(0.0, 1.0, len(xy))])
    yz = rng.uniform([-60, -37.5], [60, -10], (3000, 2))
    wall = np.column_stack([yz[:, 0], np.full(len(yz), 55.0), yz[:, 1]])
    cloud = PointCloud(np.vstack([table, wall]), np.zeros((4500, 3), dtype=np.uint8))
    plane = fit_table_plane(cloud, -37.5, np.array([0, 0, 40.0]), 30.0, 4.0, 200,
                            footprint_mm=np.array([[-20.0, -20.0], [20.0, 20.0]]))
    assert plane is not None and plane[0][2] > 0.999
    assert np.degrees(np.arccos(min(1.0, plane[0][2]))) < TABLE_MAX_TILT_DEG


def test_outlier_pairs_keep_the_same_points_as_open3d_on_a_surface_with_edges():
    """The kept points against open3d's on a noisy strip whose many edge points sit near
    the threshold, with speckles; the pairs are all those of the kept points within 3 mm."""
    rng = np.random.default_rng(5)
    strip = rng.uniform(0, 1, (3000, 3)) * [60, 6, 0.5] + rng.normal(0, 0.3, (3000, 3))
    points = np.vstack([strip, rng.uniform(-30, 90, (100, 3))])
    cloud = PointCloud(points, np.zeros((len(points), 3), dtype=np.uint8))
    kept, pairs = remove_radius_outliers_with_pairs(cloud, 5.0, 350, 3.0)
    o3d_cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    _, o3d_kept = o3d_cloud.remove_radius_outlier(nb_points=350, radius=5.0)
    np.testing.assert_array_equal(kept.points_mm, points[np.sort(o3d_kept)])
    assert 0.5 * len(strip) < len(kept) < len(strip)  # edge points and speckles go
    assert len(pairs) == len(radius_pairs(kept.points_mm, 3.0))
