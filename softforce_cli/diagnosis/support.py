"""A plate under the body (support_contact), screened by solving the contact at every state.

A one-sided plane has no first-order signature: below the body it changes nothing, and
where it touches it props the body by as much as the body sags onto it. So the screening
solves the contact itself on each state's linearisation. The nodes that may touch a plate
(`contact_candidates`: free surface nodes not facing up that sink below their rest height
and below the highest plate searched) get their held-cable responses to upward unit forces
(diagnosis.sensitivities.contact_responses); at state s, with their predicted heights z_s
(m,) and compliance C_s (m, m: the height change of each under a unit force at each), a
plate at height h pushes those above it at rest (the others pass through its hole, as
fem.supports.SupportPlane does) with forces lam >= 0 such that

    z_s + C_s lam >= h,    lam >= 0,    lam . (z_s + C_s lam - h) = 0,

the linear complementarity problem of min 1/2 lam^T C_s lam + (z_s - h)^T lam over lam >= 0
(`one_sided_contact`). The body then moves by the responses times lam. The exact refit
solves the plate itself (fem.supports, diagnosis.refit).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.optimize

from softforce_cli.diagnosis.sensitivities import contact_responses
from softforce_cli.diagnosis.solves import Progress, SolveCache, StateSolutions
from softforce_cli.fem.compliance import linearize
from softforce_cli.model.robot import Robot

# Plates are searched from the lowest point the body reaches up to this height above it: a
# support props the lower part of a body, and every node that may touch one costs a solve
# per input.
SUPPORT_REACH_MM = 40.0
# A node whose outward normal points up more than this (its z component) faces away from
# any plate below it.
UPWARD_NORMAL = 0.5
# A node that sinks less than this below its rest height in every state cannot press on a
# plate by more than the camera resolves.
MIN_SINK_MM = 0.5
# At most this many nodes, the lowest reaching: each costs a solve per input, n x 3 floats of
# memory per input and a column of every contact problem (118 on the coarse Diamond).
MAX_CONTACT_NODES = 200
# Cholesky factors of the contact compliances kept for the plate's fits (SupportBasis): one per
# distinct input and set of nodes above the plate, at most MAX_CONTACT_NODES^2 floats each
# (0.3 MB): a fit visits a few such sets, and this bounds the memory to 40 MB.
KEPT_FACTORS = 128
# Bump when what the cached responses mean changes.
SUPPORT_VERSION = 1


@dataclass(frozen=True, eq=False)
class SupportBasis:
    """What the screening of a plate needs at each of the U distinct inputs of the states
    (states of equal inputs, a hold and its loading, share one equilibrium).

    nodes      : (m,) mesh nodes that may touch a plate.
    rest_z_mm  : (m,) their rest heights (robot frame).
    of_state   : (S,) each state's distinct input.
    heights_mm : (U, m) their predicted heights.
    compliance : (U, m, m) mm/N: height change of node i under a unit upward force at j.
    responses  : (U, m, n, 3) mm/N: every mesh node's motion under those forces (float32).
    lower_mm, upper_mm : the plate heights searched.
    """

    nodes: np.ndarray
    rest_z_mm: np.ndarray
    of_state: np.ndarray
    heights_mm: np.ndarray
    compliance: np.ndarray
    responses: np.ndarray
    lower_mm: float
    upper_mm: float
    _factors: dict = field(default_factory=dict, init=False, repr=False)

    def forces_n(self, height_mm: float) -> np.ndarray:
        """(U, m) N: the plate's upward force on each node at every distinct input."""
        above = self.rest_z_mm > height_mm
        forces = np.zeros(self.heights_mm.shape)
        for u, z in enumerate(self.heights_mm):
            gap = z[above] - height_mm
            if (gap < 0.0).any():
                forces[u, above] = one_sided_contact(self._cholesky(u, above), gap)
        return forces

    def _cholesky(self, u: int, above: np.ndarray) -> np.ndarray:
        """The lower Cholesky factor of input u's compliance among the nodes `above` (m,)
        bool, kept per set of nodes: a fit of the plate's height crosses a node's rest
        height only now and then, and asks for the same factors at every evaluation."""
        key = (u, above.tobytes())
        factor = self._factors.get(key)
        if factor is None:
            if len(self._factors) >= KEPT_FACTORS:
                self._factors.clear()
            factor = self._factors[key] = contact_cholesky(
                self.compliance[u][np.ix_(above, above)])
        return factor

    def motion_mm(self, height_mm: float) -> np.ndarray:
        """(S, n, 3) mm: every mesh node's motion with a plate at height_mm (robot frame), per
        state."""
        forces = self.forces_n(height_mm)
        motion = np.zeros((len(forces), *self.responses.shape[2:]))
        for u in np.flatnonzero(forces.any(axis=1)):
            pressed = np.flatnonzero(forces[u])  # a plate props a few of the m nodes
            motion[u] = np.tensordot(forces[u, pressed], self.responses[u, pressed], axes=1)
        return motion[self.of_state]


def contact_cholesky(compliance: np.ndarray) -> np.ndarray:
    """(m, m) lower Cholesky factor of a compliance (m, m) mm/N, symmetrised first (what
    one_sided_contact solves with)."""
    return scipy.linalg.cholesky(0.5 * (compliance + compliance.T), lower=True)


