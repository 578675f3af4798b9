"""Feature points: surface vertices spread evenly over the robot (paper, section V-A.4)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def farthest_point_sampling(points: np.ndarray, count: int, start: int) -> np.ndarray:
    """Indices (count,) into points (p, 3) of an evenly spread subset.

    Greedy: each next point is the one farthest from those already chosen, beginning with
    `start`. Deterministic, and within a factor 2 of the best possible covering radius.
    """
    count = min(count, len(points))
    chosen = np.empty(count, dtype=np.int64)
    chosen[0] = start
    distance = np.linalg.norm(points - points[start], axis=1)
    for i in range(1, count):
        chosen[i] = int(np.argmax(distance))
        distance = np.minimum(distance, np.linalg.norm(points - points[chosen[i]], axis=1))
    return chosen


def spread_surface_nodes(nodes_mm: np.ndarray, surface_nodes: np.ndarray, excluded: np.ndarray,
                         count: int) -> np.ndarray:
    """`count` surface node indices spread evenly, skipping `excluded` (clamped) nodes.

    The highest node comes first, so the apex of a robot is always a feature point.
    """
    candidates = np.setdiff1d(surface_nodes, excluded)
    start = int(np.argmax(nodes_mm[candidates, 2]))
    return np.sort(candidates[farthest_point_sampling(nodes_mm[candidates], count, start)])


def nearest_surface_nodes(nodes_mm: np.ndarray, surface_nodes: np.ndarray,
                          points_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Surface node nearest to each point (p, 3) -> indices (p,), distances (p,) mm."""
    distance, index = cKDTree(nodes_mm[surface_nodes]).query(np.asarray(points_mm, float))
    return surface_nodes[index], distance
