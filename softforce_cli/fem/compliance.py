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
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from softforce_cli.fem.attachment import Attachment
from softforce_cli.fem.coordinates import Factor, State
from softforce_cli.fem.model import FEModel
from softforce_cli.fem.statics import PointLoads


@dataclass(frozen=True)
class Linearization:
    """The model linearised at a configuration.

    state            : the configuration (fem.coordinates State); positions_mm (n, 3) are its
                       node positions (a reduced model lifts them when first asked for).
    cable_tensions_n : (a,) cable forces whose geometric stiffness is in K.
    free_motion      : (c,) K^-1 (f_ext - g(x)) in the model's coordinates (fem.coordinates);
                       free_motion_mm is it as node motions (n, 3): where the nodes go, to
                       first order, if every constraint force (cables, forces) is removed.
    factorization    : of K(x) in the model's coordinates (fem.coordinates: the free dofs,
                       or a reduced basis).
    """

    model: FEModel
    state: State
    cable_tensions_n: np.ndarray
    free_motion: np.ndarray
    factorization: Factor

    @property
    def positions_mm(self) -> np.ndarray:
        return self.state.positions_mm

    @cached_property
    def free_motion_mm(self) -> np.ndarray:
        """(n, 3) mm: the free motion at the nodes."""
        return self.model.coordinates.lift(self.free_motion).reshape(-1, 3)

    def solve_rows(self, rows) -> np.ndarray:
        """(K^-1 in coordinates) (H T)^T for rows H (k, 3n) -> (c, k)."""
        projected = self.model.coordinates.project_rows(rows)
        projected = projected.toarray() if sp.issparse(projected) else projected
        return self.factorization.solve(projected.T)

    def responses(self, rows: np.ndarray) -> np.ndarray:
        """K^-1 H^T for rows H (k, 3n) (dense or sparse) -> (3n, k) mm per unit force; clamped
        dofs 0. In a model's coordinates x = x_0 + T q this is T (T^T K T)^-1 (H T)^T."""
        return self.model.coordinates.lift(self.solve_rows(rows))


def linearize(
    model: FEModel,
    positions_mm: np.ndarray,
    cable_tensions_n: np.ndarray | None = None,
    loads: PointLoads | None = None,
    factorization: Factor | None = None,
) -> Linearization:
    """Assemble and factorise K(x) (elastic + cable geometric stiffness) and the free motion
    at node positions (n, 3) (a reduced model's: the nearest configuration in its span).

    Pass the previous Linearization's factorization to reuse its symbolic analysis.
    """
    return linearize_state(model, model.coordinates.state(positions_mm), cable_tensions_n,
                           loads, factorization)


def linearize_state(
    model: FEModel,
    state: State,
    cable_tensions_n: np.ndarray | None = None,
    loads: PointLoads | None = None,
    factorization: Factor | None = None,
) -> Linearization:
    """linearize() at a configuration given as a State of the model's coordinates (as a
    sensing loop holds it: a reduced model then never forms all the node positions)."""
    tensions = np.zeros(len(model.cables)) if cable_tensions_n is None else cable_tensions_n
    space = model.coordinates
    internal, tangent = state.forces_and_tangent(tensions)
    factor = space.factorize(tangent, factorization)
    motion = factor.solve(space.project_loads(loads) - internal)
    return Linearization(model, state, tensions, motion, factor)


def rows_at(rows, state: State) -> np.ndarray:
    """H x (k,) for rows H (k, 3n) (dense or sparse) at a configuration, from the positions of
    the few nodes the rows touch."""
    rows = rows if sp.issparse(rows) and rows.format == "csr" else sp.csr_matrix(rows)
    nodes, inverse = np.unique(rows.indices // 3, return_inverse=True)
    values = rows.data * state.nodes_mm(nodes).ravel()[3 * inverse + rows.indices % 3]
    owners = np.repeat(np.arange(rows.shape[0]), np.diff(rows.indptr))
    return np.bincount(owners, weights=values, minlength=rows.shape[0])


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

    def held_ef(self, held: np.ndarray) -> np.ndarray:
        """(e, f) mm/N: the effectors' motion per unit force with the cables `held` (a,) bool
        kept at their lengths, W_ef - W_eh W_hh^-1 W_hf (eq. 3-4 with delta_h fixed: what a
        displacement-controlled taut cable does, and what sensing's eq. 14 solves with)."""
        held = np.asarray(held, dtype=bool)
        if not held.any():
            return np.asarray(self.W_ef)
        tensions = np.linalg.solve(np.asarray(self.W_aa)[np.ix_(held, held)],
                                   np.asarray(self.W_af)[held])
        return np.asarray(self.W_ef) - np.asarray(self.W_ea)[:, held] @ tensions


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
    """W matrices and free displacements for effector rows H_e and force rows H_f.

    Worked in the model's coordinates (W_ij = (H_i T) K^-1 (H_j T)^T), so a reduced model
    never lifts its solutions to the nodes.
    """
    space = linearization.model.coordinates
    # the cables' rows come projected (H_a T, from the few nodes they touch): neither a
    # dense (a, 3n) row array nor its sparse copy is formed
    shortenings, projected_a = linearization.state.cables()
    projected_f = space.project_rows(forces)
    projected_f = projected_f.toarray() if sp.issparse(projected_f) else projected_f
    a = len(projected_a)
    solved = linearization.factorization.solve(np.vstack([projected_a, projected_f]).T)
    projected_e = space.project_rows(effectors)
    free_motion = linearization.free_motion
    return Compliance(
        W_ea=np.asarray(projected_e @ solved[:, :a]),
        W_ef=np.asarray(projected_e @ solved[:, a:]),
        W_aa=projected_a @ solved[:, :a],
        W_af=projected_a @ solved[:, a:],
        delta_e_free=np.asarray(rows_at(effectors, linearization.state)
                                + projected_e @ free_motion),
        delta_a_free=shortenings + projected_a @ free_motion,
    )
