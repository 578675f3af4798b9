"""How well a calibration's markers pin the camera pose down: the covariance of a small rigid
correction of the robot in the camera's view, from the markers' scatter about the fit.

A correction (dtheta, dt) moves a robot point p by dtheta x p + dt (robot frame, rad and
mm). The calibration fits the pose and the taut cables' tensions to the markers (Algorithm
1); at its fit, linear least squares gives the parameters' covariance sigma^2 (J^T J)^-1,
J = [the (3 n, 6) motions of the markers under the six (rigid.rigid_motion_basis about the
robot's origin), the markers' compliance to the taut cables' tensions (W_ea's columns)],
sigma^2 the used markers' sum of squared residuals over their degrees of freedom. The pose's
block of it counts the tensions' trade with the pose (a pull that bends an arm beside a turn
of the camera). A calibration file written before the covariance was (it has no
`pose_covariance`) gives the rigid block alone, without the tensions: a lower bound.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softforce_cli.calibration.result import CalibrationResult
from softforce_cli.calibration.rigid import rigid_motion_basis

# Fewer used markers than this do not fix a pose with degrees of freedom to spare.
MIN_MARKERS = 4


@dataclass(frozen=True)
class MarkerFit:
    """A linear least-squares fit of the markers at a calibration: the residual variance per
    coordinate s^2 (mm^2, the sum of squares over the degrees of freedom) and the unscaled
    parameter covariance (J^T J)^+ (the parameters' covariance is s^2 times it)."""

    variance_mm2: float
    unscaled: np.ndarray

    @property
    def covariance(self) -> np.ndarray:
        return self.variance_mm2 * self.unscaled


def marker_fit(markers_mm: np.ndarray, residuals_mm: np.ndarray, input_columns: np.ndarray,
               centre_mm: np.ndarray | None = None) -> MarkerFit | None:
    """The fit of the six rigid motions about centre_mm (the robot's origin by default) and
    the inputs to markers at model positions (n, 3) mm with residuals (n, 3) mm, the inputs'
    marker motions (3 n, k) per unit each; None with no degree of freedom left."""
    markers = np.asarray(markers_mm, dtype=float).reshape(-1, 3)
    residuals = np.asarray(residuals_mm, dtype=float).reshape(-1, 3)
    centre = np.zeros(3) if centre_mm is None else centre_mm
    jacobian = np.hstack([rigid_motion_basis(markers, centre),
                          np.asarray(input_columns, dtype=float)])
    freedom = 3 * len(markers) - np.linalg.matrix_rank(jacobian)
    if freedom <= 0:
        return None
    return MarkerFit(float(np.sum(residuals**2)) / freedom,
                     np.linalg.pinv(jacobian.T @ jacobian))


def pose_covariance(markers_mm: np.ndarray, residuals_mm: np.ndarray,
                    input_columns: np.ndarray) -> np.ndarray | None:
    """(6, 6) covariance of (dtheta rad, dt mm) from the used markers' model positions
    (n, 3) mm (robot frame), their residuals (n, 3) mm and the markers' motion (3 n, k) per
    unit of each input fitted with the pose (mm/N: the taut cables' W_ea columns; k = 0 for
    none); None with fewer than MIN_MARKERS markers or no degree of freedom left."""
    if len(np.asarray(markers_mm).reshape(-1, 3)) < MIN_MARKERS:
        return None
    fit = marker_fit(markers_mm, residuals_mm, input_columns)
    return None if fit is None else fit.covariance[:6, :6]


def calibration_pose_covariance(calibration: CalibrationResult) -> np.ndarray | None:
    """A calibration's pose covariance: the one it was written with, else the rigid block of
    its used markers (pose_covariance without inputs: a lower bound); None for a pose given
    without markers (a pose-only file, the truth's camera of a simulated recording)."""
    if calibration.pose_covariance is not None:
        return calibration.pose_covariance
    used = [m for m in calibration.markers if m.used]
    if not used:
        return None
    return pose_covariance(np.array([m.model_robot_mm for m in used]),
                           np.array([m.residual_mm for m in used]), np.zeros((3 * len(used), 0)))
