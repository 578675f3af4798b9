"""Contact location detection (paper Algorithm 2), mapping to feature points and where a
contact touches the observed skin."""

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
                        cluster first, then the occluded tips (occluded_tips).
    point_counts      : (c,) int64 contact points in each cluster (0 for an occluded tip).
    contact_points_mm : (k, 3) float64 every object point found in contact (Algorithm 2's
                        contact points), clustered or not.
    occluded          : (c,) bool, True where the contact is an elongated object's hidden tip
                        (its axis extended to the robot), not Algorithm 2's contact points.
    """

    centres_mm: np.ndarray
    point_counts: np.ndarray
    contact_points_mm: np.ndarray
    occluded: np.ndarray

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
    camera_mm: np.ndarray | None = None,
) -> DetectedContacts:
    """Algorithm 2: object points with MORE than contact_min_neighbours robot points within
    contact_radius_mm are contact points; their Euclidean clusters (cluster_tolerance_mm, at
    least cluster_min_points) are the contacts, located at the cluster means. Then the
    occluded tips (occluded_tips, unless settings.occluded_tip_mm is 0): elongated objects
    with no contact point whose axis, extended, meets the robot.

    excluded_box_mm (6,), optional: the clamped region's box; contact points and occluded
    tips within contact_exclusion_mm of it are ignored (a fixture holding the base is not a
    load). camera_mm (3,), optional: the camera's position (robot frame), which puts an
    occluded tip on the object's axis rather than on its seen side (occluded_tips).
    """
    robot, objects = segmentation.robot.points_mm, segmentation.objects.points_mm
    if len(robot) == 0 or len(objects) == 0:
        return DetectedContacts(np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros((0, 3)),
                                np.zeros(0, dtype=bool))
    neighbours = segmentation.robot_tree.query_ball_point(
        objects, settings.contact_radius_mm, return_length=True
    )
    touching = neighbours > settings.contact_min_neighbours
    contact = touching.copy()
    if excluded_box_mm is not None:
        grown = np.asarray(excluded_box_mm, dtype=float) + settings.contact_exclusion_mm * (
            np.array([-1, -1, -1, 1, 1, 1])
        )
        contact &= ~inside_box(objects, grown)
    points = objects[contact]
    labels, sizes = euclidean_clusters(
        points, settings.cluster_tolerance_mm, settings.cluster_min_points
    )
    kept = labels >= 0
    sums = np.stack([np.bincount(labels[kept], points[kept, a], len(sizes)) for a in range(3)],
                    axis=1)
    centres, sizes = merge_close_clusters(sums / np.maximum(sizes, 1)[:, None], sizes,
                                          settings.contact_merge_mm)
    tips = np.zeros((0, 3))
    if settings.occluded_tip_mm > 0:
        # an object touching anywhere, the clamped box included, is Algorithm 2's: its axis
        # is not extended, so no object gives two contacts
        tips = occluded_tips(objects, object_regions(segmentation), touching,
                             segmentation.robot_tree, settings, camera_mm)
        if excluded_box_mm is not None:
            tips = tips[~inside_box(tips, grown)]
    return DetectedContacts(
        np.vstack([centres, tips]),
        np.concatenate([sizes, np.zeros(len(tips), dtype=np.int64)]),
        points,
        np.repeat([False, True], [len(centres), len(tips)]),
    )


def merge_close_clusters(centres_mm: np.ndarray, sizes: np.ndarray, distance_mm: float
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Clusters (c, 3) of sizes (c,) whose centres are joined by chains of steps shorter than
    distance_mm become one, at their point-weighted mean -> (centres (m, 3), sizes (m,)),
    largest first (0 merges nothing)."""
    if distance_mm <= 0 or len(centres_mm) < 2:
        return centres_mm, sizes
    labels, _ = euclidean_clusters(centres_mm, distance_mm, 1)
    count = labels.max() + 1
    merged_sizes = np.bincount(labels, sizes, count)
    sums = np.stack([np.bincount(labels, sizes * centres_mm[:, a], count) for a in range(3)],
                    axis=1)
    order = np.argsort(-merged_sizes, kind="stable")
    return (sums / merged_sizes[:, None])[order], merged_sizes[order].astype(np.int64)


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


