"""Feature point matching along the model's surface normals (paper Algorithm 3).

For each feature x_e with unit normal n_e, the robot point x_c nearest to the normal line
{x_e + t n_e} is its match. The paper searches the whole robot cloud; here candidates are the
robot points within match_search_mm of x_e, because the line through one arm of a robot such
as the Diamond also crosses the other arms and the apex far away, where the nearest point to
the line would be a wrong match. A feature is hidden when no candidate lies within d_m of the
line, and its match rejected (mis-segmented) when further than d_l from x_e.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from softforce_cli.vision.settings import VisionSettings


@dataclass(frozen=True, eq=False)
class FeatureMatches:
    """Matches of p feature points in the robot's cloud; NaN where a feature is not matched.

    matched          : (p,) bool, usable for force computation.
    hidden           : (p,) bool, no robot point within d_m of the normal line (occluded, out
                       of view, or facing away from the camera).
    rejected         : (p,) bool, a match within d_m of the line but further than d_l from
                       the feature: mis-segmented, discarded.
    points_mm        : (p, 3) float64 matched observed point x_c.
    normal_mm        : (p,) float64 x_c . n_e, the observed position along the normal (the
                       paper's delta_c^N entries).
    offset_mm        : (p,) float64 (x_c - x_e) . n_e, the feature's observed displacement
                       along its normal (outward positive).
    line_distance_mm : (p,) float64 d_mini, distance of the best candidate from the normal
                       line; NaN where no robot point came within about 1.1 d_m of it.
    """

    matched: np.ndarray
    hidden: np.ndarray
    rejected: np.ndarray
    points_mm: np.ndarray
    normal_mm: np.ndarray
    offset_mm: np.ndarray
    line_distance_mm: np.ndarray

    @property
    def matched_count(self) -> int:
        return int(np.count_nonzero(self.matched))

    @property
    def hidden_count(self) -> int:
        return int(np.count_nonzero(self.hidden))


def match_features(
    feature_positions_mm: np.ndarray,
    normals: np.ndarray,
    robot_points_mm: np.ndarray,
    settings: VisionSettings = VisionSettings(),
    camera_mm: np.ndarray | None = None,
    robot_tree: cKDTree | None = None,
) -> FeatureMatches:
    """Algorithm 3 for features (p, 3) mm with unit outward normals (p, 3) against the robot
    cloud X_r (n, 3) mm -> FeatureMatches.

    camera_mm (3,), optional: the camera's position in the robot frame (robot_from_camera's
    translation). Features whose normal points away from it are hidden: the camera cannot see
    that side, and the normal line would meet the opposite face of the body instead. Features
    seen nearly edge-on (normal more than match_max_view_deg from the line of sight) are
    hidden unless their observed point lies within match_grazing_mm of them along the normal:
    the camera samples such a face sparsely, and the line can meet the opposite face of a
    thin part first.
    robot_tree, optional: a cKDTree of robot_points_mm (Segmentation.robot_tree), reused.
    """
    features = np.asarray(feature_positions_mm, dtype=float).reshape(-1, 3)
    normals = np.asarray(normals, dtype=float).reshape(-1, 3)
    robot = np.asarray(robot_points_mm, dtype=float).reshape(-1, 3)
    p = len(features)
    visible = np.ones(p, dtype=bool)
    grazing = np.zeros(p, dtype=bool)
    if camera_mm is not None:
        sight = np.asarray(camera_mm, dtype=float) - features
        towards = np.einsum("ij,ij->i", sight, normals) / np.linalg.norm(sight, axis=1)
        visible = towards > 0
        grazing = towards < np.cos(np.radians(settings.match_max_view_deg))
    best, line, mean = _nearest_to_lines(features, normals, visible, robot, settings,
                                         robot_tree)
    near_line = visible & (best >= 0) & (line <= settings.match_line_mm)
    along = np.abs(np.einsum("ij,ij->i", mean - features, normals))
    near_line[grazing & near_line] = along[grazing & near_line] <= settings.match_grazing_mm
    found = np.full((p, 3), np.nan)
    found[near_line] = mean[near_line]
    too_far = near_line & (np.linalg.norm(found - features, axis=1) > settings.match_limit_mm)
    matched = near_line & ~too_far
    points = np.where(matched[:, None], found, np.nan)
    return FeatureMatches(
        matched=matched,
        hidden=~near_line,
        rejected=too_far,
        points_mm=points,
        normal_mm=np.einsum("ij,ij->i", points, normals),
        offset_mm=np.einsum("ij,ij->i", points - features, normals),
        line_distance_mm=line,
    )


def _nearest_to_lines(
    features: np.ndarray,
    normals: np.ndarray,
    active: np.ndarray,
    robot: np.ndarray,
    settings: VisionSettings,
    robot_tree: cKDTree | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each active feature, the robot point nearest to its normal line among those within
    match_search_mm of the feature -> index (p,) int64 (-1: none), distance (p,) mm (NaN),
    and the observed point (p, 3) mm (NaN): the mean of the candidates within match_mean_mm
    of the line and within match_line_mm along it of the nearest one (that point alone when
    none other is).

    Only points near the line can match, so candidates come from balls around samples of the
    line at steps of match_line_mm: every point within match_line_mm of the line (and within
    match_search_mm along it) is within sqrt(d_m^2 + (d_m / 2)^2) of a sample. A third of the
    pairs of a ball of match_search_mm around each feature.
    """
    p = len(features)
    best = np.full(p, -1, dtype=np.int64)
    line = np.full(p, np.nan)
    mean = np.full((p, 3), np.nan)
    index = np.flatnonzero(active)
    if len(robot) == 0 or len(index) == 0:
        return best, line, mean
    step = settings.match_line_mm
    count = int(np.ceil(settings.match_search_mm / step))
    offsets = step * np.arange(-count, count + 1)
    samples = features[index, None, :] + offsets[None, :, None] * normals[index, None, :]
    radius = float(np.hypot(settings.match_line_mm, step / 2))
    sample_pairs = cKDTree(samples.reshape(-1, 3)).sparse_distance_matrix(
        cKDTree(robot) if robot_tree is None else robot_tree, radius, output_type="ndarray"
    )
    # a point near two samples of the same line is one candidate (pairs as one integer key:
    # a 1D unique sorts four times faster than a row-wise one)
    keys = np.unique(index[sample_pairs["i"] // len(offsets)] * len(robot)
                     + sample_pairs["j"].astype(np.int64))
    i, j = np.divmod(keys, len(robot))
    relative = np.take(robot, j, axis=0) - np.take(features, i, axis=0)
    along = np.einsum("ij,ij->i", relative, np.take(normals, i, axis=0))
    squared = np.einsum("ij,ij->i", relative, relative)
    in_reach = squared <= settings.match_search_mm**2
    i, j, along = i[in_reach], j[in_reach], along[in_reach]
    to_line = np.sqrt(np.maximum(squared[in_reach] - along**2, 0.0))
    order = np.lexsort((to_line, i))  # by feature, nearest to the line first
    first = order[np.unique(i[order], return_index=True)[1]]
    best[i[first]] = j[first]
    line[i[first]] = to_line[first]
    nearest_along = np.full(p, np.nan)
    nearest_along[i[first]] = along[first]
    keep = (to_line <= settings.match_mean_mm) & (
        np.abs(along - nearest_along[i]) <= settings.match_line_mm)
    keep[first] = True
    counts = np.bincount(i[keep], minlength=p)
    sums = np.stack([np.bincount(i[keep], robot[j[keep], a], p) for a in range(3)], axis=1)
    has = counts > 0
    mean[has] = sums[has] / counts[has, None]
    return best, line, mean
