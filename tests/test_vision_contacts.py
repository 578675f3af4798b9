"""Algorithm 2 (contact points, Euclidean clusters) and location mapping, on known layouts;
contacts whose tip the camera cannot see (occluded_tips), on synthetic clouds and the sample
recording; where a contact touches the observed skin (touch_points)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.io.mcap_reader import iter_frames
from softforce_cli.vision.contacts import (
    detect_contacts,
    euclidean_clusters,
    merge_close_clusters,
    nearest_features,
    touch_points,
)
from softforce_cli.vision.pipeline import process_frame
from softforce_cli.vision.point_cloud import PointCloud, cloud_from_frame
from softforce_cli.vision.segmentation import Regions, Segmentation, learn_robot_colour
from softforce_cli.vision.settings import VisionSettings


def _segmentation(robot_mm: np.ndarray, *objects_mm: np.ndarray) -> Segmentation:
    """The robot as colour region 0 and each object array as a region of its own, the
    robot's points first (as segment_robot's regions index the cloud)."""
    def cloud(points):
        return PointCloud(points, np.zeros((len(points), 3), dtype=np.uint8))

    parts = [robot_mm, *(o.reshape(-1, 3) for o in objects_mm)]
    labels = np.repeat(np.arange(len(parts)), [len(p) for p in parts])
    regions = Regions(labels, np.zeros((len(parts), 3)), np.array([len(p) for p in parts]))
    objects = np.vstack(parts[1:]) if len(parts) > 1 else np.zeros((0, 3))
    return Segmentation(cloud(robot_mm), cloud(objects), regions,
                        np.arange(len(parts)) == 0)


def _plane(half: float = 40.0, step: float = 1.0, z: float = 0.0) -> np.ndarray:
    x, y = np.meshgrid(np.arange(-half, half + step / 2, step), np.arange(-half, half + step / 2,
                                                                          step))
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])


def _hemisphere(centre: np.ndarray, radius: float, n: int, rng) -> np.ndarray:
    u = rng.normal(size=(n, 3))
    u[:, 2] = np.abs(u[:, 2])
    return centre + radius * u / np.linalg.norm(u, axis=1, keepdims=True)


def test_a_blob_resting_on_the_robot_is_one_contact_under_it():
    rng = np.random.default_rng(0)
    robot = _plane()
    blob = _hemisphere(np.array([10.0, -5.0, 0.5]), 6.0, 2000, rng)  # rim 0.5 mm above
    contacts = detect_contacts(_segmentation(robot, blob), VisionSettings())
    assert len(contacts) == 1
    # contact points: the blob's lowest ring, whose mean lies on the axis, near the plane
    np.testing.assert_allclose(contacts.centres_mm[0, :2], [10.0, -5.0], atol=0.3)
    assert 0.5 <= contacts.centres_mm[0, 2] < 4.0
    assert contacts.point_counts[0] == len(contacts.contact_points_mm)
    lifted_blob = blob + np.array([0.0, 0.0, 10.0])
    lifted = detect_contacts(_segmentation(robot, lifted_blob), VisionSettings())
    assert len(lifted) == 0 and len(lifted.contact_points_mm) == 0


def test_contact_needs_more_than_n_neigh_robot_points_within_r_search():
    # robot points on a line 1 mm apart under one object point at height 1 mm: within 4 mm
    # of it lie the robot points at |x| <= sqrt(15) = 3.87, i.e. x = -3..3, seven of them
    robot = np.column_stack([np.arange(-10.0, 11.0), np.zeros(21), np.zeros(21)])
    obj = np.array([[0.0, 0.0, 1.0]])
    for n_neigh, expected in [(6, 1), (7, 0)]:
        settings = VisionSettings(contact_min_neighbours=n_neigh)
        assert len(detect_contacts(_segmentation(robot, obj), settings)) == expected


def test_clusters_at_known_centres_sorted_by_size():
    rng = np.random.default_rng(1)
    centres = np.array([[0.0, 0.0, 0.0], [50.0, 0.0, 0.0], [0.0, 60.0, 10.0]])
    sizes = [30, 80, 55]
    points = np.vstack([c + rng.uniform(-1.5, 1.5, (n, 3)) for c, n in zip(centres, sizes,
                                                                            strict=True)])
    points = np.vstack([points, [[200.0, 0.0, 0.0]]])  # a lone point: a cluster of one
    labels, counts = euclidean_clusters(points, 5.0, 2)
    np.testing.assert_array_equal(counts, [80, 55, 30])
    assert labels[-1] == -1
    for rank, original in enumerate([1, 2, 0]):
        members = points[labels == rank]
        start = sum(sizes[:original])
        np.testing.assert_allclose(members.mean(axis=0),
                                   points[start:start + sizes[original]].mean(axis=0))


def test_two_objects_give_two_contacts_mapped_to_their_nearest_features():
    rng = np.random.default_rng(2)
    robot = _plane(half=60.0)
    blobs = np.vstack([_hemisphere(np.array([-30.0, 0.0, 0.5]), 5.0, 1500, rng),
                       _hemisphere(np.array([35.0, 20.0, 0.5]), 5.0, 1000, rng)])
    contacts = detect_contacts(_segmentation(robot, blobs), VisionSettings())
    assert len(contacts) == 2
    np.testing.assert_allclose(contacts.centres_mm[:, :2], [[-30.0, 0.0], [35.0, 20.0]],
                               atol=0.4)
    features = np.array([[0.0, 0.0, 0.0], [-28.0, 3.0, 0.0], [40.0, 18.0, 0.0],
                         [-40.0, 0.0, 0.0]])
    np.testing.assert_array_equal(nearest_features(contacts.centres_mm, features), [1, 2])
    assert nearest_features(np.zeros((0, 3)), features).shape == (0,)


def test_contacts_in_the_clamped_box_are_ignored():
    rng = np.random.default_rng(3)
    robot = _plane()
    blob = _hemisphere(np.array([0.0, 0.0, 0.5]), 5.0, 1500, rng)
    # contact points lie up to 4 mm (r_search) above the robot's plane z = 0
    clamp = np.array([-15.0, -15.0, -40.0, 15.0, 15.0, 0.0])  # grown by 5 mm: up to z = 5
    settings = VisionSettings()
    assert len(detect_contacts(_segmentation(robot, blob), settings, clamp)) == 0
    lower = clamp - np.array([0, 0, 0, 0, 0, 6.0])  # up to z = -1: excludes nothing
    assert len(detect_contacts(_segmentation(robot, blob), settings, lower)) == 1


# --- contacts whose tip the camera cannot see (occluded_tips) ---------------------------------

CAMERA_MM = np.array([0.0, 0.0, 500.0])  # above the robot, looking down (-z)
ROD_RADIUS_MM = 5.0


def _rod_seen_from_camera(tip_mm: np.ndarray, axis: np.ndarray, hidden_mm: float,
                          length_mm: float = 60.0, step_mm: float = 0.8) -> np.ndarray:
    """The points a camera at CAMERA_MM sees of a rod of radius ROD_RADIUS_MM whose
    hemispherical tip touches tip_mm, its axis running from the tip along `axis`: the
    cylinder's half facing the camera, sampled evenly across the view (as pixels are), from
    hidden_mm along the axis up to length_mm (the tip and the rod's first hidden_mm are out
    of view, as under a tilted probe)."""
    u = axis / np.linalg.norm(axis)
    towards = CAMERA_MM - tip_mm
    towards -= (towards @ u) * u
    towards /= np.linalg.norm(towards)
    s, x = np.meshgrid(np.arange(hidden_mm, length_mm, step_mm),
                       np.arange(-ROD_RADIUS_MM + step_mm / 2, ROD_RADIUS_MM, step_mm))
    s, x = s.ravel()[:, None], x.ravel()[:, None]
    # the tip touches on the axis: the axis passes through tip_mm
    return (tip_mm + s * u + x * np.cross(u, towards)
            + np.sqrt(ROD_RADIUS_MM**2 - x**2) * towards)


def _robot_seen_past_rod(robot_mm: np.ndarray, tip_mm: np.ndarray, axis: np.ndarray
                         ) -> np.ndarray:
    """The robot's points whose ray to CAMERA_MM does not pass through the rod (within its
    radius of its axis, sampled every 0.5 mm): the surface under a tilted rod is hidden."""
    u = axis / np.linalg.norm(axis)
    centres = tip_mm + np.arange(0.0, 60.0, 0.5)[:, None] * u  # (m, 3)
    rays = CAMERA_MM - robot_mm  # (n, 3)
    lengths = np.linalg.norm(rays, axis=1)
    rays /= lengths[:, None]
    relative = centres[None] - robot_mm[:, None]  # (n, m, 3)
    along = np.einsum("nmi,ni->nm", relative, rays)
    across = np.linalg.norm(relative - along[..., None] * rays[:, None], axis=2)
    return robot_mm[~np.any((across < ROD_RADIUS_MM) & (along > 0), axis=1)]


ROD_AXIS = np.array([-np.sin(np.radians(38.0)), 0.0, np.cos(np.radians(38.0))])


def _tilted_rod_scene(gap_mm: float, hidden_mm: float = 6.0, slab_normal=ROD_AXIS,
                      noise_mm: float = 0.2):
    """A robot slab's face through TIP (normal slab_normal, 1 mm grid) and a rod 38 degrees
    from the vertical whose tip is gap_mm from TIP along its axis (0: touching at TIP), seen
    from above. By default the rod pushes along the face's normal, as the sample's probes
    do on the Diamond's sloping bars."""
    rng = np.random.default_rng(4)
    normal = np.asarray(slab_normal, dtype=float) / np.linalg.norm(slab_normal)
    across = np.cross(normal, [0.0, 1.0, 0.0])
    across /= np.linalg.norm(across)
    grid = _plane(half=50.0)
    slab = TIP + grid[:, :1] * across + grid[:, 1:2] * np.cross(normal, across)
    rod = _rod_seen_from_camera(TIP + gap_mm * ROD_AXIS, ROD_AXIS, hidden_mm)
    robot = _robot_seen_past_rod(slab, TIP, ROD_AXIS)
    return (robot + rng.normal(0, noise_mm, robot.shape),
            rod + rng.normal(0, noise_mm, rod.shape))