# Where a contact is reported: the robot points within TOUCH_RADIUS_MM of the camera's line
# of sight through its centre, from TOUCH_BEFORE_MM before the centre to TOUCH_BEHIND_MM
# behind it, give the skin's plane there. The object hides the touch itself, so the points
# lie around it; 6 mm takes a ring of them beyond a 10 mm probe's shadow (4 mm: the same
# within 0.25 mm on the 12-location probes, docs/sensing_studies.md). The touch lay 4-7 mm
# behind the centre there; the segment stops short of another arm seen behind.
TOUCH_RADIUS_MM = 6.0
TOUCH_BEFORE_MM = 5.0
TOUCH_BEHIND_MM = 15.0
# Fewer robot points than this, a plane seen within this cosine of edge-on, points further
# than TOUCH_MAX_RMS_MM from their plane (two faces, not one: the D415's noise leaves
# 0.5-0.9 mm there), or a plane the line meets off the segment keep the model's node.
TOUCH_MIN_POINTS = 8
TOUCH_MIN_COSINE = 0.3
TOUCH_MAX_RMS_MM = 1.5


def touch_points(centres_mm: np.ndarray, camera_mm: np.ndarray, robot_tree: cKDTree,
                 nodes_mm: np.ndarray) -> np.ndarray:
    """(c, 3) mm where the camera's line of sight through each contact centre (c, 3) meets
    the observed skin, robot frame; nodes_mm (c, 3), the model's contact nodes, where the
    points do not show it.

    The skin there is the plane fitted (least squares) to the robot points of robot_tree
    within TOUCH_RADIUS_MM of the line, from TOUCH_BEFORE_MM before the centre to
    TOUCH_BEHIND_MM behind it. A contact centre is the mean of the object points seen
    touching, and the touch lies behind it on that line (estimation.sensing.contact_nodes);
    the model's node there sits where the model's surface is, which a body other than the
    model's (a finer mesh, a sagging rest shape) and the model's own dent under a point
    force put millimetres from the real touch: on the 12-location probes of a mesh-converged
    body, 4.0 mm at the median against 1.6 mm for the point on the observed skin
    (docs/sensing_studies.md). camera_mm (3,): the camera's position in the robot frame.
    """
    centres = np.asarray(centres_mm, dtype=float).reshape(-1, 3)
    touches = np.asarray(nodes_mm, dtype=float).reshape(-1, 3).copy()
    if not len(centres) or robot_tree.n == 0:
        return touches
    sight = centres - np.asarray(camera_mm, dtype=float)
    sight /= np.linalg.norm(sight, axis=1, keepdims=True)
    half = 0.5 * (TOUCH_BEFORE_MM + TOUCH_BEHIND_MM)
    middles = centres + (half - TOUCH_BEFORE_MM) * sight
    points_mm = robot_tree.data
    for k, near in enumerate(robot_tree.query_ball_point(middles, np.hypot(half,
                                                                           TOUCH_RADIUS_MM))):
        offset = points_mm[near] - centres[k]
        along = offset @ sight[k]
        across = np.linalg.norm(offset - np.outer(along, sight[k]), axis=1)
        skin = points_mm[near][(across < TOUCH_RADIUS_MM) & (along >= -TOUCH_BEFORE_MM)
                               & (along <= TOUCH_BEHIND_MM)]
        if len(skin) < TOUCH_MIN_POINTS:
            continue
        mean = skin.mean(axis=0)
        _, spread, axes = np.linalg.svd(skin - mean, full_matrices=False)
        normal = axes[2]
        facing = normal @ sight[k]
        if (abs(facing) < TOUCH_MIN_COSINE
                or spread[2] / np.sqrt(len(skin)) > TOUCH_MAX_RMS_MM):
            continue
        depth = (mean - centres[k]) @ normal / facing
        if -TOUCH_BEFORE_MM <= depth <= TOUCH_BEHIND_MM:
            touches[k] = centres[k] + depth * sight[k]
    return touches


# An object's points within this of a contact centre give its axis: long enough to cover
# 40 mm of a 10 mm probe or a finger, short enough to stay clear of a second object
# touching another bar of the Diamond 60 mm away.
AXIS_RADIUS_MM = 40.0
# The axis is taken when the points' spread along it is this many times their spread
# across (the ratio of the covariance's two largest eigenvalues): a rod seen over 40 mm
# gives about 20, a ball or a palm about 1.
AXIS_ELONGATION = 4.0
# Fewer object points than this show no axis.
AXIS_MIN_POINTS = 10


