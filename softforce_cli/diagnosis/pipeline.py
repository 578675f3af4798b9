"""The whole diagnosis: observations -> states -> one solve and one tangent per state (and
the responses of the nodes a plate may touch) -> nominal residuals -> every hypothesis
screened on the first-order model (fit and leave-one-segment-out) -> the best refitted on
the exact model -> forward selection of up to two effects -> a camera effect only the
markers see, when the clouds find nothing -> a camera chosen with the mesh's allowance ->
the mesh's own error left unnamed -> verdict, groups, location."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import zip_longest

import numpy as np

from softforce_cli.diagnosis.background import Table, observed_table
from softforce_cli.diagnosis.basis import Basis, build_basis
from softforce_cli.diagnosis.fit_bracket import FitBracket, fit_bracket, nominal_bracket
from softforce_cli.diagnosis.fitting import (
    Candidate,
    HeldOut,
    fit_values,
    held_out,
    judged_residuals,
    shift_jacobian,
)
from softforce_cli.diagnosis.hypotheses import ABSOLUTE, Hypothesis, Inputs, hypotheses
from softforce_cli.diagnosis.jumps import jumps_in_holds
from softforce_cli.diagnosis.markers import marker_field, marker_inputs, marker_rms_mm
from softforce_cli.diagnosis.observations import DiagnosisError, Observations
from softforce_cli.diagnosis.refit import ExactModel, Prediction, Refit, refit
from softforce_cli.diagnosis.residuals import (
    Field,
    measure,
    node_rms,
    node_systematic_mm,
    static_after_pose_mm,
    static_mm,
    surface_normals,
)
from softforce_cli.diagnosis.selection import (
    SAME_FIT_SHARE,
    UNEXPLAINED_MM,
    clear_improvement,
    confidence_intervals,
    effective_sample_size,
    excess_share,
    explains,
    indistinct,
    noise_floor_mm,
    systematic_mm,
    worth_refitting,
)
from softforce_cli.diagnosis.sensitivities import ColumnSet, column_set
from softforce_cli.diagnosis.solves import (
    ElementBracket,
    SolveCache,
    StateSolutions,
    element_bracket,
    solve_states,
)
from softforce_cli.diagnosis.states import States, group_states, trajectory_segments
from softforce_cli.diagnosis.support import support_basis
from softforce_cli.errors import SolverError
from softforce_cli.fem.processes import map_on_cores
from softforce_cli.fem.threads import one_blas_thread
from softforce_cli.model.effects import FrameContext, frame_contexts
from softforce_cli.model.regions import node_regions
from softforce_cli.model.robot import Robot

# Accepted candidates refitted on the exact model (two FE solves per affected state each).
REFIT_COUNT = 1
# Further candidates refitted when none of those is named (rejected, or accepted as a
# partial fit) and a structured residual remains (before the verdict `unexplained`).
FALLBACK_REFITS = 2
# ... among those whose screened held-out gain is this many standard errors above zero: a
# gain carried by one segment alone reaches at most 1 (selection, rule 1).
FALLBACK_Z = 1.0
# Candidates tried as the second effect of forward selection, and of those refitted.
SECOND_CANDIDATES = 3
SECOND_REFITS = 2
# Screened rivals of a named effect refitted before they may be grouped with it.
RIVAL_REFITS = 2
# Regions whose RMS systematic residual exceeds the whole body's by this factor hold it.
REGION_FACTOR = 1.25
# The static effects whose values are reported from a fit with the mesh's allowance
# (_with_the_mesh): fitted alone, they take up the coarse mesh's own stiffness error. Not
# the load scales (the allowance is one), nor a plate, whose prediction jumps where its
# height passes a node's rest height: fitted with the allowance, the plate at -10 mm ended
# at -6.72 mm, leaving 0.69 mm held-out against 0.43 alone (-7.46).
WITH_MESH_ALLOWANCE = frozenset({"compliant_base", "material_nonlinearity"})
NOT_WITH_MESH_ALLOWANCE = frozenset({"gravity", "stiffness_scale", "support_contact"})
Stage = Callable[[str, int, int | None], None]


@dataclass(frozen=True, eq=False)
class Screened:
    """One candidate on the first-order model: fitted values and held-out error, relative to
    a static baseline per node (relative) or absolute (hypotheses.ABSOLUTE), on the point
    clouds' residuals or (a camera effect) on the markers' (`channel`, diagnosis.markers)."""

    candidate: Candidate
    values: np.ndarray
    heldout: HeldOut
    relative: bool
    ci95: np.ndarray  # (k, 2) from the first-order model's Gauss-Newton covariance
    table_misfit_mm: float | None  # the observed table's height left unexplained
    channel: str = "clouds"

    @property
    def key(self) -> tuple[str, bool]:
        return self.candidate.hypotheses[0].name, self.relative


@dataclass(frozen=True, eq=False)
class Final:
    """A refitted candidate: the exact fit, its held-out error, intervals, acceptance, and
    its held-out error relative to the static baseline per node (`relative_heldout`: the
    same for a relative fit; for an absolute one its exact fit with the offsets refitted per
    fold; None for a camera judged on the markers)."""

    screened: Screened
    refit: Refit
    heldout: HeldOut
    ci95: np.ndarray
    accepted: bool
    table_misfit_mm: float | None
    relative_heldout: HeldOut | None = None

    @property
    def candidate(self) -> Candidate:
        return self.refit.candidate

    @property
    def values(self) -> np.ndarray:
        return self.refit.values


@dataclass(eq=False)
class Diagnosis:
    """The result (or what an interrupted run reached: `stage`, `interrupted`)."""

    robot: Robot
    observations: Observations
    states: States | None = None
    noise_floor_mm: float = float("nan")
    nominal: Field | None = None
    uncorrected: Field | None = None
    predicted_mm: np.ndarray | None = None
    screened: list[Screened] = field(default_factory=list)
    finals: list[Final] = field(default_factory=list)
    selected: list[Final] = field(default_factory=list)
    verdict: str | None = None
    groups: list[list[str]] = field(default_factory=list)
    location: dict = field(default_factory=dict)
    evidence: dict = field(default_factory=dict)
    not_refitted: list[str] = field(default_factory=list)
    # accepted effects that explain too little of the mismatch to be named (selection.explains)
    partial: list[str] = field(default_factory=list)
    # a body heavier or softer by no more than the mesh's discretisation makes: the selected
    # effects not named (_within_mesh), and that bound (solves.element_bracket)
    within_mesh: list[str] = field(default_factory=list)
    mesh_bracket: ElementBracket | None = None
    mesh_bracket_sought: bool = False  # _mesh_bracket asked once (None then: no bracket)
    # the two elements' disagreement at a fit that left too much to name on its own
    # (diagnosis.fit_bracket), and whether what it left is within it: named then, the rest
    # left to the mesh
    fit_bracket: FitBracket | None = None
    mesh_rest: bool = False
    # ... named since only what every frame shares was beyond the mesh's error without it
    # (FitBracket.explains_static_beyond, against nominal_bracket)
    mesh_rest_static: bool = False
    # the two elements' disagreement at the nominal model (_nominal_bracket), asked for a fit
    # with too much left to name or where no effect is named and a mismatch remains; whether
    # the mismatch is within it (_mismatch_within_mesh): then `none`, not `unexplained`
    nominal_bracket: FitBracket | None = None
    nominal_bracket_sought: bool = False
    mismatch_within_mesh: bool = False
    # a camera effect's held-out RMS (mm) with the mesh's allowance, when the first selected
    # effect was a camera's (_camera_with_the_mesh): {camera label: mm}
    camera_with_mesh_mm: dict[str, float] = field(default_factory=dict)
    # a selected static effect refitted with the mesh's allowance, its values the reported
    # ones (_with_the_mesh): {selected Final: that fit}
    with_mesh: dict[Final, Final] = field(default_factory=dict)
    # second effects accepted with the first besides the selected one (best first)
    second_rivals: list[Final] = field(default_factory=list)
    # the screening's inputs at the markers' residual entries (diagnosis.markers), their
    # floor and the camera effects screened on them; None / NaN / empty without markers
    marker_inputs: Inputs | None = None
    marker_floor_mm: float = float("nan")
    marker_screened: list[Screened] = field(default_factory=list)
    # the calibration's camera pose uncertainty (calibration.pose_covariance), None for a
    # pose given without markers
    pose_covariance: np.ndarray | None = None
    stage: str = "observations"
    interrupted: bool = False

    @property
    def final_field(self) -> Field | None:
        return self.selected[-1].refit.field if self.selected else self.nominal

    @property
    def fitted(self) -> Final | None:
        """The selected model: the last selected candidate holds every selected effect (a
        second effect is refitted with the first); None when nothing is selected."""
        return self.selected[-1] if self.selected else None

    @property
    def relative_nominal_mm(self) -> float:
        """The nominal model's held-out RMS residual relative to the static baseline (mm)."""
        return next(s.heldout.rms_before_mm for s in self.screened if s.relative)

    @property
    def markers(self) -> Field | None:
        """The markers' residual entries (diagnosis.markers), None without markers."""
        return None if self.marker_inputs is None else self.marker_inputs.field

    def floor_for(self, item: Screened | Final) -> float:
        """The noise floor (mm) of the channel a candidate was judged on."""
        screened = item.screened if isinstance(item, Final) else item
        return self.marker_floor_mm if screened.channel == "markers" else self.noise_floor_mm


