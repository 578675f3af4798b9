"""Tetrahedral elements as data, and the element kernels shared by every element type.

An element type is its shape functions in barycentric coordinates, a quadrature rule and a
mass lumping. The kernels below are vectorised over (element m, quadrature point q) and never
ask which type they run: P1 is the k = 4 node, q = 1 point case and P2 the k = 10, q = 4 case
of the same code. P2-P0 is P2 whose lambda (volumetric) terms are integrated at the centroid
only (q = 4 + 1 points): for the linear law that is exactly the mixed P2 displacement / P0
pressure method with the pressure condensed (div u is linear on a P2 element, so its mean is
its centroid value), which does not lock as Poisson's ratio nears 0.5.

Elements are straight-sided, so the shape-function gradients are the chain rule
grad N_a = sum_b dN_a/dL_b grad L_b with the corner tetrahedron's constant grad L. Local
dofs are node-major: (node a, component i) -> 3 a + i.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from softforce_cli.fem import tet_p1, tet_p2


@dataclass(frozen=True)
class TetElement:
    """A tetrahedral element type.

    name                  : "p1", "p2" or "p2-p0", as in the robot file.
    node_count            : k, nodes per element (corners first).
    quadrature_points     : (q, 4) barycentric coordinates of the rule for the whole law (or
                            only its mu terms when lambda_points is given).
    quadrature_weights    : (q,) fractions of the element volume, summing to 1.
    lambda_points, lambda_weights : (r, 4), (r,) a separate rule for the law's lambda terms,
                            or None (one rule for the whole law).
    lumped_mass_fractions : (k,) positive fractions of the element mass, summing to 1.
    shape_values          : (..., 4) barycentric -> (..., k) N_a.
    shape_derivatives     : (..., 4) barycentric -> (..., k, 4) dN_a / dL_b.
    """

    name: str
    node_count: int
    quadrature_points: np.ndarray
    quadrature_weights: np.ndarray
    lumped_mass_fractions: np.ndarray
    shape_values: Callable[[np.ndarray], np.ndarray] = field(repr=False)
    shape_derivatives: Callable[[np.ndarray], np.ndarray] = field(repr=False)
    lambda_points: np.ndarray | None = None
    lambda_weights: np.ndarray | None = None

    @property
    def quadrature_count(self) -> int:
        """Points of the main rule (the first ones of `integration_points`)."""
        return len(self.quadrature_weights)

    @property
    def integration_points(self) -> tuple[np.ndarray, np.ndarray]:
        """Every point the kernels evaluate: the main rule, then the lambda rule if any."""
        if self.lambda_points is None:
            return self.quadrature_points, self.quadrature_weights
        return (np.vstack([self.quadrature_points, self.lambda_points]),
                np.concatenate([self.quadrature_weights, self.lambda_weights]))


P1 = TetElement("p1", tet_p1.NODE_COUNT, tet_p1.QUADRATURE_POINTS, tet_p1.QUADRATURE_WEIGHTS,
                tet_p1.LUMPED_MASS_FRACTIONS, tet_p1.shape_values, tet_p1.shape_derivatives)
P2 = TetElement("p2", tet_p2.NODE_COUNT, tet_p2.QUADRATURE_POINTS, tet_p2.QUADRATURE_WEIGHTS,
                tet_p2.LUMPED_MASS_FRACTIONS, tet_p2.shape_values, tet_p2.shape_derivatives)
P2P0 = TetElement("p2-p0", tet_p2.NODE_COUNT, tet_p2.QUADRATURE_POINTS,
                  tet_p2.QUADRATURE_WEIGHTS, tet_p2.LUMPED_MASS_FRACTIONS, tet_p2.shape_values,
                  tet_p2.shape_derivatives, tet_p1.QUADRATURE_POINTS, tet_p1.QUADRATURE_WEIGHTS)
ELEMENTS = {element.name: element for element in (P1, P2, P2P0)}


def element_of(elements: np.ndarray, name: str | None = None) -> TetElement:
    """The element type `name`, or by default the one of a connectivity's width: (m, 4) P1,
    (m, 10) P2; ValueError when they do not match."""
    candidates = [ELEMENTS[name]] if name in ELEMENTS else [P1, P2] if name is None else []
    for element in candidates:
        if elements.ndim == 2 and elements.shape[1] == element.node_count:
            return element
    raise ValueError(f"elements {elements.shape} do not fit element {name!r}: expected (m, 4) "
                     f"for p1, (m, 10) for p2 and p2-p0")


def reference_gradients(
    nodes: np.ndarray, elements: np.ndarray, element: TetElement
) -> tuple[np.ndarray, np.ndarray]:
    """Shape-function gradients and weights at the element's integration points.

    nodes (n, 3) mm, elements (m, k) -> gradients (m, q, k, 3) 1/mm, weights (m, q) mm^3
    (volume times the rule's weight; each rule's weights sum to the element volume).
    """
    points, fractions = element.integration_points
    corner_gradients, volumes = tet_p1.shape_gradients(nodes, elements)  # grad L (m, 4, 3)
    derivatives = element.shape_derivatives(points)  # (q, k, 4)
    gradients = np.einsum("qab,mbj->mqaj", derivatives, corner_gradients)
    return gradients, volumes[:, None] * fractions


def gradient_operators(gradients: np.ndarray) -> np.ndarray:
    """B with vec(dF) = B dx_e: (..., k, 3) -> (..., 9, 3k), B[(i, j), (a, l)] = d_il dN_a/dX_j.

    The kernels below contract with the gradients directly (B is mostly zeros); B is the
    textbook form they are checked against.
    """
    *lead, k, _ = gradients.shape
    B = np.zeros((*lead, 3, 3, k, 3))
    for i in range(3):
        B[..., i, :, :, i] = np.swapaxes(gradients, -1, -2)
    return B.reshape(*lead, 9, 3 * k)


def deformation_gradients(
    positions: np.ndarray, elements: np.ndarray, gradients: np.ndarray
) -> np.ndarray:
    """F = sum_a x_a (outer) grad N_a at each quadrature point.

    positions (n, 3) mm, elements (m, k), gradients (m, q, k, 3) -> (m, q, 3, 3).
    """
    corners = positions[elements].transpose(0, 2, 1)[:, None]  # (m, 1, 3, k)
    return corners @ gradients


def element_forces(
    first_piola: np.ndarray, gradients: np.ndarray, weights: np.ndarray
) -> np.ndarray:
    """Internal nodal forces of each element, f_ai = sum_q w_q P_ij dN_a/dX_j (= V B^T vec P).

    first_piola (m, q, 3, 3) MPa, gradients (m, q, k, 3) 1/mm, weights (m, q) mm^3
    -> (m, 3k) N.
    """
    per_point = (weights[:, :, None, None] * gradients) @ first_piola.transpose(0, 1, 3, 2)
    return per_point.sum(axis=1).reshape(len(weights), -1)


def element_stiffness(
    tangent: np.ndarray, gradients: np.ndarray, weights: np.ndarray
) -> np.ndarray:
    """Element tangent stiffness sum_q w_q B^T A B, without forming the sparse B.

    K[(a, i), (b, k)] = sum_q w_q dN_a/dX_j A_ijkl dN_b/dX_l, contracted in two batched
    products: first over l, then over (q, j) together.
    tangent (m, q, 9, 9) or (m, q, 3, 3, 3, 3) MPa (dP_ij / dF_kl), gradients (m, q, k, 3),
    weights (m, q) mm^3 -> (m, 3k, 3k) N/mm.
    """
    m, q, k, _ = gradients.shape
    # C[m, q, (i, j, k), b] = A_ijkl dN_b/dX_l
    inner = tangent.reshape(m, q, 27, 3) @ gradients.transpose(0, 1, 3, 2)
    # rows (q, j), columns (i, b, k): the one copy, ordered so that the second product comes
    # out node-major, [a, i, b, k], with no transpose of the (larger) result
    inner = inner.reshape(m, q, 3, 3, 3, k).transpose(0, 1, 3, 2, 5, 4).reshape(m, 3 * q, 9 * k)
    left = (weights[:, :, None, None] * gradients).transpose(0, 2, 1, 3).reshape(m, k, 3 * q)
    return (left @ inner).reshape(m, 3 * k, 3 * k)


@dataclass(frozen=True)
class ElementMesh:
    """The nodes and elements an FE model works on, built from a tetrahedral mesh.

    nodes_mm     : (N, 3) float64; the mesh's n nodes first, in their order, then (P2) the
                   mid-edge nodes, N = n + e.
    elements     : (m, k) int64 connectivity of `element`.
    corner_count : n, the mesh's own nodes.
    edges        : (e, 2) int64 corner pairs of the mid-edge nodes n .. n + e - 1 (empty: P1).
    """

    element: TetElement
    nodes_mm: np.ndarray
    elements: np.ndarray
    corner_count: int
    edges: np.ndarray

    @property
    def node_count(self) -> int:
        return len(self.nodes_mm)

    def from_corners(self, corner_values: np.ndarray) -> np.ndarray:
        """(N, ...) a field given at the corners (n, ...) at every node: a mid-edge node takes
        its edge's mean (the field linear along the edge)."""
        return _with_midside_means(np.asarray(corner_values), self.edges)

    def with_midside(self, corner_nodes: np.ndarray) -> np.ndarray:
        """(j,) sorted: the corner nodes given, and the mid-edge nodes of the edges whose two
        corners are both among them (so a clamped set keeps clamping the same faces)."""
        chosen = np.zeros(self.corner_count, dtype=bool)
        chosen[np.asarray(corner_nodes, dtype=np.int64)] = True
        middle = self.corner_count + np.flatnonzero(chosen[self.edges].all(axis=1))
        return np.concatenate([np.flatnonzero(chosen), middle])

    def surface_triangles(self, faces: np.ndarray) -> np.ndarray:
        """Boundary triangles (s, 3) of the corner mesh -> triangles over all nodes: P1 the
        same; P2 each split in four at its mid-edge nodes, (4s, 3), orientation kept."""
        if not len(self.edges):
            return np.asarray(faces)
        keys = self.edges[:, 0] * self.corner_count + self.edges[:, 1]
        a, b, c = np.asarray(faces, dtype=np.int64).T

        def middle(u, v):
            low, high = np.minimum(u, v), np.maximum(u, v)
            return self.corner_count + np.searchsorted(keys, low * self.corner_count + high)

        ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
        split = [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]
        return np.stack([np.stack(t, axis=1) for t in split], axis=1).reshape(-1, 3)


