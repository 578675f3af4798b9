"""Linearisation at a configuration: tangent, free motion and compliance matrices (eq. 3-6).

    delta_e = W_ea lam_a + W_ef lam_f + delta_e_free          (3)
    delta_a = W_aa lam_a + W_af lam_f + delta_a_free          (4)
    W_ij    = H_i K^-1 H_j^T                                  (5)

Effectors (e), actuators (a) and external forces (f) are each a set of rows H over the dofs.
Only K^-1 H_a^T and K^-1 H_f^T are solved for (a + f columns), since every W in (3)-(4) has
an actuator or force index on its right.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from softforce_cli.fem.attachment import Attachment
from softforce_cli.fem.linear_solver import Factorization
from softforce_cli.fem.model import FEModel
from softforce_cli.fem.statics import PointLoads, external_forces


@dataclass(frozen=True)
class Linearization:
    """The model linearised at a configuration x.

    positions_mm     : (n, 3) the configuration.
    cable_tensions_n : (a,) cable forces whose geometric stiffness is in K.
    free_motion_mm   : (n, 3) K^-1 (f_ext - g(x)): where the nodes go, to first order, if
                       every constraint force (cables, external forces) is removed.
    factorization    : of K(x) over the free dofs.
    """

    model: FEModel
    positions_mm: np.ndarray
    cable_tensions_n: np.ndarray
    free_motion_mm: np.ndarray
    factorization: Factorization

    def responses(self, rows: np.ndarray) -> np.ndarray:
        """K^-1 H^T for dense rows H (k, 3n) -> (3n, k) mm per unit force; clamped dofs 0."""
        free = self.model.free_dofs
        solved = self.factorization.solve(rows[:, free].T)
        out = np.zeros((3 * self.model.node_count, rows.shape[0]))
        out[free] = solved
        return out


def linearize(
    model: FEModel,
    positions_mm: np.ndarray,
    cable_tensions_n: np.ndarray | None = None,
    loads: PointLoads | None = None,
    factorization: Factorization | None = None,
) -> Linearization:
    """Assemble and factorise K(x) (elastic + cable geometric stiffness) and the free motion.

    Pass the previous Linearization's factorization to reuse its symbolic analysis.
    """
    tensions = np.zeros(len(model.cables)) if cable_tensions_n is None else cable_tensions_n
    internal, stiffness = model.internal_forces_and_stiffness(positions_mm)
    tangent = stiffness + model.cable_stiffness(positions_mm, tensions)
    factor = (
        Factorization(tangent) if factorization is None else factorization.refactor(tangent)
    )
    free = model.free_dofs
    motion = np.zeros(3 * model.node_count)
    motion[free] = factor.solve((external_forces(model, loads) - internal).ravel()[free])
    return Linearization(model, positions_mm, tensions, motion.reshape(-1, 3), factor)


@dataclass(frozen=True)
class Compliance:
    """Projected compliance matrices and free displacements of eq. 3-5 (mm/N and mm).

    W_ea (e, a), W_ef (e, f), W_aa (a, a), W_af (a, f);
    delta_e_free (e,): effector coordinates after the free motion;
    delta_a_free (a,): cable shortenings after the free motion.
    """

    W_ea: np.ndarray
    W_ef: np.ndarray
    W_aa: np.ndarray
    W_af: np.ndarray
    delta_e_free: np.ndarray
    delta_a_free: np.ndarray


def effector_rows(
    points: Attachment, node_count: int, normals: np.ndarray | None = None
) -> sp.csr_matrix:
    """H_e: (3p, 3n) for 3D effectors, or (p, 3n) along unit normals (p, 3) (eq. 10)."""
    if normals is None:
        return points.cartesian_rows(node_count)
    return points.directional_rows(normals, node_count)


def force_rows(points: Attachment, directions: np.ndarray, node_count: int) -> sp.csr_matrix:
    """H_f: (f, 3n), unit force j applied along directions[j] (f, 3) at points[j]."""
    return points.directional_rows(directions, node_count)


def compliance(
    linearization: Linearization, effectors: sp.spmatrix, forces: sp.spmatrix
) -> Compliance:
    """W matrices and free displacements for effector rows H_e and force rows H_f."""
    model = linearization.model
    positions = linearization.positions_mm.ravel()
    actuators = model.cable_jacobian(linearization.positions_mm)
    response = linearization.responses(np.vstack([actuators, forces.toarray()]))
    a = actuators.shape[0]
    free_motion = linearization.free_motion_mm.ravel()
    return Compliance(
        W_ea=effectors @ response[:, :a],
        W_ef=effectors @ response[:, a:],
        W_aa=actuators @ response[:, :a],
        W_af=actuators @ response[:, a:],
        delta_e_free=effectors @ (positions + free_motion),
        delta_a_free=model.cable_shortenings(linearization.positions_mm)
        + actuators @ free_motion,
    )
