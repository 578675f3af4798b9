"""Outlier markers: found by leave-one-out refits, reported always, excluded on request.

A marker on a cable's arm can be matched by the actuation almost wherever it is, so its
residual in the full fit says little: a wrong elbow marker bends the model's arm toward
itself and spreads its error over the others. What exposes it is prediction: calibrate
without the marker and see how far the others put it (its *deleted residual* e, 3 vectors).
Markers are not equally predictable (the others pin an elbow down poorly), so e is judged
against its own covariance, that of linear least squares at the refit:

    C = s^2 (I_3 + J_i (J^T J)^-1 J_i^T),   d = sqrt(e^T C^-1 e)

with J the refit's Jacobian of the markers with respect to the 6 rigid motions and the cable
tensions (J_i the left-out marker's rows) and s^2 the refit's residual variance per coordinate
(sum of squares over its degrees of freedom). For Gaussian errors d^2 is chi^2 with 3 degrees
of freedom; a marker is an outlier when d > OutlierSettings.studentized and |e| exceeds
min_residual_mm.

Refits are cold starts (from the rest shape, like the first fit): a warm start from the
contaminated fit can settle in a poorer local minimum. They are tried in decreasing order of
full-fit residual (at most OutlierSettings.candidates of them) and stop at the first outlier,
so a check costs one extra calibration when there is a gross outlier, a few when the fit is
merely imperfect, and none when every residual is small (the screen).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from softforce_cli.calibration.calibrate import (
    CalibrationSettings,
    IterationReport,
    calibrate,
    match_markers,
)
from softforce_cli.calibration.linear_model import linear_model
from softforce_cli.calibration.pose_covariance import marker_fit
from softforce_cli.calibration.result import CalibrationResult
from softforce_cli.calibration.rigid import rigid_motion_basis
from softforce_cli.camera.frame import Markers
from softforce_cli.model.robot import Robot

# Leave-one-out refits only rank and measure markers to ~0.01 mm: a looser convergence test
# and fewer iterations than a calibration; the kept refit is then converged fully.
REFIT_ITERATIONS = 12
REFIT_TOLERANCE_MM = 1e-3


@dataclass(frozen=True)
class OutlierSettings:
    """When a marker is an outlier, with why.

    studentized     : d above this (see the module notes). Gaussian theory puts 1 clean
                      marker in ~20000 above 4.75; with the cross-model error and 1 mm noise
                      the documented study saw clean markers up to 4.4 and 10 mm outliers
                      from 5.1 (docs/calibration.md).
    min_residual_mm : and |e| above this: the cross-model residual of the default robot is
                      ~0.5 mm and a D415 measures markers to ~1 mm, so 3 mm is a gross error.
    screen_mm       : no refits unless some full-fit residual exceeds this (every gross
                      outlier of the documented study left one above 2.6 mm).
    candidates      : refit without at most this many markers, the largest full-fit residuals
                      first (a gross outlier was the first or second in all 162 cases of the
                      documented study; this bounds the cost on clean but imperfect data).
    min_dof         : degrees of freedom the refit must keep to estimate s (3 (k - 1) - 6 -
                      cables): 9 markers with 4 cables give 14; 6 markers are the fewest.
    max_excluded    : how many outliers --robust may exclude, one at a time.
    """

    studentized: float = 4.75
    min_residual_mm: float = 3.0
    screen_mm: float = 1.5
    candidates: int = 4
    min_dof: int = 5
    max_excluded: int = 1


@dataclass(frozen=True)
class Outlier:
    """A marker found to be an outlier: the fit without it, how far that fit puts it (mm),
    and its studentized deleted residual d."""

    marker_id: str
    refit: CalibrationResult
    left_out_mm: float
    studentized: float


def calibrate_checked(
    robot: Robot,
    observed: Markers,
    settings: CalibrationSettings = CalibrationSettings(),
    exclude_outliers: bool = False,
    outliers: OutlierSettings = OutlierSettings(),
    progress: Callable[[IterationReport], None] | None = None,
    source: str = "markers",
) -> CalibrationResult:
    """Calibrate, look for an outlier marker and flag it; with exclude_outliers, return the
    calibration without it (and look again, up to outliers.max_excluded)."""
    started = time.perf_counter()
    result = calibrate(robot, observed, settings, progress=progress, source=source)
    excluded: tuple[str, ...] = ()
    while len(excluded) < outliers.max_excluded:
        found = find_outlier(robot, observed, result, settings, outliers, source)
        if found is None:
            break
        message = (f"marker {found.marker_id!r} is an outlier: the other markers put it "
                   f"{found.left_out_mm:.1f} mm from where it was observed ({found.studentized:.1f}"
                   " standard errors)")
        if not exclude_outliers:
            flagged = _flag(result, found.marker_id, found.left_out_mm)
            return flagged.replace(elapsed_s=time.perf_counter() - started, warnings=(
                *flagged.warnings, f"{message}; check it, or pass --robust to exclude it"))
        excluded = (*excluded, found.marker_id)
        refit = found.refit
        if not refit.converged or settings.residual_tolerance_mm < REFIT_TOLERANCE_MM:
            refit = calibrate(robot, observed, settings,
                              excluded=(*result.excluded, found.marker_id), source=source)
        result = _flag(refit, found.marker_id, found.left_out_mm)
        result = result.replace(warnings=(*result.warnings, f"{message}; excluded"))
    return result.replace(robust=exclude_outliers, elapsed_s=time.perf_counter() - started)


def find_outlier(
    robot: Robot,
    observed: Markers,
    result: CalibrationResult,
    settings: CalibrationSettings,
    outliers: OutlierSettings = OutlierSettings(),
    source: str = "markers",
) -> Outlier | None:
    """The outlier among result's used markers, or None (module notes)."""
    used = [m for m in result.markers if m.used]
    dof = 3 * (len(used) - 1) - 6 - len(result.cable_names)
    distances = np.array([m.distance_mm for m in used])
    if dof < outliers.min_dof or distances.max() <= outliers.screen_mm:
        return None
    quick = dataclasses.replace(settings, outer_iterations=min(settings.outer_iterations,
                                                                REFIT_ITERATIONS),
                                residual_tolerance_mm=REFIT_TOLERANCE_MM,
                                step_tolerance_mm=10 * REFIT_TOLERANCE_MM)
    for k in np.argsort(-distances)[:outliers.candidates]:
        marker_id = used[k].id
        refit = calibrate(robot, observed, quick, excluded=(*result.excluded, marker_id),
                          source=source)
        left_out = next(m for m in refit.markers if m.id == marker_id)
        score = studentized_deleted_residual(robot, observed, refit, marker_id, source)
        if score > outliers.studentized and left_out.distance_mm > outliers.min_residual_mm:
            return Outlier(marker_id, refit, left_out.distance_mm, score)
    return None