class _StopRequestedError(Exception):
    """A stop was requested: the Diagnosis keeps what was reached (`interrupted`)."""


@dataclass(frozen=True, eq=False)
class _Judge:
    """What every candidate of one diagnosis is fitted and judged with: the exact model, the
    first-order inputs at the nominal residual's entries, the trajectory segments left out in
    turn, the noise floor (mm), the effective and actual frame counts, and the run's progress
    and stop callbacks."""

    exact: ExactModel
    inputs: Inputs
    nominal: Field
    segments: np.ndarray
    floor: float
    n_eff: float
    frames: int
    report: Stage
    stop_requested: Callable[[], bool]

    @property
    def table(self) -> Table | None:
        return self.exact.basis.table

    def check_stop(self) -> None:
        if self.stop_requested():
            raise _StopRequestedError

    def screen(self, candidate: Candidate, relative: bool,
               start: np.ndarray | None = None) -> Screened:
        """A candidate on the first-order model of the point clouds' residuals."""
        return _screen(candidate, self.inputs, self.segments, relative, self.n_eff, self.frames,
                       start=start)

    def final(self, screened: Screened, baseline: HeldOut | None = None,
              near: Prediction | None = None) -> Final:
        """A screened candidate refitted on the exact model, accepted when it clearly improves
        on the nominal model (or on `baseline`) and agrees with the table; its solves start
        near an earlier prediction where given (a pair's, its first effect's fit: refit)."""
        exact = self.exact

        # the refit stops on the residuals' own scatter; the reported interval also counts
        # how far the segments disagree (selection.confidence_intervals)
        def half_widths(field: Field, jacobian: np.ndarray, values: np.ndarray) -> np.ndarray:
            interval = confidence_intervals(field, jacobian, values, self.n_eff, self.frames)
            return 0.5 * (interval[:, 1] - interval[:, 0])

        fitted = refit(exact, screened.candidate, screened.values, screened.relative,
                       half_widths, self.stop_requested, near)
        final = self._judged(screened, fitted, baseline)
        if not fitted.prediction.followed:
            return final
        # a fit that followed the body past a fold is one start of two: its first-order
        # model is the standing body's tangent, and from a noisier start it can end far off
        # (the study's creep_0.5, seed 2: relaxation 0.71 at 0.84 s, not accepted, where
        # the standing fit is named); the standing branch's fit is kept unless the followed
        # one is accepted and generalises better
        try:
            standing = refit(exact, screened.candidate, screened.values, screened.relative,
                             half_widths, self.stop_requested, near, follow=False)
        except SolverError:  # no standing equilibrium even halfway back
            return final
        other = self._judged(screened, standing, baseline)
        if final.accepted and final.heldout.rms_after_mm < other.heldout.rms_after_mm:
            return final
        return other

    def _judged(self, screened: Screened, fitted: Refit, baseline: HeldOut | None) -> Final:
        """A refit as a Final: its held-out errors, intervals and acceptance (final)."""
        exact, segments, nominal = self.exact, self.segments, self.nominal
        inputs = exact.basis.inputs_for(fitted.field)
        result = exact_heldout(fitted, inputs, segments, nominal, screened.relative)
        relative = result if screened.relative else exact_heldout(fitted, inputs, segments,
                                                                  nominal, True)
        # the residual at the values (one first-order step from the last exact evaluation)
        left = fitted.field.mean_mm - fitted.jacobian @ (fitted.values - fitted.evaluated)
        field, jacobian = judged_residuals(fitted.field, left, fitted.jacobian,
                                           screened.relative)
        ci = confidence_intervals(field, jacobian, fitted.values, self.n_eff, self.frames,
                                  segments)
        table = fitted.candidate.table_misfit_mm(fitted.values, inputs)
        return Final(screened, fitted, result, ci,
                     clear_improvement(result, self.floor, baseline)
                     and _table_agrees(table, self.table), table, relative)

    def refit(self, result: Diagnosis, candidates: list[Screened]) -> None:
        """Refit candidates into result.finals (a failed solve noted in result.not_refitted);
        _StopRequestedError when a stop is requested."""
        for i, screened in enumerate(candidates):
            self.check_stop()
            self.report("refit", i, len(candidates))
            try:
                result.finals.append(self.final(screened))
            except SolverError as error:  # no equilibrium with this effect near the nominal
                result.not_refitted.append(f"{screened.candidate.label}: {error}")
        self.report("refit", len(candidates), len(candidates))


def diagnose_observations(robot: Robot, observations: Observations, cache: SolveCache,
                          stage: Stage | None = None,
                          stop_requested: Callable[[], bool] = lambda: False,
                          pose_covariance: np.ndarray | None = None) -> Diagnosis:
    """Screen every hypothesis, refit the best, choose what the data supports; the camera
    pose as uncertain as `pose_covariance` (calibration.pose_covariance) says, or exact.
    Returns the Diagnosis reached so far (interrupted) when stop_requested() turns true."""
    result = Diagnosis(robot, observations, pose_covariance=pose_covariance)
    report = stage or (lambda name, done, total: None)
    try:
        contexts = _states(result)
        result.stage = "solves"
        columns = column_set(robot)
        solutions = solve_states(robot, result.states.actuation, cache, columns,
                                 lambda done, total: report("FE states", done, total),
                                 stop_requested)
        if solutions is None:
            raise _StopRequestedError
        judge = _nominal(result, solutions, columns, cache, contexts, report, stop_requested)
        # the fits' thousands of small products on one BLAS thread (fem.threads); the
        # solves and the plate's responses above keep the threads their large products use
        with one_blas_thread():
            result.stage = "screening"
            _screen_hypotheses(result, judge)
            _screen_markers(result, solutions, judge.exact.basis, judge.segments,
                            judge.frames)
            # a stop ends the refit under way at its current values: no answer to judge
            result.stage = "refit"
            _first_effects(result, judge)
            judge.check_stop()
            _select(result, judge)
            judge.check_stop()
            _camera_with_the_mesh(result, judge, solutions, cache)
            judge.check_stop()
            _within_mesh(result, solutions, cache)
            _second_within_mesh(result, solutions, cache)
            judge.check_stop()
            result.stage = "mesh allowance"
            _with_the_mesh(result, judge, solutions, cache)
            judge.check_stop()
            result.stage = "verdict"
            _verdict(result, judge, solutions, cache)
            result.stage = "done"
    except _StopRequestedError:
        result.interrupted = True
    return result


def _states(result: Diagnosis) -> tuple[FrameContext, ...]:
    """Group the frames into states of equal inputs (result.states); the frames' contexts.
    DiagnosisError when the recordings cannot tell a model from its missing physics."""
    observations = result.observations
    contexts = tuple(frame_contexts(observations.times_s, observations.actuations))
    states = result.states = group_states(contexts)
    if states.count < 2 or np.ptp(states.actuation, axis=0).max(initial=0.0) <= 0.0:
        raise DiagnosisError(
            f"{', '.join(observations.recordings)}: the actuation never changes, and a model "
            "cannot be told from its missing physics without it; record loading, unloading "
            "and holds of the cables")
    if np.bincount(states.of_frame).max() < 2:
        raise DiagnosisError(
            f"{', '.join(observations.recordings)}: no input is held for two frames or more, "
            "so the camera's noise floor cannot be measured; record holds between the moves")
    return contexts


