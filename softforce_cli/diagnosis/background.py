"""The static background as evidence about the camera: the table the robot stands on.

A miscalibrated camera (depth_bias, extrinsic_offset) moves the table in the robot frame as it
moves the robot; a physics effect (a compliant base, more gravity, a softer body) moves the
robot only. The table is where the robot's lowest rest point is (the clamp stands on it),
horizontal (the robot frame's z is up); the vision stage fits its plane in every recording
(diagnosis.observations, `table_plane`). Its observed height over the robot's footprint is
then a residual only a camera effect can explain, and one that separates the camera effects
too: a depth scale moves the table (617 mm from the sample camera) more than the robot (450 to
620 mm), a camera move along its axis moves both alike, and a lateral move or a turn about
the axis leaves a horizontal table where it is.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.model.effects import Effect, effects_of_kind, observed_points_robot

# A table found further than this from the robot's lowest point is not the one it stands on
# (a robot on a pedestal, a fit on the floor): it is not used.
TABLE_SEARCH_MM = 30.0
# How far (RMS over the footprint) the observed table may be from where an explanation puts
# it: the gap under the clamp the setup leaves (0.5 mm in the simulated scenes) and the plane
# fit's error (0.1 mm on the sample recordings).
TABLE_TOLERANCE_MM = 1.0
# ... plus this share of the table's observed offset: a camera effect refitted on the robot
# alone keeps the size the table shows to within a few percent (a -2% depth scale refitted
# -2.09%, the table seen 11.75 mm high for 12.9 predicted).
TABLE_RELATIVE_TOLERANCE = 0.1
# Nor is a table seen further off than TABLE_TOLERANCE_MM plus this many times the robot's
# own residual: a camera effect moves the robot about as far as the table (a depth scale
# moves the sample camera's table, 617 mm away, 1.0-1.4 times as far as the robot, 450-620
# mm; a move of the camera moves both alike), so that table was not moved by the camera but
# is another surface (a finger clamped 30 mm above its table: seen 30.0 mm low beside a
# robot within 1.2 mm of its model, it contradicted every physics effect).
CAMERA_TABLE_RATIO = 3.0
# Grid points per side over the robot's footprint where the table's height is compared.
GRID_SIDE = 5


@dataclass(frozen=True, eq=False)
class Table:
    """The table under the robot as the camera shows it.

    points_mm   : (g, 3) grid over the robot's footprint on the expected table (z = the
                  robot's lowest rest point), robot frame.
    observed_mm : (g,) observed table height above the expected one at each grid point (mean
                  over the frames' planes).
    """

    points_mm: np.ndarray
    observed_mm: np.ndarray

    @property
    def tolerance_mm(self) -> float:
        """How far from the observed table an explanation may leave it (RMS, mm)."""
        offset = float(np.sqrt(np.mean(self.observed_mm**2)))
        return TABLE_TOLERANCE_MM + TABLE_RELATIVE_TOLERANCE * offset

    def shift(self, effects: Iterable[Effect], robot_from_camera: RigidTransform) -> np.ndarray:
        """(g,) mm: how far the sensor `effects` raise the table at the grid points (a
        horizontal plane moved and turned by a few degrees: its height at a point is the
        moved point's height to within 0.01 mm)."""
        effects = effects_of_kind(tuple(effects), "sensor")
        if not effects:
            return np.zeros(len(self.points_mm))
        moved = observed_points_robot(self.points_mm, effects, robot_from_camera)
        return moved[:, 2] - self.points_mm[:, 2]

    def left_mm(self, effects: Iterable[Effect], robot_from_camera: RigidTransform
                ) -> np.ndarray:
        """(g,) mm: the observed table height less what `effects` explain."""
        return self.observed_mm - self.shift(effects, robot_from_camera)

    def misfit_mm(self, effects: Iterable[Effect], robot_from_camera: RigidTransform) -> float:
        """RMS (mm) of the observed table height less what `effects` explain."""
        return float(np.sqrt(np.mean(self.left_mm(effects, robot_from_camera) ** 2)))


def observed_table(planes: Iterable[tuple[np.ndarray, float] | None],
                   rest_nodes_mm: np.ndarray, robot_residual_mm: float) -> Table | None:
    """The Table from the frames' table planes (unit normal (3,), offset) or None, the
    robot's rest nodes (n, 3) mm and the RMS (mm) of its observed points' residual to the
    nominal model; None when no frame found the table, or it is not the one the robot
    stands on (TABLE_SEARCH_MM, CAMERA_TABLE_RATIO)."""
    found = [(np.asarray(n, dtype=float), float(d)) for n, d in
             (p for p in planes if p is not None) if abs(n[2]) > 0.5]
    if not found:
        return None
    low, high = rest_nodes_mm.min(axis=0), rest_nodes_mm.max(axis=0)
    axes = [np.linspace(low[i], high[i], GRID_SIDE) for i in range(2)]
    x, y = (a.ravel() for a in np.meshgrid(*axes))
    # height of each plane n . p + d = 0 over every grid point, less the expected table's
    heights = np.array([-(n[0] * x + n[1] * y + d) / n[2] for n, d in found])
    observed = heights.mean(axis=0) - low[2]
    offset = np.sqrt(np.mean(observed**2))
    if offset > min(TABLE_SEARCH_MM, TABLE_TOLERANCE_MM + CAMERA_TABLE_RATIO * robot_residual_mm):
        return None
    return Table(np.column_stack([x, y, np.full(len(x), low[2])]), observed)