def studentized_deleted_residual(robot: Robot, observed: Markers, refit: CalibrationResult,
                                 marker_id: str, source: str = "markers") -> float:
    """d = sqrt(e^T C^-1 e) for the marker `refit` left out (module notes)."""
    indices = match_markers(robot, observed, source)
    model = robot.fe_model
    rows = robot.marker_points.subset(indices).cartesian_rows(model.node_count)
    lm = linear_model(model, refit.positions_mm, refit.tensions_n, rows)
    markers = lm.markers(refit.tensions_n)
    used = np.array([m.used for m in refit.markers])
    residuals = np.array([m.residual_mm for m in refit.markers])
    i = [m.id for m in refit.markers].index(marker_id)
    # the left-out marker's rows from the same motions as the refit's: about the used
    # markers' centre, the left-out one among the positions
    centre = markers[used].mean(axis=0)
    fit = marker_fit(markers[used], residuals[used], lm.W_ea[np.repeat(used, 3)], centre)
    own = np.hstack([rigid_motion_basis(markers[i:i + 1], centre), lm.W_ea[3 * i:3 * i + 3]])
    # the refit keeps OutlierSettings.min_dof degrees of freedom: fit is never None here
    covariance = fit.variance_mm2 * np.eye(3) + own @ fit.covariance @ own.T
    error = refit.markers[i].residual_mm
    return float(np.sqrt(error @ np.linalg.solve(covariance, error)))


def _flag(result: CalibrationResult, marker_id: str, left_out_mm: float | None
          ) -> CalibrationResult:
    markers = tuple(
        dataclasses.replace(m, outlier=True, left_out_mm=left_out_mm or m.left_out_mm)
        if m.id == marker_id else m
        for m in result.markers
    )
    return result.replace(markers=markers)
