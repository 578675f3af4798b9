"""The robot's deformed shape in a sensed frame, rebuilt from what the run keeps.

sense.json does not store the FE configuration, only each frame's cable tensions and contact
forces. The shape is the FE equilibrium under the cables' inputs, then the contact forces at
the surface nodes nearest to the contact positions on that shape (sense applies them at
surface nodes: estimation contact_at "node"). The cables' inputs are the recording's own
(its /robot/actuation, in the robot file's control modes) when the recording is at hand, as
sense used them; otherwise the sensed tensions, as force control.

Force control from the rest shape is the harder problem for Newton: on the coarse P1 Diamond
the full 3.5 N at once does not converge (60 iterations, residual 4 mN) but two halves do
(16 iterations), hence RAMP_STEPS; on the P2 Diamond even half fails where the displacement
inputs of the same frame converge in 11 iterations, hence the recording's inputs first.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from softforce_cli.fem.attachment import Attachment
from softforce_cli.fem.cables import CableInputs
from softforce_cli.fem.statics import PointLoads, solve_equilibrium
from softforce_cli.model.robot import Robot

RAMP_STEPS = 2


@dataclass(frozen=True)
class RobotShape:
    """positions_mm (N, 3) every FE node, robot frame; surface_faces (f, 3) into them."""

    positions_mm: np.ndarray
    surface_faces: np.ndarray

    @property
    def surface_mm(self) -> np.ndarray:
        """(f, 3, 3) the surface triangles' corners."""
        return self.positions_mm[self.surface_faces]


def rest_shape(robot: Robot) -> RobotShape:
    return RobotShape(robot.rest_nodes_mm, robot.mesh.surface_faces)


def frame_cable_inputs(robot: Robot, actuation: np.ndarray | None,
                       cable_tensions_n: np.ndarray) -> CableInputs:
    """The recorded actuation (a,) in the robot file's control modes when given, else the
    sensed tensions (a,) N as force control."""
    if actuation is not None:
        return robot.cable_inputs(actuation)
    return CableInputs(("force",) * len(robot.cable_specs),
                       np.asarray(cable_tensions_n, dtype=float))


def sensed_shape(robot: Robot, inputs: CableInputs, contact_points_mm: np.ndarray,
                 contact_forces_n: np.ndarray, start_mm: np.ndarray | None = None) -> RobotShape:
    """The equilibrium under the frame's loads (see the module docstring).

    inputs: the cables' (frame_cable_inputs); contact_points_mm (c, 3) on the deformed robot
    and contact_forces_n (c, 3) on the robot, robot frame; start_mm (N, 3) a nearby
    configuration to start Newton from (the previous frame's). SolverError if a solve fails.
    """
    model = robot.fe_model
    ramp = start_mm is None and not inputs.displacement_controlled.any()
    fractions = np.arange(1, RAMP_STEPS + 1) / RAMP_STEPS if ramp else (1.0,)
    positions = start_mm
    for fraction in fractions:
        step = CableInputs(inputs.control, fraction * np.asarray(inputs.values, dtype=float))
        positions = solve_equilibrium(model, step, start_mm=positions).positions_mm
    points = np.asarray(contact_points_mm, dtype=float).reshape(-1, 3)
    if not len(points):
        return RobotShape(positions, robot.mesh.surface_faces)
    surface = robot.mesh.surface_nodes
    _, nearest = cKDTree(positions[surface]).query(points)
    loads = PointLoads(Attachment.at_nodes(surface[np.asarray(nearest, dtype=np.int64)]),
                       np.asarray(contact_forces_n, dtype=float).reshape(-1, 3))
    loaded = solve_equilibrium(model, inputs, loads, start_mm=positions)
    return RobotShape(loaded.positions_mm, robot.mesh.surface_faces)
