"""Colour region growing (as PCL's RegionGrowingRGB) to split the robot from other objects.

Regions grow over a radius graph: points closer than a neighbour distance whose colours are
close are joined (connected components of the graph, not a seeded queue: same regions, no
Python loop over points). Neighbouring regions with close mean colours are then merged, and
regions below a minimum size join the neighbouring region they touch most, or are dropped when
isolated. A region is robot when its mean colour is close to the robot's colour.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from softforce_cli.errors import SensingError
from softforce_cli.vision.filters import radius_pairs
from softforce_cli.vision.point_cloud import PointCloud
from softforce_cli.vision.settings import VisionSettings

# A robot colour within this angle of grey (in RGB) spans no plane with a white highlight:
# its highlights are its own shades, brighter (segmentation._highlighted)
MIN_SATURATION_DEG = 10.0
# RMS colour noise of an RGB-D camera's colour stream, levels per channel (the D415's, as
# the virtual camera draws it): it turns the direction of a dark colour in RGB
COLOUR_NOISE_LEVELS = 2.0


@dataclass(frozen=True, eq=False)
class Regions:
    """A partition of a cloud's points into colour regions.

    labels : (n,) int64 region of each point, -1 for points of dropped (isolated, small)
             regions.
    colors : (r, 3) float64 mean RGB of each region.
    sizes  : (r,) int64 points in each region.
    """

    labels: np.ndarray
    colors: np.ndarray
    sizes: np.ndarray

    @property
    def count(self) -> int:
        return len(self.sizes)


@dataclass(frozen=True, eq=False)
class Segmentation:
    """The robot's points X_r and the other objects' points X_o of one cloud.

    robot, objects : the two clouds; points of dropped regions and of rims are in neither.
    regions        : the colour regions they came from (labels index the input cloud).
    robot_regions  : (r,) bool, which regions are robot.
    rim_regions    : (r,) bool, which other regions are the robot's rim (segment_robot),
                     None: none.
    robot_tree     : a KD-tree of the robot points, built once (here when not given) for the
                     rims, contact detection and every feature matching of the frame.
    """

    robot: PointCloud
    objects: PointCloud
    regions: Regions
    robot_regions: np.ndarray
    rim_regions: np.ndarray | None = None
    robot_tree: cKDTree | None = None

    def __post_init__(self) -> None:
        if self.robot_tree is None:
            object.__setattr__(self, "robot_tree", cKDTree(self.robot.points_mm))

    @cached_property
    def object_regions(self) -> np.ndarray:
        """(r,) bool, which regions are objects: neither robot nor rim."""
        rims = np.zeros_like(self.robot_regions) if self.rim_regions is None else self.rim_regions
        return ~self.robot_regions & ~rims

    @property
    def dropped_points(self) -> int:
        return int(np.count_nonzero(self.regions.labels < 0))


def _components(n: int, pairs: np.ndarray) -> tuple[int, np.ndarray]:
    """Connected components of n nodes joined by pairs (m, 2) -> (count, labels (n,))."""
    graph = coo_matrix((np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), (n, n))
    return connected_components(graph, directed=False)


def _means(labels: np.ndarray, count: int, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean of values (n, 3) per label (n,) in 0..count-1 -> (count, 3), sizes (count,)."""
    sizes = np.bincount(labels, minlength=count)
    sums = np.stack([np.bincount(labels, values[:, a], count) for a in range(3)], axis=1)
    return sums / np.maximum(sizes, 1)[:, None], sizes