def _nominal(result: Diagnosis, solutions: StateSolutions, columns: ColumnSet,
             cache: SolveCache, contexts: tuple[FrameContext, ...], report: Stage,
             stop_requested: Callable[[], bool]) -> _Judge:
    """The plate's screening, the nominal model's residuals (result.nominal, uncorrected,
    predicted_mm), the hypotheses' first-order basis and the noise floor, as a _Judge."""
    result.stage = "plate contacts"
    support = support_basis(solutions, cache,
                            lambda done, total: report("plate contacts", done, total),
                            stop_requested)
    if stop_requested():
        raise _StopRequestedError
    robot, observations, states = result.robot, result.observations, result.states
    points = [f.points_mm for f in observations.frames]
    mesh = robot.mesh
    camera = observations.robot_from_camera.translation_mm

    def residuals(predicted_mm: np.ndarray) -> Field:
        return measure(points, predicted_mm, states.of_frame, mesh.surface_nodes,
                       mesh.surface_faces, camera)

    result.predicted_mm = solutions.predicted_mm
    nominal = result.nominal = residuals(solutions.predicted_mm)
    result.uncorrected = nominal if solutions.given_mm is None else residuals(solutions.given_mm)
    frames = len(observations.frames)
    recordings = np.array([f.recording for f in observations.frames])
    table = observed_table((f.table_plane for f in observations.frames), mesh.nodes_mm,
                           nominal.rms())
    basis = build_basis(solutions.predicted_mm, solutions.mesh_columns, mesh.surface_faces,
                        columns, states.of_frame, contexts,
                        tuple(spec.name for spec in robot.cable_specs),
                        observations.robot_from_camera, states.actuation, table, support)
    # the physics' own fields are cleared from the scatter first: drift within a hold is not
    # camera noise (selection.noise_floor_mm)
    result.noise_floor_mm = noise_floor_mm(nominal, states.of_frame, basis.normal_columns)
    return _Judge(ExactModel(solutions, states, contexts, points, basis, recordings),
                  basis.inputs_for(nominal), nominal, trajectory_segments(states, recordings),
                  result.noise_floor_mm, effective_sample_size(nominal, frames), frames, report,
                  stop_requested)


def _screen_hypotheses(result: Diagnosis, judge: _Judge) -> None:
    """Every hypothesis on the first-order model, relative (and absolute where it may be
    static: hypotheses.ABSOLUTE), into result.screened, best first; on the machine's cores
    (fem.processes: each fit is independent of the others)."""
    robot = result.robot
    tasks = [(Candidate((h,)), relative)
             for h in hypotheses(robot, judge.exact.basis.column_set, judge.exact.basis.support)
             for relative in (True, False) if relative or h.name in ABSOLUTE]
    judge.inputs.own_cable_columns  # noqa: B018 (cached once here, for every worker)
    judge.report("screening", 0, len(tasks))
    screened = map_on_cores(lambda i: judge.screen(*tasks[i]), len(tasks),
                            lambda done: judge.report("screening", done, len(tasks)),
                            judge.stop_requested)
    result.screened.extend(screened)  # what a stop leaves is kept, in order
    judge.check_stop()
    result.screened.sort(key=lambda s: -excess_share(s.heldout, judge.floor))


def _first_effects(result: Diagnosis, judge: _Judge) -> None:
    """The best screened candidates refitted on the exact model into result.finals (best
    first), and, when none of them names the mismatch while a structured residual remains,
    the next few (fallback_candidates), then the best on the region that holds the residual
    (located_candidates)."""
    floor, table = judge.floor, judge.table
    relative_nominal = result.relative_nominal_mm
    structured = _structured(judge.nominal.rms(), relative_nominal, floor)

    def unnamed() -> bool:
        return structured and not any(names_the_mismatch(f, relative_nominal, floor)
                                      for f in result.finals)

    agreeing = [s for s in _best_per_effect(result.screened)
                if _table_agrees(s.table_misfit_mm, table)]
    best = [s for s in agreeing if worth_refitting(s.heldout, floor)][:REFIT_COUNT]
    if not best and structured:
        # heading for `unexplained`: a large nonlinear effect may screen short of the floor
        # in size as well as in share (30% more gravity sags the Diamond 64% more, which
        # its first-order column explains 0.26 mm of, floor 0.36): the exact model judges
        # the best candidate that generalises (rule 1) with a quarter of the excess
        best = [s for s in agreeing if worth_refitting(s.heldout, floor, size=False)
                ][:REFIT_COUNT]
    judge.refit(result, best)
    if unnamed():
        # still heading for `unexplained`: the refit failed or fell short of a name (a
        # softer north arm fits part of a south arm twice as stiff, which screens just
        # behind it and is named once refitted): the exact model judges the next few
        judge.refit(result, fallback_candidates(result.screened, best, table))
    if unnamed():
        # then the region that holds the residual: an east arm 0.6 as stiff, pulled by
        # its own cable, screened at 0.81 with 13% of the relative excess, a gain of 0.4
        # standard errors over the segments, and was named 0.607 once refitted (on the
        # estimator's own model; 0.624 against the body on another mesh)
        strongest = _location(result.robot, judge.nominal, [])["regions"][:1]
        judge.refit(result, located_candidates(result.screened, result.finals, strongest,
                                               table))
    result.finals.sort(key=lambda f: -excess_share(f.heldout, floor))


def _select(result: Diagnosis, judge: _Judge) -> None:
    """result.selected: the first accepted effect that names the mismatch (or fits part of
    it) with a second effect where one clearly helps; a camera only the markers see when the
    clouds find nothing; a rival the exact model prefers, once refitted."""
    floor, relative_nominal = judge.floor, result.relative_nominal_mm
    # one that explains the mismatch before one that fits part of it (the verdict's rule)
    accepted = sorted((f for f in result.finals if f.accepted),
                      key=lambda f: not names_the_mismatch(f, relative_nominal, floor))
    if accepted:
        _select_first(result, judge, accepted[0])
    if not result.selected and not _structured(judge.nominal.rms(), relative_nominal, floor):
        # the clouds find nothing: a camera turned about the vertical or moved sideways
        # slides the surfaces along themselves, which only the markers see
        camera = _camera_from_markers(result, judge)
        result.selected = [] if camera is None else [camera]
    # (a rival of both selected effects is refitted once)
    rivals = list(dict.fromkeys(s for chosen in result.selected
                                if names_the_mismatch(chosen, relative_nominal, floor)
                                for s in screened_rivals(result, chosen, floor, judge.table)))
    if not rivals:
        return
    # a group says the data cannot tell them apart: the exact model judges the rivals the
    # screening could not separate from a named effect (a plate under the arms screens as
    # well as a lighter body, which the exact model leaves half the change across frames
    # unexplained)
    result.stage = "rivals"
    judge.refit(result, rivals)
    better = better_rival(result, relative_nominal, floor)
    if better is not None:
        # the exact model prefers a rival the screening had ranked behind (a base of 5 N/mm
        # screens behind a softer body, and refitted leaves 0.33 mm to its 0.38): it is the
        # first effect, and the second is sought anew with it
        _select_first(result, judge, better)


def _within_mesh(result: Diagnosis, solutions: StateSolutions, cache: SolveCache) -> None:
    """Leave unnamed (result.within_mesh) a selection that fits no better than a body
    heavier or softer (load_scale) by no more than the mesh's own discretisation makes it,
    when the mismatch is no larger than that error either (solves.element_bracket): the
    two quadratic elements on the robot's mesh bracket the converged body, so such a fit
    cannot be told from the mesh's error. The coarse P2 Diamond, against a clean recording
    of the converged body (P2-P0 on the 4.8 mm mesh), fits gravity 1.062 tilted 1.1
    degrees, or as well a body 0.944 as stiff, with 1.08 mm of systematic residual, where
    P2-P0 on its mesh deforms 1.14 times as much and lies 1.29 mm RMS away. A compliant
    base in that body fits a load scale of 1.13 too, but leaves 2.40 mm: not the mesh alone
    (docs/diagnosis.md, limits)."""
    if not result.selected:
        return
    first = result.selected[0]
    alike = [first, *_fitting_as_well(result, first)]
    scales = [(final, scale) for final in alike
              if (scale := load_scale(final, result.robot)) is not None]
    if not scales:
        return
    bracket = _mesh_bracket(result, solutions, cache)
    if bracket is None or systematic_mm(result.nominal.rms(), result.noise_floor_mm) > (
            bracket.surface_rms_mm):
        return
    inside = [(final, scale) for final, scale in scales if bracket.holds(scale)]
    if inside:
        result.within_mesh = [f"{final.candidate.label} (load scale g / E {scale:.3g})"
                              for final, scale in inside]
        result.selected = []