TIP = np.array([5.0, 3.0, 0.0])


def test_a_tilted_rod_hiding_its_tip_is_a_contact_at_the_tip():
    robot, rod = _tilted_rod_scene(0.0)
    segmentation = _segmentation(robot, rod)
    # Algorithm 2 alone misses it: no rod point within r_search of the slab
    off = detect_contacts(segmentation, VisionSettings(occluded_tip_mm=0), camera_mm=CAMERA_MM)
    assert len(off) == 0
    found = detect_contacts(segmentation, VisionSettings(), camera_mm=CAMERA_MM)
    assert len(found) == 1 and found.occluded.tolist() == [True]
    assert found.point_counts.tolist() == [0] and len(found.contact_points_mm) == 0
    assert np.linalg.norm(found.centres_mm[0] - TIP) < 2.0
    # without the camera's position the tip lies on the line through the seen side of the
    # rod, about one radius off, towards the camera
    seen_side = detect_contacts(segmentation, VisionSettings()).centres_mm
    assert 3.0 < np.linalg.norm(seen_side[0] - TIP) < 6.5


def test_a_rod_pressing_obliquely_is_found_at_its_tip():
    # the same rod on a level face, 38 degrees from the face's normal: the line through the
    # rod's seen side meets the face further down the axis than the axis does (3.5 mm off
    # without the step to the face's plane), 8-10 mm beyond its last seen point when its last
    # 6 mm are hidden, which the default 10 mm reaches and the former 8 mm did not
    for hidden in (3.0, 6.0):
        robot, rod = _tilted_rod_scene(0.0, hidden, slab_normal=[0.0, 0.0, 1.0])
        found = detect_contacts(_segmentation(robot, rod), VisionSettings(), camera_mm=CAMERA_MM)
        assert len(found) == 1 and found.occluded.all()
        assert np.linalg.norm(found.centres_mm[0] - TIP) < 2.0
    assert len(detect_contacts(_segmentation(robot, rod), VisionSettings(occluded_tip_mm=8.0),
                               camera_mm=CAMERA_MM)) == 0


