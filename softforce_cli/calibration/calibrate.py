"""Algorithm 1: camera-to-robot transform and actuator inputs from observed markers.

    repeat at most I1 times (outer):
        marker positions on the FE model by eq. 3        m = W_ea lam + delta_e_free
        rigid transform by SVD                           (R, T) = argmin sum |R p_cam + T - m|^2
        observed markers in the robot frame              delta_tran = R p_cam + T
        actuation by the bounded QP of eq. 9             lam
        FE update by eq. 6, at most I2 times             x <- x + dx_free + K^-1 H_a^T lam
    until the residual RMS changes less than a tolerance and the actuation step is negligible

An FE update is one Newton step of the static problem (SOFA's constraint-based step): K(x) and
dx_free = K^-1 (f_ext - g(x)) are recomputed at the current x and eq. 6 moves it; the paper's
I2 updates after each QP bring the configuration to equilibrium "to compute more accurate
values for W_e and delta_e_free". Here they stop as soon as an update moves no node more than
EQUILIBRIUM_MM, so near convergence an outer iteration costs one factorisation. Three
safeguards keep the iteration converging where plain Algorithm 1 can cycle or diverge (an
inconsistent marker, a robot near buckling under gravity):

- the state carried between updates is the cable *inputs*: a displacement-controlled cable
  keeps its length at every update, its tension re-solved from eq. 4, which stabilises the
  structure as the real cable does, instead of a tension acting as a dead load;
- the QP sees the markers with their rigid motions projected out (variable projection), so the
  actuation step anticipates the SVD re-fit that follows; without it the alternation between
  SVD and QP converges linearly and slowly (``project_rigid=False`` is the paper's scheme);
- a trust region on the actuation step, measured as the largest marker motion it predicts:
  a step that does not lower the residual (evaluated at equilibrium) is retried shorter.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from softforce_cli.calibration.actuation_qp import (
    ActuationBounds,
    ActuationSolution,
    solve_actuation_qp,
)
from softforce_cli.calibration.linear_model import LinearModel, linear_model
from softforce_cli.calibration.pose_covariance import pose_covariance
from softforce_cli.calibration.result import CalibrationResult, MarkerResidual
from softforce_cli.calibration.rigid import (
    COLLINEAR_RATIO,
    collinearity,
    fit_rigid_transform,
    rigid_motion_projector,
)
from softforce_cli.camera.frame import Markers
from softforce_cli.errors import CalibrationError, SolverError
from softforce_cli.fem.cables import CableInputs
from softforce_cli.model.robot import Robot

# A cable whose tension is below this is reported slack (N; a tenth of the lightest load of
# interest in the paper, 10 mN).
SLACK_TENSION_N = 1e-3
# Cable bounds (mm or N) that the converged solution misses by more than this cannot hold.
BOUND_TOLERANCE = 1e-3
# The configuration counts as a static equilibrium once an FE update moves no node further
# than EQUILIBRIUM_RATIO times the actuation step that led there, within [EQUILIBRIUM_MM,
# SETTLE_MM]: the residual evaluated there (to first order in the update) is then exact to
# second order, ~(0.1 step)^2 / 50 mm, enough to judge the step. Newton's quadratic
# convergence makes one update enough for steps below a few mm.
EQUILIBRIUM_MM = 1e-4
EQUILIBRIUM_RATIO = 0.01
SETTLE_MM = 0.1
# FE updates allowed to reach equilibrium from the rest shape, before the first rigid fit.
SETTLE_UPDATES = 30
# Trust region: starts at INITIAL_RADIUS_MM (a fifth of the Diamond's height; first steps from
# rest move markers 10-25 mm); a step whose actual residual decrease is below ACCEPT of the
# predicted one is retried SHRINK times as long; one above GROW of it that used the whole
# radius doubles it.
INITIAL_RADIUS_MM = 25.0
ACCEPT, GROW, SHRINK = 1e-2, 0.75, 0.25
MIN_RADIUS_MM = 1e-6


@dataclass(frozen=True)
class CalibrationSettings:
    """Iteration counts and convergence thresholds, with why.

    outer_iterations      : I1, the most rigid fits (SVD) and QPs; the paper's Fig. 6 shows 10.
    inner_iterations      : I2, the most FE updates after each QP (fewer once at equilibrium).
    residual_tolerance_mm : converged when the residual RMS changes less than this between two
                            outer iterations (far below any camera's noise, ~1 mm) ...
    step_tolerance_mm     : ... and the actuation step moves no marker further than this
    step_ratio            : or than this fraction of the residual RMS: with a large residual
                            (model or marker errors) Gauss-Newton converges only linearly, and
                            steps a thousandth of the misfit no longer matter.
    project_rigid         : project the rigid motions out of the QP (see the module notes).
    """

    outer_iterations: int = 40
    inner_iterations: int = 4
    residual_tolerance_mm: float = 1e-5
    step_tolerance_mm: float = 1e-4
    step_ratio: float = 1e-3
    project_rigid: bool = True

    def __post_init__(self) -> None:
        if self.outer_iterations < 1 or self.inner_iterations < 1:
            raise CalibrationError(
                f"iterations must be >= 1, got I1 = {self.outer_iterations}, "
                f"I2 = {self.inner_iterations}")


@dataclass(frozen=True)
class IterationReport:
    """Progress after one outer iteration: its number (1-based), the residual RMS (mm) at the
    equilibrium it started from, the actuation step's predicted largest marker motion (mm),
    how many FE updates it took, and whether its step was rejected and retried shorter."""

    iteration: int
    residual_rms_mm: float
    step_mm: float
    fe_updates: int
    rejected: bool = False


def match_markers(robot: Robot, observed: Markers, source: str) -> np.ndarray:
    """Indices (k,) into robot.marker_ids of the observed markers; CalibrationError for
    unknown, repeated or non-finite markers, or fewer than 3 non-collinear ones."""
    if not robot.marker_ids:
        raise CalibrationError(f"{robot.config.source}: the robot file defines no [[marker]]; "
                               "add the markers' rest positions (docs/robot_model.md)")
    known = {marker_id: i for i, marker_id in enumerate(robot.marker_ids)}
    seen: set[str] = set()
    for marker_id in observed.ids:
        if marker_id not in known:
            raise CalibrationError(
                f"{source}: marker {marker_id!r} is not in {robot.config.source.name} (its "
                f"markers: {', '.join(robot.marker_ids)}); fix the id or add the marker")
        if marker_id in seen:
            raise CalibrationError(f"{source}: marker {marker_id!r} appears twice; keep one")
        seen.add(marker_id)
    positions = np.asarray(observed.positions_mm, dtype=float).reshape(-1, 3)
    bad = ~np.isfinite(positions).all(axis=1)
    if bad.any():
        raise CalibrationError(f"{source}: marker {observed.ids[int(np.argmax(bad))]!r} has a "
                               "non-finite (NaN or inf) position; remove it or re-measure")
    if len(observed.ids) < 3:
        raise CalibrationError(f"{source}: {len(observed.ids)} markers observed; calibration "
                               "needs at least 3 non-collinear markers (5 or more recommended)")
    if collinearity(positions) < COLLINEAR_RATIO:
        raise CalibrationError(f"{source}: the observed markers {', '.join(observed.ids)} are "
                               "collinear; the rotation about their line is undetermined. Use "
                               "at least 3 markers that are not on one line")
    return np.array([known[marker_id] for marker_id in observed.ids], dtype=np.int64)


def calibrate(
    robot: Robot,
    observed: Markers,
    settings: CalibrationSettings = CalibrationSettings(),
    progress: Callable[[IterationReport], None] | None = None,
    excluded: tuple[str, ...] = (),
    source: str = "markers",
    start_mm: np.ndarray | None = None,
    start_inputs: np.ndarray | None = None,
) -> CalibrationResult:
    """Calibrate robot_from_camera and the actuation from observed markers (camera frame, mm).

    excluded : observed marker ids left out of the fit (still reported with their residual).
    start_mm : (n, 3) configuration to start from, with cable inputs start_inputs (a,) in
               control units (mm or N); by default the rest shape with all inputs 0.
    Raises CalibrationError for inconsistent markers or bounds, or when the FE update fails.
    """
    started = time.perf_counter()
    indices = match_markers(robot, observed, source)
    camera_mm = np.asarray(observed.positions_mm, dtype=float).reshape(-1, 3)
    used = np.array([marker_id not in excluded for marker_id in observed.ids])
    if used.sum() < 3 or collinearity(camera_mm[used]) < COLLINEAR_RATIO:
        raise CalibrationError(f"{source}: after excluding {', '.join(excluded)}, fewer than 3 "
                               "non-collinear markers remain")
    bounds = ActuationBounds.from_specs(robot.cable_specs)
    loop = _Loop(robot, robot.marker_points.subset(indices[used]), camera_mm[used], bounds,
                 settings)
    positions = robot.fe_model.rest_nodes_mm if start_mm is None else np.array(start_mm, float)
    inputs = CableInputs(bounds.control, np.zeros(len(bounds.names)) if start_inputs is None
                         else np.array(start_inputs, float))
    state = loop.settle(positions, inputs, np.zeros(len(bounds.names)), SETTLE_UPDATES,
                        SETTLE_MM)
    history, durations, converged = loop.run(state, progress)
    final = loop.accepted
    if (final.solution is not None
            and final.solution.bound_violation.max(initial=0.0) > BOUND_TOLERANCE):
        raise _bounds_error(robot, final.positions_mm, final.tensions_n, bounds,
                            final.solution.bound_violation)
    positions = final.lm.positions(final.tensions_n)
    return _result(robot, observed, indices, used, positions, final.tensions_n, final.lm.W_ea,
                   bounds, history, durations, converged, settings, source,
                   time.perf_counter() - started)


@dataclass
class _State:
    """A configuration at (or near) equilibrium for some cable inputs, and what follows.

    lm is linearised at positions_mm; tensions_n meet `inputs` on it; `settled` says an FE
    update from here moves no node more than the tolerance it was settled to. After the
    rigid fit: target (3k,) the observed markers in the robot frame and residual_rms_mm; after
    the QP: solution, whose tensions the next step heads for.
    """

    positions_mm: np.ndarray
    inputs: CableInputs
    lm: LinearModel
    tensions_n: np.ndarray
    updates: int
    settled: bool
    target: np.ndarray | None = None
    residual_rms_mm: float = np.inf
    solution: ActuationSolution | None = None

    def markers(self) -> np.ndarray:
        return self.lm.markers(self.tensions_n)

    def step(self, radius_mm: float) -> tuple[np.ndarray, float]:
        """Tensions along the QP's step, shortened so that no marker is predicted to move
        further than radius_mm; and the predicted largest marker motion (mm)."""
        direction = self.solution.tensions_n - self.tensions_n
        motion = (self.lm.W_ea @ direction).reshape(-1, 3)
        largest = float(np.sqrt(np.max(np.sum(motion**2, axis=1))))
        fraction = min(1.0, radius_mm / largest) if largest > 0 else 1.0
        return self.tensions_n + fraction * direction, fraction * largest


class _Loop:
    """Algorithm 1's iteration with its trust region; see the module notes."""

    def __init__(self, robot: Robot, markers, camera_mm: np.ndarray, bounds: ActuationBounds,
                 settings: CalibrationSettings) -> None:
        self.robot = robot
        self.rows = markers.cartesian_rows(robot.fe_model.node_count)
        self.camera_mm = camera_mm
        self.bounds = bounds
        self.settings = settings
        self.factorization = None
        self.accepted: _State | None = None

    def settle(self, positions: np.ndarray, inputs: CableInputs, tensions: np.ndarray,
               updates: int, tolerance_mm: float) -> _State:
        """At most `updates` FE updates (eq. 6) with the inputs held, until one moves no node
        more than tolerance_mm; the state is linearised before that last, small update."""
        for count in range(1, updates + 1):
            try:
                lm = linear_model(self.robot.fe_model, positions, tensions, self.rows,
                                  self.factorization)
            except SolverError as error:
                raise CalibrationError(f"the FE update failed during calibration ({error}); "
                                       "check that the markers match the robot") from error
            self.factorization = lm.factorization
            tensions = lm.tensions(inputs)
            moved = lm.positions(tensions)
            settled = float(np.abs(moved - positions).max()) <= tolerance_mm
            if settled or count == updates:
                return _State(positions, inputs, lm, tensions, count, settled)
            positions = moved
        raise AssertionError("unreachable")

    def fit(self, state: _State) -> _State:
        """The rigid fit (SVD) of the state's markers and the residual RMS."""
        markers = state.markers()
        transform = fit_rigid_transform(self.camera_mm, markers)
        state.target = transform.apply(self.camera_mm).ravel()
        state.residual_rms_mm = _rms(markers.ravel() - state.target)
        return state

    def propose(self, state: _State) -> None:
        """The QP's actuation step from `state` (eq. 9, rigid motions projected out)."""
        lm = state.lm
        W_ea, offset = lm.W_ea, lm.delta_e_free - state.target
        if self.settings.project_rigid:
            projector = rigid_motion_projector(state.target.reshape(-1, 3))
            W_ea, offset = projector @ W_ea, projector @ offset
        state.solution = solve_actuation_qp(W_ea, offset, np.zeros_like(offset), lm.W_aa,
                                            lm.delta_a_free, self.bounds)

    def predicted_rms_mm(self, state: _State, tensions: np.ndarray) -> float:
        markers = state.lm.markers(tensions)
        target = state.target.reshape(-1, 3)
        return _rms(markers.ravel() - fit_rigid_transform(target, markers).apply(target).ravel())

    def run(self, state: _State, progress) -> tuple[list[float], list[float], bool]:
        settings = self.settings
        self.accepted = self.propose_from(self.fit(state))
        radius, length, predicted = INITIAL_RADIUS_MM, 0.0, 0.0
        history, durations = [], []
        for outer in range(settings.outer_iterations):
            tick = time.perf_counter()
            if outer > 0:
                trial = self.fit(state)
                before = self.accepted.residual_rms_mm
                expected = before - predicted
                agreement = ((before - trial.residual_rms_mm) / expected if expected > 0
                             else (1.0 if trial.residual_rms_mm <= before else 0.0))
                rejected = (agreement < ACCEPT or not trial.settled) and length > MIN_RADIUS_MM
                if rejected:
                    radius = SHRINK * length
                else:
                    if agreement > GROW and length >= 0.9 * radius:
                        radius *= 2.0
                    self.accepted = self.propose_from(trial)
            else:
                trial, rejected = state, False
            history.append(trial.residual_rms_mm)
            tensions, length = self.accepted.step(radius)
            predicted = self.predicted_rms_mm(self.accepted, tensions)
            start = self.accepted.lm.positions(tensions)
            inputs = self.accepted.lm.inputs(self.bounds.control, tensions)
            state = self.settle(start, inputs, tensions, settings.inner_iterations,
                                min(max(EQUILIBRIUM_MM, EQUILIBRIUM_RATIO * length), SETTLE_MM))
            durations.append(time.perf_counter() - tick)
            if progress is not None:
                progress(IterationReport(outer + 1, history[-1], length, state.updates,
                                         rejected))
            small = max(settings.step_tolerance_mm, settings.step_ratio * history[-1])
            if (not rejected and outer > 0 and length < small
                    and abs(history[-1] - history[-2]) < settings.residual_tolerance_mm):
                return history, durations, True
        return history, durations, False

    def propose_from(self, state: _State) -> _State:
        self.propose(state)
        return state


def _rms(residual: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(residual.reshape(-1, 3) ** 2, axis=1))))


