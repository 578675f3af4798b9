"""The robot's deformed shape in a sensed frame, rebuilt from what sense.json keeps.

sense.json does not store the FE configuration, only each frame's cable tensions and contact
forces. The shape is the FE equilibrium under those loads: the cables at the sensed tensions
(force control), then the contact forces at the surface nodes nearest to the contact
positions on that shape (sense applies them at surface nodes: estimation contact_at "node").
It matches the sensor's own configuration up to its last linearised update step.

From the rest shape the tensions are applied in RAMP_STEPS increments: Newton on the full
tensions at once from rest does not converge on the Diamond (3.5 N: 60 iterations, residual
4 mN), in two halves it does (16 iterations). From a nearby shape (the previous frame's) one
step is enough.
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


def sensed_shape(robot: Robot, cable_tensions_n: np.ndarray, contact_points_mm: np.ndarray,
                 contact_forces_n: np.ndarray, start_mm: np.ndarray | None = None) -> RobotShape:
    """The equilibrium under the sensed loads (see the module docstring).

    cable_tensions_n (a,) N; contact_points_mm (c, 3) on the deformed robot and
    contact_forces_n (c, 3) on the robot, robot frame; start_mm (N, 3) a nearby configuration
    to start Newton from (the previous frame's). Raises SolverError if a solve diverges.
    """
    model = robot.fe_model
    tensions = np.asarray(cable_tensions_n, dtype=float)
    fractions = (1.0,) if start_mm is not None else np.arange(1, RAMP_STEPS + 1) / RAMP_STEPS
    positions = start_mm
    for fraction in fractions:
        inputs = CableInputs(("force",) * len(robot.cable_specs), fraction * tensions)
        positions = solve_equilibrium(model, inputs, start_mm=positions).positions_mm
    points = np.asarray(contact_points_mm, dtype=float).reshape(-1, 3)
    if not len(points):
        return RobotShape(positions, robot.mesh.surface_faces)
    surface = robot.mesh.surface_nodes
    _, nearest = cKDTree(positions[surface]).query(points)
    loads = PointLoads(Attachment.at_nodes(surface[np.asarray(nearest, dtype=np.int64)]),
                       np.asarray(contact_forces_n, dtype=float).reshape(-1, 3))
    loaded = solve_equilibrium(model, inputs, loads, start_mm=positions)
    return RobotShape(loaded.positions_mm, robot.mesh.surface_faces)
