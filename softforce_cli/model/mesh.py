"""Tetrahedral meshes: a frozen data class over pure functions on arrays.

Points are (n, 3) row-major in millimetres; tetrahedra are (m, 4) node indices.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

# The local faces of a tetrahedron (v0, v1, v2, v3), each ordered so that its normal
# (right-hand rule) points away from the opposite vertex when the tetrahedron is positive.
TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def tet_signed_volumes(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes of tetrahedra.

    nodes (n, 3) mm, tets (m, 4) int -> (m,) mm^3, positive for right-handed ordering.
    """
    corners = nodes[tets]
    edges = corners[:, 1:] - corners[:, :1]
    return np.linalg.det(edges) / 6.0


def boundary_faces(tets: np.ndarray) -> np.ndarray:
    """Faces that belong to exactly one tetrahedron, oriented like their tetrahedron's face.

    tets (m, 4) int, positively oriented -> (k, 3) int, outward normals by the right-hand rule.
    """
    faces = tets[:, TET_FACES].reshape(-1, 3)
    keys = np.sort(faces, axis=1)
    _, first, counts = np.unique(keys, axis=0, return_index=True, return_counts=True)
    return faces[np.sort(first[counts == 1])]


def face_normals(nodes: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit normals of triangles: nodes (n, 3), faces (k, 3) -> (k, 3)."""
    tri = nodes[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def face_areas(nodes: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Areas of triangles: nodes (n, 3) mm, faces (k, 3) -> (k,) mm^2."""
    tri = nodes[faces]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def vertex_normals(nodes: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals of a triangle surface.

    nodes (n, 3), faces (k, 3) -> (n, 3); rows of nodes not on the surface are zero.
    """
    tri = nodes[faces]
    weighted = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # 2 * area * normal
    normals = np.zeros_like(nodes, dtype=float)
    for corner in range(3):
        np.add.at(normals, faces[:, corner], weighted)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)


@dataclass(frozen=True)
class TetMesh:
    """A linear tetrahedral mesh in the robot frame.

    nodes_mm : (n, 3) float64, node positions in millimetres.
    tets     : (m, 4) int64, node indices of each tetrahedron, positively oriented.
    """

    nodes_mm: np.ndarray
    tets: np.ndarray

    @property
    def node_count(self) -> int:
        return len(self.nodes_mm)

    @property
    def tet_count(self) -> int:
        return len(self.tets)

    @cached_property
    def tet_volumes_mm3(self) -> np.ndarray:
        """(m,) float64 volume of each tetrahedron in mm^3."""
        return tet_signed_volumes(self.nodes_mm, self.tets)

    @cached_property
    def volume_mm3(self) -> float:
        return float(self.tet_volumes_mm3.sum())

    @cached_property
    def tet_centroids_mm(self) -> np.ndarray:
        """(m, 3) float64 centroid of each tetrahedron."""
        return self.nodes_mm[self.tets].mean(axis=1)

    @cached_property
    def surface_faces(self) -> np.ndarray:
        """(k, 3) int64 boundary triangles, outward oriented."""
        return boundary_faces(self.tets)

    @cached_property
    def surface_nodes(self) -> np.ndarray:
        """(s,) int64 sorted indices of the nodes on the boundary."""
        return np.unique(self.surface_faces)

    @cached_property
    def surface_face_areas_mm2(self) -> np.ndarray:
        return face_areas(self.nodes_mm, self.surface_faces)

    @cached_property
    def vertex_normals(self) -> np.ndarray:
        """(n, 3) float64 outward unit normal of every surface node (zero inside)."""
        return vertex_normals(self.nodes_mm, self.surface_faces)

    @cached_property
    def bounds_mm(self) -> np.ndarray:
        """(2, 3) float64 axis-aligned bounding box: [min, max]."""
        return np.array([self.nodes_mm.min(axis=0), self.nodes_mm.max(axis=0)])

    def moved(self, nodes_mm: np.ndarray) -> TetMesh:
        """The same connectivity at other node positions (n, 3) mm, e.g. a deformed state."""
        return TetMesh(np.asarray(nodes_mm, dtype=float), self.tets)
