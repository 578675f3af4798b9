"""Colour region growing and the robot/object split, on point sets with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from softforce_cli.errors import SensingError
from softforce_cli.vision.point_cloud import PointCloud
from softforce_cli.vision.segmentation import grow_regions, learn_robot_colour, segment_robot
from softforce_cli.vision.settings import VisionSettings

ROBOT = np.array([40, 90, 210])
PROBE = np.array([220, 50, 40])
TABLE = np.array([150, 118, 84])


def _grid(x0: float, x1: float, y0: float, y1: float, z: float, step: float = 1.0) -> np.ndarray:
    x, y = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step))
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])


def _colour(n: int, rgb: np.ndarray, rng: np.random.Generator, sigma: float = 2.0) -> np.ndarray:
    return np.clip(np.rint(rgb + rng.normal(0.0, sigma, (n, 3))), 0, 255).astype(np.uint8)


def test_two_paints_side_by_side_are_two_regions():
    rng = np.random.default_rng(0)
    left, right = _grid(0, 20, 0, 20, 0.0), _grid(20, 40, 0, 20, 0.0)
    points = np.vstack([left, right])
    colors = np.vstack([_colour(len(left), ROBOT, rng), _colour(len(right), PROBE, rng)])
    regions = grow_regions(points, colors, 3.0, 30.0, 40.0, 10)
    assert regions.count == 2
    assert len(np.unique(regions.labels[: len(left)])) == 1
    assert len(np.unique(regions.labels[len(left):])) == 1
    means = regions.colors[regions.labels[[0, -1]]]
    np.testing.assert_allclose(means, [ROBOT, PROBE], atol=0.5)  # noise mean over 400 points


def test_smooth_shading_stays_one_region():
    rng = np.random.default_rng(1)
    points = _grid(0, 60, 0, 10, 0.0)
    # lit from 0.7 to 1.0 of the paint across 60 mm: 70 levels end to end, 1.2 per step
    shade = 0.7 + 0.3 * points[:, 0] / 60.0
    colors = np.clip(np.rint(ROBOT * shade[:, None] + rng.normal(0, 2.0, (len(points), 3))),
                     0, 255).astype(np.uint8)
    regions = grow_regions(points, colors, 3.0, 30.0, 40.0, 10)
    assert regions.count == 1
    assert np.all(regions.labels == 0)


def test_halves_split_by_points_merge_by_region_colour():
    # noise-free halves 35 apart: over the point threshold (30), under the region one (40)
    left, right = _grid(0, 20, 0, 20, 0.0), _grid(20, 40, 0, 20, 0.0)
    colors = np.vstack([np.tile([40, 90, 210], (len(left), 1)),
                        np.tile([40, 90, 175], (len(right), 1))]).astype(np.uint8)
    points = np.vstack([left, right])
    assert grow_regions(points, colors, 3.0, 30.0, 40.0, 10).count == 1
    assert grow_regions(points, colors, 3.0, 30.0, 30.0, 10).count == 2


def test_small_regions_join_their_neighbour_or_are_dropped():
    rng = np.random.default_rng(2)
    patch = _grid(0, 20, 0, 20, 0.0)
    speck = np.array([[10.0, 10.0, 0.0], [10.0, 11.0, 0.0], [11.0, 10.0, 0.0]])
    inside = (patch[:, None, :] == speck[None]).all(axis=2).any(axis=1)
    island = _grid(100, 102, 100, 102, 0.0)  # 4 points far from everything
    points = np.vstack([patch, island])
    colors = np.vstack([_colour(len(patch), ROBOT, rng), _colour(len(island), ROBOT, rng)])
    colors[: len(patch)][inside] = PROBE  # 3 red points inside the blue patch
    regions = grow_regions(points, colors, 3.0, 30.0, 40.0, 10)
    assert regions.count == 1
    assert np.all(regions.labels[: len(patch)] == 0)  # the red speck joined the patch
    assert np.all(regions.labels[len(patch):] == -1)  # the island is dropped


def test_robot_is_split_from_a_touching_object_and_a_table():
    rng = np.random.default_rng(3)
    robot = _grid(-30, 30, -30, 30, 50.0)
    # a red ball of radius 8 resting on the robot's top (its lower half hidden)
    u = rng.normal(size=(1500, 3))
    ball = 8.0 * u / np.linalg.norm(u, axis=1, keepdims=True)
    ball = ball[ball[:, 2] > 0] + [0.0, 0.0, 50.0]
    table = _grid(-100, 100, -100, -40, -37.5, step=1.5)
    points = np.vstack([robot, ball, table])
    colors = np.vstack([_colour(len(robot), ROBOT, rng), _colour(len(ball), PROBE, rng),
                        _colour(len(table), TABLE, rng)])
    segmentation = segment_robot(PointCloud(points, colors), ROBOT, VisionSettings())
    assert len(segmentation.robot) == len(robot)
    np.testing.assert_array_equal(segmentation.robot.points_mm, robot)
    assert len(segmentation.objects) == len(ball) + len(table)
    assert segmentation.dropped_points == 0
    assert segmentation.robot_regions.sum() == 1


def test_robot_colour_is_learned_from_points_near_the_model():
    rng = np.random.default_rng(4)
    robot = _grid(-30, 30, -30, 30, 50.0)
    shade = 0.8 + 0.2 * rng.random(len(robot))
    other = _grid(-30, 30, 40, 70, 50.0)  # another object beside it
    points = np.vstack([robot, other])
    colors = np.vstack([np.rint(ROBOT * shade[:, None]), np.tile(PROBE, (len(other), 1))])
    cloud = PointCloud(points, colors.astype(np.uint8))
    model = _grid(-30, 30, -30, 30, 51.0, step=4.0)  # the model's surface, 1 mm off
    learned = learn_robot_colour(cloud, model, max_distance_mm=3.0)
    np.testing.assert_allclose(learned, ROBOT * 0.9, atol=2.0)  # median of the shading
    with pytest.raises(SensingError, match="in view"):
        learn_robot_colour(cloud, model + np.array([500.0, 0.0, 0.0]))
