"""Algorithm 2 (contact points, Euclidean clusters) and location mapping, on known layouts."""

from __future__ import annotations

import numpy as np

from softforce_cli.vision.contacts import detect_contacts, euclidean_clusters, nearest_features
from softforce_cli.vision.point_cloud import PointCloud
from softforce_cli.vision.segmentation import Regions, Segmentation
from softforce_cli.vision.settings import VisionSettings


def _segmentation(robot_mm: np.ndarray, objects_mm: np.ndarray) -> Segmentation:
    def cloud(points):
        return PointCloud(points, np.zeros((len(points), 3), dtype=np.uint8))

    empty = Regions(np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros(0, dtype=np.int64))
    return Segmentation(cloud(robot_mm), cloud(objects_mm), empty, np.zeros(0, dtype=bool))


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
