"""Ground truth of a scenario: the truth robot (its own mesh, element and law) solved under
each load.

The truth robot is deliberately not the estimator's model: another mesh, an element that does
not lock (the sample truth: quadratic tetrahedra, within about 1 mm of the mesh-converged
body, docs/locking.md) and, by default, a Neo-Hookean law, so that accuracy figures measured
on synthetic data are not inverse crimes, and not flattered by a truth that locks like a
linear-element estimator.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from softforce_cli.errors import ScenarioError, SolverError
from softforce_cli.fem.attachment import Attachment
from softforce_cli.fem.model import FEModel
from softforce_cli.fem.statics import Equilibrium, PointLoads, solve_equilibrium
from softforce_cli.model.config import load_config
from softforce_cli.model.effects import effects_of_kind
from softforce_cli.model.mesh_io import read_tet_mesh
from softforce_cli.model.robot import Robot, build_robot, robot_with_effects
from softforce_cli.sim.scenario import FrameSpec, LoadSpec, Scenario

# Load steps tried, in turn, when a state cannot be reached in one Newton solve.
CONTINUATION_STEPS = (1, 4, 16)
# Lattice points per hook radius that sample a weight's hook (about 120 in a whole ball).
HOOK_SAMPLES_PER_RADIUS = 3


@dataclass(frozen=True)
class Contact:
    """A load as it acts in the solved state.

    kind          : "weight" or "probe".
    rest_point_mm : (3,) where it is attached on the rest shape, robot frame.
    point_mm      : (3,) the same material point in the deformed state.
    force_n       : (3,) force on the robot, N.
    normal        : (3,) outward surface normal at the point (rest shape), or zeros inside.
    """

    kind: str
    rest_point_mm: np.ndarray
    point_mm: np.ndarray
    force_n: np.ndarray
    normal: np.ndarray


@dataclass(frozen=True)
class TruthState:
    equilibrium: Equilibrium
    contacts: tuple[Contact, ...]


def truth_robot(scenario: Scenario) -> Robot:
    """The scenario's robot, with its law replaced by the scenario's `law` if given, and the
    scenario's concealed physics effects added to its own (actuation and sensor effects act
    in sim.simulate; creep, which needs frame times, too)."""
    config = load_config(scenario.robot)
    if scenario.law is not None:
        config = dataclasses.replace(
            config, material=dataclasses.replace(config.material, law=scenario.law)
        )
    spec = config.mesh
    mesh = read_tet_mesh(spec.path, spec.scale, spec.rotation_deg, spec.translation_mm)
    robot = build_robot(config, mesh)
    physics = effects_of_kind(scenario.effects, "physics")
    return robot_with_effects(robot, robot.effects + physics) if physics else robot


def load_points(
    robot: Robot, loads: tuple[LoadSpec, ...]
) -> tuple[Attachment, Attachment, np.ndarray, np.ndarray]:
    """Where each load acts: (the attachment its force acts through, the attachment of its
    point, its force vector (p, 3) N, its surface normal (p, 3)).

    A probe acts at the surface node nearest to its point (a probe touches the skin); a
    weight hangs from a hook: its force is spread uniformly over the material within
    hook_radius_mm of its point (hook_region), which is the point the truth reports.
    """
    mesh = robot.mesh
    points, forces, normals = [], [], []
    for load in loads:
        point = np.array(load.point_mm)
        normal = np.zeros(3)
        if load.kind == "probe":
            surface = mesh.surface_nodes
            node = surface[np.argmin(np.linalg.norm(mesh.nodes_mm[surface] - point, axis=1))]
            point, normal = mesh.nodes_mm[node], mesh.vertex_normals[node]
        direction = -normal if load.direction is None else np.array(load.direction)
        points.append(point)
        forces.append(load.force_n * direction)
        normals.append(normal)
    attachment = robot.attach(np.array(points).reshape(-1, 3))
    acting = [hook_region(robot, points[i], load.hook_radius_mm) if load.hook_radius_mm > 0
              else attachment.subset(np.array([i])) for i, load in enumerate(loads)]
    through = Attachment.concatenate(acting) if acting else attachment
    return through, attachment, np.array(forces).reshape(-1, 3), np.array(normals).reshape(-1, 3)


def hook_region(robot: Robot, point_mm: np.ndarray, radius_mm: float) -> Attachment:
    """One attachment averaging the material within radius_mm of point_mm (3,): a cubic
    lattice of spacing radius_mm / HOOK_SAMPLES_PER_RADIUS inside the ball and the body."""
    steps = np.arange(-HOOK_SAMPLES_PER_RADIUS, HOOK_SAMPLES_PER_RADIUS + 1)
    offsets = np.stack(np.meshgrid(steps, steps, steps, indexing="ij"), -1).reshape(-1, 3)
    offsets = offsets[np.linalg.norm(offsets, axis=1) <= HOOK_SAMPLES_PER_RADIUS]
    samples = robot.attach(point_mm + offsets * (radius_mm / HOOK_SAMPLES_PER_RADIUS))
    if not samples.inside.any():
        raise ScenarioError(f"a weight's hook at {np.round(point_mm, 2).tolist()} mm is outside "
                            "the robot: put point_mm inside the body")
    return samples.subset(samples.inside).mean()


def solve_frame(robot: Robot, frame: FrameSpec, start: Equilibrium | None,
                model: FEModel | None = None) -> TruthState:
    """Equilibrium of the truth robot (or of `model`, its FE model of this frame's context)
    under a frame's actuation and loads.

    Starts from `start` (the previous frame) and, if Newton fails there, walks to the target
    in equal load steps (continuation).
    """
    if len(frame.actuation) != len(robot.cable_specs):
        raise ScenarioError(
            f"a frame gives {len(frame.actuation)} actuation values for the "
            f"{len(robot.cable_specs)} cables of {robot.config.source}"
        )
    target = np.array(frame.actuation, dtype=float)
    acting, attachment, forces, normals = load_points(robot, frame.loads)
    model = robot.fe_model if model is None else model
    controlled = robot.cable_inputs(target).displacement_controlled
    previous_actuation = (
        np.zeros_like(target)
        if start is None
        else np.where(controlled, start.cable_shortenings_mm, start.cable_tensions_n)
    )
    previous_forces = np.zeros_like(forces)
    last_error: SolverError | None = None
    for steps in CONTINUATION_STEPS:
        state = start
        try:
            for step in range(1, steps + 1):
                share = step / steps
                inputs = robot.cable_inputs(
                    previous_actuation + share * (target - previous_actuation)
                )
                loads = PointLoads(acting, previous_forces + share * (forces - previous_forces))
                state = solve_equilibrium(
                    model, inputs, loads, None if state is None else state.positions_mm
                )
            break
        except SolverError as error:
            last_error = error
    else:
        raise ScenarioError(
            f"the truth robot cannot reach a frame's state even in "
            f"{CONTINUATION_STEPS[-1]} load steps: {last_error}"
        )
    deformed = attachment.positions(state.positions_mm)
    rest = attachment.positions(robot.rest_nodes_mm)
    contacts = tuple(
        Contact(load.kind, rest[i], deformed[i], forces[i], normals[i])
        for i, load in enumerate(frame.loads)
    )
    return TruthState(state, contacts)
