"""The whole vision stage of one frame: depth and colour in, contacts and matches out.

decimation of a fine frame (decimation.py, timed with the cloud) -> table plane (fitted on
a sample of the crop) -> cloud (crop, PassThrough, and table removal while back-projecting)
-> VoxelGrid -> RadiusOutlier -> colour segmentation -> contacts
(Algorithm 2, and the elongated objects whose tip is hidden) -> feature matching (Algorithm
3), each stage timed. Up to the contacts the stages need nothing of the FE model but a crop
box (observe_frame); the nearest features and the matching need the current feature
geometry (match_observation), so a sensor can run the first part of the next frame while
its model settles on this one. The table goes before the VoxelGrid, unlike the other filters'
paper order: it is most of the points in the crop box, and every later stage costs less
without it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.camera.intrinsics import CameraIntrinsics
from softforce_cli.vision.contacts import DetectedContacts, detect_contacts, nearest_features
from softforce_cli.vision.decimation import decimate_frame
from softforce_cli.vision.depth_edges import bled_pixels
from softforce_cli.vision.feature_matching import FeatureMatches, match_features
from softforce_cli.vision.filters import (
    crop_box_from_bounds,
    fit_table_plane,
    radius_pairs,
    remove_radius_outliers_with_pairs,
    voxel_downsample,
)
from softforce_cli.vision.point_cloud import PointCloud, box_pixels, cloud_from_frame
from softforce_cli.vision.segmentation import Segmentation, segment_robot
from softforce_cli.vision.settings import VisionSettings, settings_for_frame

# The table plane is fitted to every third pixel row and column of the crop: a ninth of the
# pixels, still thousands of table points, so RANSAC and the least-squares refit lose nothing.
TABLE_STRIDE = 3
# observe_frame's stages (no feature geometry needed), then match_observation's
OBSERVED_STAGES = ("table", "cloud", "voxel", "outliers", "segmentation", "contacts")
STAGES = (*OBSERVED_STAGES, "matching")


@dataclass(frozen=True, eq=False)
class Observation:
    """What one frame shows, before the model is consulted: the stages up to the contacts,
    which depend on the FE configuration only through the crop box.

    cloud       : the filtered cloud that was segmented.
    table_plane : (unit normal (3,), offset) of the removed table, or None.
    settings    : the vision settings used (scaled to the camera), which matching uses too.
    camera_mm   : (3,) the camera's position (robot frame).
    timings_ms  : milliseconds per stage (OBSERVED_STAGES).
    """

    cloud: PointCloud
    segmentation: Segmentation
    contacts: DetectedContacts
    table_plane: tuple[np.ndarray, float] | None
    settings: VisionSettings
    camera_mm: np.ndarray
    timings_ms: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class VisionResult:
    """Everything the vision stage found in one frame.

    cloud            : the filtered cloud that was segmented.
    contact_features : (c,) int64 nearest feature of each contact centre.
    table_plane      : (unit normal (3,), offset) of the removed table, or None.
    timings_ms       : milliseconds per stage (STAGES), and "total".
    """

    cloud: PointCloud
    segmentation: Segmentation
    contacts: DetectedContacts
    contact_features: np.ndarray
    matches: FeatureMatches
    table_plane: tuple[np.ndarray, float] | None
    timings_ms: dict[str, float] = field(default_factory=dict)


def robot_distance_mm(model_bounds_mm: np.ndarray, robot_from_camera: RigidTransform
                      ) -> float:
    """mm from the camera to the centre of the model's bounds (2, 3) [min, max], robot frame
    (the distance settings_for_camera scales the neighbour counts for)."""
    centre = np.asarray(model_bounds_mm, dtype=float).reshape(2, 3).mean(axis=0)
    return float(np.linalg.norm(centre - robot_from_camera.translation_mm))


def process_frame(
    depth_mm: np.ndarray,
    color: np.ndarray,
    intrinsics: CameraIntrinsics,
    robot_from_camera: RigidTransform,
    model_bounds_mm: np.ndarray,
    feature_positions_mm: np.ndarray,
    feature_normals: np.ndarray,
    robot_rgb: np.ndarray,
    settings: VisionSettings = VisionSettings(),
    excluded_box_mm: np.ndarray | None = None,
    table_plane: tuple[np.ndarray, float] | None = None,
) -> VisionResult:
    """One frame through the vision stage: observe_frame, then match_observation.

    depth_mm (h, w) uint16, color (h, w, 3) uint8; model_bounds_mm (2, 3) [min, max] of the
    model's current shape (robot frame); feature_positions_mm (p, 3) and feature_normals
    (p, 3) at the current shape; robot_rgb (3,); excluded_box_mm (6,) the clamped region.
    A fine frame is decimated, and the neighbour counts of settings are scaled to the camera
    (its focal length, and its distance to the model's bounds) unless
    settings.scale_to_camera is False (settings.settings_for_frame).
    table_plane: a previous frame's VisionResult.table_plane, to skip fitting it again when
    the camera does not move (saves 2-5 ms a frame); None fits it on this frame.
    """
    observation = observe_frame(depth_mm, color, intrinsics, robot_from_camera,
                                model_bounds_mm, robot_rgb, settings, excluded_box_mm,
                                table_plane)
    return match_observation(observation, feature_positions_mm, feature_normals)


def observe_frame(
    depth_mm: np.ndarray,
    color: np.ndarray,
    intrinsics: CameraIntrinsics,
    robot_from_camera: RigidTransform,
    model_bounds_mm: np.ndarray,
    robot_rgb: np.ndarray,
    settings: VisionSettings = VisionSettings(),
    excluded_box_mm: np.ndarray | None = None,
    table_plane: tuple[np.ndarray, float] | None = None,
) -> Observation:
    """The stages of process_frame (same arguments) that need no feature geometry: the
    decimation of a fine frame, table, cloud, filters, segmentation, contacts. A sensor runs
    them on the next frame while its FE model settles on this one (estimation.lookahead)."""
    clock = _Clock()
    bounds = np.asarray(model_bounds_mm, dtype=float).reshape(2, 3)
    settings = settings_for_frame(settings, intrinsics.fx,
                                  robot_distance_mm(bounds, robot_from_camera))
    box = crop_box_from_bounds(bounds, settings.crop_margin_mm)
    window = box_pixels(box, intrinsics, robot_from_camera)  # a fifth of the frame or less
    if settings.edge_bleed_px > 0:
        bled = bled_pixels(depth_mm, color, settings.edge_bleed_px, settings.edge_jump_mm,
                           settings.point_colour_threshold, window)
        if bled.any():  # the frame's own depth is left as it was
            depth_mm = depth_mm.copy()
            depth_mm[bled] = 0
    if settings.decimation > 1:
        depth_mm, color, intrinsics = decimate_frame(depth_mm, color, intrinsics,
                                                     settings.decimation, window)
    decimation_ms = clock.lap("decimation")
    plane = table_plane
    if plane is None:
        sample = cloud_from_frame(depth_mm, color, intrinsics, robot_from_camera, box,
                                  stride=TABLE_STRIDE)
        plane = fit_table_plane(sample, bounds[0, 2], bounds.mean(axis=0),
                                settings.table_slab_mm, settings.table_fit_mm,
                                settings.table_min_points // TABLE_STRIDE**2,
                                footprint_mm=bounds[:, :2])
    clock.lap("table")
    above = None if plane is None else (plane[0], plane[1], settings.table_clearance_mm)
    cloud = cloud_from_frame(depth_mm, color, intrinsics, robot_from_camera, box,
                             above_plane=above)
    clock.lap("cloud")
    cloud = voxel_downsample(cloud, settings.voxel_mm)
    clock.lap("voxel")
    pair_mm = min(settings.region_neighbour_mm, settings.outlier_radius_mm)
    if settings.outlier_min_neighbours == 0:  # filter off: only the region growing's pairs
        pairs = radius_pairs(cloud.points_mm, settings.region_neighbour_mm)
    else:
        cloud, pairs = remove_radius_outliers_with_pairs(
            cloud, settings.outlier_radius_mm, settings.outlier_min_neighbours, pair_mm
        )
        if pair_mm < settings.region_neighbour_mm:
            pairs = None  # region growing reaches further than the outlier search
    clock.lap("outliers")
    segmentation = segment_robot(cloud, robot_rgb, settings, pairs)
    clock.lap("segmentation")
    camera_mm = robot_from_camera.translation_mm
    contacts = detect_contacts(segmentation, settings, excluded_box_mm, camera_mm=camera_mm)
    clock.lap("contacts")
    timings = {stage: clock.laps[stage] for stage in OBSERVED_STAGES}
    timings["cloud"] += decimation_ms  # the decimated frame is the cloud's first step
    return Observation(cloud, segmentation, contacts, plane, settings, camera_mm, timings)


def match_observation(observation: Observation, feature_positions_mm: np.ndarray,
                      feature_normals: np.ndarray) -> VisionResult:
    """The rest of process_frame at the current feature geometry (p, 3), (p, 3): each
    contact's nearest feature and the feature matching (Algorithm 3)."""
    clock = _Clock()
    contact_features = nearest_features(observation.contacts.centres_mm, feature_positions_mm)
    clock.lap("contacts")
    matches = match_features(feature_positions_mm, feature_normals,
                             observation.segmentation.robot.points_mm, observation.settings,
                             camera_mm=observation.camera_mm,
                             robot_tree=observation.segmentation.robot_tree)
    clock.lap("matching")
    timings = dict(observation.timings_ms)
    timings["contacts"] += clock.laps["contacts"]
    timings["matching"] = clock.laps["matching"]
    timings["total"] = sum(timings.values())
    return VisionResult(observation.cloud, observation.segmentation, observation.contacts,
                        contact_features, matches, observation.table_plane, timings)


class _Clock:
    """Milliseconds between successive laps."""

    def __init__(self) -> None:
        self.last = time.perf_counter()
        self.laps: dict[str, float] = {}

    def lap(self, name: str) -> float:
        """Milliseconds since the last lap, kept as laps[name]."""
        now = time.perf_counter()
        self.laps[name] = 1e3 * (now - self.last)
        self.last = now
        return self.laps[name]