def object_axes(centres_mm: np.ndarray, object_points_mm: np.ndarray,
                radius_mm: float = AXIS_RADIUS_MM,
                elongation: float = AXIS_ELONGATION) -> np.ndarray:
    """The axis of the object touching at each contact: the principal direction of the
    object points within radius_mm of the centre, pointing from them towards the centre
    (the way an elongated object pushes) -> (c, 3) unit vectors, NaN where the points show
    no axis (fewer than AXIS_MIN_POINTS, or not elongation times longer than wide).

    centres_mm (c, 3), object_points_mm (k, 3), robot frame.
    """
    centres = np.asarray(centres_mm, dtype=float).reshape(-1, 3)
    objects = np.asarray(object_points_mm, dtype=float).reshape(-1, 3)
    axes = np.full((len(centres), 3), np.nan)
    if len(objects) == 0:
        return axes
    near = cKDTree(objects).query_ball_point(centres, radius_mm)
    for k, indices in enumerate(near):
        if len(indices) < AXIS_MIN_POINTS:
            continue
        points = objects[indices]
        mean = points.mean(axis=0)
        values, vectors = np.linalg.eigh(np.cov((points - mean).T))  # ascending
        if values[2] < elongation * values[1]:
            continue
        axis = vectors[:, 2]
        axes[k] = axis if axis @ (centres[k] - mean) >= 0 else -axis
    return axes


def object_regions(segmentation: Segmentation) -> np.ndarray:
    """(k,) int64 colour region of each object point (segmentation.objects' order): the
    segmentation's connected objects, which occluded_tips takes as the objects."""
    labels = segmentation.regions.labels
    is_object = labels >= 0
    is_object[is_object] = segmentation.object_regions[labels[is_object]]
    return labels[is_object]