def _second_within_mesh(result: Diagnosis, solutions: StateSolutions, cache: SolveCache
                        ) -> None:
    """Leave unnamed (result.within_mesh) a second effect that is, or fits no better than
    (a rival pair the data cannot tell from it), a load scale within the mesh's own error
    (as _within_mesh a first one), where the first effect alone leaves no more residual that
    stays the same in every frame than that error (leaves_static_beyond) and names the
    mismatch across frames (names_the_mismatch): then the second explains the mesh's sag,
    not physics. Against the converged body a west cable 2 mm slack took gravity 1.061
    tilted 1.1 degrees as its second effect, as well as a body 0.939 as stiff, and wrote it
    into the fitted robot file (docs/diagnosis.md, method 11)."""
    if len(result.selected) != 2:
        return
    first, pair = result.selected
    library = [s.candidate.hypotheses[0] for s in result.screened]
    # the mesh's allowance a camera was fitted with (_camera_with_the_mesh) is the mesh's
    # already, and not one of the library's hypotheses
    alike = [f for f in (pair, *(r for r in result.second_rivals
                                 if indistinct(r.heldout, pair.heldout)))
             if any(f.candidate.hypotheses[-1] is h for h in library)]
    scales = [scale for f in alike if (scale := second_load_scale(f, result.robot)) is not None]
    bracket = _mesh_bracket(result, solutions, cache) if scales else None
    if bracket is None or not any(map(bracket.holds, scales)):
        return
    if leaves_static_beyond(first, _static_left_mm(result, first.refit.field),
                            bracket.surface_rms_mm) or not names_the_mismatch(
            first, result.relative_nominal_mm, result.noise_floor_mm):
        return  # the first alone would be a partial fit: the pair is judged as it stands
    result.within_mesh.append(
        ", ".join(f.candidate.hypotheses[-1].label for f in alike) + " as a second effect "
        f"(load scale g / E {', '.join(f'{scale:.3g}' for scale in scales)})")
    result.selected, result.second_rivals = [first], []


def _camera_with_the_mesh(result: Diagnosis, judge: _Judge, solutions: StateSolutions,
                          cache: SolveCache) -> None:
    """When the first selected effect is a camera's (on the clouds' absolute residuals), the
    camera effects are compared again, each fitted with the mesh's allowance: a load scale
    g / E between 1 and the other quadratic element's (solves.element_bracket, as
    _within_mesh), a stiffness scale bounded there. The coarse mesh's own error is a body
    sagging further than the model, which a camera's six parameters take up in part and a
    depth scale's one cannot: against the converged body a 1% depth scale was named a camera
    moved 6.4 mm along its axis (absolute held-out 0.55 mm against the depth scale's 0.72,
    floor 0.38); each with the allowance, the depth scale leaves 0.45 mm (0.0108, a body
    0.96 as stiff) and the move 0.48. The camera effect whose pair is clearly the best
    (selection.indistinct from none other) is then the first effect, its second sought
    anew, or else its allowance; the pairs' held-out errors are kept
    (result.camera_with_mesh_mm)."""
    if not result.selected:
        return
    first = result.selected[0]
    if (first.screened.channel != "clouds" or first.screened.relative
            or first.candidate.hypotheses[0].kind != "sensor"):
        return
    allowance = _mesh_allowance(result, solutions, cache)
    if allowance is None:
        return
    cameras = [s for s in _best_per_effect(result.screened) if not s.relative
               and s.candidate.hypotheses[0].kind == "sensor"
               and _table_agrees(s.table_misfit_mm, judge.table)]
    pairs: dict[str, Final] = {}
    for i, camera in enumerate(cameras):
        judge.check_stop()
        judge.report("camera with the mesh", i, len(cameras))
        final = _refit_with(result, judge, camera.candidate, camera.values, allowance)
        if final is not None and final.accepted:
            pairs[camera.candidate.label] = final
    judge.report("camera with the mesh", len(cameras), len(cameras))
    result.camera_with_mesh_mm = {label: f.heldout.rms_after_mm for label, f in pairs.items()}
    if not pairs:
        return
    best = min(pairs, key=lambda label: pairs[label].heldout.rms_after_mm)
    if best == first.candidate.hypotheses[0].label or any(
            indistinct(pairs[best].heldout, other.heldout)
            for label, other in pairs.items() if label != best):
        return
    alone = next((f for f in result.finals if not f.screened.relative
                  and f.screened.candidate.label == best), None)
    if alone is None:
        screened = next(c for c in cameras if c.candidate.label == best)
        try:
            alone = judge.final(screened)
        except SolverError as error:
            result.not_refitted.append(f"{best}: {error}")
            return
        result.finals.append(alone)
    floor, relative_nominal = judge.floor, result.relative_nominal_mm
    if not names_the_mismatch(alone, relative_nominal, floor):
        return
    _select_first(result, judge, alone)
    pair = pairs[best]
    # the second effect's screening runs on the first-order model, which puts the depth
    # scale alone at 1.54 mm where its exact fit leaves 0.72, and finds no second: the
    # allowance that decided the camera is its second effect when it clearly helps
    if (len(result.selected) == 1 and clear_improvement(pair.heldout, floor, alone.heldout)
            and second_keeps_the_first(alone, pair, relative_nominal, floor)):
        result.selected.append(pair)


def _mesh_allowance(result: Diagnosis, solutions: StateSolutions, cache: SolveCache
                    ) -> Hypothesis | None:
    """The mesh's own stiffness error as a hypothesis: a stiffness scale between 1 and the
    other quadratic element's 1 / load scale (solves.element_bracket: the two elements on
    the robot's mesh bracket the converged body); None without a bracket, or with one that
    leaves no room."""
    bracket = _mesh_bracket(result, solutions, cache)
    if bracket is None or bracket.load_scale == 1.0:
        return None
    stiffness = sorted((1.0, 1.0 / bracket.load_scale))
    return Hypothesis("stiffness_scale", None, ("scale",), np.ones(1),
                      np.array(stiffness[:1]), np.array(stiffness[1:]))


def _with_the_mesh(result: Diagnosis, judge: _Judge, solutions: StateSolutions,
                   cache: SolveCache) -> None:
    """Refit each selected static effect of WITH_MESH_ALLOWANCE (on the clouds' absolute
    residuals) together with the mesh's allowance (_mesh_allowance), into result.with_mesh
    when that fit is accepted and leaves no more held-out error than the effect alone
    (within selection.SAME_FIT_SHARE: the pair holds the effect alone, so more means its
    refit stopped short). Fitted alone, such an effect takes up the coarse mesh's own
    error, a body stiffer than the one recorded: against the 6.5 mm truth a base of 5 N/mm
    fitted 4.07 alone and 5.57 with the allowance (a body 0.98 as stiff), the corotational
    file's law switch (1) a blend of 0.65 alone and 0.95 with it, each at the same held-out
    error (docs/diagnosis.md, step 11). The verdict is decided on the effects alone; the
    values reported are this fit's."""
    chosen = [final for final in result.selected if takes_the_mesh(final)]
    if not chosen:
        return
    allowance = _mesh_allowance(result, solutions, cache)
    if allowance is None:
        return
    for i, final in enumerate(chosen):
        judge.check_stop()
        judge.report("mesh allowance", i, len(chosen))
        fitted = _refit_with(result, judge, final.candidate, final.values, allowance,
                             near=final.refit.prediction)
        if fitted is not None and fitted.accepted and fitted.heldout.rms_after_mm <= (
                (1.0 + SAME_FIT_SHARE) * final.heldout.rms_after_mm):
            result.with_mesh[final] = fitted
    judge.report("mesh allowance", len(chosen), len(chosen))


def _refit_with(result: Diagnosis, judge: _Judge, candidate: Candidate, values: np.ndarray,
                allowance: Hypothesis, near: Prediction | None = None) -> Final | None:
    """A candidate refitted on the absolute residuals together with the mesh's allowance,
    from its values and none (its solves started near `near`, the candidate's own fit,
    where given); None (noted in result.not_refitted) when a solve fails."""
    pair = judge.screen(Candidate((*candidate.hypotheses, allowance)), False,
                        start=np.concatenate([values, np.ones(1)]))
    try:
        return judge.final(pair, near=near)
    except SolverError as error:
        result.not_refitted.append(f"{pair.candidate.label}: {error}")
        return None