def _bounds_error(robot, positions, tensions, bounds, violation) -> CalibrationError:
    shortenings = robot.fe_model.cable_shortenings(positions)
    parts = []
    for i in np.flatnonzero(violation > BOUND_TOLERANCE):
        displacement = bounds.control[i] == "displacement"
        value = float(np.round(shortenings[i] if displacement else tensions[i], 2)) + 0.0
        unit = "mm" if displacement else "N"
        note = (" (a longer cable would have to push)"
                if displacement and value > bounds.upper[i] else "")
        parts.append(f"cable {bounds.names[i]!r} gets no closer than {value:.2f} {unit} to its "
                     f"bounds [{bounds.lower[i]:g}, {bounds.upper[i]:g}]{note}")
    return CalibrationError(f"the actuation bounds cannot hold: {'; '.join(parts)}; check the "
                            f"cables' min/max in {robot.config.source.name} and the markers")


def _result(robot, observed, indices, used, positions, tensions, marker_compliance, bounds,
            history, durations, converged, settings, source, elapsed_s) -> CalibrationResult:
    """Final rigid fit on the converged configuration, the per-marker residuals and the
    pose's covariance (the used markers' compliance (3k, a) to the cables' tensions)."""
    camera_mm = np.asarray(observed.positions_mm, dtype=float).reshape(-1, 3)
    model_mm = robot.marker_points.subset(indices).positions(positions)
    transform = fit_rigid_transform(camera_mm[used], model_mm[used])
    residual = transform.apply(camera_mm) - model_mm
    distance = np.linalg.norm(residual, axis=1)
    shortenings = robot.fe_model.cable_shortenings(positions)
    actuation = np.where(bounds.displacement, shortenings, tensions)
    slack = tensions < SLACK_TENSION_N
    warnings = []
    unknowns = 6 + len(tensions)
    if 3 * used.sum() < unknowns:
        warnings.append(f"{int(used.sum())} markers give {3 * int(used.sum())} coordinates for "
                        f"{unknowns} unknowns (6 rigid + {len(tensions)} cables): the actuation "
                        "is not identifiable; observe more markers")
    for i in np.flatnonzero(slack & bounds.displacement):
        warnings.append(f"cable {bounds.names[i]!r} is slack: its displacement is only known to "
                        f"be at most {shortenings[i]:.3f} mm")
    for i in range(len(tensions)):
        value = actuation[i]
        for limit, word in ((bounds.lower[i], "min"), (bounds.upper[i], "max")):
            if np.isfinite(limit) and abs(value - limit) <= BOUND_TOLERANCE and not (
                    word == "min" and slack[i] and bounds.displacement[i]):
                warnings.append(f"cable {bounds.names[i]!r} is at its {word} bound ({limit:g}): "
                                "the markers may ask for more; check the bounds")
    if not converged:
        warnings.append(f"not converged after {len(history)} outer iterations; raise --iterations")
    return CalibrationResult(
        robot_name=robot.name,
        robot_file=str(robot.config.source),
        source=source,
        robot_from_camera=transform,
        cable_names=bounds.names,
        cable_controls=bounds.control,
        actuation=actuation,
        tensions_n=tensions,
        slack=slack,
        residual_rms_mm=float(np.sqrt(np.mean(distance[used] ** 2))),
        residual_history_mm=tuple(history),
        markers=tuple(
            MarkerResidual(observed.ids[j], camera_mm[j], model_mm[j], residual[j],
                           bool(used[j]), False)
            for j in range(len(indices))
        ),
        unobserved=tuple(m for m in robot.marker_ids if m not in observed.ids),
        converged=converged,
        outer_iterations=settings.outer_iterations,
        inner_iterations=settings.inner_iterations,
        iteration_durations_s=tuple(durations),
        elapsed_s=elapsed_s,
        warnings=tuple(warnings),
        pose_covariance=pose_covariance(model_mm[used], residual[used],
                                        marker_compliance[:, ~slack]),
        positions_mm=positions,
    )
