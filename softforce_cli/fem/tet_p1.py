"""Linear (P1) tetrahedra: the four barycentric shape functions, and the affine geometry that
every straight-sided tetrahedron (P1 or P2) shares.

Barycentric coordinates L = (L0, L1, L2, L3) sum to 1; the shape functions are N_a = L_a.
One quadrature point (the centroid) integrates the constant P1 strain exactly.
"""

from __future__ import annotations

import numpy as np

NODE_COUNT = 4
QUADRATURE_POINTS = np.full((1, 4), 0.25)  # (q, 4) barycentric coordinates
QUADRATURE_WEIGHTS = np.ones(1)  # (q,) fractions of the element volume
# Diagonal (row-sum) lumping: each corner carries a quarter of the element's mass.
LUMPED_MASS_FRACTIONS = np.full(4, 0.25)


def shape_values(barycentric: np.ndarray) -> np.ndarray:
    """N_a at barycentric coordinates (..., 4) -> (..., 4)."""
    return np.asarray(barycentric, dtype=float).copy()


def shape_derivatives(barycentric: np.ndarray) -> np.ndarray:
    """dN_a / dL_b at barycentric coordinates (..., 4) -> (..., 4, 4): the identity."""
    barycentric = np.asarray(barycentric, dtype=float)
    return np.broadcast_to(np.eye(4), (*barycentric.shape[:-1], 4, 4)).copy()


def shape_gradients(nodes: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradients of the four barycentric coordinates and element volumes, reference state.

    nodes (n, 3) mm, tets (m, 4) int (corner nodes) -> gradients (m, 4, 3) 1/mm, volumes (m,)
    mm^3. These are the P1 shape-function gradients, and the chain-rule factor dL/dX of any
    straight-sided element.
    """
    corners = nodes[tets[:, :4]]
    edges = (corners[:, 1:] - corners[:, :1]).transpose(0, 2, 1)  # columns x1-x0, x2-x0, x3-x0
    volumes = np.linalg.det(edges) / 6.0
    inverse = np.linalg.inv(edges)  # rows: gradients of L1, L2, L3
    gradients = np.concatenate([-inverse.sum(axis=1, keepdims=True), inverse], axis=1)
    return gradients, volumes