def test_a_rod_stopping_short_of_the_robot_is_no_contact():
    # its extended axis meets the slab 15 mm beyond its tip (21 mm beyond its last seen point)
    robot, rod = _tilted_rod_scene(15.0)
    assert len(detect_contacts(_segmentation(robot, rod), VisionSettings(),
                               camera_mm=CAMERA_MM)) == 0
    # a gap of a few mm more than occluded_tip_mm already is not one
    robot, rod = _tilted_rod_scene(0.0, hidden_mm=13.0)
    assert len(detect_contacts(_segmentation(robot, rod), VisionSettings(),
                               camera_mm=CAMERA_MM)) == 0


def test_a_rod_seen_in_pieces_goes_on_through_them():
    # the rod's last 13 mm hidden, beyond occluded_tip_mm, but a piece of it seen 5-8 mm from
    # the tip as a colour region of its own (at 424x240 a probe's tip splits off so): the
    # axis goes on from the piece and meets the face at the tip
    robot, rod = _tilted_rod_scene(0.0, hidden_mm=13.0)
    assert len(detect_contacts(_segmentation(robot, rod), VisionSettings(),
                               camera_mm=CAMERA_MM)) == 0
    piece = _rod_seen_from_camera(TIP, ROD_AXIS, 5.0, length_mm=8.0)
    found = detect_contacts(_segmentation(robot, rod, piece), VisionSettings(),
                            camera_mm=CAMERA_MM)
    assert len(found) == 1 and found.occluded.all()
    assert np.linalg.norm(found.centres_mm[0] - TIP) < 2.0
    # a piece that touches is Algorithm 2's contact, and the rod gives no second one
    touching = _rod_seen_from_camera(TIP, ROD_AXIS, 1.0, length_mm=4.0)
    found = detect_contacts(_segmentation(robot, rod, touching), VisionSettings(),
                            camera_mm=CAMERA_MM)
    assert len(found) == 1 and not found.occluded.any()


