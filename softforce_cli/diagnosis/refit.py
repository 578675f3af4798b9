"""Nonlinear refit of the best screened candidates: full FE solves with the effect.

The screening's first-order model ranks every hypothesis; the few best are refitted on the
exact model: each state solved again with the effects (warm-started from its nominal
equilibrium of the accurate model moved to first order, diagnosis.solves, plus what the
refit's previous evaluation found beyond its own first-order start), the camera effects
applied, and the residuals measured again (each point re-associated with the moved
surface). Gauss-Newton steps use the first-order model's Jacobian at the current values with
these exact residuals, corrected by Broyden's secant update from the shifts the steps before
made (a chord method alone converges at the first-order model's rate, which for a large
stiffness change is slow), each step kept only when the exact residual falls.

A creeping body can pass a fold within a hold and tip over, onto a branch of equilibria no
solve near the nominal ones reaches: there the exact model follows the frames in turn, each
from the one before, as the body moves (ExactModel.followed), where that holds more of the
camera's points and fits them better. Such a fit is then searched along the fold's valley
(diagnosis.fold), which Gauss-Newton steps cross but do not follow.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property, partial

import numpy as np
from scipy.optimize import least_squares

from softforce_cli.diagnosis.basis import Basis
from softforce_cli.diagnosis.fitting import (
    Candidate,
    TableRows,
    _linear_step,
    judged_residuals,
    node_offsets,
    shift_jacobian,
    table_row_weight,
    table_rows,
)
from softforce_cli.diagnosis.fold import search_along_the_fold
from softforce_cli.diagnosis.residuals import Field, measure
from softforce_cli.diagnosis.solves import SETTINGS, StateSolutions, other_element
from softforce_cli.diagnosis.states import States
from softforce_cli.errors import SolverError
from softforce_cli.fem.cables import CableInputs
from softforce_cli.fem.processes import map_on_cores
from softforce_cli.fem.statics import Equilibrium, solve_by_continuation, solve_equilibrium
from softforce_cli.model.effect_physics import fe_model_with_effects
from softforce_cli.model.effects import (
    Effect,
    FrameContext,
    effective_actuation,
    effects_of_kind,
    observed_points_robot,
)

# Gauss-Newton steps of the refit after the exact evaluation at the screened values, each
# solved only while it moves the values by more than half their 95% interval: cable effects
# screen within a few percent and stop after one (docs/diagnosis.md); a large stiffness
# change (an arm twice as stiff) screens 40% off and needs four or five, each with the
# Jacobian corrected by what the steps before it moved (secant_update). Each costs a P2 solve of
# every affected state (5-15 s each on a loaded 2-core machine).
REFIT_STEPS = 5
# A step smaller than this share of a parameter's screening range ends the refit.
REFIT_TOLERANCE = 1e-3
# The secant's gains on the first-order Jacobian are kept within these (refit.secant_update).
MIN_SECANT, MAX_SECANT = 0.02, 50.0
# A state whose solve does not converge from its first-order start is solved again with the
# effect's values reached in this many equal steps from the neutral ones (a body 30% softer
# under displacement-controlled cables: 60 Newton iterations from the first-order start
# stopped 3 mN short). Each step starts from the last equilibrium, a quarter of the change
# away, and gives up after 15 Newton iterations: the Diamond 36% softer fails its steps
# anyway (its soft apex-tipping mode), and 60 iterations each had cost 10 minutes a diagnosis.
CONTINUATION_STEPS = 4
STEP_SETTINGS = dataclasses.replace(SETTINGS, max_iterations=15)
# The direct solve from the first-order start gives up after this many Newton iterations:
# the refits that converge take 2-22 (the study's gravity_1.3, 61 solves, the Neo-Hookean
# robot), and one that does not had spent 60 (about 30 s) before its continuation.
DIRECT_SETTINGS = dataclasses.replace(SETTINGS, max_iterations=30)
# A screened start (or a Gauss-Newton step) that no solve reaches is pulled this many times
# halfway back towards the neutral values (the step halved): the coarse Diamond's P2 model
# snaps through its apex-tipping mode between 0.75 and 0.7 times its stiffness with the
# north cable pulled, so a body 30% softer screens at 0.64, beyond any equilibrium near the
# nominal one, while its refit can still approach from the stable side.
BACKOFFS = 2
# A step that raises the exact residual (past the minimum along it) is halved this many times
# before the refit ends: the south arm at half its stiffness, on the very model that made the
# data, went 0.70, 0.65, 0.59 and then past the truth to 0.47, where the residual doubled.
OVERSHOOT_HALVINGS = 1
# A positive parameter whose range spans this factor is stepped (and halved) in its
# logarithm: creep's time constant (0.05-1000 s) enters as exp(-hold / tau), whose tangent
# at 1.9 s sent a step for the study's 0.5 s to the bound, 0.05 s, where the body has no
# equilibrium; in log tau the same step lands at 0.44 s.
LOG_RANGE = 100.0
# A Gauss-Newton step over which the first-order model itself departs from its tangent by
# more than this share of the tangent's shift (RMS) is solved on the first-order model
# instead (_curved_step): creep's relaxation saturates, a (1 - exp(-hold / tau)) <= a, and
# the tangent's step for the study's (0.3, 0.5 s) from (0.26, 1.5 s) went to (0.72, 0.05 s).
CURVED_STEP = 0.25
# ExactModel.followed's solve of a frame from the frame before: in one Newton solve, else
# in 4 equal steps of the cable inputs, each with up to 200 iterations. A body that creeps
# past its fold within a hold falls over in one solve, its inputs held: the coarse Diamond
# relaxed to 0.64 of its modulus with its four cables at 6 mm took 89 iterations to hang
# inverted, 100 mm lower (the study's creep_0.5).
FOLLOWED_STEPS = (1, 4)
FOLLOWED_SETTINGS = dataclasses.replace(SETTINGS, max_iterations=200)
# A followed fit's Jacobian (its 95% intervals, its held-out refits) is the exact model's, by
# forward differences of this share of each parameter's range in the step coordinates
# (creep's relaxation 0.0045 of its 0-0.9, its time constant 5% in the logarithm): the
# first-order model is the nominal states' tangent, which says little about a tipped body.
FOLLOWED_DIFFERENCE = 0.005


class NoEquilibriumError(SolverError):
    """The exact model has no equilibrium near the recording's shape at one state with a
    candidate's values, even by continuation: past a snap-through of the mesh (the coarse
    Diamond's P2 model tips its apex between 0.75 and 0.7 of its stiffness under the north
    cable's 9 mm), or a value the body itself could not hold.

    inputs : (a,) the state's effective cable inputs.
    values : (k,) the candidate's values tried.
    """

    def __init__(self, candidate: Candidate, values: np.ndarray, inputs: np.ndarray) -> None:
        self.candidate, self.values, self.inputs = candidate, np.asarray(values), inputs
        super().__init__(f"no equilibrium at inputs {_listed(inputs)} with "
                         f"{candidate.label} at {_listed(values)}")


class _UnreachedError(Exception):
    """A group's solve failed even by continuation (its index among the solved groups, the
    last solve's message): a worker's report, which pickles, that the caller turns into a
    NoEquilibriumError."""

    def __init__(self, index: int, message: str) -> None:
        super().__init__(index, message)
        self.index, self.message = index, message


def _listed(values: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:.4g}" for v in np.asarray(values, dtype=float)) + ")"


@dataclass(frozen=True, eq=False)
class Prediction:
    """The exact model's surface with a candidate: positions_mm (G, n, 3) of G solved groups
    of frames, of_frame (t,) each frame's group, and the FE solves it took. A group is a
    state, or with creep a state's frames of one hold time (the body relaxes within a
    hold, so each hold time is its own equilibrium)."""

    positions_mm: np.ndarray
    of_frame: np.ndarray
    solves: int
    # (G, N, 3) mm: each group's equilibrium (every node) less the first-order start it was
    # solved from, which a next prediction carries over (ExactModel.predict's `near`); in
    # float32, as a Newton start needs no more, since a diagnosis keeps every refit's
    nonlinear_mm: np.ndarray | None = None
    # the frames followed in the recordings' order, each its own group (ExactModel.followed)
    followed: bool = False


@dataclass(frozen=True, eq=False)
class Refit:
    """A candidate on the exact model: the fitted values (k,); the exact residual entries,
    Jacobian (E, k: the first-order one with the secant's correction) and prediction at
    `evaluated` (k,) (the last exact evaluation: `values` is one Gauss-Newton step from it
    when that step was within half the 95% interval, else `values` itself); the FE solves it
    took; and the values the exact model could not follow (`unreached`: each the
    SolverError, a NoEquilibriumError as a rule, after which the values were pulled back)."""

    candidate: Candidate
    values: np.ndarray
    field: Field
    jacobian: np.ndarray
    prediction: Prediction
    solves: int
    evaluated: np.ndarray
    unreached: tuple[SolverError, ...] = ()


@dataclass(frozen=True, eq=False)
class ExactModel:
    """Everything an exact evaluation needs."""

    solutions: StateSolutions
    states: States
    contexts: tuple[FrameContext, ...]
    points_mm: list[np.ndarray]
    basis: Basis
    # (t,) each frame's recording (ExactModel.followed starts each anew); None: one
    recordings: np.ndarray | None = None

    def predict(self, candidate: Candidate, values: np.ndarray,
                near: Prediction | None = None) -> Prediction:
        """The predicted mesh nodes with the candidate's effects, per group of frames; the
        groups' solves, independent of each other, run on the machine's cores
        (fem.processes).

        Each group's Newton solve starts from its state's nominal equilibrium moved to first
        order by the candidate (StateSolutions.first_order), plus, given `near` (an earlier
        prediction of this model: a refit's last step), what near's equilibrium of the
        group's first frame was beyond its own first-order start. A refit's next step is a
        small change, and that start spares its solves an iteration; the plain start is
        tried after it where it fails."""
        solutions = self.solutions
        robot = solutions.robot
        n = robot.mesh.node_count
        effects, physics, effective, creep = self._with_effects(candidate, values)
        cables = [spec.name for spec in robot.cable_specs]
        of_frame, firsts = self._groups(creep)
        plate = self._plate_motion(candidate, values)
        predicted = solutions.predicted_mm[self.states.of_frame[firsts]].copy()
        nonlinear = np.zeros((len(firsts), *solutions.positions_mm.shape[1:]), np.float32)
        # without creep one model serves every group: made here, so that workers inherit it
        shared = (None if creep else fe_model_with_effects(robot, physics) if physics
                  else robot.nominal_fe_model)
        controls = tuple(spec.control for spec in robot.cable_specs)
        # the groups whose nominal prediction does not do, each solved or sharing the solve of
        # the first group of its inputs (a twin)
        changed = [g for g, first in enumerate(firsts) if physics or not np.allclose(
            effective[first], solutions.actuation[self.states.of_frame[first]])]
        leader = dict(zip(changed, _leaders(effective, firsts[changed], creep, changed),
                          strict=True))
        solved = [g for g in changed if leader[g] == g]
        twins = {g: first for g, first in leader.items() if first != g}

        def solve(index: int) -> tuple[np.ndarray, np.ndarray, int]:
            first = firsts[solved[index]]
            s = int(self.states.of_frame[first])
            inputs = effective[first]
            context = self.contexts[first]
            model = fe_model_with_effects(robot, physics, context) if creep else shared
            first_order = solutions.first_order(s, _column_changes(
                candidate, values, context.hold_s,
                dict(zip(cables, inputs - solutions.actuation[s], strict=True))))
            if plate is not None:
                first_order += robot.fe_mesh.from_corners(plate[s])
            starts = [first_order]
            if near is not None and near.nonlinear_mm is not None:
                starts.insert(0, first_order + near.nonlinear_mm[near.of_frame[first]])
            for start in starts:
                try:
                    solution = solve_equilibrium(model, CableInputs(controls, inputs),
                                                 start_mm=start, settings=DIRECT_SETTINGS)
                    return solution.positions_mm[:n], solution.positions_mm - first_order, 1
                except SolverError:  # too far for Newton from this start
                    pass
            try:
                solution = self._continued(candidate, values, first)
            except SolverError as error:
                raise _UnreachedError(index, str(error)) from error
            return (solution.positions_mm[:n], solution.positions_mm - first_order,
                    CONTINUATION_STEPS)

        try:
            results = map_on_cores(solve, len(solved))
        except _UnreachedError as unreached:
            first = firsts[solved[unreached.index]]
            raise NoEquilibriumError(candidate, values, effective[first]) from SolverError(
                unreached.message)
        for g, (positions, beyond, _) in zip(solved, results, strict=True):
            predicted[g], nonlinear[g] = positions, beyond
        for g, twin in twins.items():
            predicted[g], nonlinear[g] = predicted[twin], nonlinear[twin]
        solves = sum(count for *_, count in results)
        return Prediction(self._seen(predicted, effects), of_frame, solves, nonlinear)

    def followed(self, candidate: Candidate, values: np.ndarray) -> Prediction:
        """The prediction with the candidate's effects solved frame by frame in the
        recordings' order, each frame from the equilibrium of the frame before (the first of
        a recording from its state's nominal one), by continuation of the inputs where one
        Newton solve does not reach it: the body as it moves, as `simulate` moves its truth.
        A creeping body that passes a fold within a hold tips over and hangs on another
        branch of equilibria, which no solve near the nominal ones reaches (the study's
        creep_0.5: its apex drops 113 mm in frame 6 and stays down). One group per frame,
        solved in turn. Raises NoEquilibriumError at a frame not reached."""
        solutions = self.solutions
        robot = solutions.robot
        n = robot.mesh.node_count
        effects, physics, effective, _ = self._with_effects(candidate, values)
        controls = tuple(spec.control for spec in robot.cable_specs)
        frames = len(self.contexts)
        recordings = self.recording_of_frame
        predicted = np.empty((frames, n, 3))
        for i in range(frames):
            if i == 0 or recordings[i] != recordings[i - 1]:
                s = int(self.states.of_frame[i])
                last = (solutions.actuation[s], solutions.positions_mm[s])
            model = fe_model_with_effects(robot, physics, self.contexts[i])
            try:
                solution = solve_by_continuation(model, controls, effective[i], [last],
                                                 FOLLOWED_SETTINGS, FOLLOWED_STEPS)
            except SolverError as error:
                raise NoEquilibriumError(candidate, values, effective[i]) from error
            last = (effective[i], solution.positions_mm)
            predicted[i] = solution.positions_mm[:n]
        return Prediction(self._seen(predicted, effects), np.arange(frames), frames,
                          followed=True)

    @property
    def recording_of_frame(self) -> np.ndarray:
        """(t,) each frame's recording (all 0 for one)."""
        if self.recordings is None:
            return np.zeros(len(self.contexts), dtype=int)
        return np.asarray(self.recordings)

    def followed_each(self, candidate: Candidate, values: list[np.ndarray]
                      ) -> list[Prediction | NoEquilibriumError]:
        """followed at each of the values (each (k,)), on the machine's cores
        (fem.processes); a frame not reached gives its NoEquilibriumError in that place."""

        def follow(i: int) -> Prediction | tuple[np.ndarray, np.ndarray]:
            try:
                return self.followed(candidate, values[i])
            except NoEquilibriumError as error:  # its arguments pickle, it does not
                return error.values, error.inputs

        return [NoEquilibriumError(candidate, *result) if isinstance(result, tuple) else result
                for result in map_on_cores(follow, len(values))]

    def _seen(self, predicted_mm: np.ndarray, effects: tuple[Effect, ...]) -> np.ndarray:
        """(G, n, 3) mm: predicted nodes as the camera effects among `effects` show them."""
        sensor = effects_of_kind(effects, "sensor")
        if not sensor:
            return predicted_mm
        return observed_points_robot(predicted_mm.reshape(-1, 3), sensor,
                                     self.basis.robot_from_camera).reshape(predicted_mm.shape)

    def other_element(self, candidate: Candidate | None, values: np.ndarray | None,
                      prediction: Prediction) -> list[np.ndarray | None]:
        """Per group of `prediction` (this model's at `values`, a candidate without camera
        effects; None: the nominal model, nominal_prediction), the mesh nodes (n, 3) mm of
        the mesh's other quadratic element (solves.other_element) with the same effects, each
        solved from this model's equilibrium (once per effective input without creep, as
        predict solves); None where Newton's method finds no equilibrium near it."""
        solutions = self.solutions
        robot = solutions.robot
        other = other_element(robot)
        n = robot.mesh.node_count
        _, physics, effective, creep = self._with_effects(candidate, values)
        _, firsts = np.unique(prediction.of_frame, return_index=True)
        controls = tuple(spec.control for spec in robot.cable_specs)
        # without creep one model serves every group: made here, so that workers inherit it
        shared = None if creep else fe_model_with_effects(other, physics)

        def solve(g: int) -> np.ndarray | None:
            first = firsts[g]
            s = int(self.states.of_frame[first])
            model = (fe_model_with_effects(other, physics, self.contexts[first]) if creep
                     else shared)
            # the prediction keeps the corners: its mid-edge nodes moved as their edges
            start = solutions.positions_mm[s] + robot.fe_mesh.from_corners(
                prediction.positions_mm[g] - solutions.predicted_mm[s])
            try:
                return solve_equilibrium(model, CableInputs(controls, effective[first]),
                                         start_mm=start, settings=DIRECT_SETTINGS
                                         ).positions_mm[:n]
            except SolverError:
                return None

        leader = _leaders(effective, firsts, creep, range(len(firsts)))
        leaders = sorted(set(leader))
        solved = dict(zip(leaders, map_on_cores(lambda i: solve(leaders[i]), len(leaders)),
                          strict=True))
        return [solved[g] for g in leader]

    def _with_effects(self, candidate: Candidate | None, values: np.ndarray | None
                      ) -> tuple[tuple[Effect, ...], tuple[Effect, ...], np.ndarray, bool]:
        """The candidate's effects at `values` (none without a candidate), their physics,
        every frame's effective cable inputs (t, a) and whether the physics creeps (a group
        per hold time, _groups)."""
        effects = () if candidate is None else candidate.effects(values)
        physics = effects_of_kind(effects, "physics")
        cables = [spec.name for spec in self.solutions.robot.cable_specs]
        creep = any(e.name == "viscoelastic_creep" for e in physics)
        return effects, physics, effective_actuation(effects, self.contexts, cables), creep

    def _plate_motion(self, candidate: Candidate, values: np.ndarray) -> np.ndarray | None:
        """(S, n, 3) mm: each state's motion at the mesh nodes with the candidate's plate,
        its contact solved on the state's linearisation (diagnosis.support), or None without
        one. Newton's start: from the nominal equilibrium alone, a plate 30 mm into the
        hanging Diamond pushes its nodes with 800 N (the coarse P2 model at (0, 6, 0, 6) with
        the plate at -5.5 mm: 33 iterations, against 10 from this start)."""
        height = candidate.plate_height_mm(values)
        return None if height is None else self.basis.support.motion_mm(height)

    def _groups(self, by_hold: bool) -> tuple[np.ndarray, np.ndarray]:
        """(of_frame (t,) each frame's group, firsts (G,) each group's first frame): the
        states, or (by_hold) each state's frames of one hold time."""
        keys = self.states.of_frame.astype(float)
        if by_hold:
            holds = np.round([c.hold_s for c in self.contexts], 6)
            keys = np.stack([keys, holds], axis=1)
            _, firsts, of_frame = np.unique(keys, axis=0, return_index=True,
                                            return_inverse=True)
        else:
            _, firsts, of_frame = np.unique(keys, return_index=True, return_inverse=True)
        return of_frame.ravel(), firsts

    def _continued(self, candidate: Candidate, values: np.ndarray, first: int) -> Equilibrium:
        """The equilibrium of frame `first`'s group with the candidate at `values` by
        continuation: the values approached from the neutral ones (candidate.start) in
        CONTINUATION_STEPS equal steps, each solve starting from the last equilibrium (the
        first from the state's nominal one)."""
        robot = self.solutions.robot
        cables = [spec.name for spec in robot.cable_specs]
        controls = tuple(spec.control for spec in robot.cable_specs)
        context = self.contexts[first]
        positions = self.solutions.positions_mm[self.states.of_frame[first]]
        for t in np.linspace(0.0, 1.0, CONTINUATION_STEPS + 1)[1:]:
            effects = candidate.effects(candidate.start + t * (values - candidate.start))
            model = fe_model_with_effects(robot, effects_of_kind(effects, "physics"), context)
            inputs = effective_actuation(effects, self.contexts, cables)[first]
            solution = solve_equilibrium(model, CableInputs(controls, inputs),
                                         start_mm=positions, settings=STEP_SETTINGS)
            positions = solution.positions_mm
        return solution

    @cached_property
    def nominal_prediction(self) -> Prediction:
        """The prediction of the nominal model (every candidate at its neutral values): the
        states' own solves."""
        return Prediction(self.solutions.predicted_mm, self.states.of_frame, 0)

    @cached_property
    def nominal_field(self) -> Field:
        """The residual field of the nominal prediction."""
        return self.field(self.nominal_prediction)

    def field(self, prediction: Prediction) -> Field:
        robot = self.solutions.robot
        return measure(self.points_mm, prediction.positions_mm, prediction.of_frame,
                       robot.mesh.surface_nodes, robot.mesh.surface_faces,
                       self.basis.robot_from_camera.translation_mm)


def _leaders(effective: np.ndarray, firsts: np.ndarray, creep: bool, groups) -> list[int]:
    """Per group of `groups` (its first frame in `firsts`), the group whose solve it shares:
    the first of them with the same effective inputs (loading and unloading), itself with
    creep (its hold time is its own)."""
    first_of: dict[bytes, int] = {}
    return [g if creep else first_of.setdefault(effective[first].tobytes(), g)
            for g, first in zip(groups, firsts, strict=True)]


def _column_changes(candidate: Candidate, values: np.ndarray, hold_s: float,
                    input_changes: dict[str, float]) -> dict[str, float]:
    """{sensitivity column: change} that moves a state to the candidate to first order."""
    changes = {f"cable.{name}": change for name, change in input_changes.items()}
    for hypothesis, part in zip(candidate.hypotheses, candidate.split(values), strict=True):
        v = dict(zip(hypothesis.free, part, strict=True))
        name = hypothesis.name
        if name == "gravity":
            changes.update({"gravity.scale": v["scale"] - 1.0,
                            "gravity.tilt_x_deg": v["tilt_x_deg"],
                            "gravity.tilt_y_deg": v["tilt_y_deg"]})
        elif name == "stiffness_scale":
            changes["stiffness"] = 1.0 - 1.0 / v["scale"]
        elif name == "regional_stiffness":
            changes[f"region.{hypothesis.target}"] = 1.0 - 1.0 / v["scale"]
        elif name == "material_nonlinearity":
            changes["blend"] = v["blend"]
        elif name == "compliant_base":
            changes["base_compliance"] = v["compliance_mm_per_n"]
        elif name == "viscoelastic_creep":
            changes["stiffness"] = 1.0 - 1.0 / (1.0 - v["relaxation"] * (
                1.0 - np.exp(-hold_s / v["time_constant_s"])))
    return changes


def refit(exact: ExactModel, candidate: Candidate, start: np.ndarray, relative: bool,
          half_widths: Callable[[Field, np.ndarray, np.ndarray], np.ndarray],
          stop_requested: Callable[[], bool] = lambda: False,
          near: Prediction | None = None, follow: bool = True) -> Refit:
    """Gauss-Newton on the exact model from the screening's values `start` (relative: with
    the static offsets per node, diagnosis.fitting). half_widths(field, jacobian, values)
    gives the 95% half-widths (k,): a step within half of them is taken on the first-order
    model, without solving the states again (the data cannot tell the two values apart).
    The steps and the secant are taken in StepCoordinates. A camera effect is fitted to the
    observed table's height too, as in its screening (diagnosis.fitting.table_rows).
    Each evaluation's solves start near the one before (ExactModel.predict), the first near
    `near` where given. With `follow`, a creeping candidate whose values leave the equilibria
    near the nominal ones is followed frame by frame where that fits the camera's points
    better (_followed_if_better), and from there on; without, its values are pulled back.
    A followed fit is searched along the fold's valley (fold.search_along_the_fold), and its
    Jacobian is the exact model's, by differences (followed_differences)."""
    values = np.clip(np.asarray(start, dtype=float), candidate.lower, candidate.upper)
    neutral = np.clip(candidate.start, candidate.lower, candidate.upper)
    coordinates = StepCoordinates.of(candidate)
    unreached: list[SolverError] = []
    basis = exact.basis

    def table(field: Field, at: np.ndarray) -> TableRows | None:
        return table_rows(candidate, basis.table, basis.robot_from_camera, at,
                          float(field.weight.sum()))

    def objective(field: Field, at: np.ndarray) -> float:
        return _objective(field, relative, table(field, at))

    def follow_at(at: np.ndarray, reference: Field, reference_at: np.ndarray
                  ) -> Prediction | None:
        """The followed prediction at `at` (a creeping body past a fold), where it holds
        more of the camera's points than the evaluation `reference` at `reference_at` it
        would replace and fits them better (_followed_if_better); None otherwise."""
        if not follow:
            return None
        return _followed_if_better(exact, candidate, at, reference,
                                   objective(reference, reference_at), objective)

    for backoff in range(BACKOFFS + 1):
        try:
            prediction = exact.predict(candidate, values, near)
            break
        except SolverError as error:  # beyond the equilibria near the nominal one
            if backoff == 0 and (prediction := follow_at(values, exact.nominal_field,
                                                         neutral)) is not None:
                break
            if backoff == BACKOFFS:
                raise
            unreached.append(error)
            values = coordinates.midway(values, neutral)

    def tangent(field: Field, at: np.ndarray) -> np.ndarray:
        """(E, k) the first-order model's Jacobian at `at` in the step coordinates."""
        return shift_jacobian(candidate, exact.basis.inputs_for(field), at) \
            * coordinates.per_unit(at)

    def stepped(field: Field, at: np.ndarray, jacobian: np.ndarray, corrected: np.ndarray,
                held: np.ndarray | None = None) -> np.ndarray:
        """The Gauss-Newton trial from `at`, or _curved_step's where the step is curved;
        the parameters `held` (k,) bool, where given, kept at their values."""
        free = np.ones(len(at), dtype=bool) if held is None else ~held
        jacobian, corrected = jacobian * free, corrected * free
        rows = table(field, at)
        if rows is not None:  # in the step's coordinates, as the robot's Jacobian
            rows = TableRows(rows.left_mm, rows.jacobian * coordinates.per_unit(at) * free,
                             rows.weight)
        step = _step(field, corrected, relative, rows)
        curved = _curved_step(candidate, exact.basis.inputs_for(field), field, at, step,
                              corrected, jacobian, coordinates, relative)
        step = (step if curved is None else curved) * free
        return np.clip(coordinates.moved(at, step), candidate.lower, candidate.upper)

    solves = prediction.solves
    field = exact.field(prediction)
    jacobian = tangent(field, values)
    # a camera's first-order shift is the exact model's (diagnosis.hypotheses): the secant
    # corrects the others only
    camera_parameters = np.concatenate([np.full(len(h.free), h.kind == "sensor")
                                  for h in candidate.hypotheses])
    secant = np.eye(len(values))
    if unreached:
        # the first-order model misjudged the effect's size (near a snap-through the body
        # gives more than its tangent says): how far the exact model moved from the neutral
        # values to these, against the first-order model, scales the first step
        nominal = exact.nominal_field
        at_nominal = exact.basis.inputs_for(nominal)
        gain = path_gain(nominal, field, candidate.shift(values, at_nominal)
                         - candidate.shift(neutral, at_nominal), relative)
        secant = np.diag(np.where(camera_parameters, 1.0, gain))
    span = candidate.upper - candidate.lower

    def told(prediction: Prediction, field: Field, at: np.ndarray, corrected: np.ndarray
             ) -> tuple[np.ndarray, int]:
        """(E, k) d shift / d value at the evaluation (prediction, field) at `at` for its
        Refit, and the FE solves it took: the corrected first-order model's `corrected`, or
        at a followed evaluation the exact model's (followed_differences) in the physics'
        columns."""
        if not prediction.followed:
            return corrected / coordinates.per_unit(at), 0
        differenced, count = followed_differences(exact, candidate, field, at, coordinates,
                                                  ~camera_parameters, corrected)
        return differenced / coordinates.per_unit(at), count

    for _ in range(REFIT_STEPS):
        if stop_requested():
            break
        corrected = jacobian @ secant
        trial = stepped(field, values, jacobian, corrected)
        reported = corrected / coordinates.per_unit(values)  # d shift / d value
        # a followed prediction's first-order model is the nominal states' tangent, far from
        # the tipped body's: it tells no interval, and each step is solved
        untold = 0.0 if prediction.followed else 0.5 * half_widths(field, reported, values)
        if np.all(np.abs(trial - values) <= np.maximum(REFIT_TOLERANCE * span, untold)):
            if prediction.followed:  # on to the fold's search and the exact Jacobian
                break
            return Refit(candidate, trial, field, reported, prediction, solves, values,
                         tuple(unreached))
        # the first-order model sent a parameter to the end of its range, past where it
        # holds (creep's time constant to 0.05 s, a basin apart from the truth's): the step
        # of the others with it held is solved too, and the best kept
        holds = _holds_at_bounds(_landed_on_bounds(candidate, values, trial))
        best = objective(field, values)
        here = partial(follow_at, reference=field, reference_at=values)
        for _ in range(OVERSHOOT_HALVINGS + 1):
            moved, trial = _reached(exact, candidate, values, trial, coordinates, unreached,
                                    prediction, here)
            if moved is None:
                break
            solves += moved.solves
            trial_field = exact.field(moved)
            if (reached := objective(trial_field, trial)) < best:
                best = reached
                break
            # past the minimum along the step
            moved, trial = None, coordinates.midway(values, trial)
        for held in holds:
            other, at = _reached(exact, candidate, values,
                                 stepped(field, values, jacobian, corrected, held),
                                 coordinates, unreached, prediction, here)
            if other is None:
                continue
            solves += other.solves
            other_field = exact.field(other)
            if (reached := objective(other_field, at)) < best:
                moved, trial, trial_field, best = other, at, other_field, reached
        if moved is None:
            break
        secant = secant_update(secant, field, trial_field, jacobian,
                               coordinates.step(values, trial), relative, camera_parameters)
        values, prediction, field = trial, moved, trial_field
        jacobian = tangent(field, values)
    if prediction.followed and not stop_requested() and (found := search_along_the_fold(
            exact, candidate, values, prediction, objective, stop_requested)) is not None:
        values, prediction, field, count = found
        solves += count
        jacobian = tangent(field, values)
    reported, count = told(prediction, field, values, jacobian @ secant)
    return Refit(candidate, values, field, reported, prediction, solves + count, values,
                 tuple(unreached))


def _landed_on_bounds(candidate: Candidate, values: np.ndarray, trial: np.ndarray
                      ) -> np.ndarray:
    """(k,) bool: the parameters the step from values (k,) to trial (k,) ended at a bound of
    their range they did not start at (within a millionth, or a billionth of the range at
    a bound of 0: a step curved or taken in the logarithm ends 6e-9 from the bound it was
    clipped to, creep's relaxation 3e-17 from 0)."""
    span = candidate.upper - candidate.lower

    def at(bound: np.ndarray, point: np.ndarray) -> np.ndarray:
        return np.abs(point - bound) <= np.maximum(1e-6 * np.abs(bound), 1e-9 * span)

    return ((at(candidate.lower, trial) & ~at(candidate.lower, values))
            | (at(candidate.upper, trial) & ~at(candidate.upper, values)))


def _holds_at_bounds(bounded: np.ndarray) -> list[np.ndarray]:
    """The parameters to hold (each (k,) bool) in the steps tried beside one that ended the
    parameters `bounded` (k,) at their bounds: those, or, where it ended every one there (the
    study's creep on its second timeline: relaxation 0 and 1000 s), each alone in turn."""
    if not bounded.any() or len(bounded) == 1:
        return []
    if not bounded.all():
        return [bounded]
    return list(np.eye(len(bounded), dtype=bool))


def _curved_step(candidate: Candidate, inputs, field: Field, values: np.ndarray,
                 step: np.ndarray, corrected: np.ndarray, tangent: np.ndarray,
                 coordinates: StepCoordinates, relative: bool) -> np.ndarray | None:
    """(k,) the step (in coordinates) that fits the exact residuals at values best on the
    first-order model itself, scaled by the gain the secant gives along the Gauss-Newton
    step: the exact model at values + z is taken to move that many times as far as the
    first-order one. None when the Gauss-Newton step (its tangent `corrected` (E, k), the
    first-order tangent `tangent`) is straight enough (CURVED_STEP)."""
    origin = candidate.shift(values, inputs)
    weight = field.weight
    straight = corrected @ step
    plain = tangent @ step
    gain = float(np.sum(weight * straight * plain) / max(np.sum(weight * plain**2), 1e-30))

    def shift(z: np.ndarray) -> np.ndarray:
        moved = np.clip(coordinates.moved(values, z), candidate.lower, candidate.upper)
        return gain * (candidate.shift(moved, inputs) - origin)

    bend = shift(step) - straight
    if np.sum(weight * bend**2) <= CURVED_STEP**2 * np.sum(weight * straight**2):
        return None
    root = np.sqrt(weight)
    everything = np.ones(len(weight), dtype=bool)
    table_root = np.sqrt(table_row_weight(candidate, inputs.table, float(weight.sum())))

    def residual(z: np.ndarray) -> np.ndarray:
        left = field.mean_mm - shift(z)
        if relative:
            left = left - node_offsets(left, field, everything)
        on_table = candidate.table_left_mm(
            np.clip(coordinates.moved(values, z), candidate.lower, candidate.upper),
            inputs.table, inputs.robot_from_camera)
        if on_table is None:
            return root * left
        return np.concatenate([root * left, table_root * on_table])

    lower = coordinates.step(values, candidate.lower)
    upper = coordinates.step(values, candidate.upper)
    # a bound the values sit on is met by a zero step: keep the box open for the solver
    lower, upper = np.minimum(lower, -1e-9), np.maximum(upper, 1e-9)
    start = np.clip(np.zeros(len(values)), lower, upper)
    return least_squares(residual, start, bounds=(lower, upper), x_scale="jac",
                         diff_step=1e-4, max_nfev=60).x


@dataclass(frozen=True)
class StepCoordinates:
    """The coordinates the refit steps in: each parameter's value, or its logarithm for a
    positive one whose range spans LOG_RANGE (`logarithmic` (k,))."""

    logarithmic: np.ndarray

    @classmethod
    def of(cls, candidate: Candidate) -> StepCoordinates:
        return cls((candidate.lower > 0) & (candidate.upper >= LOG_RANGE * candidate.lower))

    def coordinates(self, values: np.ndarray) -> np.ndarray:
        return np.where(self.logarithmic, np.log(np.where(self.logarithmic, values, 1.0)),
                        values)

    def per_unit(self, values: np.ndarray) -> np.ndarray:
        """(k,) d value / d coordinate at values."""
        return np.where(self.logarithmic, values, 1.0)

    def step(self, values: np.ndarray, to: np.ndarray) -> np.ndarray:
        return self.coordinates(to) - self.coordinates(values)

    def moved(self, values: np.ndarray, step: np.ndarray) -> np.ndarray:
        """The values `step` (in coordinates) away from `values`."""
        return np.where(self.logarithmic, values * np.exp(np.where(self.logarithmic, step, 0.0)),
                        values + step)

    def midway(self, values: np.ndarray, towards: np.ndarray) -> np.ndarray:
        return self.moved(values, 0.5 * self.step(values, towards))


def _reached(exact: ExactModel, candidate: Candidate, values: np.ndarray, trial: np.ndarray,
             coordinates: StepCoordinates, unreached: list[SolverError], near: Prediction,
             follow: Callable[[np.ndarray], Prediction | None]
             ) -> tuple[Prediction | None, np.ndarray]:
    """(the prediction at trial, trial), solved near the prediction at values (predict), or
    where none is near, the followed one that `follow` takes (a creeping body past a fold);
    else the step from values halved while no solve reaches it (BACKOFFS times at most; each
    failure appended to unreached): (None, trial) when none does. From a followed
    prediction (`near`), the body is followed on, the frames in turn."""
    if near.followed:
        try:
            return exact.followed(candidate, trial), trial
        except SolverError as error:
            unreached.append(error)
            return None, trial
    for halving in range(BACKOFFS):
        try:
            return exact.predict(candidate, trial, near), trial
        except SolverError as error:  # the step left what Newton can follow: halve it
            if halving == 0 and (followed := follow(trial)) is not None:
                return followed, trial
            unreached.append(error)
            trial = coordinates.midway(values, trial)
    return None, trial


def _followed_if_better(exact: ExactModel, candidate: Candidate, values: np.ndarray,
                        reference: Field, reference_objective: float,
                        objective: Callable[[Field, np.ndarray], float]) -> Prediction | None:
    """The prediction at `values` with the frames followed in turn (ExactModel.followed),
    for a candidate that creeps, whose solve near the nominal equilibria found none: taken
    only where it holds more of the camera's points (within MAX_ASSOCIATION_MM of its
    surface) than `reference`, the evaluation it would replace, and fits them better
    (`objective` below reference_objective); None otherwise.

    A fit on the distances alone does not tell a tipped model from a standing body: on the
    study's creep_0.3, whose body stands, the model tipped at the screened start (relaxation
    0.511 at 0.79 s) is 2.70 mm RMS from the recording against the nominal model's 4.24, but
    holds 43,938 of its points against 52,191; on creep_0.5, whose body tips over, 47,278
    against 42,785 (docs/diagnosis.md, limits)."""
    if not any(h.name == "viscoelastic_creep" for h in candidate.hypotheses):
        return None
    try:
        followed = exact.followed(candidate, values)
    except SolverError:
        return None
    field = exact.field(followed)
    if (field.weight.sum() <= reference.weight.sum()
            or objective(field, values) >= reference_objective):
        return None
    return followed


def followed_differences(exact: ExactModel, candidate: Candidate, field: Field,
                         values: np.ndarray, coordinates: StepCoordinates,
                         columns: np.ndarray, jacobian: np.ndarray) -> tuple[np.ndarray, int]:
    """(E, k) `jacobian` (the Jacobian at the followed evaluation `field` at values (k,), in
    the step coordinates) with the parameters `columns` (k,) bool differenced on the exact
    model: each moved by FOLLOWED_DIFFERENCE of its range (backwards at its upper bound) and
    the frames followed again (ExactModel.followed_each). A column is the shift at the
    entries both evaluations share, zero at the others (the points their surfaces hold
    differ there); a column whose evaluation fails is kept. Also returns the FE solves."""
    span = coordinates.step(candidate.lower, candidate.upper)
    steps = []
    for i in np.flatnonzero(columns):
        step = np.zeros(len(values))
        step[i] = FOLLOWED_DIFFERENCE * span[i]
        if coordinates.moved(values, step)[i] > candidate.upper[i]:
            step[i] = -step[i]
        steps.append(step)
    predictions = exact.followed_each(candidate, [coordinates.moved(values, step)
                                                  for step in steps])
    differenced = jacobian.copy()
    solves = 0
    for step, prediction in zip(steps, predictions, strict=True):
        if isinstance(prediction, SolverError):  # its column stays the first-order model's
            continue
        solves += prediction.solves
        i = int(np.flatnonzero(step)[0])
        shift, at_field = _exact_shift(field, exact.field(prediction))
        differenced[:, i] = 0.0
        differenced[at_field, i] = shift.mean_mm / step[i]
    return differenced, solves


def secant_update(secant: np.ndarray, before: Field, after: Field, jacobian: np.ndarray,
                  step: np.ndarray, relative: bool, exact: np.ndarray | None = None
                  ) -> np.ndarray:
    """(k, k) correction S of the first-order Jacobian J (E, k) of `before`'s entries, by
    Broyden's update in the parameters: after it, J S step is the shift the exact model made
    between the two evaluations (least squares over their common entries, less the static
    offsets when relative) and S is unchanged across `step`. The parameters in `exact` (k,)
    bool, whose first-order shift is the exact one (a camera's), keep S's rows and columns
    of the identity: the shift measured between two evaluations is noisier than their
    model, and a step along a direction the robot's faces barely see (a camera moved
    sideways against its turn) had shrunk J there 14-fold, a 95% interval of [-7.7, 16.4]
    mm for a 3 mm move ([2.75, 5.47] with S kept).

    The first-order model is the nominal state's tangent: the refit's chord steps converge
    at the rate at which it is right. A south arm twice as stiff moves the Diamond far less
    than its tangent says, and the chord stopped at 1.38 after three steps on the very
    model that made the data; with the secant, 1.96 [1.75, 2.16]. The same ratio makes a
    95% interval from J too narrow (there [1.31, 1.44]): the refit reports J S."""
    common, at_before = _exact_shift(before, after)
    if len(at_before) <= len(step) or not np.any(step):
        return secant
    seen = _step(common, jacobian[at_before], relative)  # J seen ~ the shift
    updated = secant + np.outer(seen - secant @ step, step) / (step @ step)
    if exact is not None and exact.any():
        identity = np.eye(len(step))
        updated[exact], updated[:, exact] = identity[exact], identity[:, exact]
    gains = np.linalg.svd(updated, compute_uv=False)
    # a shift lost in the re-association of points (a step too small to see) says nothing
    if step @ (updated @ step) <= 0.0 or gains.min() < MIN_SECANT or gains.max() > MAX_SECANT:
        return secant
    return updated


def path_gain(before: Field, after: Field, first_order: np.ndarray, relative: bool
              ) -> float:
    """How many times the first-order shift (E,) at `before`'s entries the exact model moved
    between the two evaluations (least squares over their common entries, less the static
    offsets when relative), within [MIN_SECANT, MAX_SECANT]; 1 when nothing is shared."""
    common, at_before = _exact_shift(before, after)
    if len(at_before) < 2 or not np.any(first_order[at_before]):
        return 1.0
    gain = _step(common, first_order[at_before, None], relative)[0]
    return float(np.clip(gain, MIN_SECANT, MAX_SECANT))


def _exact_shift(before: Field, after: Field) -> tuple[Field, np.ndarray]:
    """The exact model's shift between two evaluations at their common (frame, node)
    entries (before - after, with before's weights), and those entries' indices in before."""
    nodes = int(max(before.node.max(), after.node.max())) + 1
    _, at_before, at_after = np.intersect1d(
        before.frame.astype(np.int64) * nodes + before.node,
        after.frame.astype(np.int64) * nodes + after.node, assume_unique=True,
        return_indices=True)
    return Field(before.frame[at_before], before.node[at_before],
                 before.mean_mm[at_before] - after.mean_mm[at_after],
                 before.weight[at_before]), at_before


def _step(field: Field, jacobian: np.ndarray, relative: bool,
          table: TableRows | None = None) -> np.ndarray:
    """(k,) Gauss-Newton step on the exact residuals (E,) with the Jacobian (E, k), and the
    table's rows of a camera effect."""
    judged, jacobian = judged_residuals(field, field.mean_mm, jacobian, relative)
    return _linear_step(judged, jacobian, np.ones(len(field.mean_mm), dtype=bool), table)


def _objective(field: Field, relative: bool, table: TableRows | None = None) -> float:
    """Point-weighted mean square of the residuals (less their static offsets: relative),
    with the table's rows of a camera effect."""
    r = field.mean_mm
    if relative:
        r = r - node_offsets(r, field, np.ones(len(r), dtype=bool))
    on_table = 0.0 if table is None else table.cost()
    return float((np.sum(field.weight * r**2) + on_table) / field.weight.sum())
