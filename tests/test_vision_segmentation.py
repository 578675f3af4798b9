"""Colour region growing and the robot/object split, on point sets with known answers and
on a scene the virtual D415 renders under a lamp."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.camera.intrinsics import CameraIntrinsics
from softforce_cli.errors import SensingError
from softforce_cli.sim.camera_pose import look_at
from softforce_cli.sim.depth_noise import apply_d415
from softforce_cli.sim.props import probe_surface
from softforce_cli.sim.render import SceneSurface, render, table_surface
from softforce_cli.vision.contacts import detect_contacts
from softforce_cli.vision.pipeline import observe_frame
from softforce_cli.vision.point_cloud import PointCloud, cloud_from_frame
from softforce_cli.vision.segmentation import (
    grow_regions,
    learn_robot_colour,
    robot_paint,
    segment_robot,
)
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


def test_the_robots_paint_shaded_is_the_robot_and_other_paints_are_not():
    """A white lamp scales a paint's three channels alike: the robot colour at 0.3 to 1.6 of
    its brightness is the robot (far beyond the 70 levels of the Euclidean rule at 0.3), a
    grey, the table and the probe at any brightness are not, nor the robot's paint darker
    than robot_min_shade (its direction is noise there)."""
    shades = np.array([0.3, 0.42, 0.7, 1.0, 1.2])
    assert robot_paint(ROBOT * shades[:, None], ROBOT).all()
    assert not robot_paint(ROBOT * shades[:2, None], ROBOT,
                           VisionSettings(robot_hue_deg=0.0)).any()  # the rule before
    others = np.vstack([grey * np.array([1.0, 1.0, 1.0]) for grey in (40, 80, 160)]
                       + [TABLE * k for k in (0.3, 1.0)] + [PROBE * k for k in (0.3, 1.0)])
    assert not robot_paint(others, ROBOT).any()
    assert not robot_paint(ROBOT * 0.2, ROBOT).any()
    # a skin probe is 8.5 degrees from a white robot, which is robot at any shade
    white, skin = np.array([225, 225, 220]), np.array([225, 170, 140])
    assert robot_paint(white * np.array([[0.3], [0.7]]), white).all()
    assert not robot_paint(skin * np.array([[0.3], [0.7], [1.0]]), white).any()


def test_dark_paints_side_by_side_are_split_by_their_direction():
    """Under a low lamp (a 0.15 ambient share) a probe's shaded side [33, 8, 6] lies 38
    levels from the robot's shaded face (0.15 of its paint), so the regions merge (40), but
    70 degrees from it; a skin probe's shaded side [67, 51, 42] lies 29 levels from a white
    robot's shadow [67, 67, 66] (their points join, 30), 8.5 degrees from it. The default
    region_hue_deg keeps both pairs apart, and each side is classified by its own colour;
    the same paint shaded from 0.15 to 1 of its colour along a face stays one region, its
    dark points' directions turned by the colour noise."""
    rng = np.random.default_rng(5)
    hue = VisionSettings().region_hue_deg
    face, rod = _grid(0, 20, 0, 20, 0.0), _grid(20, 30, 0, 20, 0.0)
    points = np.vstack([face, rod])
    for robot, face_rgb, rod_rgb in ((ROBOT * 0.5, ROBOT * 0.15, [33, 8, 6]),
                                     ([190, 190, 186], [67, 67, 66], [67, 51, 42])):
        colors = np.vstack([_colour(len(face), face_rgb, rng), _colour(len(rod), rod_rgb, rng)])
        assert grow_regions(points, colors, 3.0, 30.0, 40.0, 10).count == 1  # hue not tested
        assert grow_regions(points, colors, 3.0, 30.0, 40.0, 10, hue_deg=hue).count == 2
        segmentation = segment_robot(PointCloud(points, colors), robot)
        np.testing.assert_array_equal(segmentation.robot.points_mm, face)
        np.testing.assert_array_equal(segmentation.objects.points_mm, rod)
    shaded = _grid(0, 60, 0, 10, 0.0)
    shade = 0.15 + 0.85 * shaded[:, 0] / 60.0
    colors = np.clip(np.rint(ROBOT * shade[:, None] + rng.normal(0, 2.0, (len(shaded), 3))),
                     0, 255).astype(np.uint8)
    assert grow_regions(shaded, colors, 3.0, 30.0, 40.0, 10, hue_deg=hue).count == 1


@pytest.mark.parametrize("key, value", [("robot_hue_deg", 90.0), ("region_hue_deg", -1.0),
                                        ("robot_min_shade", 1.5), ("robot_max_shade", 0.9),
                                        ("robot_max_shade", 20.0), ("rim_mm", -1.0)])
def test_hue_shade_and_rim_settings_are_checked(key, value):
    with pytest.raises(ValueError, match=key):
        VisionSettings(**{key: value})