def test_a_rod_touching_in_view_is_algorithm_2s_contact_only():
    # the same rod seen down to its tip's side: Algorithm 2 finds it, and its axis is not
    # extended into a second contact
    robot, rod = _tilted_rod_scene(0.0, hidden_mm=0.0)
    found = detect_contacts(_segmentation(robot, rod), VisionSettings(), camera_mm=CAMERA_MM)
    assert len(found) == 1 and not found.occluded.any()
    assert np.linalg.norm(found.centres_mm[0] - TIP) < 8.0


def test_table_cable_and_marker_are_no_occluded_contact():
    robot = _plane(half=30.0)
    # the table around the robot's foot, 6 mm below its face (beyond r_search): flat, square
    table = _plane(half=60.0, z=-6.0)
    table = table[np.abs(table[:, :2]).max(axis=1) > 32.0]
    # a cable lying along the robot 6 mm above it, ending over it: its axis runs parallel
    x = np.arange(-80.0, 10.0, 0.5)
    cable = np.column_stack([x, np.full_like(x, 5.0), np.full_like(x, 6.0)])
    cable = np.vstack([cable + np.array([0.0, dy, 0.0]) for dy in (-0.5, 0.0, 0.5)])
    # a round marker sticker 5 mm above the face: not elongated
    marker = _hemisphere(np.array([-10.0, -10.0, 5.0]), 2.0, 60, np.random.default_rng(5))
    for objects in (table, cable, marker):
        found = detect_contacts(_segmentation(robot, objects), VisionSettings(),
                                camera_mm=CAMERA_MM)
        assert len(found) == 0
    # the cable ending 3 mm above the robot along its own axis, pointing down at it, is one
    down = np.column_stack([np.zeros(80), np.zeros(80), 3.0 + np.arange(80) * 0.5])
    found = detect_contacts(_segmentation(robot, down), VisionSettings(
        contact_min_neighbours=0, contact_radius_mm=2.5))
    assert len(found) == 1 and found.occluded.all()
    np.testing.assert_allclose(found.centres_mm[0], [0.0, 0.0, 0.0], atol=1.0)