def one_sided_contact(lower: np.ndarray, gap_mm: np.ndarray) -> np.ndarray:
    """(m,) N: lam >= 0 with gap + C lam >= 0 and lam . (gap + C lam) = 0, for a symmetric
    positive definite compliance C = L L^T (mm/N) given by its lower Cholesky factor L
    (m, m; contact_cholesky) and gaps (m,) mm (negative: below the plane).

    min 1/2 lam^T C lam + gap^T lam = 1/2 |L^T lam + L^-1 gap|^2 - const, a non-negative
    least-squares problem (scipy's nnls, an active-set method: exact in finitely many steps).
    """
    target = -scipy.linalg.solve_triangular(lower, gap_mm, lower=True)
    return scipy.optimize.nnls(lower.T, target)[0]


def facing_down(robot: Robot) -> np.ndarray:
    """(k,) sorted: the free surface nodes whose outward normal does not point up (those a
    plate below may touch)."""
    mesh = robot.mesh
    nodes = np.setdiff1d(mesh.surface_nodes, robot.fixed_nodes)
    return nodes[mesh.vertex_normals[nodes, 2] < UPWARD_NORMAL]


def rim_heights_mm(robot: Robot, height_mm: float) -> tuple[float | None, float | None]:
    """(below, above) mm: the rest heights of the free surface nodes not facing up nearest a
    plate at height_mm, at or below it and above it (None: no such node). The plate
    props the nodes above it at rest and lets the others through, so between the two it
    props the same nodes and its prediction is smooth; past either it jumps: a fitted height
    is resolved to that spacing, whatever its interval says."""
    heights = robot.mesh.nodes_mm[facing_down(robot), 2]
    below, above = heights[heights <= height_mm], heights[heights > height_mm]
    return (float(below.max()) if len(below) else None,
            float(above.min()) if len(above) else None)


def contact_candidates(robot: Robot, predicted_mm: np.ndarray
                       ) -> tuple[np.ndarray, float, float]:
    """(nodes (m,), lowest plate height, highest) for the predicted mesh nodes (S, n, 3).

    The nodes: free surface nodes not facing up that sink at least MIN_SINK_MM below their
    rest height in some state (the MAX_CONTACT_NODES that reach lowest). The heights: from
    the lowest any of them reaches (a plate there touches nothing) up SUPPORT_REACH_MM, or
    to the highest candidate's rest height when lower (a plate above a node's rest height
    lets it through); the nodes that never reach that high are left out. Neither assumes
    where the robot stands: a body on a table, a finger hanging from a mount.
    """
    rest = robot.mesh.nodes_mm
    nodes = facing_down(robot)
    deepest = predicted_mm[:, nodes, 2].min(axis=0)
    keep = deepest < rest[nodes, 2] - MIN_SINK_MM
    if not keep.any():
        return nodes[:0], 0.0, 0.0
    lowest = float(deepest[keep].min())
    keep &= deepest < lowest + SUPPORT_REACH_MM
    nodes = nodes[keep][np.argsort(deepest[keep], kind="stable")[:MAX_CONTACT_NODES]]
    nodes.sort()
    return nodes, lowest, min(lowest + SUPPORT_REACH_MM, float(rest[nodes, 2].max()))


def support_basis(solutions: StateSolutions, cache: SolveCache,
                  progress: Progress | None = None,
                  stop_requested: Callable[[], bool] = lambda: False
                  ) -> SupportBasis | None:
    """The plate's screening data at every state of `solutions` (one tangent factorisation
    and m solves per distinct state, cached with the states' solves); None when no node may
    touch a plate, or when stop_requested() turns true."""
    robot = solutions.robot
    nodes, lower, upper = contact_candidates(robot, solutions.predicted_mm)
    if not len(nodes) or upper <= lower:
        return None
    model = robot.nominal_fe_model
    n = robot.mesh.node_count
    controls = tuple(spec.control for spec in robot.cable_specs)
    tag = hashlib.sha256(nodes.tobytes()).hexdigest()[:12]
    _, firsts, of_state = np.unique(solutions.actuation, axis=0, return_index=True,
                                    return_inverse=True)
    responses = np.empty((len(firsts), len(nodes), n, 3), dtype=np.float32)
    factor = None
    for u, s in enumerate(firsts):
        if stop_requested():
            return None
        inputs = robot.cable_inputs(solutions.actuation[s])
        key = f"{cache.key(model, inputs)}-support{SUPPORT_VERSION}-{tag}"
        stored = cache.load(key)
        if stored is not None and stored["responses"].shape == responses[u].shape:
            responses[u] = stored["responses"]
        else:
            lin = linearize(model, solutions.positions_mm[s], solutions.tensions_n[s],
                            factorization=factor)
            factor = lin.factorization
            responses[u] = contact_responses(lin, solutions.tensions_n[s], controls,
                                             nodes)[:, :n]
            cache.store(key, responses=responses[u])
        if progress is not None:
            progress(u + 1, len(firsts))
    # C[u, i, j]: node i's height change under a unit force at node j
    compliance = responses[:, :, nodes, 2].transpose(0, 2, 1).astype(float)
    return SupportBasis(nodes, robot.mesh.nodes_mm[nodes, 2], of_state.ravel(),
                        solutions.predicted_mm[firsts][:, nodes, 2], compliance, responses,
                        lower, upper)