def takes_the_mesh(final: Final) -> bool:
    """Whether a selected fit's values are reported with the mesh's allowance: an absolute
    fit on the clouds with an effect of WITH_MESH_ALLOWANCE and none of
    NOT_WITH_MESH_ALLOWANCE."""
    names = {h.name for h in final.candidate.hypotheses}
    return (not final.screened.relative and final.screened.channel == "clouds"
            and bool(names & WITH_MESH_ALLOWANCE) and not names & NOT_WITH_MESH_ALLOWANCE)


def _fitting_as_well(result: Diagnosis, chosen: Final) -> list[Final]:
    """The other accepted refitted effects of the chosen one's mode whose held-out errors per
    segment the data cannot tell from its own (selection.indistinct)."""
    return [f for f in result.finals if f is not chosen and f.accepted
            and f.screened.relative == chosen.screened.relative
            and indistinct(f.heldout, chosen.heldout)]


def _select_first(result: Diagnosis, judge: _Judge, first: Final) -> None:
    """result.selected: `first`, and a second effect with it where one clearly helps."""
    result.stage = "second effect"
    result.selected = [first]
    second = _second(result, judge, first)
    if second is not None:
        result.selected.append(second)


def _screen(candidate: Candidate, inputs: Inputs, segments: np.ndarray, relative: bool,
            n_eff: float, frames: int, channel: str = "clouds",
            start: np.ndarray | None = None) -> Screened:
    """A candidate fitted on the first-order model at inputs.field's entries, validated by
    leaving each trajectory segment out."""
    field = inputs.field
    values = fit_values(candidate, inputs, field, relative, start=start)
    return Screened(candidate, values, held_out(candidate, inputs, field, segments, values,
                                                relative),
                    relative, _first_order_ci(candidate, inputs, field, values, relative, n_eff,
                                              frames, segments),
                    candidate.table_misfit_mm(values, inputs), channel)


def _screen_markers(result: Diagnosis, solutions, basis: Basis, segments: np.ndarray,
                    frames: int) -> None:
    """The camera effects screened on the markers' residuals (absolute: a camera error is
    static), into result.marker_inputs, marker_floor_mm and marker_screened (best first); their
    intervals count the markers' own effective frames."""
    observed = [f.markers_mm for f in result.observations.frames]
    if not any(len(o) for o in observed):
        return
    marker_points = solutions.robot.marker_points
    predicted = np.stack([marker_points.positions(p) for p in solutions.positions_mm])
    markers = marker_field(observed, predicted, basis.of_frame)
    if markers is None:
        return
    result.marker_floor_mm = noise_floor_mm(markers, basis.of_frame)
    inputs = result.marker_inputs = marker_inputs(markers, predicted, basis)
    n_eff = effective_sample_size(markers, frames)
    cameras = [h for h in hypotheses(result.robot, basis.column_set) if h.kind == "sensor"]
    result.marker_screened = sorted(
        (_screen(Candidate((h,)), inputs, segments, False, n_eff, frames, "markers")
         for h in cameras), key=lambda s: -excess_share(s.heldout, result.marker_floor_mm))


def camera_seen_by_markers(marker_screened: list[Screened], marker_floor_mm: float,
                           table: Table | None,
                           leaves_clouds_explained: Callable[[Screened], bool]
                           ) -> Screened | None:
    """The first camera effect of `marker_screened` (best first) that the markers accept
    (rules 1-3 against their own noise floor), that puts the table where the camera shows it
    and that leaves the clouds explained (their residual, with it applied, not structured).
    Not that it must improve the clouds: the markers' six-parameter fit takes up part of the
    model's own static mismatch at the markers in parameters the clouds see (a 1 degree turn
    was fitted with a 0.5 mm sideways move, within its interval, that took the clouds from
    0.82 to 0.94 mm RMS)."""
    return next((s for s in marker_screened if _markers_accept(s, marker_floor_mm, table)
                 and leaves_clouds_explained(s)), None)


def _markers_accept(screened: Screened, marker_floor_mm: float, table: Table | None) -> bool:
    """Rules 1-3 on the markers' residuals against their floor, and the table where seen."""
    return (clear_improvement(screened.heldout, marker_floor_mm)
            and _table_agrees(screened.table_misfit_mm, table))


def _camera_from_markers(result: Diagnosis, judge: _Judge) -> Final | None:
    """camera_seen_by_markers as a Final: its exact prediction is the nominal one seen
    through the camera effect (no FE solve), its held-out figures the markers'."""
    exact = judge.exact

    def leaves_clouds_explained(screened: Screened) -> bool:
        shift = screened.candidate.shift(screened.values, judge.inputs)
        return not _structured(judge.nominal.rms(shift=shift), result.relative_nominal_mm,
                               judge.floor)

    screened = camera_seen_by_markers(result.marker_screened, result.marker_floor_mm,
                                      exact.basis.table, leaves_clouds_explained)
    if screened is None:
        return None
    candidate, values = screened.candidate, screened.values
    prediction = exact.predict(candidate, values)
    field = exact.field(prediction)
    jacobian = shift_jacobian(candidate, exact.basis.inputs_for(field), values)
    return Final(screened, Refit(candidate, values, field, jacobian, prediction, 0, values),
                 screened.heldout, screened.ci95, True, screened.table_misfit_mm)


def fallback_candidates(screened: list[Screened], tried: list[Screened],
                        table: Table | None) -> list[Screened]:
    """The next FALLBACK_REFITS of `screened` not in `tried`, on any target (a south arm
    twice as stiff screens just behind a softer north arm, which fits part of it), whose
    screened gain rests on more than one segment (FALLBACK_Z) and which put the table where
    the camera shows it: the next of each mode in turn, relative first (shares of the
    relative and of the absolute excess do not compare: a south arm half as stiff screens
    at 0.20 of the relative one, behind a heavier, a softer body and a base at 0.35-0.43 of
    the absolute one, and was named only once refitted)."""
    done = {(s.candidate.label, s.relative) for s in tried}
    eligible = [s for s in screened if (s.candidate.label, s.relative) not in done
                and s.heldout.gain_z() > FALLBACK_Z
                and _table_agrees(s.table_misfit_mm, table)]
    modes = ([s for s in eligible if s.relative], [s for s in eligible if not s.relative])
    turns = [s for pair in zip_longest(*modes) for s in pair if s is not None]
    return turns[:FALLBACK_REFITS]


def located_candidates(screened: list[Screened], refitted: list[Final], regions: list[str],
                       table: Table | None) -> list[Screened]:
    """The best screened candidate, not refitted yet, on the region or cable where the
    nominal residual concentrates (_location) whose first-order fit improves on the nominal
    model (held-out) and puts the table where the camera shows it; none if there is no
    such region. A large effect on an actuated part of the body may screen far short of
    its size (its first-order column is taken at the nominal value), and its gain is then
    no clearer than the other candidates' noise."""
    done = {(f.screened.candidate.label, f.screened.relative) for f in refitted}
    return [s for s in screened
            if s.candidate.hypotheses[0].target in regions
            and (s.candidate.label, s.relative) not in done
            and s.heldout.rms_after_mm < s.heldout.rms_before_mm
            and _table_agrees(s.table_misfit_mm, table)][:1]


def screened_rivals(result: Diagnosis, chosen: Final, floor: float, table: Table | None
                    ) -> list[Screened]:
    """The screened effects (best target of each) other than the chosen one's that clearly
    improve on the nominal model, agree with the table and whose screening the chosen
    one's does not beat (selection.indistinct), not refitted yet: one signature to first
    order, for the exact model to judge (a 1% depth scale and a 4.7 mm camera move along
    its axis, 80 mm of depth at 470, are one on the exact model too). None for a camera
    judged on the markers."""
    if chosen.screened.channel == "markers":
        return []
    refitted = {(f.screened.candidate.label, f.screened.relative) for f in result.finals}
    name = chosen.screened.candidate.hypotheses[0].name
    return [s for s in _best_per_effect(result.screened)
            if s.key != chosen.screened.key and s.candidate.hypotheses[0].name != name
            and (s.candidate.label, s.relative) not in refitted
            and clear_improvement(s.heldout, floor)
            and _table_agrees(s.table_misfit_mm, table)
            and indistinct(s.heldout, chosen.screened.heldout)][:RIVAL_REFITS]