def _region_pairs(
    labels: np.ndarray, count: int, pairs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Distinct neighbouring region pairs (q, 2), i < j, and how many point pairs join each."""
    a, b = labels[pairs[:, 0]], labels[pairs[:, 1]]
    low, high = np.minimum(a, b), np.maximum(a, b)
    between = low != high
    key, counts = np.unique(low[between] * count + high[between], return_counts=True)
    return np.stack([key // count, key % count], axis=1), counts


def _same_hue(first: np.ndarray, second: np.ndarray, first_norm: np.ndarray,
              second_norm: np.ndarray, hue_deg: float,
              counts: np.ndarray | float = 1.0) -> np.ndarray:
    """(m,) bool: which pairs of colours (m, 3), (m, 3) of norms (m,), (m,) point within
    hue_deg of each other in RGB, or within what the camera's colour noise turns colours
    that dark (three standard deviations; for means of `counts` (m,) points each, sqrt(counts)
    times less)."""
    with np.errstate(divide="ignore"):
        noise = (3.0 * np.sqrt(2.0) * COLOUR_NOISE_LEVELS) / (
            np.minimum(first_norm, second_norm) * np.sqrt(counts))
    allowed = np.maximum(np.radians(hue_deg), np.minimum(noise, np.pi))
    return np.einsum("ij,ij->i", first, second) >= np.cos(allowed) * first_norm * second_norm


def _norms(colors: np.ndarray) -> np.ndarray:
    """(n,) Euclidean norms of colours (n, 3): their brightness in RGB levels."""
    return np.sqrt(np.einsum("ij,ij->i", colors, colors))


def grow_regions(
    points_mm: np.ndarray,
    colors: np.ndarray,
    neighbour_mm: float,
    point_threshold: float,
    region_threshold: float,
    min_points: int,
    pairs: np.ndarray | None = None,
    hue_deg: float = 0.0,
) -> Regions:
    """Colour region growing on points (n, 3) mm with colours (n, 3) (RGB levels).

    1. Points closer than neighbour_mm whose colours differ by less than point_threshold
       (Euclidean RGB) are in one region (connected components).
    2. Neighbouring regions whose mean colours differ by less than region_threshold merge.
    3. A region of fewer than min_points points joins the neighbouring region of at least
       min_points with which it shares the most neighbour pairs; with none, it is dropped.
    In 1 and 2 two colours must also point within hue_deg of each other in RGB, or within
    what the colour noise turns colours that dark (0: not tested): in the dark, two paints
    differ by fewer levels than the Euclidean thresholds, but still by their direction.
    """
    n = len(points_mm)
    if n == 0:
        return Regions(np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros(0, dtype=np.int64))
    if pairs is None:
        pairs = radius_pairs(points_mm, neighbour_mm)
    rgb = colors.astype(np.float32)
    one, other = pairs[:, 0].copy(), pairs[:, 1].copy()
    first, second = np.take(rgb, one, axis=0), np.take(rgb, other, axis=0)
    difference = first - second
    similar = np.einsum("ij,ij->i", difference, difference) < point_threshold**2
    if hue_deg > 0.0:
        norms = _norms(rgb)
        similar &= _same_hue(first, second, np.take(norms, one), np.take(norms, other),
                             hue_deg)
    count, labels = _components(n, pairs[similar])
    # 2. merge regions of close mean colour
    means, sizes = _means(labels, count, rgb)
    neighbours, _ = _region_pairs(labels, count, pairs)
    gap = np.linalg.norm(means[neighbours[:, 0]] - means[neighbours[:, 1]], axis=1)
    close = gap < region_threshold
    if hue_deg > 0.0:
        a, b = neighbours[:, 0], neighbours[:, 1]
        norms = _norms(means)
        close &= _same_hue(means[a], means[b], norms[a], norms[b], hue_deg,
                           np.minimum(sizes[a], sizes[b]))
    count, merged = _components(count, neighbours[close])
    labels = merged[labels]
    # 3. small regions into their most connected large neighbour
    sizes = np.bincount(labels, minlength=count)
    neighbours, shared = _region_pairs(labels, count, pairs)
    small = sizes < min_points
    both = np.concatenate([neighbours, neighbours[:, ::-1]])
    weight = np.concatenate([shared, shared]).astype(float)
    into_large = small[both[:, 0]] & ~small[both[:, 1]]
    target = np.where(small, -1, np.arange(count))
    if into_large.any():
        links = coo_matrix(
            (weight[into_large], (both[into_large, 0], both[into_large, 1])), (count, count)
        ).tocsr()
        rows = np.flatnonzero(small & (links.getnnz(axis=1) > 0))
        target[rows] = np.asarray(links[rows].argmax(axis=1)).ravel()
    labels = target[labels]
    # compact numbering of the regions that remain
    kept, labels_kept = np.unique(labels[labels >= 0], return_inverse=True)
    final = np.full(n, -1, dtype=np.int64)
    final[labels >= 0] = labels_kept
    means, sizes = _means(final[final >= 0], len(kept), rgb[final >= 0].astype(float))
    return Regions(final, means, sizes)


def segment_robot(
    cloud: PointCloud,
    robot_rgb: np.ndarray,
    settings: VisionSettings = VisionSettings(),
    pairs: np.ndarray | None = None,
) -> Segmentation:
    """Split a filtered cloud into robot X_r and objects X_o by colour region growing.

    robot_rgb (3,): the robot's colour (given, or learn_robot_colour). A region whose mean
    colour is the robot's paint (robot_paint) is robot; any other is object, unless none of
    its points lies further than settings.rim_mm from a robot point: such a region is the
    robot's own rim in another colour (a depth camera bleeds the nearer depth a pixel or two
    into the background beside an edge, a colour image registered a pixel off the depth
    paints the edge in the background's colour, a marker sticker lies on the skin), in
    neither cloud.
    pairs (m, 2), optional: the cloud's point pairs at most region_neighbour_mm apart.
    """
    regions = grow_regions(
        cloud.points_mm,
        cloud.colors,
        settings.region_neighbour_mm,
        settings.point_colour_threshold,
        settings.region_colour_threshold,
        settings.min_region_points,
        pairs,
        settings.region_hue_deg,
    )
    robot_regions = robot_paint(regions.colors, robot_rgb, settings)
    labels = regions.labels
    kept = labels >= 0
    is_robot = np.zeros(len(cloud), dtype=bool)
    is_robot[kept] = robot_regions[labels[kept]]
    robot = cloud.subset(is_robot)
    robot_tree = cKDTree(robot.points_mm)
    is_object = kept & ~is_robot
    rim_regions = _rims(cloud.points_mm, labels, is_object, regions.count, robot_tree,
                        settings.rim_mm)
    is_object[is_object] = ~rim_regions[labels[is_object]]
    return Segmentation(
        robot=robot,
        objects=cloud.subset(is_object),
        regions=regions,
        robot_regions=robot_regions,
        rim_regions=rim_regions,
        robot_tree=robot_tree,
    )


def _rims(points_mm: np.ndarray, labels: np.ndarray, is_object: np.ndarray, count: int,
          robot_tree: cKDTree, rim_mm: float) -> np.ndarray:
    """(count,) bool: the regions of objects none of whose points lies further than rim_mm
    from robot_tree's points; points_mm (n, 3), their region labels (n,), is_object (n,)."""
    rims = np.zeros(count, dtype=bool)
    if rim_mm == 0.0 or robot_tree.n == 0 or not is_object.any():
        return rims
    gaps, _ = robot_tree.query(points_mm[is_object], distance_upper_bound=rim_mm)
    rims[np.unique(labels[is_object])] = True
    rims[labels[is_object][np.isinf(gaps)]] = False  # a point beyond rim_mm
    return rims


def robot_paint(colors: np.ndarray, robot_rgb: np.ndarray,
                settings: VisionSettings = VisionSettings()) -> np.ndarray:
    """(r,) bool: which colours (r, 3) RGB levels are the robot's paint: within
    settings.robot_colour_tolerance of robot_rgb (3,), or robot_rgb shaded by a white light,
    pointing within robot_hue_deg of it at robot_min_shade to robot_max_shade times its
    brightness, or so shaded under a white highlight (_highlighted)."""
    colors = np.asarray(colors, dtype=float).reshape(-1, 3)
    robot = np.asarray(robot_rgb, dtype=float)
    near = np.linalg.norm(colors - robot, axis=1) < settings.robot_colour_tolerance
    if settings.robot_hue_deg == 0.0:
        return near
    brightness, robot_brightness = np.linalg.norm(colors, axis=1), np.linalg.norm(robot)
    shade = brightness / max(robot_brightness, 1e-9)
    aligned = colors @ robot >= np.cos(np.radians(settings.robot_hue_deg)) * np.maximum(
        brightness * robot_brightness, 1e-9)
    shaded = aligned & (shade >= settings.robot_min_shade) & (shade <= settings.robot_max_shade)
    return near | shaded | _highlighted(colors, robot, settings)


def _highlighted(colors: np.ndarray, robot: np.ndarray, settings: VisionSettings) -> np.ndarray:
    """(r,) bool: colours (r, 3) that are the robot colour (3,) shaded under a white
    highlight. A glossy surface reflects a white light's colour at its surface on top of its
    paint's (the dichromatic reflection model, Shafer 1985): a robot + b (1, 1, 1), here with
    a from robot_min_shade to robot_max_shade, b >= 0, within robot_hue_deg of that plane.
    None for a robot colour within MIN_SATURATION_DEG of grey, whose highlights are its own
    shades (the shaded rule's)."""
    white = np.ones(3)
    if robot @ white < np.cos(np.radians(MIN_SATURATION_DEG)) * np.linalg.norm(robot) * np.sqrt(3):
        basis = np.column_stack([robot, white])
        (body, surface), *_ = np.linalg.lstsq(basis, colors.T, rcond=None)
        off_plane = np.linalg.norm(colors - (basis @ np.vstack([body, surface])).T, axis=1)
        return ((off_plane <= np.sin(np.radians(settings.robot_hue_deg))
                 * np.linalg.norm(colors, axis=1))
                & (body >= settings.robot_min_shade) & (body <= settings.robot_max_shade)
                & (surface >= 0.0))
    return np.zeros(len(colors), dtype=bool)


def learn_robot_colour(
    cloud: PointCloud, model_surface_points_mm: np.ndarray, max_distance_mm: float = 3.0,
    min_points: int = 50,
) -> np.ndarray:
    """The robot's colour seen in a frame: (3,) float64 median RGB of the cloud's points within
    max_distance_mm of the predicted robot surface.

    model_surface_points_mm (k, 3): points on the model's current surface (its surface nodes,
    and face centroids where the mesh is coarse). Use a frame where nothing touches the robot;
    the median ignores the few object or table points that still come close. SensingError when
    fewer than min_points points are near the model (robot not in view, or a wrong calibration).
    """
    surface = np.asarray(model_surface_points_mm, dtype=float).reshape(-1, 3)
    if len(cloud) == 0 or len(surface) == 0:
        raise SensingError("no point of the frame lies on the robot model: check that the "
                           "robot is in view and the calibration belongs to this camera")
    distance, _ = cKDTree(surface).query(cloud.points_mm, distance_upper_bound=max_distance_mm)
    near = np.isfinite(distance)
    if np.count_nonzero(near) < min_points:
        raise SensingError(
            f"only {np.count_nonzero(near)} points of the frame lie within {max_distance_mm} mm "
            "of the robot model: check that the robot is in view and the calibration belongs "
            "to this camera"
        )
    return np.median(cloud.colors[near].astype(float), axis=0)
