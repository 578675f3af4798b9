"""Named regions of a robot's body, for regional effects and for locating a mismatch.

Every point of the body belongs to exactly one region, decided by its rest position:

- `base`: within BASE_MARGIN_FRACTION of the robot's height from a [[fixed]] box (the clamp
  and the material next to it);
- `apex`: otherwise, in the top APEX_FRACTION of the body's height (robot frame, +z up);
- one region per cable, named after it (the Diamond's `north`, `west`, `south`, `east`):
  otherwise, the cable whose path (its points on the body, then its pull point) passes
  nearest: the arm that cable drives.

A robot without cables has only `base` and `apex` (and `body` for the rest).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from softforce_cli.model.robot import Robot

BASE = "base"
APEX = "apex"
# The rest of the body when there is no cable to name an arm after.
BODY = "body"
# The base region reaches this fraction of the body's height beyond the clamp boxes: about
# one element layer of the default meshes (the Diamond: 166 mm tall -> 13 mm).
BASE_MARGIN_FRACTION = 0.08
# The apex region is the top 15% of the height: the Diamond's apex block and the tops of the
# four upper bars (z > 101 mm of 126 mm).
APEX_FRACTION = 0.15


def region_names(robot: Robot) -> tuple[str, ...]:
    """The robot's region names: `base`, `apex`, then its cables' names (or `body`)."""
    return names_for_cables(tuple(spec.name for spec in robot.cable_specs))


def names_for_cables(cable_names: tuple[str, ...]) -> tuple[str, ...]:
    """The region names of a robot with these cables (what region_names gives)."""
    return (BASE, APEX, *(tuple(cable_names) or (BODY,)))


def region_labels(robot: Robot, points_mm: np.ndarray) -> np.ndarray:
    """(p,) int64 index into region_names(robot) of each rest-shape point (p, 3) mm."""
    points = np.asarray(points_mm, dtype=float).reshape(-1, 3)
    nodes = robot.mesh.nodes_mm
    height = float(np.ptp(nodes[:, 2]))
    boxes = np.array(robot.config.fixed_boxes_mm, dtype=float).reshape(-1, 6)
    # distance to the nearest clamp box (0 inside)
    outside = np.maximum(np.maximum(boxes[None, :, :3] - points[:, None],
                                    points[:, None] - boxes[None, :, 3:]), 0.0)
    box_distance = np.linalg.norm(outside, axis=2).min(axis=1)
    labels = np.full(len(points), 2, dtype=np.int64)
    if robot.cable_specs:
        distances = np.stack([_polyline_distance(points, np.vstack([spec.path_mm,
                                                                    spec.pull_point_mm]))
                              for spec in robot.cable_specs], axis=1)
        labels = 2 + np.argmin(distances, axis=1)
    labels[points[:, 2] >= nodes[:, 2].max() - APEX_FRACTION * height] = 1
    labels[box_distance <= BASE_MARGIN_FRACTION * height] = 0
    return labels


def element_regions(robot: Robot) -> dict[str, np.ndarray]:
    """{region name: (m,) bool} over the FE model's elements, by their rest centroids."""
    centroids = robot.mesh.nodes_mm[robot.mesh.tets].mean(axis=1)
    return _masks(robot, region_labels(robot, centroids))


def node_regions(robot: Robot) -> dict[str, np.ndarray]:
    """{region name: (N,) bool} over the FE nodes (robot.rest_nodes_mm; the mesh's n nodes
    first, so [:n] is the mesh nodes' version), by their rest positions."""
    return _masks(robot, region_labels(robot, robot.rest_nodes_mm))


def _masks(robot: Robot, labels: np.ndarray) -> dict[str, np.ndarray]:
    return {name: labels == i for i, name in enumerate(region_names(robot))}


def _polyline_distance(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """(p,) distance of each point (p, 3) to a polyline (k, 3), k >= 2."""
    starts, ends = polyline[:-1], polyline[1:]
    along = ends - starts  # (s, 3)
    length2 = np.maximum(np.einsum("sj,sj->s", along, along), 1e-300)
    t = np.clip(np.einsum("psj,sj->ps", points[:, None] - starts, along) / length2, 0.0, 1.0)
    nearest = starts + t[..., None] * along  # (p, s, 3)
    return np.linalg.norm(points[:, None] - nearest, axis=2).min(axis=1)
