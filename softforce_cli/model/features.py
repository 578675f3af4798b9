"""Feature points: surface vertices spread evenly over the robot (paper, section V-A.4)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from softforce_cli.model.mesh import face_normals, vertex_normals

# How far a face node's normal may turn from each of its triangles': a node on a flat face
# (or a gently curved one) passes, one on an edge or a corner of the body (45-90 degrees on
# a box section) does not
FACE_NODE_MAX_ANGLE_DEG = 10.0
PLACEMENTS = ("spread", "faces")


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


def face_nodes(nodes_mm: np.ndarray, surface_faces: np.ndarray,
               max_angle_deg: float = FACE_NODE_MAX_ANGLE_DEG) -> np.ndarray:
    """Sorted indices of the surface nodes that lie on a face of the body, not on an edge.

    nodes (n, 3) mm, surface_faces (k, 3) outward triangles -> (f,) int64: the nodes whose
    vertex normal is within max_angle_deg of the normal of every triangle they belong to.
    On an edge the vertex normal is the mean of the two faces' and no surface is normal to
    it: a line along it leaves the body at the edge, where the camera's nearest point moves
    as the edge turns (docs/sensing_studies.md, "Feature points on faces").
    """
    normals = vertex_normals(nodes_mm, surface_faces)
    triangle_normals = face_normals(nodes_mm, surface_faces)
    worst = np.ones(len(nodes_mm))
    for corner in range(3):
        node = surface_faces[:, corner]
        np.minimum.at(worst, node, np.einsum("ij,ij->i", normals[node], triangle_normals))
    on_surface = np.zeros(len(nodes_mm), dtype=bool)
    on_surface[surface_faces.ravel()] = True
    return np.flatnonzero(on_surface & (worst >= np.cos(np.radians(max_angle_deg))))


def spread_surface_nodes(nodes_mm: np.ndarray, surface_nodes: np.ndarray, excluded: np.ndarray,
                         count: int, among: np.ndarray | None = None) -> np.ndarray:
    """`count` surface node indices spread evenly, skipping `excluded` (clamped) nodes.

    among (f,), optional: only these nodes are candidates (e.g. face_nodes), unless fewer
    than `count` of them are free. The highest candidate comes first, so the apex of a robot
    is always a feature point.
    """
    candidates = np.setdiff1d(surface_nodes, excluded)
    if among is not None and len(np.intersect1d(candidates, among)) >= count:
        candidates = np.intersect1d(candidates, among)
    start = int(np.argmax(nodes_mm[candidates, 2]))
    return np.sort(candidates[farthest_point_sampling(nodes_mm[candidates], count, start)])


def nearest_surface_nodes(nodes_mm: np.ndarray, surface_nodes: np.ndarray,
                          points_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Surface node nearest to each point (p, 3) -> indices (p,), distances (p,) mm."""
    distance, index = cKDTree(nodes_mm[surface_nodes]).query(np.asarray(points_mm, float))
    return surface_nodes[index], distance
