"""Contact location detection (paper Algorithm 2) and mapping to feature points."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from softforce_cli.vision.point_cloud import inside_box
from softforce_cli.vision.segmentation import Segmentation
from softforce_cli.vision.settings import VisionSettings


@dataclass(frozen=True, eq=False)
class DetectedContacts:
    """Where objects touch the robot in one frame.

    centres_mm        : (c, 3) float64 mean of each contact cluster (robot frame), largest
                        cluster first.
    point_counts      : (c,) int64 contact points in each cluster.
    contact_points_mm : (k, 3) float64 every object point found in contact (Algorithm 2's
                        contact points), clustered or not.
    """

    centres_mm: np.ndarray
    point_counts: np.ndarray
    contact_points_mm: np.ndarray

    def __len__(self) -> int:
        return len(self.centres_mm)


def euclidean_clusters(
    points_mm: np.ndarray, tolerance_mm: float, min_points: int
) -> tuple[np.ndarray, np.ndarray]:
    """Euclidean cluster extraction (PCL): points (n, 3) joined by chains of steps shorter
    than tolerance_mm -> labels (n,) int64 (-1 for clusters smaller than min_points), and
    the kept clusters' sizes (c,); clusters numbered from the largest down."""
    n = len(points_mm)
    if n == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    pairs = cKDTree(points_mm).query_pairs(tolerance_mm, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), (n, n))
    count, labels = connected_components(graph, directed=False)
    sizes = np.bincount(labels, minlength=count)
    # stable sort: equal sizes keep their component order, so the numbering is deterministic
    order = np.argsort(-sizes, kind="stable")
    order = order[sizes[order] >= min_points]
    rank = np.full(count, -1, dtype=np.int64)
    rank[order] = np.arange(len(order))
    return rank[labels], sizes[order]


def detect_contacts(
    segmentation: Segmentation,
    settings: VisionSettings = VisionSettings(),
    excluded_box_mm: np.ndarray | None = None,
) -> DetectedContacts:
    """Algorithm 2: object points with MORE than contact_min_neighbours robot points within
    contact_radius_mm are contact points; their Euclidean clusters (cluster_tolerance_mm, at
    least cluster_min_points) are the contacts, located at the cluster means.

    excluded_box_mm (6,), optional: the clamped region's box; contact points within
    contact_exclusion_mm of it are ignored (a fixture holding the base is not a load).
    """
    robot, objects = segmentation.robot.points_mm, segmentation.objects.points_mm
    none = DetectedContacts(np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros((0, 3)))
    if len(robot) == 0 or len(objects) == 0:
        return none
    neighbours = segmentation.robot_tree.query_ball_point(
        objects, settings.contact_radius_mm, return_length=True
    )
    contact = neighbours > settings.contact_min_neighbours
    if excluded_box_mm is not None:
        grown = np.asarray(excluded_box_mm, dtype=float) + settings.contact_exclusion_mm * (
            np.array([-1, -1, -1, 1, 1, 1])
        )
        contact &= ~inside_box(objects, grown)
    points = objects[contact]
    labels, sizes = euclidean_clusters(
        points, settings.cluster_tolerance_mm, settings.cluster_min_points
    )
    if len(sizes) == 0:
        return DetectedContacts(none.centres_mm, none.point_counts, points)
    kept = labels >= 0
    sums = np.stack([np.bincount(labels[kept], points[kept, a], len(sizes)) for a in range(3)],
                    axis=1)
    return DetectedContacts(sums / sizes[:, None], sizes, points)


def nearest_features(centres_mm: np.ndarray, feature_positions_mm: np.ndarray) -> np.ndarray:
    """Location mapping: the feature nearest to each contact centre.

    centres_mm (c, 3), feature_positions_mm (p, 3) current positions -> (c,) int64 indices
    into the features.
    """
    centres = np.asarray(centres_mm, dtype=float).reshape(-1, 3)
    if len(centres) == 0:
        return np.zeros(0, dtype=np.int64)
    _, index = cKDTree(np.asarray(feature_positions_mm, dtype=float)).query(centres)
    return np.asarray(index, dtype=np.int64)


# An object's points within this of a contact centre give its axis: long enough to cover
# 40 mm of a 10 mm probe or a finger, short enough to stay clear of a second object
# touching another bar of the Diamond 60 mm away.
AXIS_RADIUS_MM = 40.0
# The axis is taken when the points' spread along it is this many times their spread
# across (the ratio of the covariance's two largest eigenvalues): a rod seen over 40 mm
# gives about 20, a ball or a palm about 1.
AXIS_ELONGATION = 4.0


def object_axes(centres_mm: np.ndarray, object_points_mm: np.ndarray,
                radius_mm: float = AXIS_RADIUS_MM,
                elongation: float = AXIS_ELONGATION) -> np.ndarray:
    """The axis of the object touching at each contact: the principal direction of the
    object points within radius_mm of the centre, pointing from them towards the centre
    (the way an elongated object pushes) -> (c, 3) unit vectors, NaN where the points show
    no axis (fewer than 10, or not elongation times longer than wide).

    centres_mm (c, 3), object_points_mm (k, 3), robot frame.
    """
    centres = np.asarray(centres_mm, dtype=float).reshape(-1, 3)
    objects = np.asarray(object_points_mm, dtype=float).reshape(-1, 3)
    axes = np.full((len(centres), 3), np.nan)
    if len(objects) == 0:
        return axes
    near = cKDTree(objects).query_ball_point(centres, radius_mm)
    for k, indices in enumerate(near):
        if len(indices) < 10:
            continue
        points = objects[indices]
        mean = points.mean(axis=0)
        values, vectors = np.linalg.eigh(np.cov((points - mean).T))  # ascending
        if values[2] < elongation * values[1]:
            continue
        axis = vectors[:, 2]
        axes[k] = axis if axis @ (centres[k] - mean) >= 0 else -axis
    return axes
