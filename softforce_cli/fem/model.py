"""The finite element model: mesh, material, supports, body load and cables, as arrays."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from softforce_cli.fem.assembly import ReducedPattern, assemble_vector, element_dofs
from softforce_cli.fem.cables import Cable
from softforce_cli.fem.coordinates import FreeDofs
from softforce_cli.fem.element import (
    TetElement,
    deformation_gradients,
    element_forces,
    element_of,
    element_stiffness,
    gradient_operators,
    midside_offset_mm,
    reference_gradients,
)
from softforce_cli.fem.materials import Material
from softforce_cli.fem.supports import Support
from softforce_cli.fem.tet_p1 import shape_gradients

# Newtons per (kg * mm/s^2): forces are in N while lengths are in mm.
NEWTON_PER_KG_MM_S2 = 1e-3
# A P2 mid-edge node further than this fraction of the mesh's size from its edge's midpoint
# means a curved element, which the straight-sided kernels would treat wrongly.
MIDSIDE_TOLERANCE = 1e-9


@dataclass(frozen=True)
class FEModel:
    """A quasi-static tetrahedral FE model in the robot frame (mm, N, MPa, kg).

    rest_nodes_mm : (n, 3) float64 rest positions of every node (for P2: the mesh's nodes
                    first, then the mid-edge nodes; see fem.element.element_mesh).
    tets          : (m, 4) int64 linear (P1) or (m, 10) quadratic (P2, VTK node order)
                    tetrahedra, positively oriented; the width selects the element.
    material      : the constitutive law and its parameters.
    fixed_nodes   : (k,) int64 nodes clamped at their rest position.
    node_masses_kg: (n,) float64 lumped masses.
    gravity_mm_s2 : (3,) float64.
    cables        : the cable actuators, in the robot file's order.
    element_name  : "p1", "p2" or "p2-p0" (fem.element.ELEMENTS), or None for the element of
                    the width of `tets` (p1 or p2).
    element_stiffness_scale : (m,) float64 multiplier of each element's modulus (regional
                    stiffness, model.effects), or None for the material's modulus everywhere.
                    Every law is linear in its Lame parameters, so it scales the element's
                    energy, stress and tangent exactly.
    supports      : springs and contact planes (fem.supports) besides the clamped nodes; their
                    forces count as internal forces, their stiffness as tangent.
    """

    rest_nodes_mm: np.ndarray
    tets: np.ndarray
    material: Material
    fixed_nodes: np.ndarray
    node_masses_kg: np.ndarray
    gravity_mm_s2: np.ndarray
    cables: tuple[Cable, ...] = ()
    element_name: str | None = None
    element_stiffness_scale: np.ndarray | None = None
    supports: tuple[Support, ...] = ()

    @property
    def node_count(self) -> int:
        return len(self.rest_nodes_mm)

    @cached_property
    def element(self) -> TetElement:
        """The element type: element_name's, or P1 / P2 from the width of `tets`."""
        return element_of(self.tets, self.element_name)

    @cached_property
    def _reference(self) -> tuple[np.ndarray, np.ndarray]:
        size = float(np.ptp(self.rest_nodes_mm, axis=0).max())
        if midside_offset_mm(self.rest_nodes_mm, self.tets) > MIDSIDE_TOLERANCE * size:
            raise ValueError("P2 mid-edge nodes must lie at their edges' midpoints "
                             "(straight-sided elements); build them with element_mesh")
        return reference_gradients(self.rest_nodes_mm, self.tets, self.element)

    @property
    def shape_gradients(self) -> np.ndarray:
        """(m, q, k, 3) 1/mm reference shape-function gradients at the quadrature points."""
        return self._reference[0]

    @property
    def quadrature_weights_mm3(self) -> np.ndarray:
        """(m, q) mm^3: element volume times the rule's weights."""
        return self._reference[1]

    @cached_property
    def law_weights_mm3(self) -> np.ndarray:
        """(m, q) mm^3: the quadrature weights the constitutive terms are integrated with,
        times element_stiffness_scale when given (the weights themselves otherwise)."""
        if self.element_stiffness_scale is None:
            return self.quadrature_weights_mm3
        return self.quadrature_weights_mm3 * self.element_stiffness_scale[:, None]

    @cached_property
    def tet_volumes_mm3(self) -> np.ndarray:
        """(m,) mm^3 element volumes."""
        return self.quadrature_weights_mm3[:, : self.element.quadrature_count].sum(axis=1)

    @cached_property
    def gradient_operators(self) -> np.ndarray:
        """(m, q, 9, 3k) B: vec(dF) = B dx_e (for reference; the kernels do not form it)."""
        return gradient_operators(self.shape_gradients)

    @cached_property
    def element_dofs(self) -> np.ndarray:
        """(m, 3k) global dofs of each element."""
        return element_dofs(self.tets)

    @cached_property
    def pattern(self) -> ReducedPattern:
        return ReducedPattern.build(self.tets, self.node_count, self.fixed_nodes)

    @property
    def free_dofs(self) -> np.ndarray:
        """(f,) global dofs (3 node + component) that are not clamped."""
        return self.pattern.free_dofs

    @cached_property
    def gravity_forces_n(self) -> np.ndarray:
        """(n, 3) nodal weights in N."""
        return np.outer(self.node_masses_kg, self.gravity_mm_s2) * NEWTON_PER_KG_MM_S2

    def deformation_gradients(self, positions_mm: np.ndarray) -> np.ndarray:
        """(m, q, 3, 3) F at each element's quadrature points, for node positions (n, 3)."""
        return deformation_gradients(positions_mm, self.tets, self.shape_gradients)

    def _nodal(self, element_vectors: np.ndarray) -> np.ndarray:
        return assemble_vector(element_vectors, self.element_dofs, 3 * self.node_count).reshape(
            -1, 3
        )

    def strain_energy(self, positions_mm: np.ndarray) -> float:
        """Total elastic energy in mJ (N mm)."""
        return self.energy_and_forces(positions_mm)[0]

    def internal_forces(self, positions_mm: np.ndarray) -> np.ndarray:
        """(n, 3) N: the elastic forces g(x) = dE/dx that the body exerts against deformation."""
        return self.energy_and_forces(positions_mm)[1]

    def _constitutive(self, F: np.ndarray, with_tangent: bool) -> tuple[np.ndarray, np.ndarray]:
        """(energy density (m, q), P (m, q, 3, 3)), or with_tangent (P, A (m, q, 9, 9)), at
        F (m, q, 3, 3): the whole law at every point, or (P2-P0) its mu terms at the main
        rule's points and its lambda terms at the lambda rule's."""
        m, q = F.shape[:2]
        points = np.broadcast_to(np.arange(q), (m, q)).ravel()
        pair = self.constitutive_at(F.reshape(-1, 3, 3), points, with_tangent)
        return tuple(a.reshape(m, q, *a.shape[1:]) for a in pair)  # type: ignore[return-value]

    def constitutive_at(self, F: np.ndarray, points: np.ndarray, with_tangent: bool
                        ) -> tuple[np.ndarray, np.ndarray]:
        """(energy density (p,), P (p, 3, 3)), or with_tangent (P, A (p, 9, 9)), at F
        (p, 3, 3) taken at quadrature points `points` (p,) of the element's whole rule (main
        rule first, then the lambda rule's): which terms of the law a point carries depends
        on the rule it belongs to (hyper-reduction samples single points)."""
        law = self.material.stress_and_tangent if with_tangent else self.material.energy_and_stress
        if self.element.lambda_points is None:
            first, second = law(F, "all")
            return (first, second.reshape(-1, 9, 9)) if with_tangent else (first, second)
        first = np.zeros((len(F), 3, 3) if with_tangent else len(F))
        second = np.zeros((len(F), 9, 9) if with_tangent else (len(F), 3, 3))
        for mask, part in self.law_parts(points):
            if mask.any():
                a, b = law(F[mask], part)
                first[mask], second[mask] = a, b.reshape(second[mask].shape)
        return first, second

    def law_parts(self, points: np.ndarray) -> list[tuple[np.ndarray, str]]:
        """[(mask (p,), part)]: which terms of the law (materials.PARTS) quadrature points
        `points` (p,) of the element's whole rule carry: all of it, or (P2-P0) its mu terms
        at the main rule's points and its lambda terms at the lambda rule's."""
        if self.element.lambda_points is None:
            return [(np.ones(len(points), dtype=bool), "all")]
        lam = np.asarray(points) >= self.element.quadrature_count
        return [(~lam, "mu"), (lam, "lambda")]

    def energy_and_forces(self, positions_mm: np.ndarray) -> tuple[float, np.ndarray]:
        """Elastic energy (mJ) and internal forces g(x) (n, 3) N, sharing one stress pass."""
        F = self.deformation_gradients(positions_mm)
        density, stress = self._constitutive(F, with_tangent=False)
        weights = self.law_weights_mm3
        forces = self._nodal(element_forces(stress, self.shape_gradients, weights))
        energy = float(density.ravel() @ weights.ravel())
        for support in self.supports:
            support_energy, support_forces, _ = support.terms(positions_mm)
            energy += support_energy
            np.add.at(forces, support.nodes, support_forces)
        return energy, forces

    def internal_forces_and_stiffness(
        self, positions_mm: np.ndarray
    ) -> tuple[np.ndarray, sp.csr_matrix]:
        """g(x) (n, 3) N and the tangent stiffness dg/dx over the free dofs, CSR (f, f) N/mm."""
        F = self.deformation_gradients(positions_mm)
        stress, tangent = self._constitutive(F, with_tangent=True)
        weights = self.law_weights_mm3
        forces = self._nodal(element_forces(stress, self.shape_gradients, weights))
        stiffness = self.pattern.assemble(element_stiffness(tangent, self.shape_gradients,
                                                            weights))
        if self.supports:
            forces, stiffness = self._with_supports(positions_mm, forces, stiffness)
        return forces, stiffness

    def _with_supports(self, positions_mm: np.ndarray, forces: np.ndarray,
                       stiffness: sp.csr_matrix) -> tuple[np.ndarray, sp.csr_matrix]:
        """Forces (n, 3) and tangent (f, f) with the supports' terms added."""
        forces = forces.copy()
        diagonal = np.zeros(3 * self.node_count)
        for support in self.supports:
            _, support_forces, support_diagonal = support.terms(positions_mm)
            np.add.at(forces, support.nodes, support_forces)
            dofs = (3 * support.nodes[:, None] + np.arange(3)).ravel()
            np.add.at(diagonal, dofs, support_diagonal.ravel())
        return forces, stiffness + sp.diags(diagonal[self.free_dofs], format="csr")

    def element_terms(
        self, positions_mm: np.ndarray, which: np.ndarray, with_tangent: bool
    ) -> tuple[np.ndarray | None, np.ndarray, np.ndarray | None]:
        """Per-element terms of elements `which` (s,) at positions (n, 3): energies (s,) mJ
        (None with_tangent), internal forces (s, 3k) N in element_dofs order and, with_tangent,
        stiffness (s, 3k, 3k) N/mm (else None). Used by hyper-reduction (few elements); the
        supports are not element terms and are left out."""
        gradients = self.shape_gradients[which]
        weights = self.law_weights_mm3[which]
        F = deformation_gradients(positions_mm, self.tets[which], gradients)
        if not with_tangent:
            density, stress = self._constitutive(F, with_tangent=False)
            return ((density * weights).sum(axis=1),
                    element_forces(stress, gradients, weights), None)
        stress, tangent = self._constitutive(F, with_tangent=True)
        return (None, element_forces(stress, gradients, weights),
                element_stiffness(tangent, gradients, weights))

    @cached_property
    def coordinates(self) -> FreeDofs:
        """The coordinates static solves work in: the free dofs (fem.coordinates)."""
        return FreeDofs(self)

    def cable_shortenings(self, positions_mm: np.ndarray) -> np.ndarray:
        """(a,) mm: delta = L0 - L(x) of each cable."""
        return np.array([cable.shortening(positions_mm) for cable in self.cables])

    def cable_jacobian(self, positions_mm: np.ndarray) -> np.ndarray:
        """H_a (a, 3n) dense: rows d(delta)/dx of each cable (a is a handful)."""
        rows = [cable.jacobian_row(positions_mm, self.node_count) for cable in self.cables]
        return np.array(rows).reshape(len(self.cables), 3 * self.node_count)

    def cable_stiffness(self, positions_mm: np.ndarray, tensions_n: np.ndarray) -> sp.csr_matrix:
        """Geometric stiffness (f, f) N/mm of the taut cables, over the free dofs."""
        rows, cols, values = [], [], []
        for cable, tension in zip(self.cables, tensions_n, strict=True):
            if tension != 0.0:
                dofs = self.pattern.reduced_index[cable.dofs]
                rows.append(np.repeat(dofs, len(dofs)))
                cols.append(np.tile(dofs, len(dofs)))
                values.append(cable.geometric_stiffness(positions_mm, tension).ravel())
        size = self.pattern.size
        if not values:
            return sp.csr_matrix((size, size))
        rows, cols, values = np.concatenate(rows), np.concatenate(cols), np.concatenate(values)
        keep = (rows >= 0) & (cols >= 0)
        return sp.csr_matrix((values[keep], (rows[keep], cols[keep])), shape=(size, size))


def lumped_masses(nodes_mm: np.ndarray, tets: np.ndarray, density_kg_mm3: float) -> np.ndarray:
    """(n,) kg lumped masses of tets (m, 4) (a quarter per corner) or (m, 10) (HRZ: 1/36 per
    corner, 4/27 per mid-edge node); they sum to density times volume."""
    element = element_of(tets)
    _, volumes = shape_gradients(nodes_mm, tets)
    shares = density_kg_mm3 * volumes[:, None] * element.lumped_mass_fractions
    return np.bincount(tets.ravel(), weights=shares.ravel(), minlength=len(nodes_mm))
