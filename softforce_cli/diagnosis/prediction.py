"""The FE prediction of every state: surface node positions of the robot with given effects.

One static solve per state, warm-started from the nominal solution of the same state (an
effect of a few percent moves the equilibrium little, so Newton needs two or three steps).
With a linear (P1) robot the prediction adds a mesh correction: the difference between the
same mesh with locking-free quadratic elements (P2) and P1 at the reference state. P1 locks
(docs/locking.md), which under gravity alone leaves several millimetres of sag unexplained
in every recording: that is discretisation, not missing physics, and diagnosing on top of it
would name a spurious softening.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from softforce_cli.fem.cables import CableInputs
from softforce_cli.fem.model import FEModel
from softforce_cli.fem.statics import solve_equilibrium
from softforce_cli.model.robot import Robot, with_element


@dataclass
class Predictor:
    """Solves a robot's states and caches the nominal solutions as warm starts.

    robot       : the estimating robot (its element is the one diagnosed).
    actuation   : (S, a) the states' inputs.
    reference   : index of the reference state for the mesh correction (least actuated).
    correction  : (n_mesh, 3) mm added to every prediction (zeros without one).
    """

    robot: Robot
    actuation: np.ndarray
    reference: int = 0
    correction: np.ndarray | None = None
    _starts: dict[int, np.ndarray] = field(default_factory=dict)

    def positions_with(self, model: FEModel, actuation: np.ndarray,
                       states: list[int] | np.ndarray | None = None) -> np.ndarray:
        """(s, n_mesh, 3) mm: mesh node positions of `model` (the robot's FE model with
        effects) at the inputs (S, a) of states (s,) (default all), with the mesh correction."""
        states = np.arange(len(actuation)) if states is None else np.asarray(states)
        n = self.robot.mesh.node_count
        out = np.empty((len(states), n, 3))
        for i, s in enumerate(states):
            inputs = CableInputs(self.controls, np.asarray(actuation[s], dtype=float))
            solution = solve_equilibrium(model, inputs, start_mm=self._starts.get(int(s)))
            out[i] = solution.positions_mm[:n]
        if self.correction is not None:
            out += self.correction
        return out

    @property
    def controls(self) -> tuple[str, ...]:
        return tuple(spec.control for spec in self.robot.cable_specs)

    def warm(self, progress: Callable[[int, int], None] | None = None) -> None:
        """Solve every state of the nominal model once (the warm starts), in order."""
        count = len(self.actuation)
        previous = None
        for s in range(count):
            solution = solve_equilibrium(self.robot.fe_model,
                                         self.robot.cable_inputs(self.actuation[s]),
                                         start_mm=previous)
            self._starts[s] = previous = solution.positions_mm
            if progress is not None:
                progress(s + 1, count)


def mesh_correction(robot: Robot, actuation: np.ndarray) -> tuple[np.ndarray, str]:
    """(n_mesh, 3) mm: P2 minus the robot's element at the inputs (a,), and the accurate
    element's name; zeros when the robot is not P1 (P2 and P2-P0 do not lock)."""
    n = robot.mesh.node_count
    if robot.element_name != "p1":
        return np.zeros((n, 3)), robot.element_name
    accurate = with_element(robot, "p2")
    inputs = robot.cable_inputs(actuation)
    fine = solve_equilibrium(accurate.fe_model, inputs).positions_mm[:n]
    coarse = solve_equilibrium(robot.fe_model, inputs).positions_mm[:n]
    return fine - coarse, "p2"
