"""Linear (P1) tetrahedra: shape-function gradients, deformation gradients, element vectors.

One quadrature point per element; every array is vectorised over elements. Local dofs are
node-major, (node a, component i) -> 3 a + i.
"""

from __future__ import annotations

import numpy as np


def shape_gradients(nodes: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradients of the four P1 shape functions and element volumes in the reference state.

    nodes (n, 3) mm, tets (m, 4) int -> gradients (m, 4, 3) 1/mm, volumes (m,) mm^3.
    """
    corners = nodes[tets]
    edges = (corners[:, 1:] - corners[:, :1]).transpose(0, 2, 1)  # columns x1-x0, x2-x0, x3-x0
    volumes = np.linalg.det(edges) / 6.0
    inverse = np.linalg.inv(edges)  # rows: gradients of N1, N2, N3
    gradients = np.concatenate([-inverse.sum(axis=1, keepdims=True), inverse], axis=1)
    return gradients, volumes


def gradient_operators(gradients: np.ndarray) -> np.ndarray:
    """B with vec(dF) = B dx_e: (m, 4, 3) -> (m, 9, 12), B[(i, j), (a, k)] = d_ik dN_a/dX_j."""
    B = np.zeros((len(gradients), 3, 3, 4, 3))
    for i in range(3):
        B[:, i, :, :, i] = gradients.transpose(0, 2, 1)
    return B.reshape(len(gradients), 9, 12)


def deformation_gradients(
    positions: np.ndarray, tets: np.ndarray, gradients: np.ndarray
) -> np.ndarray:
    """F = sum_a x_a (outer) grad N_a per element.

    positions (n, 3) mm, tets (m, 4), gradients (m, 4, 3) -> (m, 3, 3) dimensionless.
    """
    return np.einsum("mai,maj->mij", positions[tets], gradients)


def element_forces(
    first_piola: np.ndarray, operators: np.ndarray, volumes: np.ndarray
) -> np.ndarray:
    """Internal nodal forces of each element, f = V B^T vec(P).

    first_piola (m, 3, 3) MPa, operators B (m, 9, 12) 1/mm, volumes (m,) mm^3 -> (m, 12) N.
    """
    vec_p = first_piola.reshape(len(volumes), 1, 9)
    return volumes[:, None] * (vec_p @ operators)[:, 0]


def element_stiffness(
    tangent: np.ndarray, operators: np.ndarray, volumes: np.ndarray
) -> np.ndarray:
    """Element tangent stiffness V B^T A B.

    tangent (m, 3, 3, 3, 3) or (m, 9, 9) MPa (dP_ij / dF_kl), operators B (m, 9, 12),
    volumes (m,) mm^3 -> (m, 12, 12) N/mm.
    """
    m = len(volumes)
    stiffness = operators.transpose(0, 2, 1) @ (tangent.reshape(m, 9, 9) @ operators)
    return volumes[:, None, None] * stiffness
