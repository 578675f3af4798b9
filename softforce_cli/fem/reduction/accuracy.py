"""How far a reduced model is from its full model on load cases it was not trained on.

A case is an actuation and contact forces at surface points that are not feature points (the
centroids of surface triangles with no feature corner), pressing along the face's inward
normal. Both models solve the static equilibrium and are linearised there; the figures are
the RMS surface displacement difference, the relative errors of the compliance matrices
(per matrix, |dW|_F / |W|_F, and the largest entry error over the largest entry), that of
W_ef with the taut displacement-controlled cables held (the compliance sensing solves with:
with taut cables the free blocks are ill-conditioned, docs/reduced_model.md), and the
difference of the support reactions and cable tensions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softforce_cli.fem.attachment import Attachment, attach_points
from softforce_cli.fem.cables import CableInputs
from softforce_cli.fem.compliance import (
    Compliance,
    compliance,
    effector_rows,
    force_rows,
    linearize,
)
from softforce_cli.fem.model import FEModel
from softforce_cli.fem.statics import Equilibrium, PointLoads, solve_equilibrium


@dataclass(frozen=True)
class LoadCase:
    """Cable inputs, and forces_n (c, 3) N at points_mm (c, 3) on the rest surface."""

    inputs: CableInputs
    points_mm: np.ndarray
    forces_n: np.ndarray


@dataclass(frozen=True)
class CaseErrors:
    """Reduced vs full on one case.

    rms_mm           : RMS over surface nodes of the equilibrium position difference.
    max_mm           : largest surface node difference.
    displacement_mm  : RMS surface displacement of the full model from rest (for scale).
    W_relative       : {"W_ea", "W_ef", "W_aa", "W_af": |dW|_F / |W|_F}.
    W_entry          : {name: max |dW_ij| / max |W_ij|}.
    held_ef_relative : |dW|_F / |W|_F of Compliance.held_ef with the cables `held_cables`
                       (nan without forces).
    reaction_n       : |sum of reactions (reduced) - (full)| N.
    tension_n        : max |tension difference| N.
    """

    rms_mm: float
    max_mm: float
    displacement_mm: float
    W_relative: dict[str, float]
    W_entry: dict[str, float]
    held_ef_relative: float
    reaction_n: float
    tension_n: float


def between_features(nodes_mm: np.ndarray, faces: np.ndarray, feature_nodes: np.ndarray,
                     excluded_nodes: np.ndarray, count: int, seed: int = 7
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(count, 3) centroids of surface triangles (f, 3) with no corner among the feature or
    excluded (clamped) nodes, and their outward unit normals (count, 3), chosen at random."""
    avoid = np.zeros(len(nodes_mm), dtype=bool)
    avoid[feature_nodes] = True
    avoid[excluded_nodes] = True
    candidates = faces[~avoid[faces].any(axis=1)]
    picks = np.random.default_rng(seed).choice(len(candidates), size=count, replace=False)
    corners = nodes_mm[candidates[picks]]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return corners.mean(axis=1), normals / np.linalg.norm(normals, axis=1, keepdims=True)


@dataclass(frozen=True)
class CaseResult:
    """A model's answer to a case: its equilibrium and the compliance there."""

    equilibrium: Equilibrium
    compliance: Compliance


def respond(model: FEModel, case: LoadCase, feature_nodes: np.ndarray,
            feature_normals: np.ndarray) -> CaseResult:
    """Solve a case and linearise there: W for the features along their normals (effectors),
    the cables and the case's forces."""
    points = attach_points(model.rest_nodes_mm, model.tets, case.points_mm)
    loads = PointLoads(points, case.forces_n) if len(case.forces_n) else None
    equilibrium = solve_equilibrium(model, case.inputs, loads)
    lin = linearize(model, equilibrium.positions_mm, equilibrium.cable_tensions_n, loads)
    effectors = effector_rows(Attachment.at_nodes(feature_nodes), model.node_count,
                              feature_normals)
    directions = case.forces_n / np.maximum(
        np.linalg.norm(case.forces_n, axis=1, keepdims=True), 1e-300)
    forces = force_rows(points, directions, model.node_count)
    return CaseResult(equilibrium, compliance(lin, effectors, forces))


def held_cables(case: LoadCase, full: CaseResult) -> np.ndarray:
    """(a,) bool: the case's displacement-controlled cables that pull in the full model's
    answer (a slack one holds nothing)."""
    return case.inputs.held(full.equilibrium.cable_tensions_n)


def compare(full: CaseResult, reduced: CaseResult, rest_mm: np.ndarray,
            surface_nodes: np.ndarray, held: np.ndarray | None = None) -> CaseErrors:
    """The reduced answer's errors against the full one; W_ef held with the cables `held`
    (a,) bool (held_cables; None: held_ef_relative is nan)."""
    eq_full, eq_red = full.equilibrium, reduced.equilibrium
    difference = eq_full.positions_mm[surface_nodes] - eq_red.positions_mm[surface_nodes]
    distances = np.linalg.norm(difference, axis=1)
    moved = eq_full.positions_mm[surface_nodes] - rest_mm[surface_nodes]
    relative, entry = {}, {}
    for name in ("W_ea", "W_ef", "W_aa", "W_af"):
        a = np.asarray(getattr(full.compliance, name))
        b = np.asarray(getattr(reduced.compliance, name))
        if a.size:
            relative[name] = _relative(a, b)
            entry[name] = float(np.abs(a - b).max() / max(np.abs(a).max(), 1e-300))
    held_relative = float("nan")
    if held is not None and np.asarray(full.compliance.W_ef).size:
        a, b = full.compliance.held_ef(held), reduced.compliance.held_ef(held)
        held_relative = _relative(a, b)
    return CaseErrors(
        rms_mm=float(np.sqrt(np.mean(distances**2))), max_mm=float(distances.max()),
        displacement_mm=float(np.sqrt(np.mean(np.sum(moved**2, axis=1)))),
        W_relative=relative, W_entry=entry, held_ef_relative=held_relative,
        reaction_n=float(np.linalg.norm(eq_full.reaction_forces_n.sum(axis=0)
                                        - eq_red.reaction_forces_n.sum(axis=0))),
        tension_n=float(np.abs(eq_full.cable_tensions_n - eq_red.cable_tensions_n).max(
            initial=0.0)),
    )


def _relative(expected: np.ndarray, found: np.ndarray) -> float:
    """|found - expected|_F / |expected|_F."""
    return float(np.linalg.norm(found - expected) / max(np.linalg.norm(expected), 1e-300))


def case_errors(full: FEModel, reduced: FEModel, case: LoadCase, surface_nodes: np.ndarray,
                feature_nodes: np.ndarray, feature_normals: np.ndarray) -> CaseErrors:
    """Compare the two models' equilibria and compliances on one case."""
    answer = respond(full, case, feature_nodes, feature_normals)
    return compare(answer, respond(reduced, case, feature_nodes, feature_normals),
                   full.rest_nodes_mm, surface_nodes, held_cables(case, answer))