def occluded_tips(objects_mm: np.ndarray, object_labels: np.ndarray, touching: np.ndarray,
                  robot_tree: cKDTree, settings: VisionSettings = VisionSettings(),
                  camera_mm: np.ndarray | None = None) -> np.ndarray:
    """Contacts whose tip the camera cannot see -> (t, 3) float64 meeting points, robot frame.

    objects_mm (k, 3) the object points, object_labels (k,) int64 the object each belongs to
    (>= 0: colour regions, object_regions), touching (k,) bool Algorithm 2's contact points
    among them, robot_tree a KD-tree of the robot points, camera_mm (3,) optional the camera's
    position. An object of at least AXIS_MIN_POINTS points with no touching point and an axis
    (principal direction, spread along it AXIS_ELONGATION times the spread across) is
    extended beyond its end nearer the robot, by occluded_tip_mm. When MORE than
    contact_min_neighbours robot points lie within contact_radius_mm of that extension (a
    cylinder around the line through the object's points), the object touches there, at the
    line's point at those robot points' mean axial position. With camera_mm that point is
    then moved onto the object's axis (the line runs along the object's seen side, about a
    radius off) and along the axis to the plane of the robot points around it (where the
    axis meets the robot's face).
    """
    objects = np.asarray(objects_mm, dtype=float).reshape(-1, 3)
    labels = np.asarray(object_labels, dtype=np.int64)
    if len(labels) != len(objects) or len(touching) != len(objects) or np.any(labels < 0):
        raise ValueError("occluded_tips: one label >= 0 and one touching flag per object point")
    count = int(labels.max(initial=-1)) + 1
    sizes = np.bincount(labels, minlength=count)
    candidate = (sizes >= AXIS_MIN_POINTS) & (np.bincount(labels[touching], minlength=count) == 0)
    if not candidate.any() or robot_tree.n == 0:
        return np.zeros((0, 3))
    means, covariances = _grouped_moments(objects, labels, count)
    values, vectors = np.linalg.eigh(covariances)  # ascending, per object
    candidate &= values[:, 2] >= AXIS_ELONGATION * values[:, 1]
    if not candidate.any():
        return np.zeros((0, 3))
    axes = vectors[:, :, 2]
    offsets = objects - means[labels]
    along = np.einsum("ni,ni->n", offsets, axes[labels])
    ends = np.stack([np.full(count, np.inf), np.full(count, -np.inf)], axis=1)
    np.minimum.at(ends[:, 0], labels, along)
    np.maximum.at(ends[:, 1], labels, along)
    which = np.flatnonzero(candidate)
    axes, means, ends = axes[which], means[which], ends[which]
    # both ends of each object; the one nearer the robot is where it would touch
    end_points = means[:, None, :] + ends[:, :, None] * axes[:, None, :]  # (m, 2, 3)
    gaps, _ = robot_tree.query(end_points.reshape(-1, 3))
    nearer = np.argmin(gaps.reshape(-1, 2), axis=1)
    rows = np.arange(len(which))
    starts = end_points[rows, nearer]
    directions = axes * np.where(nearer == 1, 1.0, -1.0)[:, None]
    length, radius = settings.occluded_tip_mm, settings.contact_radius_mm
    starts, through_touching = _through_pieces(starts, directions, objects, labels, which,
                                               touching, length, radius)
    # the line through the seen points meets the robot's surface seen beside the object (the
    # surface right under a tilted rod's tip is hidden by the rod itself)
    middles = starts + 0.5 * length * directions
    near = robot_tree.query_ball_point(middles, np.hypot(0.5 * length, radius))
    owner = np.repeat(rows, [len(n) for n in near])
    if len(owner) == 0:
        return np.zeros((0, 3))
    robot = robot_tree.data[np.concatenate(near).astype(np.int64)]
    relative = robot - starts[owner]
    axial = np.einsum("ni,ni->n", relative, directions[owner])
    across = np.linalg.norm(relative - axial[:, None] * directions[owner], axis=1)
    inside = (axial >= 0) & (axial <= length) & (across < radius)
    hits = np.bincount(owner[inside], minlength=len(rows))
    met = (hits > settings.contact_min_neighbours) & ~through_touching
    depth = np.bincount(owner[inside], axial[inside], len(rows))[met] / hits[met]
    tips = starts[met] + depth[:, None] * directions[met]
    if camera_mm is None or not met.any():
        return tips
    on_axis = _onto_axes(tips, axes[met], offsets, labels, which[met],
                         np.asarray(camera_mm, dtype=float))
    return _onto_faces(on_axis, directions[met], robot[inside], owner[inside], met, robot_tree,
                       radius)


# The most pieces of one object that occluded_tips follows its axis through.
PIECES_MAX = 3