def test_a_lamps_shadow_on_the_robot_is_robot_not_a_contact():
    """A blue box pressed by a red rod, rendered by the virtual D415 lit from the camera and
    under a lamp above it (its shaded faces and the rod's shadow at 0.3 of their paint):
    the same single contact both ways with the colour's direction; without it (both angles
    0), the rod's shadow on the box is an object bordering the robot, and the contact is
    found on the shadow's edge, 9 mm off."""
    box = o3d.geometry.TriangleMesh.create_box(100.0, 30.0, 30.0).subdivide_midpoint(3)
    vertices = np.asarray(box.vertices) - [50.0, 15.0, 0.0]
    robot = SceneSurface("robot", vertices, np.asarray(box.triangles), ROBOT)
    table = table_surface(-0.5, 400.0, TABLE)
    push = np.array([-0.4, 0.3, -1.0])
    rod = probe_surface(np.array([20.0, 0.0, 30.0]), push / np.linalg.norm(push), PROBE)
    camera = CameraIntrinsics(640, 480, 615.0, 615.0, 320.0, 240.0)
    pose = look_at(np.array([0.0, -150.0, 500.0]), np.array([0.0, 0.0, 15.0]))
    robot_from_camera = RigidTransform(pose[:3, :3], pose[:3, 3])
    bounds = np.array([vertices.min(axis=0), vertices.max(axis=0)])

    def contacts(settings: VisionSettings, **light) -> np.ndarray:
        rng = np.random.default_rng(0)
        depth, color = apply_d415(render([robot, table], camera, pose, **light), camera, rng)
        learned = learn_robot_colour(cloud_from_frame(depth, color, camera, robot_from_camera),
                                     vertices)  # on a frame without the rod, as sense does
        depth, color = apply_d415(render([robot, table, rod], camera, pose, **light), camera,
                                  rng)
        return observe_frame(depth, color, camera, robot_from_camera, bounds, learned,
                             settings).contacts.centres_mm

    lamp = {"ambient": 0.3, "light_direction": [1.0, 1.0, 2.0]}
    lit_from_camera = contacts(VisionSettings())
    assert len(lit_from_camera) == 1
    np.testing.assert_allclose(contacts(VisionSettings(), **lamp), lit_from_camera, atol=1.0)
    euclidean_only = contacts(VisionSettings(robot_hue_deg=0.0, region_hue_deg=0.0), **lamp)
    assert np.linalg.norm(euclidean_only - lit_from_camera, axis=1).min() > 5.0


def test_a_rim_in_the_backgrounds_colour_is_neither_robot_nor_object():
    """A depth camera's edge fattening (or a colour image registered a pixel off the depth)
    lines the robot's outline with points at the robot's depth in the table's colour: a
    strip 2 mm wide beside a robot slab's edge, none of it further than rim_mm from the
    robot. It is dropped, while a probe resting on the slab, reaching 20 mm from it, stays
    the one object and the one contact; with rim_mm = 0 the strip is an object touching
    the robot along its whole length, a contact of its own."""
    rng = np.random.default_rng(6)
    slab = _grid(-30, 30, -15, 15, 50.0)
    strip = _grid(-30, 30, 15.5, 17.5, 50.0, step=0.7)
    x, y, z = np.meshgrid([4.0, 5.0, 6.0], [-1.0, 0.0, 1.0], 51.0 + np.arange(21.0))
    rod = np.column_stack([x.ravel(), y.ravel(), z.ravel()])  # 3 x 3 points, 20 mm up
    points = np.vstack([slab, strip, rod])
    colors = np.vstack([_colour(len(slab), ROBOT, rng), _colour(len(strip), TABLE, rng),
                        _colour(len(rod), PROBE, rng)])
    cloud = PointCloud(points, colors)
    segmentation = segment_robot(cloud, ROBOT)
    np.testing.assert_array_equal(segmentation.objects.points_mm, rod)
    assert segmentation.rim_regions.sum() == 1
    contacts = detect_contacts(segmentation)
    assert len(contacts) == 1
    np.testing.assert_allclose(contacts.centres_mm[0, :2], [5.0, 0.0], atol=1.0)
    kept = segment_robot(cloud, ROBOT, VisionSettings(rim_mm=0.0))
    assert len(kept.objects) == len(strip) + len(rod)
    assert len(detect_contacts(kept, VisionSettings(rim_mm=0.0))) == 2


def test_a_marker_sticker_on_the_robots_skin_is_no_contact():
    """A flat sticker of another colour on the robot's face (a calibration marker left on):
    a region that never leaves the robot's skin, so a rim, neither robot nor object, and no
    contact; as an object (rim_mm = 0), robot points surround it: a contact."""
    rng = np.random.default_rng(7)
    slab = _grid(-30, 30, -30, 30, 50.0)
    sticker = np.linalg.norm(slab[:, :2] - [10.0, -5.0], axis=1) < 3.0
    colors = _colour(len(slab), ROBOT, rng)
    colors[sticker] = _colour(int(sticker.sum()), [40, 200, 60], rng)
    cloud = PointCloud(slab, colors)
    assert len(detect_contacts(segment_robot(cloud, ROBOT))) == 0
    as_object = VisionSettings(rim_mm=0.0)
    found = detect_contacts(segment_robot(cloud, ROBOT, as_object), as_object)
    assert len(found) == 1
    np.testing.assert_allclose(found.centres_mm[0, :2], [10.0, -5.0], atol=0.5)


def test_a_white_highlight_on_the_robots_paint_is_the_robot():
    """A glossy paint under a white light shows its colour plus white (the dichromatic
    reflection model): a body term a ROBOT and a surface term b (1, 1, 1), b >= 0. Such
    colours are the robot's, far beyond the shaded rule (up to 28 degrees from the paint);
    a grey (a = 0), the table, skin and the weight's yellow (a < 0) are not. A near-grey
    robot colour spans no plane with white: its highlights are its shades."""
    highlights = np.array([ROBOT * a + b for a, b in ((0.8, 80.0), (0.7, 120.0), (0.5, 150.0))])
    assert robot_paint(highlights, ROBOT).all()
    assert not robot_paint(highlights, ROBOT, VisionSettings(robot_hue_deg=0.0)).any()
    others = np.array([[160.0, 160.0, 160.0], TABLE, [225, 170, 140], [230, 190, 40], PROBE])
    assert not robot_paint(others, ROBOT).any()
    white = np.array([225.0, 225.0, 220.0])
    assert not robot_paint(np.array([[225.0, 170.0, 140.0], [200.0, 200.0, 200.0]]), white)[0]