def better_rival(result: Diagnosis, relative_nominal_mm: float, floor: float
                 ) -> Final | None:
    """The refitted effect that would be named instead of the first selected one: judged in
    the same mode, naming the mismatch, and leaving clearly less held-out error (not
    indistinct); None when the first stands."""
    chosen = result.selected[0]
    rivals = [f for f in result.finals if f is not chosen
              and f.screened.relative == chosen.screened.relative
              and names_the_mismatch(f, relative_nominal_mm, floor)
              and f.heldout.rms_after_mm < chosen.heldout.rms_after_mm
              and not indistinct(f.heldout, chosen.heldout)]
    return min(rivals, key=lambda f: f.heldout.rms_after_mm, default=None)


def second_keeps_the_first(first: Final, pair: Final, relative_nominal_mm: float,
                           floor: float) -> bool:
    """Whether a refitted pair (the first effect and a second) may be selected: accepted,
    and naming the mismatch when the first alone does (names_the_mismatch). A second effect
    must not undo the first: a camera moved 20 mm (at its bound) with a south arm twice as
    stiff improved the absolute fit of the converged body, but left the change across
    frames at 1.53 mm where the arm alone left 0.38 (floor 0.29), and the arm went
    unnamed."""
    return pair.accepted and (names_the_mismatch(pair, relative_nominal_mm, floor)
                              or not names_the_mismatch(first, relative_nominal_mm, floor))


def names_the_mismatch(final: Final, relative_nominal_mm: float, floor: float) -> bool:
    """Whether a refitted candidate would be named: accepted and, relative to the static
    baseline, explaining the mismatch rather than fitting part of it (_verdict). An effect
    accepted on the absolute residuals must explain what changes across frames too: a plate
    under the Diamond's arms fits as a lighter body (gravity 0.82, absolute held-out 3.05 ->
    0.98 mm) that leaves 0.59 mm of the 0.95 mm relative residual against a 0.27 mm floor,
    where the static effects of the library leave 1.02-1.21 times the floor."""
    return final.accepted and (final.relative_heldout is None or explains(
        relative_nominal_mm, final.relative_heldout.rms_after_mm, floor))


def leaves_static_beyond(final: Final, static_after_mm: float, limit_mm: float) -> bool:
    """Whether the selected model (`final`, with every selected effect) leaves more residual
    that stays the same in every frame (static_mm) than the mesh's own error explains
    (_static_limit): then it fits part of something else and is not named, as one that leaves
    what changes across frames above the noise (names_the_mismatch). Not where its refit
    stopped because the model has no equilibrium further on (Refit.unreached): what remains
    may be the same effect beyond what the mesh can solve, and the summary says so (creep
    of relaxation 0.5, which the coarse Diamond holds no equilibrium for past 0.36-0.41
    with its cables pulled, fitted 0.32, leaving 4.67 mm static). A camera judged on the
    markers is judged there."""
    return (final.screened.channel == "clouds" and static_after_mm > limit_mm
            and not final.refit.unreached)


def _mismatch_within_mesh(result: Diagnosis, exact: ExactModel, solutions: StateSolutions,
                         cache: SolveCache) -> bool:
    """Whether a mismatch no effect names is no larger than the mesh's own error
    (result.nominal_bracket, FitBracket.holds_mismatch): the nominal model's residual that
    every frame shares within what the robot's two quadratic elements disagree by, and what
    changes across frames, above the noise floor, too; then the verdict is `none`, not
    `unexplained`. Against the converged body at 640x480 the coarse Diamond's clean
    recording (0.204 mm held-out across frames, floor 0.144; 1.07 mm systematic, where the
    elements are 1.29 mm apart at rest) fits as gravity 1.06 tilted 1.1 degrees, which
    leaves 0.19 mm across frames, too much to name; at 1280x720 as gravity 1.06 untilted,
    which is the mesh's (_within_mesh), leaving the same structured residual: the mismatch
    is the mesh's, not physics outside the library. Only asked when the nominal residual is
    within the elements' distance at rest (solves.element_bracket), as _within_mesh asks."""
    bracket = _mesh_bracket(result, solutions, cache)
    floor = result.noise_floor_mm
    if bracket is None or systematic_mm(result.nominal.rms(), floor) > bracket.surface_rms_mm:
        return False
    nominal = _nominal_bracket(result, exact)
    return nominal is not None and nominal.holds_mismatch(floor)


def _nominal_bracket(result: Diagnosis, exact: ExactModel) -> FitBracket | None:
    """result.nominal_bracket (fit_bracket.nominal_bracket), solved the first time it is
    asked for only."""
    if not result.nominal_bracket_sought:
        result.nominal_bracket = nominal_bracket(exact)
        result.nominal_bracket_sought = True
    return result.nominal_bracket


def _structured(absolute_mm: float, relative_mm: float, floor: float) -> bool:
    """Whether a residual is more than noise: relative to the static baseline, more than
    the floor above it; absolute, more than UNEXPLAINED_MM above it."""
    return (systematic_mm(relative_mm, floor) > floor
            or systematic_mm(absolute_mm, floor) > UNEXPLAINED_MM)


def _table_agrees(misfit_mm: float | None, table: Table | None) -> bool:
    """Whether an explanation puts the table where the camera shows it (diagnosis.background):
    a physics effect cannot explain a moved table, nor a camera move an unmoved one."""
    return misfit_mm is None or table is None or misfit_mm <= table.tolerance_mm


def _first_order_ci(candidate: Candidate, inputs, nominal: Field, values: np.ndarray,
                    relative: bool, n_eff: float, frames: int, segments: np.ndarray
                    ) -> np.ndarray:
    """(k, 2) 95% intervals of a screened fit (its first-order model's Jacobian)."""
    left = nominal.mean_mm - candidate.shift(values, inputs)
    field, jacobian = judged_residuals(nominal, left, shift_jacobian(candidate, inputs, values),
                                       relative)
    return confidence_intervals(field, jacobian, values, n_eff, frames, segments)


def _best_per_effect(screened: list[Screened]) -> list[Screened]:
    """The best target of each effect and mode, in the order given."""
    best: dict[tuple[str, bool], Screened] = {}
    for s in screened:
        best.setdefault(s.key, s)
    return list(best.values())


def exact_heldout(fitted: Refit, inputs: Inputs, segments: np.ndarray, nominal: Field,
                  relative: bool) -> HeldOut:
    """A refitted candidate's held-out error in either mode (inputs at its exact residual's
    entries): each fold refits it on the linearisation at its last exact evaluation."""
    return held_out(fitted.candidate, inputs, fitted.field, segments, fitted.evaluated,
                    relative, jacobian=fitted.jacobian, nominal=nominal)


def _second(result: Diagnosis, judge: _Judge, first: Final) -> Final | None:
    """The best second effect, screened together with the first and refitted, accepted when
    it clearly improves on the first alone: in the first's mode, then, for a first effect
    judged relative to the static baseline, in the absolute one among the effects screened
    there (hypotheses.ABSOLUTE): the law's sag under the body's weight, a base or a camera
    move show in the absolute residuals only (a slack cable recorded through a robot file of
    another law had named the slack alone). Other pairs accepted too are kept in
    result.second_rivals (groups)."""
    relative = first.screened.relative
    accepted = _second_in_mode(result, judge, first, relative, first.screened.heldout,
                               first.heldout)
    if not accepted and relative and not judge.stop_requested():
        alone = judge.screen(first.candidate, False, start=first.values)
        exact = judge.exact
        alone_exact = exact_heldout(first.refit, exact.basis.inputs_for(first.refit.field),
                                    judge.segments, judge.nominal, False)
        accepted = _second_in_mode(result, judge, first, False, alone.heldout, alone_exact)
    result.second_rivals = accepted[1:]
    return accepted[0] if accepted else None