def test_occluded_tips_in_the_clamped_box_are_ignored():
    robot, rod = _tilted_rod_scene(0.0)
    clamp = np.array([-20.0, -20.0, -40.0, 20.0, 20.0, -2.0])  # grown by 5 mm: up to z = 3
    assert len(detect_contacts(_segmentation(robot, rod), VisionSettings(), clamp,
                               camera_mm=CAMERA_MM)) == 0


def test_occluded_tip_setting_is_checked():
    with pytest.raises(ValueError, match="occluded_tip_mm"):
        VisionSettings(occluded_tip_mm=-1.0)
    assert VisionSettings(occluded_tip_mm=0.0).occluded_tip_mm == 0.0


def test_the_sample_west_probe_hiding_its_tip_is_found(sample_robot):
    """probes.mcap (424x240, D415 noise), frame 3: the west probe's rod, 38 degrees from the
    vertical, hides its tip from the overhead camera and no probe point comes within r_search
    of the robot; its extended axis finds it (2.3 mm from the truth's contact point)."""
    recording = Path(__file__).resolve().parents[1] / "sample_data" / "recordings" / "probes.mcap"
    truth = json.loads(recording.with_name("probes.truth.json").read_text())
    pose = RigidTransform(np.array(truth["camera"]["rotation"]),
                          np.array(truth["camera"]["translation_mm"]))
    frames = list(iter_frames(recording))
    mesh = sample_robot.mesh
    surface = np.vstack([mesh.nodes_mm[mesh.surface_nodes],
                         mesh.nodes_mm[mesh.surface_faces].mean(axis=1)])
    robot_rgb = learn_robot_colour(cloud_from_frame(frames[0].depth_mm, frames[0].color,
                                                    frames[0].intrinsics, pose), surface)

    def contacts(index, settings):
        frame = frames[index]
        return process_frame(frame.depth_mm, frame.color, frame.intrinsics, pose,
                             mesh.bounds_mm, mesh.nodes_mm[sample_robot.feature_nodes],
                             sample_robot.feature_normals, robot_rgb, settings,
                             excluded_box_mm=np.array(sample_robot.config.fixed_boxes_mm[0])
                             ).contacts

    north, west = (np.array(c["point_mm"]) for c in truth["frames"][3]["contacts"])
    assert west[0] < -40.0  # the west bar's probe
    found = contacts(3, VisionSettings())
    assert found.occluded.tolist() == [False, True]
    assert np.linalg.norm(found.centres_mm[1] - west) < 3.0
    assert np.linalg.norm(found.centres_mm[0] - north) < 10.0
    alone = contacts(3, VisionSettings(occluded_tip_mm=0.0))
    assert len(alone) == 1 and not alone.occluded.any()  # Algorithm 2 misses the west probe
    for index in (0, 1, 2):  # no phantom, no second contact for the one north probe
        assert len(contacts(index, VisionSettings())) == len(truth["frames"][index]["contacts"])


