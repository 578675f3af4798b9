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
from softforce_cli.fem.statics import Equilibrium, PointLoads, SolverSettings, solve_equilibrium
from softforce_cli.model.config import load_config
from softforce_cli.model.effects import effects_of_kind
from softforce_cli.model.mesh_io import read_tet_mesh
from softforce_cli.model.robot import Robot, build_robot, robot_with_effects
from softforce_cli.sim.scenario import FrameSpec, LoadSpec, Scenario

# Load steps tried, in turn, when a state cannot be reached in one Newton solve.
CONTINUATION_STEPS = (1, 4, 16)
# Lattice points per hook radius that sample a weight's hook (about 120 in a whole ball).
HOOK_SAMPLES_PER_RADIUS = 3
# Two equilibria under one frame's loads are two states of the body when a node lies this far
# apart in them: far above the solver's tolerance (1e-7 mm), below any camera's noise.
BRANCH_SEPARATION_MM = 0.1
# Load steps of the way back that confirms a snap-through: one Newton solve over a whole
# frame's step can land on another equilibrium than the branch the body moved along.
PATH_STEPS = 8
# The way back needs its state to a hundredth of BRANCH_SEPARATION_MM only: Newton stops a
# step or two earlier than at the truth's own tolerance.
WAY_BACK = SolverSettings(step_tolerance_mm=1e-3)


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
                model: FEModel | None = None,
                loads_before: tuple[LoadSpec, ...] = ()) -> TruthState:
    """Equilibrium of the truth robot (or of `model`, its FE model of this frame's context)
    under a frame's actuation and loads.

    Starts from `start` (the previous frame's state, under its loads `loads_before`) and, if
    Newton fails there, walks to the target in equal steps (continuation) of the cable
    inputs and of the loads, from the previous frame's to this one's, as the body moves
    between the two frames.
    """
    if len(frame.actuation) != len(robot.cable_specs):
        raise ScenarioError(
            f"a frame gives {len(frame.actuation)} actuation values for the "
            f"{len(robot.cable_specs)} cables of {robot.config.source}"
        )
    acting, attachment, forces, normals = load_points(robot, frame.loads)
    walk_from, walk_to = _load_path(robot, loads_before, acting, forces)
    model = robot.fe_model if model is None else model
    last_error: SolverError | None = None
    for steps in CONTINUATION_STEPS:
        try:
            state = _walk(robot, model, start, np.array(frame.actuation, dtype=float),
                          walk_from, walk_to, steps)
            break
        except SolverError as error:
            last_error = error
    else:
        raise ScenarioError(
            f"the truth robot cannot reach the frame's state even in "
            f"{CONTINUATION_STEPS[-1]} load steps: {last_error}"
        )
    deformed = attachment.positions(state.positions_mm)
    rest = attachment.positions(robot.rest_nodes_mm)
    contacts = tuple(
        Contact(load.kind, rest[i], deformed[i], forces[i], normals[i])
        for i, load in enumerate(frame.loads)
    )
    return TruthState(state, contacts)


def _load_path(robot: Robot, loads_from: tuple[LoadSpec, ...], acting: Attachment,
               forces: np.ndarray) -> tuple[PointLoads, np.ndarray]:
    """The two ends of a walk from a frame's loads, loads_from, to forces (p, 3) N acting
    through `acting`: loads_from's forces as PointLoads on the points of both, and the
    forces at the end on the same points."""
    acting_from, _, forces_from, _ = load_points(robot, loads_from)
    points = Attachment.concatenate([acting, acting_from])
    return (PointLoads(points, np.concatenate([np.zeros_like(forces), forces_from])),
            np.concatenate([forces, np.zeros_like(forces_from)]))


def _walk(robot: Robot, model: FEModel, start: Equilibrium | None, target: np.ndarray,
          loads_before: PointLoads, forces: np.ndarray, steps: int,
          settings: SolverSettings = SolverSettings()) -> Equilibrium:
    """The equilibrium at cable inputs `target` (a,) and forces (p, 3) N on loads_before's
    points, reached in `steps` equal steps from `start` (rest when None) under loads_before:
    the inputs from the cables' state at the start, the forces from loads_before's.

    Raises SolverError when a step's Newton solve fails.
    """
    controlled = robot.cable_inputs(target).displacement_controlled
    actuation_before = (
        np.zeros_like(target)
        if start is None
        else np.where(controlled, start.cable_shortenings_mm, start.cable_tensions_n)
    )
    state = start
    for step in range(1, steps + 1):
        share = step / steps
        inputs = robot.cable_inputs(actuation_before + share * (target - actuation_before))
        loads = PointLoads(loads_before.points,
                           loads_before.forces_n + share * (forces - loads_before.forces_n))
        state = solve_equilibrium(model, inputs, loads,
                                  None if state is None else state.positions_mm, settings)
    assert state is not None  # steps >= 1
    return state


def return_separation(robot: Robot, previous_frame: FrameSpec, previous_model: FEModel | None,
                      previous: TruthState, frame: FrameSpec, current: TruthState) -> float:
    """mm: the largest node distance between `previous`, the state the body left, and the
    equilibrium the previous frame's loads (and model) reach from `current`, the state it
    reached under `frame`'s, along the way back; 0 when it returns, or when no solve from
    `current` reaches one.

    Moving on along one branch of equilibria, the body comes back to where it was (0 to the
    solver's tolerance). Above BRANCH_SEPARATION_MM it did not: at the previous loads the body
    has two equilibria, so between the frames it passed a fold of the branch it stood on and
    snapped through to another (a cable-pulled Diamond tipping over as it softens). The way
    back is one Newton solve first, then, when that lands elsewhere, PATH_STEPS steps from
    this frame's inputs and forces to the previous frame's, which follow the branch where
    one solve may jump off it. A fold whose hysteresis is narrower than the step between the
    frames is not seen: the way back snaps back too.
    """
    acting, _, forces, _ = load_points(robot, previous_frame.loads)
    walk_from, walk_to = _load_path(robot, frame.loads, acting, forces)
    model = robot.fe_model if previous_model is None else previous_model
    target = np.array(previous_frame.actuation, dtype=float)
    separation = 0.0
    for steps in (1, PATH_STEPS):
        try:
            back = _walk(robot, model, current.equilibrium, target, walk_from, walk_to, steps,
                         WAY_BACK)
        except SolverError:
            return 0.0
        gaps = back.positions_mm - previous.equilibrium.positions_mm
        separation = float(np.linalg.norm(gaps, axis=1).max())
        if separation <= BRANCH_SEPARATION_MM:
            return 0.0
    return separation