def _second_in_mode(result: Diagnosis, judge: _Judge, first: Final, relative: bool,
                    screened_alone: HeldOut, exact_alone: HeldOut) -> list[Final]:
    """_second in one mode: the next SECOND_CANDIDATES effects screened with the first, those
    worth it refitted (up to SECOND_REFITS: the first-order model under-explains a second
    effect as it does a first, the law's sag with a slack cable at a share of 0.37), the
    accepted ones returned best first. The pair must clearly improve on the first alone in
    that mode: on its screening (screened_alone) to be refitted, on its exact fit
    (exact_alone) to be accepted."""
    taken = first.candidate.hypotheses[0]
    # one camera: a depth scale and a move along the axis are nearly one signature, and
    # together they trade against each other (against the converged body a 1% depth scale
    # took a 3.7 mm move as its second effect and fell to 0.0047)
    others = [s for s in _best_per_effect(result.screened) if s.relative == relative
              and s.candidate.hypotheses[0].name != taken.name
              and not (taken.kind == "sensor" == s.candidate.hypotheses[0].kind)
              ][:SECOND_CANDIDATES]
    pairs = []
    for i, other in enumerate(others):
        judge.report("second effect", i, len(others))
        pair = Candidate((taken, *other.candidate.hypotheses))
        pairs.append(judge.screen(pair, relative,
                                  start=np.concatenate([first.values, other.values])))
    judge.report("second effect", len(others), len(others))
    worth = sorted((p for p in pairs if _table_agrees(p.table_misfit_mm, judge.table)
                    and worth_refitting(p.heldout, judge.floor, baseline=screened_alone)),
                   key=lambda p: p.heldout.rms_after_mm)[:SECOND_REFITS]
    accepted = []
    for pair in worth:
        if judge.stop_requested():
            break
        try:
            final = judge.final(pair, baseline=exact_alone, near=first.refit.prediction)
        except SolverError as error:
            result.not_refitted.append(f"{pair.candidate.label}: {error}")
            continue
        if second_keeps_the_first(first, final, result.relative_nominal_mm, judge.floor):
            accepted.append(final)
    return sorted(accepted, key=lambda f: f.heldout.rms_after_mm)


def _verdict(result: Diagnosis, judge: _Judge, solutions: StateSolutions,
             cache: SolveCache) -> None:
    """result.verdict, groups, location and evidence from what was selected."""
    floor, basis, segments = judge.floor, judge.exact.basis, judge.segments
    nominal = result.nominal
    final = result.final_field
    before, after = nominal.rms(), final.rms()
    node_count = result.robot.mesh.node_count
    static_after = static_mm(final, node_count)
    static_left = _static_left_mm(result, final)
    static_limit = _static_limit(result, solutions, cache)
    relative_before = result.relative_nominal_mm
    last = result.selected[-1] if result.selected else None
    relative_after = (last.relative_heldout.rms_after_mm
                      if last is not None and last.relative_heldout is not None
                      else relative_before)
    structured = _structured(after, relative_after, floor)
    fitted = result.selected
    static_beyond = last is not None and leaves_static_beyond(last, static_left, static_limit)
    relative_named = last is not None and names_the_mismatch(last, relative_before, floor)
    partial = last is not None and (static_beyond or not relative_named)
    if partial and last.screened.channel == "clouds":
        # too much left to name it, unless the mesh cannot resolve the body at the fit, or
        # only what every frame shares was beyond the mesh's error to begin with
        bracket = result.fit_bracket = fit_bracket(judge.exact, last.refit)
        result.mesh_rest = bracket is not None and bracket.explains_rest(
            floor, relative_named, not static_beyond)
        if bracket is not None and not result.mesh_rest:
            at_nominal = _nominal_bracket(result, judge.exact)
            result.mesh_rest_static = at_nominal is not None and bracket.explains_static_beyond(
                at_nominal, floor, not static_beyond)
            result.mesh_rest = result.mesh_rest_static
        partial = not result.mesh_rest
    if partial:
        # fitted, accepted, but most of what it fits is something else: not a name to give
        result.partial = [chosen.candidate.label for chosen in fitted]
        result.selected = []
    if result.selected:
        result.verdict = result.selected[0].candidate.hypotheses[0].name
    elif structured or partial:
        result.mismatch_within_mesh = _mismatch_within_mesh(result, judge.exact, solutions,
                                                            cache)
        result.verdict = "none" if result.mismatch_within_mesh else "unexplained"
    else:
        result.verdict = "none"
    for chosen in result.selected:
        if chosen.screened.channel == "markers":
            # judged on the markers: the other camera effects the markers accept as well
            near = [s.candidate.label for s in result.marker_screened
                    if s is not chosen.screened
                    and _markers_accept(s, result.marker_floor_mm, basis.table)
                    and indistinct(s.heldout, chosen.heldout)]
        elif len(chosen.candidate.hypotheses) > 1:
            # a second effect: the other pairs with the first that fit as well
            near = [f.candidate.hypotheses[-1].label for f in result.second_rivals
                    if names_the_mismatch(f, relative_before, floor)
                    and indistinct(f.heldout, chosen.heldout)]
        else:
            near = [f.candidate.label for f in _fitting_as_well(result, chosen)
                    if names_the_mismatch(f, relative_before, floor)]
        twin = load_scale_twin(chosen, result.robot)
        if twin is not None and twin not in near:
            near.append(twin)
        if near:
            result.groups.append([chosen.candidate.hypotheses[-1].label, *near])
    # where the nominal residual is; a named effect's target first. A partial fit's target
    # is not put first: a hidden mass on the north elbow fits as a stiffer south arm about
    # as well as a softer north one (held-out 0.396 and 0.401 mm), and the residual is
    # largest on the north arm (2.3 mm RMS against 1.0-1.2 elsewhere)
    result.location = _location(result.robot, nominal if fitted else final, result.selected)
    if result.markers is not None:  # the nominal model's error at each marker
        result.location["marker_rms_mm"] = {
            k: round(v, 3) for k, v in marker_rms_mm(result.markers,
                                                     result.robot.marker_ids).items()}
    mesh = result.robot.mesh
    given = result.uncorrected.rms()
    corrections = (np.zeros(1) if solutions.given_mm is None else
                   (solutions.predicted_mm - solutions.given_mm)[:, mesh.surface_nodes])
    result.evidence = {
        "frames": len(result.observations.frames),
        "frames_skipped": result.observations.skipped,
        "states": result.states.count,
        "segments": int(segments.max() + 1),
        "effective_frames": round(judge.n_eff, 1),
        "element": result.robot.element_name,
        "prediction_element": solutions.robot.element_name,
        "mesh_correction_rms_mm": round(float(np.sqrt(np.mean(np.sum(corrections**2,
                                                                      axis=-1)))), 3),
        "rms_given_element_mm": round(given, 3),
        # the observed table's height above where the robot stands (RMS over its footprint)
        "table_offset_mm": (None if basis.table is None else
                            round(float(np.sqrt(np.mean(basis.table.observed_mm**2))), 3)),
        "mesh_share": round(max(0.0, 1.0 - before**2 / given**2), 3) if given > 0 else 0.0,
        "rms_nominal_mm": round(before, 3),
        "rms_final_mm": round(after, 3),
        "systematic_nominal_mm": round(systematic_mm(before, floor), 3),
        "systematic_final_mm": round(systematic_mm(after, floor), 3),
        "heldout_relative_nominal_mm": round(relative_before, 3),
        "heldout_relative_final_mm": round(relative_after, 3),
        # the residual that stays the same in every frame (each node's mean), with the
        # selected effects, and the most a named effect may leave (_static_limit)
        "static_final_mm": round(static_after, 3),
        # ... of it, what the camera pose the calibration allows cannot account for
        "static_after_pose_mm": round(static_left, 3),
        "static_limit_mm": round(static_limit, 3),
        "static_beyond_limit": bool(static_beyond),
        "unexplained_threshold_mm": UNEXPLAINED_MM,
        "remaining_structured": bool(structured),
        "fe_solves_refit": int(sum(f.refit.solves for f in
                                   [*result.finals, *result.with_mesh.values()])),
        "screened": len(result.screened),
        "not_refitted": result.not_refitted,
        "partial_effects": result.partial,
        # selected effects left unnamed as within the mesh's discretisation, and what bounds
        # it (the other quadratic element on the mesh; None: not needed)
        "within_mesh_effects": result.within_mesh,
        # the elements' disagreement at a fit with too much left to name on its own, and
        # whether that rest is left to the mesh (the fit named); None: not needed
        "mesh_at_fit": (None if result.fit_bracket is None else
                        {**result.fit_bracket.as_dict(), "explains_rest": result.mesh_rest,
                         "static_beyond_only": result.mesh_rest_static}),
        # the elements' disagreement at the nominal model, its rest the nominal residual,
        # and whether that is within it (the verdict `none`); None: not needed
        "mesh_at_nominal": (None if result.nominal_bracket is None else
                            {**result.nominal_bracket.as_dict(),
                             "holds_mismatch": result.mismatch_within_mesh}),
        "mesh_bracket": (None if result.mesh_bracket is None else {
            "load_scale": round(result.mesh_bracket.load_scale, 4),
            "surface_rms_mm": round(result.mesh_bracket.surface_rms_mm, 3)}),
        # when a camera effect was selected first: each camera effect's held-out RMS (mm)
        # fitted with the mesh's allowance (empty: not needed)
        "camera_with_mesh_mm": {k: round(v, 3) for k, v in result.camera_with_mesh_mm.items()},
        # frames whose points jumped from the frame before's with the inputs held: a body
        # snapping through, or the robot or camera moved (diagnosis.jumps)
        "jumps_in_holds": [jump.as_dict()
                           for jump in jumps_in_holds(result.observations.frames)],
        # the markers' residual (diagnosis.markers): None when the recordings have none
        "markers": None if result.markers is None else {
            "observations": len(result.markers.frame) // 3,
            "noise_floor_mm": round(result.marker_floor_mm, 3),
            "rms_nominal_mm": round(result.markers.rms(), 3)},
    }