def _through_pieces(starts: np.ndarray, directions: np.ndarray, objects: np.ndarray,
                    labels: np.ndarray, which: np.ndarray, touching: np.ndarray,
                    length_mm: float, radius_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(m, 3) each elongated object's end nearer the robot, starts (m, 3), moved along its
    direction (m, 3) to the furthest point of any other object within radius_mm of that
    line and length_mm beyond the end; (m,) bool where such a point belongs to an object
    with any of Algorithm 2's touching (k,) points. objects (k, 3), labels (k,), which (m,):
    the elongated objects' labels.

    A rod's tip can be seen as colour regions of its own: at 424x240 the last 10-20 points
    of an elbow probe on the 12-location probes lay 3-4 mm from the robot, split from the
    rest of the rod, whose end was 10-13 mm away, beyond occluded_tip_mm (3 of the 60
    contacts were missed so). The rod goes on from its pieces, up to PIECES_MAX of them in
    a row. A piece of an object that touches is Algorithm 2's contact already, and the rod
    gives none of its own.
    """
    moved = starts.copy()
    through_touching = np.zeros(len(starts), dtype=bool)
    touches = np.bincount(labels[touching], minlength=labels.max(initial=-1) + 1) > 0
    tree = cKDTree(objects)
    reach = np.hypot(0.5 * length_mm, radius_mm)
    for m in range(len(starts)):
        for _ in range(PIECES_MAX):
            near = np.asarray(tree.query_ball_point(moved[m] + 0.5 * length_mm * directions[m],
                                                    reach), dtype=np.int64)
            near = near[labels[near] != which[m]]
            relative = objects[near] - moved[m]
            axial = relative @ directions[m]
            across = np.linalg.norm(relative - np.outer(axial, directions[m]), axis=1)
            ahead = (axial > 0) & (axial <= length_mm) & (across < radius_mm)
            if not ahead.any():
                break
            moved[m] += axial[ahead].max() * directions[m]
            through_touching[m] |= touches[labels[near[ahead]]].any()
    return moved, through_touching


def _onto_axes(tips: np.ndarray, axes: np.ndarray, offsets: np.ndarray, labels: np.ndarray,
               objects: np.ndarray, camera_mm: np.ndarray) -> np.ndarray:
    """(t, 3) the tips (t, 3), met on the line along each object's seen side, moved onto its
    axis (t, 3): objects (t,) the objects' labels, offsets (k, 3) and labels (k,) every object
    point's offset from its object's mean and its object, camera_mm (3,).

    The camera sees the half of a rod that faces it, so that line lies about one radius
    from the rod's axis, towards the camera (4.5-5 mm for the sample's 5 mm probes); the
    radius is the object's half-width across the view (its points spread evenly across)."""
    count = int(labels.max(initial=-1)) + 1
    sizes = np.maximum(np.bincount(labels, minlength=count), 1)
    towards = camera_mm - tips
    towards -= np.einsum("ni,ni->n", towards, axes)[:, None] * axes
    norms = np.linalg.norm(towards, axis=1, keepdims=True)
    towards = np.divide(towards, norms, out=np.zeros_like(towards), where=norms > 0)
    sideways = np.zeros((count, 3))
    sideways[objects] = np.cross(axes, towards)
    lateral = np.einsum("ni,ni->n", offsets, sideways[labels])
    half_widths = np.sqrt(3.0 * np.bincount(labels, lateral**2, count) / sizes)
    depths = np.sqrt(np.maximum(half_widths[labels]**2 - lateral**2, 0.0))
    shifts = np.bincount(labels, depths, count) / sizes
    return tips - shifts[objects, None] * towards


def _onto_faces(tips: np.ndarray, directions: np.ndarray, hits_mm: np.ndarray,
                hit_owners: np.ndarray, met: np.ndarray, robot_tree: cKDTree, radius: float
                ) -> np.ndarray:
    """(t, 3) the tips (t, 3) moved along their objects' directions (t, 3) to the plane of the
    robot points around where each line met the robot: hits_mm (h, 3) those robot points,
    hit_owners (h,) the candidate object of each (its index in met (m,) bool, the candidates
    that met the robot), radius the contact radius (mm).

    The seen side's line meets a face pressed obliquely at another depth than the axis does
    (3.5 mm off for a rod 38 degrees from the face's normal): move along the axis to the
    plane of the robot points within 2 r_search of where the line met them, by at most
    r_search (a patch over an edge gives a rough plane)."""
    hit_means = _grouped_moments(hits_mm, hit_owners, len(met))[0][met]
    around = robot_tree.query_ball_point(hit_means, 2 * radius)  # each holds the hits
    patch_means, patch_covariances = _grouped_moments(
        robot_tree.data[np.concatenate(around).astype(np.int64)],
        np.repeat(np.arange(len(around)), [len(n) for n in around]), len(around))
    normals = np.linalg.eigh(patch_covariances)[1][:, :, 0]
    cosines = np.einsum("ni,ni->n", directions, normals)
    steps = np.einsum("ni,ni->n", patch_means - tips, normals) / np.where(
        np.abs(cosines) > 1e-9, cosines, np.inf)  # an axis along the face: no step
    return tips + np.clip(steps, -radius, radius)[:, None] * directions


def _grouped_moments(points: np.ndarray, labels: np.ndarray, count: int
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Mean (count, 3) and covariance (count, 3, 3) of the points (n, 3) of each label (n,)
    in 0..count-1 (zero for a label without points)."""
    sizes = np.maximum(np.bincount(labels, minlength=count), 1)
    means = np.stack([np.bincount(labels, points[:, a], count) for a in range(3)], axis=1)
    means /= sizes[:, None]
    offsets = points - means[labels]
    products = (offsets[:, :, None] * offsets[:, None, :]).reshape(-1, 9)
    covariances = np.stack([np.bincount(labels, products[:, j], count) for j in range(9)],
                           axis=1).reshape(count, 3, 3) / sizes[:, None, None]
    return means, covariances
