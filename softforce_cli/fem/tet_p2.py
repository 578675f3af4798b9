"""Quadratic (P2) tetrahedra: ten shape functions, a degree-2 quadrature, the 10-node mesh.

Node order is VTK's quadratic tetrahedron (VTK_QUADRATIC_TETRA = 24, meshio "tetra10"): the
four corners, then the mid-edge nodes of edges 01, 12, 02, 03, 13, 23. The elements are
straight-sided (mid-edge nodes at the edge midpoints), so the geometry stays the affine map
of the corner tetrahedron and only the displacement field is quadratic.

A P2 mesh is built from a P1 mesh: the n input nodes keep their numbers, and the mid-edge
node of the j-th unique edge is node n + j.
"""

from __future__ import annotations

import numpy as np

NODE_COUNT = 10
EDGES = np.array([[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]])

# Four-point rule of degree 2 (Keast 1986, rule 2; Zienkiewicz & Taylor, table 5.4): exact
# for the P2 stiffness of a constant tangent (grad N . grad N is of degree 2).
_A, _B = (5 + 3 * np.sqrt(5)) / 20, (5 - np.sqrt(5)) / 20
QUADRATURE_POINTS = np.full((4, 4), _B) + np.eye(4) * (_A - _B)  # (q, 4) barycentric
QUADRATURE_WEIGHTS = np.full(4, 0.25)  # (q,) fractions of the element volume

# HRZ lumping (Hinton, Rock & Zienkiewicz, "A note on mass lumping and related processes in
# the finite element method", Earthquake Eng. Struct. Dyn. 4, 1976): the consistent mass
# matrix's diagonal, int N_a^2 dV = V/70 (corner) and 8 V/105 (mid-edge), scaled to sum to
# the element's mass. All positive, unlike the row sums (-V/20 at the corners).
LUMPED_MASS_FRACTIONS = np.array([1 / 36] * 4 + [4 / 27] * 6)


def shape_values(barycentric: np.ndarray) -> np.ndarray:
    """N_a at barycentric coordinates (..., 4) -> (..., 10)."""
    L = np.asarray(barycentric, dtype=float)
    corners = L * (2 * L - 1)
    edges = 4 * L[..., EDGES[:, 0]] * L[..., EDGES[:, 1]]
    return np.concatenate([corners, edges], axis=-1)


def shape_derivatives(barycentric: np.ndarray) -> np.ndarray:
    """dN_a / dL_b at barycentric coordinates (..., 4) -> (..., 10, 4)."""
    L = np.asarray(barycentric, dtype=float)
    out = np.zeros((*L.shape[:-1], NODE_COUNT, 4))
    for a in range(4):
        out[..., a, a] = 4 * L[..., a] - 1
    for e, (i, j) in enumerate(EDGES):
        out[..., 4 + e, i] = 4 * L[..., j]
        out[..., 4 + e, j] = 4 * L[..., i]
    return out


def quadratic_tets(tets: np.ndarray, node_count: int) -> tuple[np.ndarray, np.ndarray]:
    """10-node connectivity from 4-node tetrahedra.

    tets (m, 4) int, node_count n -> elements (m, 10) int64 (corners as given, mid-edge nodes
    numbered n, n + 1, ... in the order of `edges`), edges (e, 2) int64 unique corner pairs
    (lower number first, sorted), whose midpoint is node n + row.
    """
    tets = np.asarray(tets, dtype=np.int64)
    pairs = np.sort(tets[:, EDGES].reshape(-1, 2), axis=1)
    keys = pairs[:, 0] * node_count + pairs[:, 1]
    unique_keys, inverse = np.unique(keys, return_inverse=True)
    edges = np.stack([unique_keys // node_count, unique_keys % node_count], axis=1)
    middle = node_count + inverse.reshape(len(tets), len(EDGES))
    return np.concatenate([tets, middle], axis=1), edges
