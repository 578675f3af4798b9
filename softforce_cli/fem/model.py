"""The finite element model: mesh, material, supports, body load and cables, as arrays."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from softforce_cli.fem.assembly import ReducedPattern, assemble_vector, element_dofs
from softforce_cli.fem.cables import Cable
from softforce_cli.fem.materials import Material
from softforce_cli.fem.tet_p1 import (
    deformation_gradients,
    element_forces,
    element_stiffness,
    gradient_operators,
    shape_gradients,
)

# Newtons per (kg * mm/s^2): forces are in N while lengths are in mm.
NEWTON_PER_KG_MM_S2 = 1e-3


@dataclass(frozen=True)
class FEModel:
    """A quasi-static tetrahedral FE model in the robot frame (mm, N, MPa, kg).

    rest_nodes_mm : (n, 3) float64 rest positions.
    tets          : (m, 4) int64, positively oriented.
    material      : the constitutive law and its parameters.
    fixed_nodes   : (k,) int64 nodes clamped at their rest position.
    node_masses_kg: (n,) float64 lumped masses.
    gravity_mm_s2 : (3,) float64.
    cables        : the cable actuators, in the robot file's order.
    """

    rest_nodes_mm: np.ndarray
    tets: np.ndarray
    material: Material
    fixed_nodes: np.ndarray
    node_masses_kg: np.ndarray
    gravity_mm_s2: np.ndarray
    cables: tuple[Cable, ...] = ()

    @property
    def node_count(self) -> int:
        return len(self.rest_nodes_mm)

    @cached_property
    def _reference(self) -> tuple[np.ndarray, np.ndarray]:
        return shape_gradients(self.rest_nodes_mm, self.tets)

    @property
    def shape_gradients(self) -> np.ndarray:
        """(m, 4, 3) 1/mm reference shape-function gradients."""
        return self._reference[0]

    @property
    def tet_volumes_mm3(self) -> np.ndarray:
        return self._reference[1]

    @cached_property
    def gradient_operators(self) -> np.ndarray:
        """(m, 9, 12) B: vec(dF) = B dx_e."""
        return gradient_operators(self.shape_gradients)

    @cached_property
    def element_dofs(self) -> np.ndarray:
        """(m, 12) global dofs of each element."""
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
        """(m, 3, 3) per-element F at node positions (n, 3)."""
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

    def energy_and_forces(self, positions_mm: np.ndarray) -> tuple[float, np.ndarray]:
        """Elastic energy (mJ) and internal forces g(x) (n, 3) N, sharing one stress pass."""
        density, stress = self.material.energy_and_stress(
            self.deformation_gradients(positions_mm)
        )
        forces = element_forces(stress, self.gradient_operators, self.tet_volumes_mm3)
        return float(density @ self.tet_volumes_mm3), self._nodal(forces)

    def internal_forces_and_stiffness(
        self, positions_mm: np.ndarray
    ) -> tuple[np.ndarray, sp.csr_matrix]:
        """g(x) (n, 3) N and the tangent stiffness dg/dx over the free dofs, CSR (f, f) N/mm."""
        stress, tangent = self.material.stress_and_tangent(
            self.deformation_gradients(positions_mm)
        )
        forces = element_forces(stress, self.gradient_operators, self.tet_volumes_mm3)
        stiffness = element_stiffness(tangent, self.gradient_operators, self.tet_volumes_mm3)
        return self._nodal(forces), self.pattern.assemble(stiffness)

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
    """(n,) kg: each tetrahedron's mass shared equally among its four nodes."""
    _, volumes = shape_gradients(nodes_mm, tets)
    per_corner = np.repeat((density_kg_mm3 * volumes / 4.0)[:, None], 4, axis=1)
    return np.bincount(tets.ravel(), weights=per_corner.ravel(), minlength=len(nodes_mm))