def test_clusters_closer_than_the_merge_distance_are_one_contact():
    """One probe's tip patch split into clusters 7 mm apart is one contact at the clusters'
    point-weighted mean; a cluster 33 mm away stays apart; a chain of steps under the
    distance merges whole; 0 merges nothing (the paper)."""
    centres = np.array([[40.0, 0, 0], [0.0, 0, 0], [7.0, 0, 0]])
    sizes = np.array([2, 3, 1])
    merged, merged_sizes = merge_close_clusters(centres, sizes, 10.0)
    np.testing.assert_allclose(merged, [[1.75, 0, 0], [40.0, 0, 0]])
    assert merged_sizes.tolist() == [4, 2]
    chain = np.array([[0.0, 0, 0], [8.0, 0, 0], [16.0, 0, 0]])
    merged, merged_sizes = merge_close_clusters(chain, np.array([1, 1, 1]), 10.0)
    np.testing.assert_allclose(merged, [[8.0, 0, 0]])
    assert merge_close_clusters(centres, sizes, 0.0)[0] is centres


def _sloped_skin(rng, slope_deg: float, hole_mm: float, noise_mm: float) -> np.ndarray:
    """Points 1 mm apart on the plane z = tan(slope) x through the origin, with the disc of
    hole_mm about the origin missing (the probe's shadow) and Gaussian depth noise."""
    points = _plane(half=25.0)
    points[:, 2] = np.tan(np.radians(slope_deg)) * points[:, 0]
    points = points[np.linalg.norm(points, axis=1) > hole_mm]
    points[:, 2] += rng.normal(0.0, noise_mm, len(points))
    return points


CAMERA_ABOVE = np.array([10.0, -20.0, 500.0])


def test_the_touch_is_where_the_line_of_sight_meets_the_skin_around_the_shadow():
    rng = np.random.default_rng(3)
    skin = _sloped_skin(rng, 35.0, 5.0, 0.4)
    sight = -CAMERA_ABOVE / np.linalg.norm(CAMERA_ABOVE)  # through the touch at the origin
    centres = np.array([-5.5 * sight])  # the object's points hide the touch, in front of it
    # the model's node: on a surface 3 mm above the real one and 2 mm aside
    node = np.array([[2.0, 0.0, 3.0 + np.tan(np.radians(35.0)) * 2.0]])
    touch = touch_points(centres, CAMERA_ABOVE, cKDTree(skin), node)
    assert np.linalg.norm(touch[0]) < 0.3  # against the node's 3.5 mm
    # the skin, not the model, says where: a node 15 mm off (a model far from the body)
    # changes nothing
    aside = node + np.array([15.0, 0.0, 0.0])
    np.testing.assert_array_equal(touch_points(centres, CAMERA_ABOVE, cKDTree(skin), aside),
                                  touch)
    # no robot points there: the node
    far = cKDTree(skin + np.array([0.0, 0.0, 40.0]))
    np.testing.assert_array_equal(touch_points(centres, CAMERA_ABOVE, far, node), node)
    assert touch_points(np.zeros((0, 3)), CAMERA_ABOVE, cKDTree(skin),
                        np.zeros((0, 3))).shape == (0, 3)


def test_a_fold_or_a_skin_seen_edge_on_keeps_the_node():
    rng = np.random.default_rng(4)
    sight = -CAMERA_ABOVE / np.linalg.norm(CAMERA_ABOVE)
    centres = np.array([-5.5 * sight])
    node = np.array([[1.0, 1.0, 2.0]])
    # two faces meeting at the line (a ridge): no one plane within TOUCH_MAX_RMS_MM
    left, right = _sloped_skin(rng, 50.0, 0.0, 0.2), _sloped_skin(rng, -50.0, 0.0, 0.2)
    ridge = np.vstack([left[left[:, 0] < 0.0], right[right[:, 0] >= 0.0]])
    np.testing.assert_array_equal(touch_points(centres, CAMERA_ABOVE, cKDTree(ridge), node),
                                  node)
    # a wall along the line of sight, seen edge-on
    wall = _plane(half=25.0)[:, [2, 0, 1]]
    np.testing.assert_array_equal(touch_points(centres, CAMERA_ABOVE, cKDTree(wall), node),
                                  node)
