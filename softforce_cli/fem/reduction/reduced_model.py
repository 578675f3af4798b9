"""A reduced-order FE model: Galerkin projection on a POD basis with ECSW hyper-reduction.

Configurations are x = x_rest + V q with V (3n, r) orthonormal (zero on clamped dofs), and
the reduced internal forces and tangent are sums over a few sampled elements e with weights
w_e >= 0 (Farhat et al., "Dimensional reduction of nonlinear finite element dynamic models
with finite rotations and energy-based mesh sampling and weighting", IJNME 98, 2014),
sampled here down to single quadrature points p with weights w_p >= 0:

    f_r(x) = sum_p w_p G_p^T vec P_p,     K_r(x) = sum_p w_p G_p^T A_p G_p,

where the operator G_p = B_p V_e (9, r) of each sampled point is formed once, and K_r is
the derivative of f_r (Newton converges quadratically). The forces are one GEMV; the tangent
is assembled from the law's factored A_p (fem.reduction.tangent: the corotational A_p is
2 mu I plus rank 4, so a kept shift term plus symmetric rank-k updates over 4 rows per point,
in float32). Cables, point loads and gravity are not hyper-reduced: they touch a handful of
dofs, or are projected once.

The model keeps the full model's interface (node_count, rest_nodes_mm, cables,
cable_jacobian, ... are the full model's), and its `coordinates` make fem.statics and
fem.compliance work on it unchanged; callers still see full node positions (n, 3).
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
import scipy.sparse as sp

from softforce_cli.fem.assembly import assemble_vector
from softforce_cli.fem.cables import CableInputs, segment_stiffness
from softforce_cli.fem.element import gradient_operators
from softforce_cli.fem.materials import LawEvaluation
from softforce_cli.fem.model import FEModel
from softforce_cli.fem.reduction.dense import DenseFactorization
from softforce_cli.fem.reduction.ecsw import point_operators
from softforce_cli.fem.reduction.starts import StartLibrary
from softforce_cli.fem.reduction.tangent import TANGENT_DTYPE, ReducedTangent
from softforce_cli.fem.threads import on_one_blas_thread

# An actuation beyond the training box by more than this fraction of the box's width warns.
BOX_MARGIN = 0.1
# External forces (besides gravity) beyond this multiple of the largest trained one warn.
FORCE_MARGIN = 1.5
# A reduced static solve ends once its Newton step, or the next one predicted, moves no mode
# by more than this (mm): the solution is then known to about that, where the reduced model
# is 0.03-0.13 mm from its full model (docs/reduced_model.md), and the one or two iterations
# more that the full model's 1e-7 mm costs (a tangent each) buy nothing.
STEP_TOLERANCE_MM = 1e-3
# node_rows keeps the rows of V for node sets of at least this many nodes, the last few sets
# (a sensor asks for its mesh's nodes every update; a handful of nodes costs nothing to gather)
KEPT_NODE_ROWS_FROM = 64
KEPT_NODE_SETS = 4


class ReducedModelWarning(UserWarning):
    """A reduced model is used outside the loads and actuations it was trained on."""


@dataclass(frozen=True)
class TrainingBox:
    """What a reduced model was trained on, and how well it did there.

    controls       : per cable, "displacement" or "force" (the robot file's).
    cable_min, cable_max : (a,) the actuation box, in each cable's control units (mm or N).
    max_force_n    : the largest resultant of the contact forces in the training loads (N).
    gravity_mm_s2  : (3,) the gravity trained with.
    rms_error_mm   : RMS surface displacement error of the reduced model against the full
                     one on validation loads inside the box (mm), NaN when not measured.
    max_displacement_mm : the largest RMS node displacement from rest among the training's
                     equilibria (mm; NaN in files from before it was recorded): a solution
                     that deforms the body further left what the basis was trained on, even
                     when each load is inside the box (two contacts folding the Diamond).
    """

    controls: tuple[str, ...]
    cable_min: np.ndarray
    cable_max: np.ndarray
    max_force_n: float
    gravity_mm_s2: np.ndarray
    rms_error_mm: float
    max_displacement_mm: float = float("nan")


@dataclass(frozen=True)
class Reduction:
    """A trained reduction of one FE model.

    element     : the element it was trained with ("p2", "p2-p0", "p1").
    basis       : (3n, r) orthonormal POD modes, zero on clamped dofs.
    elements    : (s,) int64 the element of each sampled quadrature point (ECSW).
    points      : (s,) int64 the point's index in its element's whole rule (main rule
                  first, then a P2-P0 element's lambda points).
    weights     : (s,) > 0 their weights (multiplying the points' own volumes).
    box         : the training box.
    fingerprint : {part: hash} of the mesh, element, supports, material and cables.
    young_modulus_mpa : E it was trained with (forces scale with E: any E reuses it).
    info        : training figures (modes, energy threshold, ECSW residual, times), for docs.
    starts      : its own equilibria at the training actuations and on a grid over the box,
                  to start static solves from (None in files from before they were kept:
                  solves start at rest; training equilibria only in files from before the
                  grid).
    """

    element: str
    basis: np.ndarray
    elements: np.ndarray
    points: np.ndarray
    weights: np.ndarray
    box: TrainingBox
    fingerprint: dict[str, str]
    young_modulus_mpa: float
    info: dict[str, Any]
    starts: StartLibrary | None = None

    @property
    def mode_count(self) -> int:
        return self.basis.shape[1]


@dataclass(frozen=True)
class ReducedModel:
    """A full FEModel and a Reduction of it; reads as the full model except for its
    `coordinates`, through which static solves and linearisations run reduced.
    tangent_dtype is the precision of the reduced tangent's per-update products
    (fem.reduction.tangent; np.float64 makes it exact to round-off)."""

    full: FEModel
    reduction: Reduction
    tangent_dtype: type = TANGENT_DTYPE

    def __getattr__(self, name: str) -> Any:
        # every attribute that is not reduced (nodes, cables, gravity, ...) is the full model's
        if name.startswith("__") or name in ("full", "reduction", "tangent_dtype"):
            raise AttributeError(name)
        return getattr(self.full, name)

    @property
    def node_count(self) -> int:
        return self.full.node_count

    @property
    def rest_nodes_mm(self) -> np.ndarray:
        return self.full.rest_nodes_mm

    @cached_property
    def coordinates(self) -> ReducedCoordinates:
        return ReducedCoordinates(self)

    def check_solution(self, moved_mm: float) -> None:
        """Warn (ReducedModelWarning) when a solution deforms the body further than every
        training equilibrium did, moved_mm its RMS node displacement from rest: its shape is then
        an extrapolation of the basis. The Diamond's equilibria reach 15.7 mm; the bench's two
        contacts of 0.4 N fold the full model 20.8 mm, and the reduced answer, 5.8 mm RMS off,
        15.7 mm: an extrapolating basis is stiff, so its own deformation understates how far
        outside it is, and no margin is allowed (the bench's 0.25 N probe, 10.4 mm, is 0.28
        mm off)."""
        box = self.reduction.box
        if moved_mm > box.max_displacement_mm:  # False for NaN (a file from before)
            warnings.warn(ReducedModelWarning(
                f"the reduced model's solution moves the body {moved_mm:.1f} mm RMS, beyond its "
                f"training's equilibria ({box.max_displacement_mm:.1f} mm at most): its error "
                f"there is not bounded ({self._error_scale()}); check it with the full model "
                "or retrain with larger forces"), stacklevel=3)

    def _error_scale(self) -> str:
        error = self.reduction.box.rms_error_mm
        return f"{error:.2g} mm RMS inside it" if np.isfinite(error) else "not measured"

    def check_load(self, inputs: CableInputs, external_n: np.ndarray) -> None:
        """Warn (ReducedModelWarning) for actuations or forces far outside the training box,
        with the error measured inside it as the scale of what to expect."""
        box = self.reduction.box
        values = np.asarray(inputs.values, dtype=float)
        width = np.maximum(box.cable_max - box.cable_min, 1e-9)
        beyond = np.maximum(box.cable_min - values, values - box.cable_max) / width
        same = np.array([c == d for c, d in zip(inputs.control, box.controls, strict=False)])
        scale = self._error_scale()
        problems = []
        if len(beyond) and (np.any(beyond[same] > BOX_MARGIN) or not same.all()):
            worst = int(np.argmax(np.where(same, beyond, np.inf)))
            problems.append(f"cable {self.cables[worst].name!r} at {values[worst]:g} is "
                            f"outside the trained [{box.cable_min[worst]:g}, "
                            f"{box.cable_max[worst]:g}]" if same[worst] else
                            f"cable {self.cables[worst].name!r} control changed")
        loads = np.asarray(external_n) - self.full.gravity_forces_n
        force = float(np.linalg.norm(loads.sum(axis=0)))
        if force > FORCE_MARGIN * box.max_force_n:
            problems.append(f"external force {force:.3g} N exceeds the trained "
                            f"{box.max_force_n:.3g} N")
        if not np.allclose(self.full.gravity_mm_s2, box.gravity_mm_s2, atol=1e-6 * 9810):
            problems.append("gravity differs from the trained one")
        if problems:
            ratio = max([*beyond[same], force / max(box.max_force_n, 1e-12) - 1.0, 0.0])
            warnings.warn(ReducedModelWarning(
                f"reduced model used outside its training box ({'; '.join(problems)}): "
                f"its error there is not bounded (estimate {1 + ratio:.1f} x the {scale}); "
                "retrain with `softforce model reduce` over a wider box"), stacklevel=3)


class ReducedCoordinates:
    """fem.coordinates protocol for x = x_rest + V q with hyper-reduced element sums."""

    step_tolerance_mm = STEP_TOLERANCE_MM
    keeps_tangent = True  # an r x r LU (Coordinates.keeps_tangent)

    def __init__(self, model: ReducedModel) -> None:
        full, reduction = model.full, model.reduction
        self.model = model
        self.full = full
        self.basis = np.ascontiguousarray(reduction.basis)
        self.rest = full.rest_nodes_mm
        # the sampled points grouped by the part of the law they carry (P2-P0: mu, lambda),
        # so that each part's points are one slice of every array below
        masks = full.law_parts(reduction.points)
        order = np.concatenate([np.flatnonzero(mask) for mask, _ in masks])
        ends = np.cumsum([mask.sum() for mask, _ in masks])
        self.parts = [(slice(end - mask.sum(), end), part)
                      for (mask, part), end in zip(masks, ends, strict=True)]
        sampled, points = reduction.elements[order], reduction.points[order]
        # each sampled point's element nodes and rule index, in this order
        self.tets = full.tets[sampled]
        self.rule_points = points
        # each sampled point as an element of one point: (s, 1, k, 3)
        self.gradients = full.shape_gradients[sampled, points][:, None]
        # the point's volume times its ECSW weight (s, 1) mm^3
        self.point_weights = (full.law_weights_mm3[sampled, points]
                              * reduction.weights[order])[:, None]
        operators = point_operators(full, self.basis, sampled, self.gradients)  # (s, 1, 9, r)
        r = self.basis.shape[1]
        # stored transposed, (r, 9s): V^T g is then a plain GEMV, twice as fast as the
        # transposed one on these cores
        self.stacked_t = np.ascontiguousarray(operators.reshape(-1, r).T)
        self.points = self.stacked_t.T.reshape(-1, 9, r)  # (s, 9, r), a view
        self.tangent = ReducedTangent(self.points, self.point_weights[:, 0],
                                      model.tangent_dtype)
        # vec F at every sampled point from the positions: one sparse (9s, 3n) product, four
        # times faster than gathering the elements' nodes and a batched product
        B = gradient_operators(self.gradients[:, 0])  # (s, 9, 3k)
        dofs = full.element_dofs[sampled]  # (s, 3k)
        self.gradient_map = sp.csr_matrix(
            (B.ravel(), (np.broadcast_to(np.arange(B.shape[0] * 9).reshape(-1, 9, 1), B.shape)
                         .ravel(), np.broadcast_to(dofs[:, None, :], B.shape).ravel())),
            shape=(9 * len(sampled), 3 * full.node_count))
        self.gradient_map.eliminate_zeros()  # B is two thirds zeros (d_il in its rows)
        # vec F at rest: a state's F is this plus G q, without lifting q to the nodes
        self.rest_gradients = self.gradient_map @ self.rest.ravel()
        # the cables over the few nodes their points touch (local node numbers), with V's rows
        # there: lengths, rows H V and geometric stiffness from those nodes' positions alone
        nodes = np.unique(np.concatenate([np.zeros(0, dtype=np.int64)]
                                         + [c.path.node_indices.ravel() for c in full.cables]))
        self.cable_nodes = nodes
        self.local_cables = [dataclasses.replace(cable, path=dataclasses.replace(
            cable.path, node_indices=np.searchsorted(nodes, cable.path.node_indices)))
            for cable in full.cables]
        self.cable_rest = self.rest[nodes]
        self.cable_basis = self.basis[(3 * nodes[:, None] + np.arange(3)).ravel()]  # (3m, r)
        # every cable's segments at once: their vectors are D x_cables + the pull points (the
        # last segment of each), their rows on V D V (s, 3, r), and the cables' geometric
        # stiffness on the basis sum_s (D_s V)^T S_s (D_s V), one small product in all
        differences = []
        for cable in self.local_cables:
            onto_nodes = np.zeros((len(cable.segment_differences), 3, 3 * len(nodes)))
            np.add.at(onto_nodes, (slice(None), slice(None), cable.dofs),
                      cable.segment_differences)
            differences.append(onto_nodes)
        self.segment_differences = np.concatenate(differences).reshape(-1, 3 * len(nodes))
        self.segment_pulls = np.concatenate([np.vstack([np.zeros((len(c.path) - 1, 3)),
                                                        c.pull_point_mm])
                                             for c in self.local_cables])
        self.segment_cables = np.concatenate([np.full(len(c.path), i)
                                              for i, c in enumerate(self.local_cables)])
        self.segment_rows = (self.segment_differences @ self.cable_basis).reshape(
            -1, 3, self.size)
        # sums over each cable's segments (a, segments), and the cables' rest lengths (a,)
        self.segment_sums = (self.segment_cables
                             == np.arange(len(self.local_cables))[:, None]).astype(float)
        self.cable_rest_lengths = np.array([c.rest_length_mm for c in self.local_cables])
        # elements with clamped and free nodes: an element with every node clamped stays at
        # rest and exerts nothing
        clamped = np.isin(full.tets, full.fixed_nodes)
        supports = np.flatnonzero(clamped.any(axis=1) & ~clamped.all(axis=1))
        self.support_elements = supports
        self.support_dofs = full.element_dofs[supports]
        self.support_nodes = np.unique(full.tets[supports])
        # projected once: reading V (3n, r) costs more than the whole hyper-reduced update
        self.gravity = self.basis.T @ full.gravity_forces_n.ravel()
        self._node_rows: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}

    @property
    def size(self) -> int:
        return self.basis.shape[1]

    @on_one_blas_thread
    def lift(self, values: np.ndarray) -> np.ndarray:
        return self.basis @ values

    def node_rows(self, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(k, 3) rest positions and (3k, r) rows of V at nodes (k,): the nodes' positions are
        rest + V_k q. The rows of the node sets asked for again and again (a sensor's mesh
        nodes) are kept."""
        nodes = np.asarray(nodes, dtype=np.int64)
        key = nodes.tobytes()
        if key in self._node_rows:
            return self._node_rows[key]
        dofs = (3 * nodes[:, None] + np.arange(3)).ravel()
        found = (self.rest[nodes], np.ascontiguousarray(self.basis[dofs]))
        if len(nodes) >= KEPT_NODE_ROWS_FROM:
            if len(self._node_rows) >= KEPT_NODE_SETS:
                self._node_rows.pop(next(iter(self._node_rows)))
            self._node_rows[key] = found
        return found

    @on_one_blas_thread
    def project(self, vectors: np.ndarray) -> np.ndarray:
        return self.basis.T @ vectors

    @on_one_blas_thread
    def project_rows(self, rows) -> np.ndarray:
        if sp.issparse(rows):
            return np.asarray(rows @ self.basis)
        rows = np.asarray(rows)
        used = np.flatnonzero(np.any(rows != 0.0, axis=0))  # rows touch few dofs
        return rows[:, used] @ self.basis[used]

    def project_loads(self, loads) -> np.ndarray:
        """V^T (gravity + loads): gravity's projection once, the point loads' few rows."""
        applied = self.gravity.copy()
        if loads is not None:
            rows = loads.points.cartesian_rows(self.full.node_count)
            applied += self.project_rows(rows).T @ np.asarray(loads.forces_n, float).ravel()
        return applied

    @on_one_blas_thread
    def state(self, positions_mm: np.ndarray | None = None) -> ReducedState:
        if positions_mm is None:
            return ReducedState(self, np.zeros(self.size))
        return ReducedState(self, self.basis.T @ (np.asarray(positions_mm) - self.rest).ravel())

    def start(self, inputs: CableInputs) -> ReducedState:
        """The start equilibrium nearest to the inputs moved to first order (inputs
        outside the box: from the nearest point of the box), or rest in a file without
        them or for other cable controls."""
        reduction = self.model.reduction
        box = reduction.box
        if reduction.starts is None or tuple(inputs.control) != box.controls:
            return ReducedState(self, np.zeros(self.size))
        values = np.clip(inputs.values, box.cable_min, box.cable_max)
        return ReducedState(self, reduction.starts.predict(values))

    def cables(self, positions_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self._cable_terms(np.asarray(positions_mm)[self.cable_nodes])

    @on_one_blas_thread
    def _cable_terms(self, nodes_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Shortenings (a,) mm and rows H V (a, r) from the cables' nodes' positions (m, 3)."""
        shortenings, directions = self._cable_segments(nodes_mm)
        # d(shortening)/dq = -sum over the cable's segments of t_s . (D_s V)
        along = np.einsum("sk,skr->sr", directions, self.segment_rows)
        return shortenings, -(self.segment_sums @ along)

    def _cable_rows(self, nodes_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Shortenings (a,) mm and rows H (a, 3m) over the cables' nodes (positions (m, 3))."""
        shortenings, directions = self._cable_segments(nodes_mm)
        differences = self.segment_differences.reshape(len(directions), 3, -1)
        along = np.einsum("sk,skn->sn", directions, differences)
        return shortenings, -(self.segment_sums @ along)

    def _cable_segments(self, nodes_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Shortenings (a,) mm and every cable segment's unit direction (segments, 3) from
        the cables' nodes' positions (m, 3)."""
        segments = self._segment_vectors(nodes_mm)
        lengths = np.linalg.norm(segments, axis=1)
        return (self.cable_rest_lengths - self.segment_sums @ lengths,
                segments / lengths[:, None])

    def _segment_vectors(self, nodes_mm: np.ndarray) -> np.ndarray:
        """(segments, 3) mm: every cable segment, from the cables' nodes' positions (m, 3)."""
        return (self.segment_differences @ nodes_mm.ravel()).reshape(-1, 3) + self.segment_pulls

    @on_one_blas_thread
    def _forces(self, stress: np.ndarray) -> np.ndarray:
        """V^T g (r,) N from P (s, 3, 3) MPa at the sampled points."""
        return self.stacked_t @ (self.point_weights * stress.reshape(-1, 9)).ravel()

    def energy_and_forces(self, positions_mm: np.ndarray) -> tuple[float, np.ndarray]:
        return self._energy_and_forces(self._law(self.gradient_map @ np.ravel(positions_mm)))

    def forces_and_tangent(self, positions_mm: np.ndarray, tensions_n: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
        positions = np.asarray(positions_mm)
        law = self._law(self.gradient_map @ positions.ravel())
        return (self._energy_and_forces(law)[1],
                self._tangent(law, positions[self.cable_nodes], tensions_n))

    def _law(self, gradients: np.ndarray) -> list[tuple[slice, LawEvaluation]]:
        """The law at the sampled points from vec F (9s,), a slice of points per part."""
        F = gradients.reshape(-1, 3, 3)
        return [(where, self.full.material.evaluate(F[where], part))
                for where, part in self.parts]

    @on_one_blas_thread
    def _energy_and_forces(self, law: list[tuple[slice, LawEvaluation]]
                           ) -> tuple[float, np.ndarray]:
        """Energy (mJ) and V^T g (r,) N from the law at the sampled points."""
        weights = self.point_weights[:, 0]
        stress = np.concatenate([evaluation.stress for _, evaluation in law])
        energy = sum(float(evaluation.energy @ weights[where]) for where, evaluation in law)
        return energy, self._forces(stress)

    @on_one_blas_thread
    def _tangent(self, law: list[tuple[slice, LawEvaluation]], nodes_mm: np.ndarray,
                 tensions_n: np.ndarray) -> np.ndarray:
        """K_r (r, r) N/mm from the law at the sampled points, the cables' nodes' positions
        (m, 3) and their tensions (a,)."""
        tangent_r = self.tangent([(where, evaluation.factors) for where, evaluation in law])
        if np.any(tensions_n):
            tangent_r += self.cable_stiffness(nodes_mm, tensions_n)
        return tangent_r

    def cable_stiffness(self, nodes_mm: np.ndarray, tensions_n: np.ndarray) -> np.ndarray:
        """(r, r) N/mm, the cables' geometric stiffness on the basis from the cables' nodes'
        positions (m, 3) and tensions (a,)."""
        blocks = segment_stiffness(self._segment_vectors(nodes_mm),
                                   np.asarray(tensions_n)[self.segment_cables])
        rows = self.segment_rows
        return rows.reshape(-1, self.size).T @ (blocks @ rows).reshape(-1, self.size)

    def factorize(self, tangent: np.ndarray, previous: DenseFactorization | None = None
                  ) -> DenseFactorization:
        return DenseFactorization(tangent) if previous is None else previous.refactor(tangent)

    def check_load(self, inputs: CableInputs, external_n: np.ndarray) -> None:
        self.model.check_load(inputs, external_n)

    def check_solution(self, state: ReducedState) -> None:
        # V is orthonormal: the RMS node displacement |V q| / sqrt(n) needs no lift
        self.model.check_solution(float(np.linalg.norm(state.q)) / np.sqrt(self.full.node_count))


class ReducedState:
    """A State (fem.coordinates) of a reduced model, x = x_rest + V q: F at the sampled points
    is vec F_rest + G q and the cables' nodes are at x_rest + V q on their rows of V, so a
    static solve's evaluations never form the node positions (a lift reads all of V); each
    is formed when first asked for (a sensing frame moves through states it never
    evaluates)."""

    def __init__(self, space: ReducedCoordinates, q: np.ndarray) -> None:
        self.space = space
        self.q = q

    @cached_property
    @on_one_blas_thread
    def gradients(self) -> np.ndarray:
        """vec F (9s,) at the sampled points."""
        # G q with G stored (r, 9s): the transposed GEMV runs faster than the plain one here
        return self.space.rest_gradients + self.space.stacked_t.T @ self.q

    @cached_property
    @on_one_blas_thread
    def cable_nodes_mm(self) -> np.ndarray:
        """(m, 3) mm: the nodes the cables' points touch."""
        space = self.space
        return space.cable_rest + (space.cable_basis @ self.q).reshape(-1, 3)

    @cached_property
    @on_one_blas_thread
    def positions_mm(self) -> np.ndarray:
        return self.space.rest + (self.space.basis @ self.q).reshape(-1, 3)

    def moved(self, step: np.ndarray, alpha: float) -> ReducedState:
        return ReducedState(self.space, self.q + alpha * step)

    @cached_property
    def law(self) -> list[tuple[slice, LawEvaluation]]:
        """The law at the sampled points (its tangent's factors formed when first asked)."""
        return self.space._law(self.gradients)

    def energy_and_forces(self) -> tuple[float, np.ndarray]:
        return self.space._energy_and_forces(self.law)

    def tangent(self, tensions_n: np.ndarray) -> np.ndarray:
        return self.space._tangent(self.law, self.cable_nodes_mm, tensions_n)

    def forces_and_tangent(self, tensions_n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.energy_and_forces()[1], self.tangent(tensions_n)

    def cables(self) -> tuple[np.ndarray, np.ndarray]:
        return self.space._cable_terms(self.cable_nodes_mm)

    @on_one_blas_thread
    def nodes_mm(self, nodes: np.ndarray) -> np.ndarray:
        if "positions_mm" in self.__dict__:  # lifted already
            return self.positions_mm[nodes]
        rest, rows = self.space.node_rows(nodes)
        return rest + (rows @ self.q).reshape(-1, 3)

    def reactions(self, external_n: np.ndarray, tensions_n: np.ndarray) -> np.ndarray:
        """The elastic forces on the clamped nodes, from the elements that touch them, shifted
        so that the supports hold exactly the applied loads' resultant (the dead loads and the
        cables' pull). Only the support elements' and the cables' nodes are formed.

        The Galerkin equilibrium holds in the basis' span only, so the free nodes next to the
        supports keep small residual forces; the body's internal forces sum to zero, so the
        exact total reaction is -(sum of external forces) for any configuration. The shift is
        shared by the clamped nodes' lumped masses (their tributary volumes).
        """
        space, full = self.space, self.space.full
        fixed = full.fixed_nodes
        loads = np.array(external_n, dtype=float)
        _, rows = space._cable_rows(self.cable_nodes_mm)
        loads[space.cable_nodes] += (rows.T @ tensions_n).reshape(-1, 3)
        positions = space.rest.copy()
        positions[space.support_nodes] = self.nodes_mm(space.support_nodes)
        _, forces, _ = full.element_terms(positions, space.support_elements, False)
        internal = assemble_vector(forces, space.support_dofs, 3 * full.node_count)
        local = -(loads - internal.reshape(-1, 3))[fixed]
        missing = -loads.sum(axis=0) - local.sum(axis=0)
        masses = full.node_masses_kg[fixed]
        share = masses / masses.sum() if masses.sum() > 0 else np.full(len(fixed), 1 / len(fixed))
        return local + share[:, None] * missing
