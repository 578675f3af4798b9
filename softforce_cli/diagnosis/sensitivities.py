"""First-order response of the equilibrium to every effect's parameters, from one tangent.

At an equilibrium x of f_ext(p) - g(x; p) + H^T lam = 0 with the displacement-controlled
cables' constraints delta(x) = u(p) (H = d delta / dx), a parameter change dp moves

    dx = K^-1 b + Z W^-1 (du - H K^-1 b),   Z = K^-1 H_A^T,  W = H_A Z   (eq. 4-5)

with b = d(f_ext - g)/dp and du = du/dp, A the taut cables (a slack cable imposes nothing).
One factorisation of K per state serves every column:

- gravity: b = the nodal weights' change per unit of scale and per degree of tilt;
- stiffness_scale: every law is linear in its modulus, b = -g(x) per unit of scale;
  regional_stiffness: the same over one region's elements;
- material_nonlinearity: the energy is blended linearly, b = g_law(x) - g_other(x) (which
  diagnosis.solves replaces by the exact change to blend 1 wherever the other law solves);
- compliant_base, in compliance c = 1/k: the clamped nodes move rigidly as the springs
  allow under the clamp's net reaction (the soft-clamp limit, _base_give), which moves the
  free nodes through the elements and shortens the cables by H d;
- cables: du = a unit of one taut cable's input (slack, friction and creep's columns are
  built from these and the stiffness column in diagnosis.hypotheses).

support_contact has no column (a plane below the body changes nothing until it touches):
contact_responses gives the held-cable responses to upward forces at the nodes that may
touch it, from which diagnosis.support solves the contact itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softforce_cli.fem.compliance import Linearization
from softforce_cli.fem.model import NEWTON_PER_KG_MM_S2, FEModel
from softforce_cli.model.effect_physics import (
    base_springs,
    effective_gravity,
    fe_model_with_effects,
)
from softforce_cli.model.effects import make_effect
from softforce_cli.model.regions import element_regions
from softforce_cli.model.robot import Robot

# Regions a regional stiffness may target: every region but the base, whose give is what
# compliant_base models (the two are one signature at the clamp).
EXCLUDED_REGIONS = ("base",)
# Finite step of the tilt derivative (deg): effective_gravity is smooth, the step is far
# below its curvature and far above round-off.
TILT_STEP_DEG = 1e-4
# Largest motion of the clamped nodes in the finite difference of the elastic forces (mm).
BASE_PROBE_MM = 1e-3


@dataclass(frozen=True)
class ColumnSet:
    """Names of the sensitivity columns of a robot, in order (C of them)."""

    names: tuple[str, ...]

    def index(self, name: str) -> int:
        return self.names.index(name)


def column_set(robot: Robot) -> ColumnSet:
    """gravity (3), stiffness, regions, blend, base compliance, one per cable."""
    regions = [r for r in element_regions(robot) if r not in EXCLUDED_REGIONS]
    return ColumnSet((
        "gravity.scale", "gravity.tilt_x_deg", "gravity.tilt_y_deg", "stiffness",
        *(f"region.{r}" for r in regions), "blend", "base_compliance",
        *(f"cable.{spec.name}" for spec in robot.cable_specs)))


def state_columns(robot: Robot, columns: ColumnSet, lin: Linearization,
                  tensions_n: np.ndarray) -> np.ndarray:
    """(C, N, 3) mm per unit of each column's parameter at every FE node, at the
    equilibrium of `lin` (the nominal model of `robot`) with cable tensions (a,)."""
    model: FEModel = lin.model
    x = lin.positions_mm
    size = 3 * model.node_count
    forces = np.zeros((size, len(columns.names)))  # b per column
    inputs = np.zeros((len(model.cables), len(columns.names)))  # du per column
    prescribed = np.zeros((size, len(columns.names)))  # clamped-node motion per column
    internal = model.internal_forces(x).ravel()
    displacement = np.array([spec.control == "displacement" for spec in robot.cable_specs])
    gravity = np.asarray(model.gravity_mm_s2, dtype=float)
    regions = element_regions(robot)
    for j, name in enumerate(columns.names):
        if name == "gravity.scale":
            forces[:, j] = _weights(model, effective_gravity(gravity, make_effect("gravity")))
        elif name.startswith("gravity.tilt"):
            axis = name.removeprefix("gravity.")
            up = effective_gravity(gravity, make_effect("gravity", **{axis: TILT_STEP_DEG}))
            down = effective_gravity(gravity, make_effect("gravity", **{axis: -TILT_STEP_DEG}))
            forces[:, j] = _weights(model, (up - down) / (2 * TILT_STEP_DEG))
        elif name == "stiffness":
            forces[:, j] = -internal
        elif name.startswith("region."):
            which = np.flatnonzero(regions[name.removeprefix("region.")])
            _, element_forces, _ = model.element_terms(x, which, with_tangent=False)
            forces[:, j] = -np.bincount(model.element_dofs[which].ravel(),
                                        weights=element_forces.ravel(), minlength=size)
        elif name == "blend":
            other = fe_model_with_effects(robot, (make_effect("material_nonlinearity",
                                                              blend=1.0),))
            forces[:, j] = internal - other.internal_forces(x).ravel()
        elif name == "base_compliance":
            forces[:, j], prescribed[:, j] = _base_give(model, x, tensions_n, internal)
        elif name.startswith("cable."):
            inputs[[c.name for c in model.cables].index(name.removeprefix("cable.")), j] = 1.0
    H = model.cable_jacobian(x)
    # a force-controlled cable's input is its tension: a unit more is a force H^T along it
    pulled = ~displacement
    forces += H[pulled].T @ inputs[pulled]
    inputs[pulled] = 0.0
    inputs -= H @ prescribed  # the clamp's give shortens the cables too
    taut = displacement & (tensions_n > 0.0)
    motion = prescribed + _constrained_response(lin, H[taut], forces, inputs[taut])
    return motion.reshape(model.node_count, 3, -1).transpose(2, 0, 1)


def contact_responses(lin: Linearization, tensions_n: np.ndarray, controls: tuple[str, ...],
                      nodes: np.ndarray) -> np.ndarray:
    """(m, N, 3) mm per N: the motion of every FE node under a unit upward force at each of
    `nodes` (m,), with the taut displacement-controlled cables held at their inputs (the
    cables' `controls`, tensions (a,) N), at the equilibrium of `lin`."""
    model: FEModel = lin.model
    forces = np.zeros((3 * model.node_count, len(nodes)))
    forces[3 * np.asarray(nodes) + 2, np.arange(len(nodes))] = 1.0
    taut = (np.array([c == "displacement" for c in controls], dtype=bool)
            & (np.asarray(tensions_n) > 0.0))
    rows = model.cable_jacobian(lin.positions_mm)[taut]
    motion = _constrained_response(lin, rows, forces, np.zeros((len(rows), len(nodes))))
    return motion.reshape(model.node_count, 3, -1).transpose(2, 0, 1)


def _weights(model: FEModel, gravity_mm_s2: np.ndarray) -> np.ndarray:
    """(3N,) N: nodal weights under a gravity vector (3,)."""
    return (np.outer(model.node_masses_kg, gravity_mm_s2) * NEWTON_PER_KG_MM_S2).ravel()


def _base_give(model: FEModel, x: np.ndarray, tensions_n: np.ndarray,
               internal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(b (3N,), prescribed motion (3N,)) per unit of base compliance (mm/N).

    The clamp's give is the rigid motion its springs allow under the clamp's net reaction
    (force and moment about the springs' centre): the soft-clamp limit, which a compliant
    base must approach to be seen at all. The derivative at the rigid clamp (each node
    giving by its own reaction, -R_i / k_i) is dominated by the clamp's self-balancing
    reactions, which relax as soon as the clamp gives: on the Diamond it predicts 8-10 times
    the response of a 2 or 10 N/mm base (correlation 0.85), the rigid give 1.0 and 0.8 times
    it (correlation 0.99; docs/diagnosis.md).
    """
    _, springs = base_springs(model, 1.0)  # shares of a unit total stiffness
    reactions = model.coordinates.state(x.reshape(-1, 3)).reactions(model.gravity_forces_n,
                                                                    tensions_n)
    carried = -reactions[np.searchsorted(model.fixed_nodes, springs.nodes)]  # (s, 3) N
    k = springs.stiffness_n_per_mm
    arm = x.reshape(-1, 3)[springs.nodes]
    arm = arm - k @ arm / k.sum()
    # 6x6 spring system about the centre: translation k_total, rotation sum k (|d|^2 I - d d^T)
    turning = np.einsum("s,sij->ij", k, np.einsum("si,si->s", arm, arm)[:, None, None]
                        * np.eye(3) - arm[:, :, None] * arm[:, None, :])
    rotation = np.linalg.solve(turning, np.cross(arm, carried).sum(axis=0))
    give = np.zeros((model.node_count, 3))
    give[springs.nodes] = carried.sum(axis=0) / k.sum() + np.cross(rotation, arm)
    give = give.ravel()
    step = BASE_PROBE_MM / max(float(np.abs(give).max()), 1e-30)
    moved = model.internal_forces(x + step * give.reshape(-1, 3)).ravel()
    return -(moved - internal) / step, give


def _constrained_response(lin: Linearization, rows: np.ndarray, forces: np.ndarray,
                          inputs: np.ndarray) -> np.ndarray:
    """(3N, C): dx = K^-1 b + Z W^-1 (du - H K^-1 b) for the taut cables' rows H (A, 3N),
    forces b (3N, C) and input changes du (A, C)."""
    space = lin.model.coordinates
    free = space.lift(lin.factorization.solve(space.project(forces)))  # K^-1 b, (3N, C)
    if not len(rows):
        return free
    Z = lin.responses(rows)  # (3N, A)
    W = rows @ Z
    multipliers = np.linalg.solve(W, inputs - rows @ free)
    return free + Z @ multipliers
