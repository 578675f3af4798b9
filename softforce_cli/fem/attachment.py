"""Attachment of arbitrary points (cable points, markers, probes) to a tetrahedral mesh.

An attached point moves with the tetrahedron that contains it (or the nearest one), as SOFA's
BarycentricMapping does: x_p = sum_a w_a x_a over the element's k nodes, with w_a the
element's shape functions at the point (k = 4, barycentric, for P1; k = 10 for P2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from softforce_cli.fem.element import element_of

# How many tetrahedra (nearest by centroid) are searched for the one containing a point.
CANDIDATE_TETS = 32
INSIDE_TOLERANCE = 1e-9


def barycentric_coordinates(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of points in tetrahedra.

    points (..., 3), corners (..., 4, 3) -> (..., 4), summing to 1.
    """
    edges = np.swapaxes(corners[..., 1:, :] - corners[..., :1, :], -1, -2)
    local = np.linalg.solve(edges, (points - corners[..., 0, :])[..., None])[..., 0]
    return np.concatenate([1.0 - local.sum(axis=-1, keepdims=True), local], axis=-1)


@dataclass(frozen=True)
class Attachment:
    """Points attached to a tetrahedral mesh.

    node_indices : (p, k) int64, the nodes of each point's element (k = 4 or 10), or of the
                   region a spread point averages over (Attachment.mean).
    weights      : (p, k) float64 shape-function values at the point (summing to 1; may
                   leave [0, 1] for a point outside the mesh, which then keeps its exact rest
                   position).
    inside       : (p,) bool, whether the point lies in its tetrahedron.
    """

    node_indices: np.ndarray
    weights: np.ndarray
    inside: np.ndarray

    def __len__(self) -> int:
        return len(self.weights)

    @classmethod
    def at_nodes(cls, nodes: np.ndarray) -> Attachment:
        """Points that are mesh nodes: weight 1 on the node itself."""
        nodes = np.asarray(nodes, dtype=np.int64)
        indices = np.repeat(nodes[:, None], 4, axis=1)
        weights = np.zeros((len(nodes), 4))
        weights[:, 0] = 1.0
        return cls(indices, weights, np.ones(len(nodes), dtype=bool))

    def positions(self, nodes_mm: np.ndarray) -> np.ndarray:
        """Current positions (p, 3) mm of the points, for node positions (n, 3)."""
        return np.einsum("pa,pai->pi", self.weights, nodes_mm[self.node_indices])

    def interpolation(self, node_count: int) -> sp.csr_matrix:
        """Sparse (p, n) matrix mapping nodal values to the points."""
        rows = np.repeat(np.arange(len(self)), self.weights.shape[1])
        return sp.csr_matrix(
            (self.weights.ravel(), (rows, self.node_indices.ravel())), shape=(len(self), node_count)
        )

    def directional_rows(self, directions: np.ndarray, node_count: int) -> sp.csr_matrix:
        """Sparse (p, 3n) H with row j = direction_j spread on point j's nodes.

        H x is the motion of each point along its direction; H^T lam applies force lam_j
        along direction_j at point j. directions (p, 3).
        """
        directions = np.asarray(directions, dtype=float)
        rows = np.repeat(np.arange(len(self)), 3 * self.weights.shape[1])
        cols = (3 * self.node_indices[:, :, None] + np.arange(3)).ravel()
        data = (self.weights[:, :, None] * directions[:, None, :]).ravel()
        return sp.csr_matrix((data, (rows, cols)), shape=(len(self), 3 * node_count))

    def cartesian_rows(self, node_count: int) -> sp.csr_matrix:
        """Sparse (3p, 3n) H whose rows are the x, y, z of each point in turn."""
        return sp.kron(self.interpolation(node_count), sp.eye(3), format="csr")

    def subset(self, which: np.ndarray) -> Attachment:
        return Attachment(self.node_indices[which], self.weights[which], self.inside[which])

    def mean(self) -> Attachment:
        """One point, the mean of these points: a force on it is shared equally among them
        (a load spread over a region sampled by the points)."""
        nodes, slot = np.unique(self.node_indices, return_inverse=True)
        weights = np.bincount(slot.ravel(), self.weights.ravel(), len(nodes)) / len(self)
        return Attachment(nodes[None], weights[None], np.array([bool(self.inside.all())]))

    @classmethod
    def concatenate(cls, parts: list[Attachment]) -> Attachment:
        """The points of every part, in order; parts with fewer nodes per point are padded
        with zero weights on their first node."""
        k = max(part.weights.shape[1] for part in parts)
        pad = [k - part.weights.shape[1] for part in parts]
        return cls(
            np.concatenate([np.pad(p.node_indices, ((0, 0), (0, w)), mode="edge")
                            for p, w in zip(parts, pad, strict=True)]),
            np.concatenate([np.pad(p.weights, ((0, 0), (0, w)))
                            for p, w in zip(parts, pad, strict=True)]),
            np.concatenate([p.inside for p in parts]),
        )


def attach_points(nodes_mm: np.ndarray, tets: np.ndarray, points_mm: np.ndarray) -> Attachment:
    """Attach points (p, 3) mm to the mesh (nodes (n, 3), elements (m, 4) or (m, 10)).

    Each point goes to the tetrahedron that contains it; a point outside every candidate goes
    to the candidate whose barycentric coordinates are least negative (the nearest one). Its
    weights are the element's shape functions at its barycentric coordinates: the point
    follows the element's (linear or quadratic) displacement field.
    """
    element = element_of(tets)
    elements, tets = tets, tets[:, :4]
    points_mm = np.atleast_2d(np.asarray(points_mm, dtype=float))
    centroids = nodes_mm[tets].mean(axis=1)
    k = min(CANDIDATE_TETS, len(tets))
    _, candidates = cKDTree(centroids).query(points_mm, k=k)
    candidates = candidates.reshape(len(points_mm), k)
    coords = barycentric_coordinates(points_mm[:, None, :], nodes_mm[tets[candidates]])
    best = np.argmax(coords.min(axis=2), axis=1)
    rows = np.arange(len(points_mm))
    barycentric = coords[rows, best]
    return Attachment(
        elements[candidates[rows, best]],
        element.shape_values(barycentric),
        barycentric.min(axis=1) >= -INSIDE_TOLERANCE,
    )