def element_mesh(nodes_mm: np.ndarray, tets: np.ndarray, element: str = "p1") -> ElementMesh:
    """The FE nodes and connectivity of `element` ("p1" | "p2" | "p2-p0") on a mesh (n, 3),
    (m, 4)."""
    if element not in ELEMENTS:
        raise ValueError(f"unknown element {element!r}; expected one of {', '.join(ELEMENTS)}")
    nodes_mm = np.asarray(nodes_mm, dtype=float)
    tets = np.asarray(tets, dtype=np.int64)
    if ELEMENTS[element].node_count == tet_p1.NODE_COUNT:
        return ElementMesh(P1, nodes_mm, tets, len(nodes_mm), np.zeros((0, 2), dtype=np.int64))
    elements, edges = tet_p2.quadratic_tets(tets, len(nodes_mm))
    return ElementMesh(ELEMENTS[element], _with_midside_means(nodes_mm, edges), elements,
                       len(nodes_mm), edges)


def _with_midside_means(corner_values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(n + e, ...) corner values (n, ...) followed by the means over the edges (e, 2)."""
    middles = 0.5 * (corner_values[edges[:, 0]] + corner_values[edges[:, 1]])
    return np.concatenate([corner_values, middles])


def midside_offset_mm(nodes_mm: np.ndarray, elements: np.ndarray) -> float:
    """Largest distance of a P2 mid-edge node from its edge's midpoint (0 for P1)."""
    if elements.shape[1] != tet_p2.NODE_COUNT:
        return 0.0
    ends = nodes_mm[elements[:, tet_p2.EDGES]]  # (m, 6, 2, 3)
    middles = nodes_mm[elements[:, 4:]]
    return float(np.abs(middles - ends.mean(axis=2)).max(initial=0.0))