def load_scale_twin(chosen: Final, robot: Robot) -> str | None:
    """The effect that is the same model as the chosen one, whatever its own refit reached:
    with every cable displacement-controlled, a body s times as stiff under gravity g is in
    equilibrium where the body is under g / s (elastic forces scale with the modulus, the
    cables' tensions follow), so a stiffness scale and an untilted gravity scale are one
    fit (the study's 30% more gravity: a body 0.7595 as stiff, gravity's own refit stopped
    at a snap-through with its tilt at -4 degrees). None for another effect, a gravity
    tilted beyond its interval, or a force-controlled cable."""
    candidate = chosen.screened.candidate
    if len(candidate.hypotheses) > 1 or chosen.screened.channel != "clouds":
        return None
    return _twin_of(candidate.hypotheses[0], chosen.ci95, robot)


def load_scale(chosen: Final, robot: Robot) -> float | None:
    """The load scale g / E (1: nominal) of a fitted effect that is one (load_scale_twin):
    1 / s for a stiffness scale s, the gravity scale itself; None for another effect."""
    if load_scale_twin(chosen, robot) is None:
        return None
    return _scale_of(chosen.candidate.hypotheses[0], chosen.values)


def second_load_scale(pair: Final, robot: Robot) -> float | None:
    """The load scale g / E of a pair's second effect where it is one (as load_scale for a
    first effect: its own 95% intervals judge the tilts); None otherwise."""
    candidate = pair.candidate
    if len(candidate.hypotheses) != 2 or pair.screened.channel != "clouds":
        return None
    second = candidate.hypotheses[1]
    if _twin_of(second, pair.ci95[-len(second.free):], robot) is None:
        return None
    return _scale_of(second, candidate.split(pair.values)[1])


def _twin_of(hypothesis: Hypothesis, ci95: np.ndarray, robot: Robot) -> str | None:
    """load_scale_twin of one fitted hypothesis, its 95% intervals (k, 2)."""
    if any(spec.control != "displacement" for spec in robot.cable_specs):
        return None
    if hypothesis.name == "stiffness_scale":
        return "gravity"
    if hypothesis.name == "gravity":
        tilted = [low > 0 or high < 0 for name, (low, high)
                  in zip(hypothesis.free, ci95, strict=True) if name.startswith("tilt")]
        return None if any(tilted) else "stiffness_scale"
    return None


def _scale_of(hypothesis: Hypothesis, values: np.ndarray) -> float:
    """The load scale g / E of a stiffness or gravity scale's values."""
    scale = float(values[hypothesis.free.index("scale")])
    return 1.0 / scale if hypothesis.name == "stiffness_scale" else scale


def _static_limit(result: Diagnosis, solutions: StateSolutions, cache: SolveCache) -> float:
    """The most static residual (static_mm, mm; after the camera pose's correction,
    _static_left_mm) the selected effects may leave and be named:
    the mesh's own error, the RMS distance between the two quadratic elements on the robot's
    mesh (solves.element_bracket, one more solve when an effect is selected; 1.29 mm on the
    coarse Diamond), or UNEXPLAINED_MM without it. An effect that explains what changes
    across frames but leaves the shape they share further off than the mesh could is a
    partial fit of something else: against the converged body a hidden 40 g mass on the north
    elbow fits as a north arm 0.80 as stiff, to 1.18-1.22 times the noise floor of the change
    across frames, and leaves 1.39-1.41 mm static (the library's effects there leave
    0.21-0.47 mm; the clean recording, nothing fitted, 1.08 mm). The bracket measures
    locking: on a mesh that does not lock its two elements agree within hundredths of a
    millimetre (a finger's 0.06 mm, a trunk's 0.005) where the mesh is a tenth of a
    millimetre from the body. A limit of 1.25 times the noise floor there named a cable's
    slack fitted right on both (0.09 mm left after the camera's pose), and a trunk's clean
    recording, given its camera's true pose, as one arm 0.75 as stiff (the mesh's error,
    0.065 mm left): a wrong name where there was none, so not kept."""
    bracket = _mesh_bracket(result, solutions, cache) if result.selected else None
    return UNEXPLAINED_MM if bracket is None else bracket.surface_rms_mm


def _static_left_mm(result: Diagnosis, field: Field) -> float:
    """The residual that stays the same in every frame (static_mm) that a fit leaves and the
    camera pose cannot account for: after the pose's correction within what the
    calibration's markers allow (residuals.static_after_pose_mm; none for a pose given
    without markers). A finger calibrated from nine markers is 1.1 degrees off its camera's
    true pose, which leaves 0.26 mm static beside a cable's slack fitted right, where P2 and
    P2-P0 on its mesh agree within 0.06 mm; the pose's correction leaves 0.09 mm."""
    count = result.robot.mesh.node_count
    if result.pose_covariance is None:
        return static_mm(field, count)
    return static_after_pose_mm(field, count, *_seen_shape(result, field),
                                result.pose_covariance)


def _seen_shape(result: Diagnosis, field: Field) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) mm each node's position and (n, 3) its unit outward normal on the nominal
    model, averaged over the frames that see it (weighted by their points; the rest shape's
    where none does): where a correction of the camera pose moves a node's mean residual. A
    turn of a degree moves a node 30 mm from its rest position by 0.5 mm more than at rest."""
    mesh = result.robot.mesh
    count = mesh.node_count
    predicted = result.predicted_mm
    normals = np.stack([surface_normals(shape, mesh.surface_faces) for shape in predicted])
    state = result.states.of_frame[field.frame]
    weight = np.bincount(field.node, weights=field.weight, minlength=count)
    seen = weight > 0

    def mean(values: np.ndarray, rest: np.ndarray) -> np.ndarray:
        summed = np.stack([np.bincount(field.node, weights=field.weight * values[:, k],
                                       minlength=count) for k in range(3)], axis=1)
        return np.where(seen[:, None], summed / np.where(seen, weight, 1.0)[:, None],
                        rest[:count])

    positions = mean(predicted[state, field.node], mesh.nodes_mm)
    directions = mean(normals[state, field.node], mesh.vertex_normals)
    length = np.linalg.norm(directions, axis=1, keepdims=True)
    return positions, np.divide(directions, length, out=np.zeros_like(directions),
                                where=length > 0)


def _mesh_bracket(result: Diagnosis, solutions: StateSolutions, cache: SolveCache
                  ) -> ElementBracket | None:
    """result.mesh_bracket (solves.element_bracket), solved the first time it is asked for
    only: a failed solve (no equilibrium of the other element) is not tried again."""
    if not result.mesh_bracket_sought:
        result.mesh_bracket = element_bracket(solutions, cache)
        result.mesh_bracket_sought = True
    return result.mesh_bracket


def _location(robot: Robot, field: Field, selected: list[Final]) -> dict:
    """Regions, cables and nodes where the residual concentrates; a selected effect's
    target first."""
    n = robot.mesh.node_count
    mean, weight = node_systematic_mm(field, n)
    masks = {name: mask[:n] for name, mask in node_regions(robot).items()}
    seen = weight > 0
    per_region = {name: node_rms(mean, weight, mask & seen)
                  for name, mask in masks.items() if (mask & seen).any()}
    overall = node_rms(mean, weight, seen)
    regions = sorted((r for r, v in per_region.items() if v > REGION_FACTOR * overall),
                     key=lambda r: -per_region[r])
    targets = [h.target for f in selected for h in f.candidate.hypotheses if h.target]
    regions = list(dict.fromkeys([*targets, *regions]))
    cables = [spec.name for spec in robot.cable_specs]
    top = np.argsort(-np.abs(mean) * seen)[:10]
    return {"regions": regions, "cables": [r for r in regions if r in cables],
            "nodes": [int(i) for i in top if seen[i]],
            "region_rms_mm": {k: round(v, 3) for k, v in per_region.items()}}
