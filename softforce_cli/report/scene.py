"""The robot with its contacts in 3D, as data for the interactive view and the projections."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from softforce_cli.model.robot import Robot
from softforce_cli.report.loading import SenseRun
from softforce_cli.report.reconstruction import (
    RobotShape,
    frame_cable_inputs,
    rest_shape,
    sensed_shape,
)

# The longest force arrow drawn, in mm: about a fifth of the Diamond's span, long enough to
# read a direction, short enough not to hide the robot.
LONGEST_ARROW_MM = 40.0


@dataclass(frozen=True)
class ContactScene:
    """shape: the robot drawn; points_mm (k, 3) contacts and forces_n (k, 3) their forces on
    the robot (robot frame); labels (k,) hover texts; nodes (m,) mesh nodes to highlight."""

    title: str
    shape: RobotShape
    points_mm: np.ndarray
    forces_n: np.ndarray
    labels: tuple[str, ...]
    nodes: np.ndarray

    @property
    def arrow_mm_per_n(self) -> float:
        largest = float(np.linalg.norm(self.forces_n, axis=1).max(initial=0.0))
        return LONGEST_ARROW_MM / largest if largest > 0 else 0.0

    @property
    def magnitudes_n(self) -> np.ndarray:
        return np.linalg.norm(self.forces_n, axis=1)


def shown_frame(run: SenseRun) -> int | None:
    """The ok frame with the largest total contact force (the last ok frame when none has
    a force) among those whose tensions sense.json kept; None when there is none."""
    frames = [int(f) for f in run.frames["frame"][run.ok] if int(f) in run.cable_tensions]
    if not frames:
        return None
    contacts = run.contacts
    totals = [contacts["force_n"][contacts["frame"] == f].sum() for f in frames]
    return frames[int(np.argmax(totals))] if max(totals) > 0 else frames[-1]


def sense_scene(run: SenseRun, robot: Robot,
                actuation: Callable[[int], np.ndarray | None]) -> ContactScene:
    """Every contact of every ok frame, on the robot as sensed in shown_frame (the rest shape
    when sense.json kept no tensions); actuation(frame) gives the frame's recorded cable
    inputs, or None (reconstruction.frame_cable_inputs)."""
    contacts = run.contacts
    points = np.column_stack([contacts[k] for k in ("x_mm", "y_mm", "z_mm")]).reshape(-1, 3)
    forces = np.column_stack([contacts[k] for k in ("fx_n", "fy_n", "fz_n")]).reshape(-1, 3)
    labels = tuple(f"frame {int(f)}, contact {int(c)}: {n:.4f} N"
                   for f, c, n in zip(contacts["frame"], contacts["contact"],
                                      contacts["force_n"], strict=True))
    frame = shown_frame(run)
    if frame is None:
        shape, title = rest_shape(robot), f"{robot.name} at rest, contacts of every frame"
    else:
        here = contacts["frame"] == frame
        inputs = frame_cable_inputs(robot, actuation(frame), run.cable_tensions[frame])
        shape = sensed_shape(robot, inputs, points[here], forces[here])
        title = f"{robot.name} as sensed in frame {frame}, contacts of every frame"
    return ContactScene(title, shape, points, forces, labels, np.zeros(0, dtype=np.int64))


def location_scene(robot: Robot, nodes: tuple, title: str) -> ContactScene:
    """The robot at rest with the mesh nodes where a diagnosis locates the mismatch."""
    indices = np.array([n for n in nodes if isinstance(n, int)
                        and 0 <= n < robot.mesh.node_count], dtype=np.int64)
    return ContactScene(title, rest_shape(robot), np.zeros((0, 3)), np.zeros((0, 3)), (),
                        indices)
