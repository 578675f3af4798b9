"""Diagnosis building blocks against independent references: plane geometry, known noise,
FE re-solves (the sensitivities), exact state solutions (the cable-effect interpolation) and
a problem with a known answer (held-out selection)."""

import os
import tomllib
from dataclasses import replace
from functools import partial
from types import SimpleNamespace

import numpy as np
import pytest

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.diagnosis import pipeline, refit, support
from softforce_cli.diagnosis.background import Table
from softforce_cli.diagnosis.basis import build_basis
from softforce_cli.diagnosis.fitting import Candidate, HeldOut, fit_values, held_out
from softforce_cli.diagnosis.hypotheses import Hypothesis, Inputs, interpolated_shift
from softforce_cli.diagnosis.pipeline import (
    Diagnosis,
    Final,
    Screened,
    better_rival,
    camera_seen_by_markers,
    fallback_candidates,
    leaves_static_beyond,
    load_scale_twin,
    located_candidates,
    names_the_mismatch,
    screened_rivals,
    second_keeps_the_first,
)
from softforce_cli.diagnosis.refit import ExactModel, Refit
from softforce_cli.diagnosis.report import effect_entry, fitted_robot_toml, group_reason
from softforce_cli.diagnosis.residuals import Field, point_residuals, static_mm
from softforce_cli.diagnosis.selection import (
    UNEXPLAINED_MM,
    clear_improvement,
    confidence_intervals,
    effective_sample_size,
    explained_mm,
    explains,
    indistinct,
    noise_floor_mm,
    worth_refitting,
)
from softforce_cli.diagnosis.sensitivities import ColumnSet, column_set, state_columns
from softforce_cli.diagnosis.solves import (
    SETTINGS,
    ElementBracket,
    SolveCache,
    StateSolutions,
    element_bracket,
    solve_states,
)
from softforce_cli.diagnosis.states import States, group_states, trajectory_segments
from softforce_cli.diagnosis.support import (
    contact_candidates,
    contact_cholesky,
    one_sided_contact,
    rim_heights_mm,
    support_basis,
)
from softforce_cli.errors import SolverError
from softforce_cli.fem import processes
from softforce_cli.fem.compliance import linearize
from softforce_cli.fem.statics import SolverSettings, solve_by_continuation, solve_equilibrium
from softforce_cli.model.effect_physics import fe_model_with_effects, support_plane
from softforce_cli.model.effects import FrameContext, frame_contexts, make_effect
from softforce_cli.model.robot import Robot, load_robot, with_element
from tests.conftest import SAMPLE_ROBOT
from tests.test_reduced_model import write_beam


def _box_surface(size_mm: float, cells: int) -> tuple[np.ndarray, np.ndarray]:
    """The outward-wound triangles of a cube [0, size]^3 meshed at cells x cells per face:
    positions (n, 3) and faces (k, 3), corners shared between faces."""
    grid = np.linspace(0.0, size_mm, cells + 1)
    points: dict[tuple, int] = {}
    faces = []
    for axis in range(3):
        for side in (0.0, size_mm):
            u_axis, v_axis = [a for a in range(3) if a != axis]
            for i in range(cells):
                for j in range(cells):
                    corners = []
                    for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        xyz = [0.0, 0.0, 0.0]
                        xyz[axis], xyz[u_axis], xyz[v_axis] = side, grid[i + di], grid[j + dj]
                        corners.append(points.setdefault(tuple(xyz), len(points)))
                    a, b, c, d = corners
                    outward = (u_axis, v_axis, axis) in ((0, 1, 2), (1, 2, 0), (2, 0, 1))
                    quad = [(a, b, c), (a, c, d)]
                    faces += quad if outward == (side > 0) else [t[::-1] for t in quad]
    return np.array(list(points)), np.array(faces)


def test_residuals_are_signed_distances_to_the_triangles_up_to_the_edges():
    # a box meshed coarsely: the reference is the analytic signed distance to the cube, which
    # a node's tangent plane misses near the edges (its averaged normal leans 45 degrees)
    positions, faces = _box_surface(40.0, 4)
    rng = np.random.default_rng(0)
    axis = rng.integers(0, 3, 400)
    side = rng.integers(0, 2, 400).astype(float)
    points = rng.uniform(0.0, 40.0, (400, 3))
    points[np.arange(400), axis] = side * 40.0
    offsets = rng.uniform(-3.0, 3.0, 400)
    normal = np.zeros((400, 3))
    normal[np.arange(400), axis] = 2.0 * side - 1.0
    observed = points + offsets[:, None] * normal
    inside = np.all((observed > 0.0) & (observed < 40.0), axis=1)
    outside_gap = np.maximum(np.maximum(-observed, observed - 40.0), 0.0)
    reference = np.where(inside, -np.minimum(observed, 40.0 - observed).min(axis=1),
                         np.linalg.norm(outside_gap, axis=1))
    residual, node = point_residuals(observed, positions, faces)
    np.testing.assert_allclose(residual, reference, atol=1e-4)
    # each point is its nearest corner's evidence: within half a cell's diagonal of it
    assert np.all(np.linalg.norm(positions[node] - points, axis=1) <= 10.0 * np.sqrt(2) / 2
                  + np.abs(offsets) + 1e-6)
    far = point_residuals(np.array([[20.0, 20.0, 60.0]]), positions, faces)
    assert np.isnan(far[0][0]) and far[1][0] == -1


def test_seen_points_are_measured_to_the_faces_the_camera_sees():
    # a slab 10 mm thick whose top is seen from above 7 mm lower than predicted: nearer its
    # predicted underside, but that face is turned away from the camera
    positions, faces = _box_surface(40.0, 4)
    positions = positions * np.array([1.0, 1.0, 0.25])  # 40 x 40 x 10 mm
    rng = np.random.default_rng(1)
    seen_top = np.c_[rng.uniform(5.0, 35.0, (50, 2)), np.full(50, 10.0 - 7.0)]
    residual, node = point_residuals(seen_top, positions, faces, np.array([20.0, 20.0, 500.0]))
    np.testing.assert_allclose(residual, -7.0, atol=1e-4)
    assert np.all(positions[node, 2] == 10.0)
    blind, _ = point_residuals(seen_top, positions, faces)
    np.testing.assert_allclose(blind, -3.0, atol=1e-4)  # the underside's distance
    inside = point_residuals(seen_top, positions, faces, np.array([20.0, 20.0, 5.0]))
    assert np.all(np.isnan(inside[0])) and np.all(inside[1] == -1)  # no face seen: none


def test_states_split_loading_from_unloading_and_segments_are_contiguous():
    actuation = np.array([[0, 0], [0, 0], [5, 0], [5, 0], [10, 0], [5, 0], [5, 0], [0, 0]],
                         dtype=float)
    contexts = frame_contexts(np.arange(8) * 0.5, actuation)
    states = group_states(contexts)
    # 0 (never moved), 5 loading, 10, 5 unloading, 0 unloading
    assert states.count == 5
    assert states.of_frame[2] != states.of_frame[5]
    assert states.of_frame[2] == states.of_frame[3]
    segments = trajectory_segments(states, np.zeros(8, dtype=int))
    assert np.all(np.diff(segments) >= 0) and segments.max() >= 2


def _field(mean: np.ndarray) -> Field:
    frames, nodes = mean.shape
    frame, node = np.meshgrid(np.arange(frames), np.arange(nodes), indexing="ij")
    return Field(frame.ravel(), node.ravel(), mean.ravel(), np.ones(mean.size))


def test_noise_floor_recovers_the_frame_noise():
    rng = np.random.default_rng(1)
    states = np.repeat(np.arange(10), 6)
    systematic = rng.normal(0, 2.0, (10, 300))
    mean = systematic[states] + rng.normal(0, 0.7, (60, 300))
    assert abs(noise_floor_mm(_field(mean), states) - 0.7) < 0.03



def test_noise_floor_is_not_inflated_by_drift_within_holds():
    """A body that creeps during each hold (a per-state shape times a relaxation growing
    with the hold) inflates the plain within-state scatter several times; cleared of the
    physics' shapes first, the floor is the camera's noise again."""
    rng = np.random.default_rng(5)
    states = np.repeat(np.arange(10), 3)
    hold = np.tile([0.0, 0.5, 1.0], 10)
    shapes = rng.normal(0, 1.0, (10, 4, 300))  # (S, C, n): four physics shapes per state
    drift = 2.0 * (1 - np.exp(-hold / 0.5))[:, None] * shapes[states, 1]
    mean = rng.normal(0, 2.0, (10, 300))[states] + drift + rng.normal(0, 0.3, (30, 300))
    assert noise_floor_mm(_field(mean), states) > 3 * 0.3
    assert abs(noise_floor_mm(_field(mean), states, shapes) - 0.3) < 0.02
    # and with no drift the shapes cost nothing but their degrees of freedom
    still = rng.normal(0, 2.0, (10, 300))[states] + rng.normal(0, 0.3, (30, 300))
    assert abs(noise_floor_mm(_field(still), states, shapes) - 0.3) < 0.02

def test_effective_sample_size_counts_correlated_frames_less():
    rng = np.random.default_rng(4)
    white = rng.normal(0, 1, (400, 1))
    walk = np.cumsum(rng.normal(0, 1, (400, 1)), axis=0)
    assert effective_sample_size(_field(white), 400) > 250
    assert effective_sample_size(_field(walk), 400) < 40


def test_intervals_count_a_model_error_that_differs_between_segments():
    """A linear fit whose residuals carry a model error drawn once per trajectory segment
    (8 segments of 5 frames) besides white noise: over 400 draws the true parameter lies in
    the segment-clustered 95% interval 89% of the time (a sandwich with few clusters runs a
    little short), in the residuals' own interval, inflated for correlated frames, 16%."""
    rng = np.random.default_rng(0)
    frames, nodes, segments = 40, 60, 8
    segment_of_frame = np.repeat(np.arange(segments), frames // segments)
    frame, node = np.repeat(np.arange(frames), nodes), np.tile(np.arange(nodes), frames)
    weight = np.full(frame.shape, 4.0)
    amplitude = (1.0 + np.sin(np.arange(frames) / 3.0))[frame]
    pattern = np.cos(np.arange(nodes) / 7.0)
    jacobian = (amplitude * pattern[node])[:, None]
    covered = {"scatter": 0, "clustered": 0}
    draws = 400
    for _ in range(draws):
        error = 0.3 * rng.standard_normal(segments)[segment_of_frame][frame]
        shape = pattern[node] + 0.5 * rng.standard_normal(nodes)[node]
        residual = error * shape * amplitude + 0.2 * rng.standard_normal(frame.size)
        normal = (jacobian * weight[:, None]).T @ jacobian
        value = np.linalg.solve(normal, (jacobian * weight[:, None]).T @ residual)
        field = Field(frame, node, residual - jacobian @ value, weight)
        n_eff = effective_sample_size(field, frames)
        for name, segments_given in (("scatter", None), ("clustered", segment_of_frame)):
            low, high = confidence_intervals(field, jacobian, value, n_eff, frames,
                                             segments_given)[0]
            covered[name] += low <= 0.0 <= high
    assert covered["clustered"] / draws > 0.85
    assert covered["scatter"] / draws < 0.3


def _linear_inputs(frames: int, nodes: int, pattern: np.ndarray) -> Inputs:
    field = _field(np.zeros((frames, nodes)))
    names = ColumnSet(("stiffness",))
    contexts = tuple(frame_contexts(np.arange(frames) * 0.5, np.zeros((frames, 1))))
    return Inputs(field, np.zeros(field.frame.size, dtype=int), np.zeros((field.frame.size, 3)),
                  np.zeros((field.frame.size, 3)), pattern.ravel()[None], names, contexts, (),
                  RigidTransform(np.eye(3), np.zeros(3)), np.zeros((1, nodes, 3)),
                  np.zeros((1, 0)), np.zeros((1, 0, nodes, 3)))


@pytest.mark.parametrize("relative", [False, True])
def test_held_out_selection_accepts_a_real_effect_and_rejects_noise(relative):
    """residual = (1 - 1 / truth) x pattern + noise: the stiffness hypothesis recovers truth and
    passes the held-out test; with truth = 1 (no effect) it is rejected."""
    frames, nodes = 48, 200
    segments = np.repeat(np.arange(8), 6)
    # the pattern changes across frames, so that a static baseline per node does not hold it
    pattern = np.sin(np.linspace(0, 6, nodes))[None] * np.linspace(-1.0, 3.0, frames)[:, None]
    inputs = _linear_inputs(frames, nodes, pattern)
    candidate = Candidate((Hypothesis("stiffness_scale", None, ("scale",), np.ones(1),
                                      np.array([0.5]), np.array([2.0])),))
    for seed, truth in ((2, 1.3), (3, 1.0)):
        rng = np.random.default_rng(seed)
        mean = (1.0 - 1.0 / truth) * pattern + rng.normal(0, 0.1, (frames, nodes))
        field = _field(mean)
        values = fit_values(candidate, inputs, field, relative)
        result = held_out(candidate, inputs, field, segments, values, relative)
        floor = noise_floor_mm(field, np.arange(frames) // 2)
        if truth != 1.0:
            assert values[0] == pytest.approx(truth, abs=0.01)
            assert result.rms_after_mm < 0.12 and result.rms_before_mm > 2 * result.rms_after_mm
            assert clear_improvement(result, floor)
        else:
            assert not clear_improvement(result, floor)


@pytest.fixture(scope="module")
def diamond_state():
    robot = load_robot(SAMPLE_ROBOT)
    model = robot.nominal_fe_model
    actuation = np.array([6.0, 0.0, 2.0, 0.0])
    solution = solve_equilibrium(model, robot.cable_inputs(actuation))
    lin = linearize(model, solution.positions_mm, solution.cable_tensions_n)
    columns = column_set(robot)
    return robot, actuation, solution, state_columns(robot, columns, lin,
                                                     solution.cable_tensions_n), columns


@pytest.mark.parametrize(("column", "effect", "step", "cable_change"), [
    ("gravity.scale", ("gravity", None, {"scale": 1.01}), 0.01, None),
    ("gravity.tilt_x_deg", ("gravity", None, {"tilt_x_deg": 0.5}), 0.5, None),
    ("stiffness", ("stiffness_scale", None, {"scale": 1.01}), 0.01, None),
    ("region.north", ("regional_stiffness", "north", {"scale": 1.01}), 0.01, None),
    ("blend", ("material_nonlinearity", None, {"blend": 0.05}), 0.05, None),
    ("base_compliance", ("compliant_base", None, {"stiffness_n_per_mm": 2.0}), 0.5, None),
    ("cable.north", None, 0.1, 0),
    ("cable.west", None, 0.1, 1),
])
def test_sensitivity_columns_match_re_solved_equilibria(diamond_state, column, effect, step,
                                                        cable_change):
    """K^-1 dR/dp with the cables' constraints against a finite difference of two full
    static solves (the effect library's own FE model), within 2% (the difference's own
    curvature error). compliant_base is the soft clamp's rigid give (diagnosis.sensitivities):
    its column against a base of 2 N/mm, which sinks the body 3 mm, within 8%."""
    robot, actuation, solution, columns, names = diamond_state
    model = robot.nominal_fe_model
    inputs = actuation.copy()
    if effect is not None:
        name, target, values = effect
        model = fe_model_with_effects(robot, (make_effect(name, target, **values),))
    else:
        inputs[cable_change] += step
    # the solver's tight defaults: the differences are down to 1e-3 mm
    moved = solve_equilibrium(model, robot.cable_inputs(inputs), start_mm=solution.positions_mm)
    n = robot.mesh.node_count
    expected = (moved.positions_mm[:n] - solution.positions_mm[:n]) / step
    predicted = columns[names.index(column)][:n]
    # the rigid give leaves out the clamp's own distortion: 5.5% of the 3 mm sink at 2 N/mm
    limit = 0.08 if column == "base_compliance" else 0.02
    assert np.linalg.norm(predicted - expected) < limit * np.linalg.norm(expected)


def test_an_actuation_effect_moves_each_frame_from_its_nearest_state_to_first_order():
    """interpolated_shift against the formula entry by entry: the state k nearest each
    frame's effective inputs u, x_k + J_k (u - u_k) at the entry's node, along its normal,
    less the predicted position (frames nearest their own state and others alike)."""
    rng = np.random.default_rng(7)
    states, nodes, cables, frames, count = 5, 30, 2, 12, 400
    library = rng.normal(size=(states, nodes, 3))
    columns = rng.normal(size=(states, nodes, cables, 3))
    library_inputs = rng.uniform(0.0, 8.0, size=(states, cables))
    of_frame = rng.integers(0, states, frames)
    frame, node = rng.integers(0, frames, count), rng.integers(0, nodes, count)
    state = of_frame[frame]
    normals = rng.normal(size=(count, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    field = Field(frame, node, np.zeros(count), np.ones(count))
    inputs = Inputs(field, state, normals, library[state, node], np.zeros((0, count)),
                    ColumnSet(()), (), ("north", "south"), RigidTransform(np.eye(3),
                    np.zeros(3)), library, library_inputs, columns)
    effective = library_inputs[of_frame] + rng.normal(scale=1.5, size=(frames, cables))
    nearest = np.abs(effective[:, None] - library_inputs[None]).sum(axis=2).argmin(axis=1)
    assert 0 < np.mean(nearest == of_frame) < 1  # both kinds of frame
    expected = np.empty(count)
    for e in range(count):
        k, change = nearest[frame[e]], effective[frame[e]] - library_inputs[nearest[frame[e]]]
        moved = library[k, node[e]] + change @ columns[k, node[e]]
        expected[e] = (moved - library[state[e], node[e]]) @ normals[e]
    np.testing.assert_allclose(interpolated_shift(effective, inputs), expected, atol=1e-12)


def test_refit_admission_without_the_size_rule_still_asks_for_generalisation():
    """A gain of 0.26 mm (explained) under a 0.36 mm floor with a third of the excess: not
    worth refitting by rules 1 and 3, worth it by rule 1 alone (the fallback before
    `unexplained`); a gain carried by one segment is refused either way."""
    rng = np.random.default_rng(5)
    before = 0.58**2 + rng.normal(0, 0.002, 8)
    spread = HeldOut(0.58, 0.52, before, before - 0.58**2 + 0.52**2)
    assert explained_mm(spread) == pytest.approx(np.sqrt(0.58**2 - 0.52**2), rel=1e-9)
    assert not worth_refitting(spread, 0.36)
    assert worth_refitting(spread, 0.36, size=False)
    one = np.zeros(8)
    one[3] = 8 * (0.58**2 - 0.52**2)
    single = HeldOut(0.58, 0.52, before, before - one)
    assert not worth_refitting(single, 0.36, size=False)


@pytest.mark.parametrize(("before", "after", "floor", "named"), [
    (0.564, 0.401, 0.282, False),  # hidden mass fitted as a softer north arm: 0.66 of it
    (2.139, 0.750, 0.385, True),  # a 50% softer south arm: 0.91 of it, 1.95 x the floor
    (1.046, 0.306, 0.281, True),  # 4 mm cable slack: ends within 1.1 x the floor
    (0.582, 0.336, 0.360, True),  # gravity x 1.3: below the floor
])
def test_only_an_effect_that_explains_the_mismatch_is_named(before, after, floor, named):
    """The held-out figures of docs/diagnosis.md's study (seed 1): an accepted effect that
    leaves much above the floor and removes little of the excess is a partial fit."""
    assert explains(before, after, floor) is named


def test_refit_continuation_reaches_the_direct_equilibrium(tmp_path):
    """A refit state solved by continuation (the effect's values reached in steps from the
    neutral ones, diagnosis.refit) is the equilibrium a tight direct solve from rest finds:
    a P2 beam 40% softer, 2 mm from its nominal shape."""
    robot = load_robot(write_beam(tmp_path))
    actuation = np.array([3.0, 2.0])
    inputs = robot.cable_inputs(actuation)
    nominal = solve_equilibrium(robot.fe_model, inputs)
    columns = column_set(robot)
    node_count = robot.fe_model.node_count
    solutions = StateSolutions(robot, "p2", actuation[None], nominal.positions_mm[None],
                               nominal.cable_tensions_n[None],
                               np.zeros((1, len(columns.names), node_count, 3)), None, columns)
    states = States(actuation[None], np.zeros((1, 2), np.int8), np.zeros(1),
                    np.zeros(1, np.int64))
    contexts = (FrameContext(0.0, actuation, np.zeros(2, np.int8), 0.0),)
    exact = ExactModel(solutions, states, contexts, [np.zeros((0, 3))], None)
    softer = Candidate((Hypothesis("stiffness_scale", None, ("scale",), np.array([1.0]),
                                   np.array([0.2]), np.array([5.0])),))
    values = np.array([0.6])
    continued = exact._continued(softer, values, 0)
    direct = solve_equilibrium(fe_model_with_effects(robot, softer.effects(values)), inputs)
    np.testing.assert_allclose(continued.positions_mm, direct.positions_mm, atol=1e-3)
    assert np.abs(direct.positions_mm - nominal.positions_mm).max() > 1.5


def _beam_states(tmp_path) -> tuple[Robot, ExactModel, list]:
    """A P2 beam's exact model at three actuations, one frame each (no sensitivity columns:
    every first-order start is the nominal equilibrium), and those equilibria."""
    robot = load_robot(write_beam(tmp_path))
    actuation = np.array([[1.0, 0.5], [3.0, 2.0], [2.0, 4.0]])
    nominal = [solve_equilibrium(robot.fe_model, robot.cable_inputs(a)) for a in actuation]
    columns = column_set(robot)
    node_count = robot.fe_model.node_count
    solutions = StateSolutions(
        robot, "p2", actuation, np.stack([e.positions_mm for e in nominal]),
        np.stack([e.cable_tensions_n for e in nominal]),
        np.zeros((3, len(columns.names), node_count, 3)), None, columns)
    states = States(actuation, np.zeros((3, 2), np.int8), np.zeros(3), np.arange(3))
    contexts = tuple(FrameContext(0.0, a, np.zeros(2, np.int8), 0.0) for a in actuation)
    return robot, ExactModel(solutions, states, contexts, [np.zeros((0, 3))] * 3, None), nominal


# the prediction of a Refit made up in a test (no states solved)
UNSOLVED = refit.Prediction(np.zeros((0, 0, 3)), np.zeros(0, np.int64), 0)
SOFTER_BEAM = Candidate((Hypothesis("stiffness_scale", None, ("scale",), np.array([1.0]),
                                    np.array([0.2]), np.array([5.0])),))


def test_the_refit_solves_its_states_on_the_cores_as_in_turn(tmp_path, monkeypatch):
    """The exact model's states, solved in worker processes (fem.processes), are the ones
    solved in turn in this process: a P2 beam 20% softer at three actuations; one the
    exact model cannot reach is reported with its inputs, as in turn."""
    robot, exact, nominal = _beam_states(tmp_path)
    softer = SOFTER_BEAM
    assert processes.worker_count(3) == min(3, len(os.sched_getaffinity(0)))
    on_cores = exact.predict(softer, np.array([0.8]))
    with monkeypatch.context() as patch:
        patch.setattr(processes, "worker_count", lambda tasks: 1)
        in_turn = exact.predict(softer, np.array([0.8]))
    np.testing.assert_allclose(on_cores.positions_mm, in_turn.positions_mm, atol=1e-12)
    assert on_cores.solves == in_turn.solves == 3
    corners = robot.mesh.node_count
    assert np.abs(on_cores.positions_mm[1] - nominal[1].positions_mm[:corners]).max() > 0.3

    def unreachable(model, inputs, **_):
        if inputs.values[1] > 1.0:
            raise SolverError("no")
        return solve_equilibrium(model, inputs)

    monkeypatch.setattr(refit, "solve_equilibrium", unreachable)
    with pytest.raises(refit.NoEquilibriumError, match=r"inputs \(3, 2\)"):
        exact.predict(softer, np.array([0.8]))


CREEP = Candidate((Hypothesis("viscoelastic_creep", None, ("relaxation", "time_constant_s"),
                              np.array([0.0, 1.0]), np.array([0.0, 0.05]),
                              np.array([0.9, 1000.0])),))


def test_followed_frames_are_the_states_solves_where_the_body_has_one_branch(tmp_path):
    """ExactModel.followed solves the frames in turn, each from the one before (a second
    recording from its state's nominal equilibrium); where the body has one equilibrium
    per input and hold, that is predict's solve of each (state, hold) group: a creeping P2
    beam, two holds of a pull and a second recording, to 1e-3 mm."""
    robot = load_robot(write_beam(tmp_path))
    pulls = np.array([[1.0, 0.5], [1.0, 0.5], [3.0, 2.0], [3.0, 2.0], [3.0, 2.0]])
    second = np.array([[3.0, 2.0], [2.0, 4.0], [2.0, 4.0]])
    contexts = (tuple(frame_contexts(0.5 * np.arange(len(pulls)), pulls))
                + tuple(frame_contexts(0.5 * np.arange(len(second)), second)))
    states = group_states(contexts)
    nominal = [solve_equilibrium(robot.fe_model, robot.cable_inputs(a))
               for a in states.actuation]
    columns = column_set(robot)
    solutions = StateSolutions(
        robot, "p2", states.actuation, np.stack([e.positions_mm for e in nominal]),
        np.stack([e.cable_tensions_n for e in nominal]),
        np.zeros((states.count, len(columns.names), robot.fe_model.node_count, 3)), None,
        columns)
    recordings = np.repeat([0, 1], [len(pulls), len(second)])
    exact = ExactModel(solutions, states, contexts, [np.zeros((0, 3))] * len(contexts), None,
                       recordings)
    values = np.array([0.4, 0.5])
    grouped = exact.predict(CREEP, values)
    followed = exact.followed(CREEP, values)
    assert followed.followed and not grouped.followed
    np.testing.assert_array_equal(followed.of_frame, np.arange(len(contexts)))
    np.testing.assert_allclose(followed.positions_mm,
                               grouped.positions_mm[grouped.of_frame], atol=1e-3)
    # the body creeps within the hold, so each frame of it is its own equilibrium
    assert np.abs(followed.positions_mm[4] - followed.positions_mm[2]).max() > 0.2


def test_a_followed_prediction_replaces_an_evaluation_only_holding_more_points_better(
        monkeypatch):
    """refit._followed_if_better: a creeping model followed past a fold is taken only where
    it holds more of the camera's points than the evaluation it would replace and fits them
    better (a tipped model can fit the points it holds closer than a standing one fits a
    standing body: docs/diagnosis.md); never for a candidate without creep, nor where the
    frames cannot be followed."""
    def field(points: float, residual_mm: float) -> Field:
        return Field(np.zeros(2, np.int64), np.arange(2), np.full(2, residual_mm),
                     np.full(2, points / 2))

    reference = field(1000, 2.0)

    def taken(points: float, residual_mm: float, candidate: Candidate = CREEP,
              reachable: bool = True) -> bool:
        prediction = refit.Prediction(np.zeros((1, 2, 3)), np.zeros(1, np.int64), 1,
                                      followed=True)

        def followed(*_):
            if not reachable:
                raise SolverError("no equilibrium")
            return prediction

        exact = SimpleNamespace(followed=followed,
                                field=lambda _: field(points, residual_mm))
        return refit._followed_if_better(
            exact, candidate, np.array([0.5, 0.5]), reference, refit._objective(
                reference, False), lambda f, _: refit._objective(f, False)) is prediction

    assert taken(1100, 1.0)
    assert not taken(900, 1.0)  # fits closer, but holds fewer points: the body stands
    assert not taken(1100, 2.5)  # holds more, but fits worse
    assert not taken(1100, 1.0, SOFTER_BEAM)  # no creep: the body has no history to follow
    assert not taken(1100, 1.0, reachable=False)


@pytest.mark.parametrize("relaxation", [0.4, 0.9])
def test_a_followed_evaluation_is_differenced_on_the_exact_model(relaxation):
    """refit.followed_differences: the Jacobian at a followed evaluation, in the step
    coordinates (creep's time constant in its logarithm), is the exact model's by forward
    differences, backwards at an upper bound; zero at an entry the moved evaluation does not
    hold, and a column whose evaluation fails keeps the first-order one. Against the
    derivatives of a made-up residual r = d - (c1 a^2 + c2 tau) per entry, to the
    differences' own error (first order in the step)."""
    c1, c2 = np.array([1.0, -2.0, 0.5, 3.0]), np.array([0.2, 0.1, -0.4, 1.0])
    observed = np.array([5.0, -1.0, 2.0, 0.5])

    def followed(_, values):
        return refit.Prediction(np.asarray(values, float).reshape(1, 1, 2), np.zeros(1, int), 3,
                                followed=True)

    def field(prediction):
        a, tau = prediction.positions_mm.ravel()
        entries = np.arange(4)
        if a != values[0]:  # the moved relaxation's surface lost the last entry's points
            entries = entries[:3]
        return Field(np.zeros(len(entries), int), entries,
                     (observed - c1 * a**2 - c2 * tau)[entries], np.ones(len(entries)))

    def made_up(follow):  # with ExactModel's own followed_each, on the cores
        exact = SimpleNamespace(followed=follow, field=field)
        exact.followed_each = partial(ExactModel.followed_each, exact)
        return exact

    values = np.array([relaxation, 0.6])
    exact = made_up(followed)
    coordinates = refit.StepCoordinates.of(CREEP)
    here = field(followed(CREEP, values))
    first_order = np.full((4, 2), 7.0)
    jacobian, solves = refit.followed_differences(
        exact, CREEP, here, values, coordinates, np.array([True, True]), first_order)
    assert solves == 6
    # -dr/d(coordinate): the shift of the surface; d tau / d log tau = tau
    np.testing.assert_allclose(jacobian[:3, 0], 2.0 * c1[:3] * relaxation, rtol=0.006)
    assert jacobian[3, 0] == 0.0
    np.testing.assert_allclose(jacobian[:, 1], c2 * values[1], rtol=0.03)

    def failing(candidate, moved):
        if moved[1] != values[1]:
            raise refit.NoEquilibriumError(candidate, moved, np.array([6.0, 0.0]))
        return followed(candidate, moved)

    jacobian, solves = refit.followed_differences(
        made_up(failing), CREEP, here, values, coordinates, np.array([True, True]), first_order)
    assert solves == 3
    np.testing.assert_array_equal(jacobian[:, 1], 7.0)
    np.testing.assert_allclose(jacobian[:3, 0], 2.0 * c1[:3] * relaxation, rtol=0.006)


@pytest.mark.parametrize(("followed", "standing", "kept"), [
    ((True, 0.48), (True, 2.49), "followed"),  # creep_0.5 seed 1: the body tipped over
    ((False, 3.04), (True, 2.50), "standing"),  # seed 2: the followed fit ended far off
    ((True, 2.60), (True, 2.50), "standing"),  # accepted, but generalising worse
])
def test_a_followed_fit_is_kept_only_accepted_and_generalising_better(monkeypatch, followed,
                                                                      standing, kept):
    """_Judge.final: a refit that followed the body past a fold is one of two starts; the
    standing branch's fit (refit without following) is judged beside it, and the followed
    one kept only when it is accepted and its held-out error is the lower."""
    tipped = refit.Prediction(np.zeros((1, 2, 3)), np.zeros(1, np.int64), 1, followed=True)
    calls = []

    def refitted(exact, candidate, values, relative, half_widths, stop, near, follow=True):
        calls.append(follow)
        return Refit(candidate, values, None, None, tipped if follow else UNSOLVED, 1, values)

    def judged(screened, fitted, baseline):
        accepted, after = followed if fitted.prediction.followed else standing
        return SimpleNamespace(refit=fitted, accepted=accepted,
                               heldout=SimpleNamespace(rms_after_mm=after))

    monkeypatch.setattr(pipeline, "refit", refitted)
    judge = SimpleNamespace(exact=None, n_eff=3.0, frames=20, stop_requested=lambda: False,
                            _judged=judged)
    screened = SimpleNamespace(candidate=CREEP, values=np.array([0.36, 0.19]), relative=True)
    final = pipeline._Judge.final(judge, screened)
    assert calls == [True, False]
    assert final.refit.prediction.followed is (kept == "followed")


def test_a_prediction_near_an_earlier_one_starts_from_its_equilibria(tmp_path, monkeypatch):
    """predict's `near`: the beam 40% softer solved from the equilibria of the one 45%
    softer (a refit's step) lands where the plain start lands, within Newton's tolerance,
    in 2 Newton iterations a state instead of 3; a near start that fails falls back on the
    plain one."""
    _, exact, _ = _beam_states(tmp_path)
    monkeypatch.setattr(processes, "worker_count", lambda tasks: 1)
    solutions = exact.solutions

    def started_near(inputs, start_mm: np.ndarray) -> bool:
        """Whether a solve of `inputs` starts elsewhere than at its state's equilibrium."""
        s = next(i for i, a in enumerate(solutions.actuation)
                 if np.array_equal(inputs.values, a))
        return not np.array_equal(start_mm, solutions.positions_mm[s])

    iterations: list[tuple[bool, int]] = []  # (started near, Newton iterations) per solve

    def counted(model, inputs, start_mm, **settings):
        equilibrium = solve_equilibrium(model, inputs, start_mm=start_mm, **settings)
        iterations.append((started_near(inputs, start_mm), equilibrium.iterations))
        return equilibrium

    monkeypatch.setattr(refit, "solve_equilibrium", counted)
    plain = exact.predict(SOFTER_BEAM, np.array([0.6]))
    earlier = exact.predict(SOFTER_BEAM, np.array([0.55]))
    iterations.clear()
    near = exact.predict(SOFTER_BEAM, np.array([0.6]), earlier)
    np.testing.assert_allclose(near.positions_mm, plain.positions_mm, atol=1e-3)
    np.testing.assert_allclose(near.nonlinear_mm, plain.nonlinear_mm, atol=1e-3)
    assert np.abs(plain.nonlinear_mm).max() > 0.3
    assert [near_start for near_start, _ in iterations] == [True] * 3
    iterations_near = [count for _, count in iterations]
    iterations.clear()
    exact.predict(SOFTER_BEAM, np.array([0.6]))
    assert iterations_near == [2] * 3
    assert [count for _, count in iterations] == [3] * 3

    def failing_near(model, inputs, start_mm, **settings):
        if started_near(inputs, start_mm):
            raise SolverError("no")
        return solve_equilibrium(model, inputs, start_mm=start_mm, **settings)

    monkeypatch.setattr(refit, "solve_equilibrium", failing_near)
    fallen_back = exact.predict(SOFTER_BEAM, np.array([0.6]), earlier)
    np.testing.assert_allclose(fallen_back.positions_mm, plain.positions_mm, atol=1e-3)
    assert fallen_back.solves == 3


def test_diagnosis_solves_do_not_stop_at_a_start_whose_imbalance_is_spread_thin(tmp_path):
    """The same beam 40% softer started from its nominal equilibrium: the weight left
    unbalanced is 5e-5 N per node, under any per-node force threshold, yet the equilibrium
    is 2 mm away; diagnosis's solves end on Newton's step, and get there."""
    robot = load_robot(write_beam(tmp_path))
    inputs = robot.cable_inputs(np.array([3.0, 2.0]))
    nominal = solve_equilibrium(robot.fe_model, inputs)
    softer = fe_model_with_effects(robot, (make_effect("stiffness_scale", scale=0.6),))
    exact = solve_equilibrium(softer, inputs)
    solved = solve_equilibrium(softer, inputs, start_mm=nominal.positions_mm, settings=SETTINGS)
    assert np.abs(exact.positions_mm - nominal.positions_mm).max() > 1.5
    np.testing.assert_allclose(solved.positions_mm, exact.positions_mm, atol=1e-3)



def test_continuation_reaches_what_one_newton_run_cannot(tmp_path):
    """The beam's cables at 6 and 4 mm (its tip 19 mm from rest) in five Newton iterations
    at most: not from rest in one run, but in equal steps of the inputs, to the tight
    direct solve's equilibrium."""
    robot = load_robot(write_beam(tmp_path))
    model = robot.nominal_fe_model
    target = np.array([6.0, 4.0])
    exact = solve_equilibrium(model, robot.cable_inputs(target))
    short = SolverSettings(max_iterations=5)
    with pytest.raises(SolverError):
        solve_equilibrium(model, robot.cable_inputs(target), settings=short)
    controls = tuple(spec.control for spec in robot.cable_specs)
    continued = solve_by_continuation(model, controls, target, [], short)
    np.testing.assert_allclose(continued.positions_mm, exact.positions_mm, atol=1e-6)


def test_a_state_newton_cannot_reach_from_its_start_is_continued_from_a_solved_one(tmp_path):
    """A warm start Newton's method cannot use (here every element inverted; in the study,
    a first-order start extrapolated across the actuation box, from 9, 0, 0, 0 to 0, 6, 0,
    6 mm, which left a fresh diagnosis with no answer) falls back to continuation from the
    nearest solved state: the equilibrium a direct solve finds."""
    robot = load_robot(write_beam(tmp_path))
    model = robot.nominal_fe_model
    inputs = robot.cable_inputs(np.array([6.0, 4.0]))
    exact = solve_equilibrium(model, inputs)
    inverted = model.rest_nodes_mm * np.array([-1.0, 1.0, 1.0])
    with np.errstate(all="ignore"):
        with pytest.raises(SolverError):
            solve_equilibrium(model, inputs, start_mm=inverted, settings=SETTINGS)
        positions, tensions = SolveCache(None).solve(
            model, inputs, inverted, [(np.zeros(2), model.rest_nodes_mm)])
    np.testing.assert_allclose(positions, exact.positions_mm, atol=1e-3)
    np.testing.assert_allclose(tensions, exact.cable_tensions_n, rtol=1e-3)


def test_law_blend_column_is_the_exact_change_to_the_other_law(tmp_path):
    """The blend's column is a secant, not a tangent (diagnosis.solves): at every state the
    other law's equilibrium minus the file's, as a direct solve from rest finds them. A
    P2 beam with the small-strain linear law, bent by its cables."""
    path = write_beam(tmp_path)
    path.write_text(path.read_text().replace('law = "corotational"', 'law = "linear"'))
    robot = load_robot(path)
    actuation = np.array([[0.0, 0.0], [5.0, 3.0]])
    solutions = solve_states(robot, actuation, SolveCache(None), column_set(robot))
    other = fe_model_with_effects(robot, (make_effect("material_nonlinearity", blend=1.0),))
    blend = solutions.column_set.index("blend")
    for s, inputs in enumerate(actuation):
        switched = solve_equilibrium(other, robot.cable_inputs(inputs)).positions_mm
        nominal = solve_equilibrium(robot.nominal_fe_model, robot.cable_inputs(inputs))
        expected = switched - nominal.positions_mm
        assert np.abs(expected).max() > 0.05  # the laws differ on this beam
        assert np.abs(solutions.columns[s, blend] - expected).max() < 1e-3


def _screened(name: str, target: str | None, gains: np.ndarray, relative: bool = True,
              table_misfit_mm: float | None = 0.4) -> Screened:
    hypothesis = Hypothesis(name, target, ("scale",), np.ones(1), np.zeros(1), np.full(1, 3.0))
    before = np.full(len(gains), 0.64)
    held = HeldOut(0.8, float(np.sqrt(np.mean(before - gains))), before, before - gains)
    return Screened(Candidate((hypothesis,)), np.ones(1), held, relative, np.ones((1, 2)),
                    table_misfit_mm)


@pytest.mark.parametrize("relative_after, named", [(0.585, False), (0.314, True), (None, True)])
def test_an_effect_fitted_on_absolute_residuals_must_explain_what_changes_too(relative_after,
                                                                            named):
    """Figures of the study's seed 1 (floor 0.27 mm): a plate under the arms fits as a
    lighter body on the absolute residuals, accepted, but leaves 0.585 of the 0.95 mm
    relative residual: not named; a compliant base leaves 0.314: named; a camera judged on
    the markers has no relative figure and is named when accepted."""
    screened = _screened("gravity", None, np.full(8, 0.3), relative=False)
    relative = None if relative_after is None else HeldOut(0.95, relative_after, np.ones(8),
                                                           np.ones(8))
    final = Final(screened, None, screened.heldout, screened.ci95, True, None, relative)
    assert names_the_mismatch(final, 0.95, 0.27) is named
    rejected = Final(screened, None, screened.heldout, screened.ci95, False, None, relative)
    assert not names_the_mismatch(rejected, 0.95, 0.27)


def test_the_static_residual_is_each_nodes_mean_over_the_frames():
    """(residuals.static_mm) Node 0 reads 1 and 3 mm in two frames (mean 2, one point each),
    node 1 reads -1 mm twice (three points each), node 2 is unseen: the RMS of the means 2
    and -1 weighted by their 2 and 6 points."""
    field = Field(np.array([0, 1, 0, 1]), np.array([0, 0, 1, 1]),
                  np.array([1.0, 3.0, -1.0, -1.0]), np.array([1.0, 1.0, 3.0, 3.0]))
    assert static_mm(field, 3) == pytest.approx(np.sqrt((2 * 2.0**2 + 6 * 1.0**2) / 8))


@pytest.mark.parametrize(("static_after_mm", "channel", "unreached", "beyond"), [
    (1.402, "clouds", False, True),  # a hidden mass on the north elbow as a softer north arm
    (1.402, "markers", False, False),  # a camera judged on the markers is judged there
    (0.240, "clouds", False, False),  # west slack, with the mesh's signature
    (1.075, "clouds", False, False),  # what the coarse mesh alone leaves
    # creep of relaxation 0.5, its refit stopped where the coarse model has no equilibrium
    (4.672, "clouds", True, False),
])
def test_a_named_effect_leaves_no_more_static_residual_than_the_mesh_error(
        monkeypatch, sample_robot, static_after_mm, channel, unreached, beyond):
    """(pipeline._static_limit, leaves_static_beyond) Figures of the study's cases (seed 1;
    the converged body but creep): the two quadratic elements on the coarse Diamond are
    1.288 mm RMS apart, the most static residual a named effect may leave, unless its refit
    stopped where the model has no equilibrium further on. The limit asks for the other
    element's solve only once an effect is selected, and without its equilibrium it is the
    absolute rule's UNEXPLAINED_MM."""
    solves = []

    def bracket(solutions, cache):
        solves.append(1)
        return ElementBracket(1.1379, 1.288)

    monkeypatch.setattr(pipeline, "element_bracket", bracket)
    result = Diagnosis(sample_robot, None)
    assert pipeline._static_limit(result, None, None) == UNEXPLAINED_MM and not solves
    screened = _screened("regional_stiffness", "north", np.full(8, 0.2), relative=True)
    screened = Screened(screened.candidate, screened.values, screened.heldout, True,
                        screened.ci95, None, channel)
    stopped = (SolverError("no equilibrium at inputs (6, 6, 6, 6)"),) if unreached else ()
    fitted = Refit(screened.candidate, screened.values, None, None, UNSOLVED, 18, screened.values,
                   stopped)
    final = Final(screened, fitted, screened.heldout, screened.ci95, True, None,
                  screened.heldout)
    result.selected = [final]
    limit = pipeline._static_limit(result, None, None)
    assert limit == 1.288 and len(solves) == 1
    assert leaves_static_beyond(final, static_after_mm, limit) is beyond
    assert pipeline._static_limit(result, None, None) == 1.288 and len(solves) == 1
    failed = []
    monkeypatch.setattr(pipeline, "element_bracket",
                        lambda solutions, cache: failed.append(1))  # None: no equilibrium
    unsolved = Diagnosis(sample_robot, None)
    unsolved.selected = [final]
    for _ in range(2):  # a failed bracket solve is not tried again
        assert pipeline._static_limit(unsolved, None, None) == UNEXPLAINED_MM
    assert len(failed) == 1


def test_a_second_effect_must_not_undo_the_first():
    """(pipeline.second_keeps_the_first) The converged body's south arm twice as stiff
    (relative held-out 0.806 mm, floor 0.293): the arm alone leaves 0.381 mm and is named; a
    camera move accepted with it on the absolute residuals leaves 1.529 mm of the change
    across frames and is not selected; a pair that still explains the change is; and where
    the first alone does not name the mismatch, an accepted pair is kept as before."""
    screened = _screened("regional_stiffness", "south", np.full(8, 0.3))

    def final(relative_after: float, accepted: bool = True) -> Final:
        relative = HeldOut(0.806, relative_after, np.ones(8), np.ones(8))
        return Final(screened, None, screened.heldout, screened.ci95, accepted, None, relative)

    arm = final(0.381)
    assert names_the_mismatch(arm, 0.806, 0.293)
    assert not second_keeps_the_first(arm, final(1.529), 0.806, 0.293)
    assert second_keeps_the_first(arm, final(0.35), 0.806, 0.293)
    assert not second_keeps_the_first(arm, final(0.35, accepted=False), 0.806, 0.293)
    assert second_keeps_the_first(final(0.7), final(0.75), 0.806, 0.293)


def test_fallback_refits_other_targets_that_generalise_and_agree_with_the_table():
    """Before answering `unexplained` the refit takes the next candidates on any target
    (regional_south_2: the south arm screens just behind the north arm that fits part of
    it), not those whose gain rests on one segment, nor those that move the table where the
    camera does not show it, nor those already refitted."""
    spread = np.array([0.30, 0.25, 0.28, 0.32, 0.27, 0.24, 0.31, 0.26])
    one_segment = np.full(8, -0.01)  # a large gain in one segment, small losses elsewhere
    one_segment[2] = 2.0
    north = _screened("regional_stiffness", "north", spread)
    screened = [north,
                _screened("regional_stiffness", "south", 0.9 * spread),
                _screened("gravity", None, one_segment),
                _screened("extrinsic_offset", None, 0.8 * spread, False, table_misfit_mm=5.0),
                _screened("stiffness_scale", None, 0.5 * spread),
                _screened("regional_stiffness", "west", 0.4 * spread)]
    table = Table(np.zeros((25, 3)), np.zeros(25))  # tolerance 1 mm
    assert screened[2].heldout.gain_z() < 1.0 < screened[5].heldout.gain_z()
    chosen = fallback_candidates(screened, [north], table)
    assert [s.candidate.label for s in chosen] == ["regional_stiffness[south]",
                                                   "stiffness_scale"]
    # the modes in turn: a relative candidate behind absolute ones with larger shares (of
    # another excess) is refitted (regional_south_0.5, seed 2: the south arm at 0.20 of the
    # relative excess, behind gravity, a softer body and a base at 0.35-0.43 of the absolute)
    heavier = _screened("gravity", None, spread, relative=False)
    absolute = [heavier, _screened("stiffness_scale", None, 0.95 * spread, relative=False),
                _screened("compliant_base", None, 0.9 * spread, relative=False),
                _screened("regional_stiffness", "south", 0.3 * spread)]
    chosen = fallback_candidates(absolute, [heavier], table)
    assert [(s.candidate.label, s.relative) for s in chosen] == [
        ("regional_stiffness[south]", True), ("stiffness_scale", False)]


def test_the_region_that_holds_the_residual_is_refitted_before_unexplained():
    """An east arm 0.6 as stiff, pulled by its own cable, screens at 0.81 with a gain no
    segment holds clearly (z 0.4: not a fallback), and is named 0.61 once refitted: before
    `unexplained` the best screened candidate on the region where the residual concentrates
    is refitted, if its first-order fit improves on the nominal model and agrees with the
    table; not one already refitted, and nothing where no region stands out."""
    spread = np.array([0.30, 0.25, 0.28, 0.32, 0.27, 0.24, 0.31, 0.26])
    noisy = np.array([0.20, -0.15, 0.10, -0.05, 0.12, -0.10, 0.08, 0.02])  # z < 1
    base = _screened("compliant_base", None, spread)
    east = _screened("regional_stiffness", "east", noisy)
    screened = [base, _screened("regional_stiffness", "west", 0.9 * spread),
                _screened("cable_slack", "east", -spread),  # worse than the nominal model
                _screened("cable_friction", "east", 0.5 * noisy, table_misfit_mm=5.0), east,
                _screened("cable_friction", "east", 0.3 * noisy)]
    table = Table(np.zeros((25, 3)), np.zeros(25))  # tolerance 1 mm
    assert east.heldout.gain_z() < 1.0
    assert east not in fallback_candidates(screened, [base], table)
    refitted = [Final(base, None, base.heldout, base.ci95, False, None)]
    assert located_candidates(screened, refitted, ["east"], table) == [east]
    tried = [*refitted, Final(east, None, east.heldout, east.ci95, False, None)]
    assert located_candidates(screened, tried, ["east"], table) == [screened[5]]
    assert located_candidates(screened, refitted, [], table) == []


def test_a_fold_that_leaves_out_all_the_candidates_information_steps_nowhere():
    """A north cable 4 mm slack on a timeline that pulls it past its slack in one segment
    alone: leaving that segment out, the refit's Jacobian is zero on the rest. The fold keeps
    the fitted value (its residual there is the fit's), where a singular solve had ended
    the whole diagnosis with a traceback."""
    segments = np.repeat(np.arange(4), 2)  # 8 frames, 4 segments
    frame = np.repeat(np.arange(8), 3)
    node = np.tile(np.arange(3), 8)
    sensitivity = np.where(segments[frame] == 2, 1.0, 0.0)
    residual = 0.3 * sensitivity + np.tile([0.01, -0.02, 0.01], 8)
    field = Field(frame, node, residual, np.ones(len(frame)))
    hypothesis = Hypothesis("cable_slack", "north", ("slack_mm",), np.zeros(1), np.zeros(1),
                            np.full(1, 20.0))
    no_table = SimpleNamespace(table=None, robot_from_camera=None)  # all held_out reads
    result = held_out(Candidate((hypothesis,)), no_table, field, segments, np.ones(1), False,
                      sensitivity[:, None])
    assert np.all(np.isfinite(result.after_ms))
    # the left-out segment 2 keeps the fit's residual; segment 0's fold steps on segment
    # 2's entries, which leaves segment 0 (J = 0 there) as it was
    np.testing.assert_allclose(result.after_ms[2], np.mean(residual[segments[frame] == 2] ** 2))
    np.testing.assert_allclose(result.after_ms[0], np.mean(residual[segments[frame] == 0] ** 2))


def test_fits_apart_by_a_consistent_but_negligible_difference_are_one():
    """(selection.indistinct) stiffness_1.5 seed 2: a gravity 0.674 and a body 1.483 as
    stiff (one model) left held-out errors 0.0014 mm apart, every segment agreeing: below a
    percent of either they are one fit; 5% apart with the same consistency they are not,
    nor a percent apart in the mean when the segments disagree by more is that difference
    significant."""
    rng = np.random.default_rng(3)
    before = np.full(8, 0.5)
    after = 0.16 + 0.01 * rng.random(8)

    def held(mean_squares: np.ndarray) -> HeldOut:
        return HeldOut(0.7, float(np.sqrt(mean_squares.mean())), before, mean_squares)

    base = held(after)
    slightly = held(after * 1.008 + 1e-6 * rng.random(8))  # 0.4% in RMS, consistent
    clearly = held(after * 1.1 + 1e-6 * rng.random(8))  # 5% in RMS, consistent
    assert indistinct(base, slightly) and indistinct(slightly, base)
    assert not indistinct(base, clearly)
    noisy = held(after * 1.1 + 0.04 * np.tile([1.0, -1.0], 4))  # 5%, segments disagreeing
    assert indistinct(base, noisy)


def test_rivals_of_a_named_effect_are_those_its_screening_cannot_beat():
    """Before a group is formed, the exact model judges the screened effects of other names
    that improve on the nominal model as much as the named one's screening (its
    per-segment held-out errors, selection.indistinct), agree with the table and were not
    refitted yet: the study's plate under the arms screens alongside a lighter and a
    stiffer body (support_-10 seed 1), which are then refitted; not an effect clearly
    worse, nor one that moves the table where the camera does not show it, nor one
    refitted already."""
    gains = 1.8 * np.array([0.30, 0.25, 0.28, 0.32, 0.27, 0.24, 0.31, 0.26])
    scatter = 0.02 * np.array([1, -1, 1, -1, 1, -1, 1, -1])  # per segment, no trend
    plate = _screened("support_contact", None, gains, relative=False)
    lighter = _screened("gravity", None, gains + scatter, relative=False)
    stiffer = _screened("stiffness_scale", None, gains - scatter - 0.002, relative=False)
    camera = _screened("depth_bias", None, 0.7 * gains, relative=False)  # clearly worse
    moved = _screened("extrinsic_offset", None, gains, relative=False, table_misfit_mm=5.0)
    result = Diagnosis(None, None, screened=[plate, lighter, stiffer, camera, moved])
    chosen = Final(plate, None, plate.heldout, plate.ci95, True, None)
    table = Table(np.zeros((25, 3)), np.zeros(25))
    assert all(clear_improvement(s.heldout, 0.27) for s in (plate, lighter, stiffer, camera))
    rivals = screened_rivals(result, chosen, 0.27, table)
    assert [s.candidate.label for s in rivals] == ["gravity", "stiffness_scale"]
    result.finals = [chosen, Final(lighter, None, lighter.heldout, lighter.ci95, True, None)]
    assert [s.candidate.label for s in screened_rivals(result, chosen, 0.27, table)] == [
        "stiffness_scale"]


def test_a_rival_the_exact_model_clearly_prefers_is_named_instead():
    """(pipeline.better_rival) A base of 5 N/mm screens behind a softer body (the study's
    base_5, seed 1) and, refitted as its rival, leaves clearly less held-out error: the
    base is named. Not a rival within the segments' scatter of the chosen one, one judged in
    the other mode, one not accepted, or one that fits part of the mismatch only."""
    gains = 1.8 * np.array([0.30, 0.25, 0.28, 0.32, 0.27, 0.24, 0.31, 0.26])
    scatter = 0.02 * np.array([1, -1, 1, -1, 1, -1, 1, -1])
    softer = _screened("stiffness_scale", None, gains, relative=False)
    base = _screened("compliant_base", None, gains + 0.03 + 0.2 * scatter, relative=False)
    close = _screened("gravity", None, gains + scatter + 0.003, relative=False)
    relative = _screened("cable_slack", "north", gains + 0.05)
    explains = HeldOut(0.95, 0.31, np.ones(8), np.ones(8))
    partly = HeldOut(0.95, 0.585, np.ones(8), np.ones(8))

    def final(screened: Screened, accepted: bool = True, relative_heldout=explains) -> Final:
        return Final(screened, None, screened.heldout, screened.ci95, accepted, None,
                     relative_heldout)

    chosen = final(softer)
    result = Diagnosis(None, None, finals=[chosen, final(close), final(relative)],
                       selected=[chosen])
    assert better_rival(result, 0.95, 0.27) is None
    for loser in (final(base, accepted=False), final(base, relative_heldout=partly)):
        result.finals = [chosen, loser]
        assert better_rival(result, 0.95, 0.27) is None
    winner = final(base)
    result.finals = [chosen, final(close), winner]
    assert better_rival(result, 0.95, 0.27) is winner


def test_a_stiffer_body_and_a_lighter_one_are_one_model_under_displacement_control(
        sample_robot):
    """(pipeline.load_scale_twin) Elastic forces scale with the modulus: the Diamond 1.3
    times as stiff under g is in equilibrium where it is under g / 1.3, its cables
    displacement-controlled (re-solved here on the P1 model); so a named stiffness scale is
    grouped with gravity, and an untilted gravity with a stiffness scale, not a tilted one."""
    inputs = sample_robot.cable_inputs([6.0, 0.0, 3.0, 0.0])
    stiffer = solve_equilibrium(fe_model_with_effects(
        sample_robot, (make_effect("stiffness_scale", scale=1.3),)), inputs)
    lighter = solve_equilibrium(fe_model_with_effects(
        sample_robot, (make_effect("gravity", scale=1 / 1.3),)), inputs)
    np.testing.assert_allclose(stiffer.positions_mm, lighter.positions_mm, atol=1e-4)

    def final(name: str, free: tuple[str, ...], ci95: np.ndarray) -> Final:
        hypothesis = Hypothesis(name, None, free, np.ones(len(free)), np.zeros(len(free)),
                                np.ones(len(free)))
        screened = Screened(Candidate((hypothesis,)), np.ones(len(free)), None, False, ci95,
                            None)
        return Final(screened, None, None, ci95, True, None)

    gravity = ("scale", "tilt_x_deg", "tilt_y_deg")
    assert load_scale_twin(final("stiffness_scale", ("scale",), np.ones((1, 2))),
                           sample_robot) == "gravity"
    untilted = np.array([[1.2, 1.3], [-0.5, 0.4], [-0.2, 0.3]])
    assert load_scale_twin(final("gravity", gravity, untilted), sample_robot) == (
        "stiffness_scale")
    tilted = untilted + np.array([0.0, 1.0, 0.0])[:, None]
    assert load_scale_twin(final("gravity", gravity, tilted), sample_robot) is None
    assert load_scale_twin(final("compliant_base", ("compliance_mm_per_n",),
                                 np.ones((1, 2))), sample_robot) is None


def test_the_mesh_bracket_is_how_far_the_other_quadratic_element_is(tmp_path):
    """(solves.element_bracket) The least-squares scale of the other quadratic element's
    displacement from rest onto the accurate model's, and their RMS distance over the
    surface, at the least actuated state (here the beam at rest under its weight, re-solved
    directly with both elements): P2-P0 deforms more than the slightly locking P2 (the
    cantilever of docs/locking.md: 0.998 against 0.944 of Timoshenko's deflection, a ratio
    of 1.057)."""
    robot = load_robot(write_beam(tmp_path))
    actuation = np.array([[3.0, 2.0], [0.0, 0.0]])
    solutions = solve_states(robot, actuation, SolveCache(None), column_set(robot))
    bracket = element_bracket(solutions, SolveCache(None))
    rest = robot.nominal_fe_model.rest_nodes_mm
    moved = {element: solve_equilibrium(model.nominal_fe_model, model.cable_inputs([0.0, 0.0]))
             .positions_mm - rest
             for element, model in (("p2", robot), ("p2-p0", with_element(robot, "p2-p0")))}
    expected = np.vdot(moved["p2-p0"], moved["p2"]) / np.vdot(moved["p2"], moved["p2"])
    assert bracket.load_scale == pytest.approx(expected, rel=1e-3)
    assert 1.02 < bracket.load_scale < 1.15
    apart = (moved["p2-p0"] - moved["p2"])[robot.mesh.surface_nodes]
    assert bracket.surface_rms_mm == pytest.approx(
        np.sqrt(np.mean(np.sum(apart**2, axis=1))), rel=1e-3)


def test_a_heavier_or_softer_body_within_the_mesh_error_is_not_named(monkeypatch,
                                                                    sample_robot):
    """(pipeline._within_mesh) With the other quadratic element 1.14 times as compliant on
    the robot's mesh and 1.29 mm RMS away (the coarse Diamond's, Neo-Hookean), a body read
    5% softer, or a gravity 6% stronger that fits as well as a 5.6% softer body, leaving
    1.08 mm of systematic residual (the converged body's clean recording), is the mesh's
    error and is not named; a body 30% softer, a stiffer one, a tilted gravity with nothing
    alike, and a body 5% softer with a mismatch larger than the mesh's error (2.40 mm: a
    compliant base in the converged body) are."""
    bracket = ElementBracket(1.14, 1.29)
    monkeypatch.setattr(pipeline, "element_bracket", lambda solutions, cache: bracket)
    gravity = ("scale", "tilt_x_deg", "tilt_y_deg")
    held = HeldOut(1.12, 0.43, np.full(8, 1.25), np.full(8, 0.19))

    def final(name: str, free: tuple[str, ...], values: list[float],
              ci95: list[list[float]]) -> Final:
        hypothesis = Hypothesis(name, None, free, np.ones(len(free)), np.zeros(len(free)),
                                np.ones(len(free)))
        candidate = Candidate((hypothesis,))
        screened = Screened(candidate, np.array(values), held, False, np.array(ci95), None)
        fitted = Refit(candidate, np.array(values), None, None, UNSOLVED, 0, np.array(values))
        return Final(screened, fitted, held, np.array(ci95), True, None)

    def named(*finals: Final, systematic_mm: float = 1.08) -> bool:
        result = Diagnosis(sample_robot, None)
        result.selected, result.finals = [finals[0]], list(finals)
        result.noise_floor_mm = 0.29
        result.nominal = _field(np.full((2, 5), np.hypot(systematic_mm, 0.29)))
        pipeline._within_mesh(result, None, None)
        assert result.mesh_bracket is bracket or not result.within_mesh
        return bool(result.selected)

    def softer(scale: float) -> Final:
        return final("stiffness_scale", ("scale",), [scale], [[scale - 0.01, scale + 0.01]])

    tilted = final("gravity", gravity, [1.062, -1.1, -0.3],
                   [[1.057, 1.066], [-1.5, -0.7], [-0.9, 0.2]])
    assert not named(softer(0.95))
    assert named(softer(0.7)) and named(softer(1.05))
    assert not named(tilted, softer(0.944))
    assert named(tilted)
    assert named(softer(0.95), systematic_mm=2.40)


def test_a_second_effect_within_the_mesh_error_is_not_named(monkeypatch, sample_robot):
    """(pipeline._second_within_mesh) A north cable 4 mm slack with gravity 1.062 as its
    second effect, the tilts' intervals holding 0 (the converged body at 640x480): with the
    other quadratic element 1.14 times as compliant and 1.29 mm away, the gravity is the
    mesh's and the slack alone is named, its static residual (1.08 mm) within the mesh's
    error; so is a gravity tilted 1.1 degrees that a body 0.939 as stiff fits as well (a
    west slack in the converged body at 424x240). The second stays where the slack alone
    leaves more (2.0 mm), where the gravity is tilted beyond its interval with no such
    rival, or beyond the bracket (1.2), where the slack alone leaves what changes across
    frames unexplained (0.6 mm against a 0.17 mm floor), and where it is not one of the
    library's hypotheses (the mesh's allowance a camera is fitted with)."""
    bracket = ElementBracket(1.14, 1.29)
    monkeypatch.setattr(pipeline, "element_bracket", lambda solutions, cache: bracket)
    slack = Hypothesis("cable_slack", "north", ("slack_mm",), np.zeros(1), np.zeros(1),
                       np.full(1, 10.0))
    gravity = Hypothesis("gravity", None, ("scale", "tilt_x_deg", "tilt_y_deg"),
                         np.array([1.0, 0.0, 0.0]), np.array([0.5, -20.0, -20.0]),
                         np.array([2.0, 20.0, 20.0]))
    stiffness = Hypothesis("stiffness_scale", None, ("scale",), np.ones(1), np.full(1, 0.2),
                           np.full(1, 5.0))
    held = HeldOut(1.1, 0.21, np.full(8, 1.2), np.full(8, 0.05))

    def final(hypotheses: tuple, values: list[float], ci95: list[list[float]],
              static_mm: float = 0.3, relative_after_mm: float = 0.21) -> Final:
        candidate, values = Candidate(hypotheses), np.array(values)
        fitted = Refit(candidate, values, _field(np.full((2, 5), static_mm)), None, None, 0,
                       values)
        relative = HeldOut(1.1, relative_after_mm, np.full(8, 1.2), np.full(8, 0.05))
        return Final(Screened(candidate, values, held, True, np.array(ci95), None), fitted,
                     held, np.array(ci95), True, None, relative)

    def second_named(values: list[float], ci95: list[list[float]], first_static_mm=1.08,
                     library=(slack, gravity, stiffness), rivals=(),
                     first_relative_after_mm=0.21) -> bool:
        result = Diagnosis(sample_robot, None)
        result.noise_floor_mm = 0.17
        result.selected = [final((slack,), [3.96], [[3.78, 4.14]], first_static_mm,
                                 first_relative_after_mm),
                           final((slack, gravity), [3.95, *values], [[3.74, 4.15], *ci95])]
        result.second_rivals = list(rivals)
        result.screened = [Screened(Candidate((h,)), None, held, True, None, None)
                           for h in library]
        pipeline._second_within_mesh(result, None, None)
        assert (len(result.selected) == 1) == bool(result.within_mesh)
        return len(result.selected) == 2

    held_zero = [[1.054, 1.07], [-1.6, 0.25], [-0.77, 0.07]]
    assert not second_named([1.062, -0.68, -0.35], held_zero)
    assert second_named([1.062, -0.68, -0.35], held_zero, first_static_mm=2.0)
    # the slack alone leaving 0.6 mm of what changes across frames (floor 0.17): a partial fit
    assert second_named([1.062, -0.68, -0.35], held_zero, first_relative_after_mm=0.6)
    assert second_named([1.062, -1.1, -0.35], [[1.054, 1.07], [-1.5, -0.7], [-0.77, 0.07]])
    assert second_named([1.2, -0.68, -0.35], [[1.19, 1.21], [-1.6, 0.25], [-0.77, 0.07]])
    assert second_named([1.062, -0.68, -0.35], held_zero, library=(slack,))
    tilted = [[1.054, 1.068], [-1.44, -0.71], [-0.87, 0.02]]
    softer = final((slack, stiffness), [2.09, 0.939], [[1.9, 2.28], [0.926, 0.952]])
    assert second_named([1.061, -1.07, -0.42], tilted)
    assert not second_named([1.061, -1.07, -0.42], tilted, rivals=[softer])


class _StubJudge:
    """A pipeline._Judge whose screening keeps a candidate's start; tests give its final."""

    def check_stop(self) -> None:
        pass

    def report(self, *progress) -> None:
        pass

    def screen(self, candidate, relative, start=None):
        return Screened(candidate, start, None, relative, None, None)


@pytest.mark.parametrize(("depth_pair_mm", "switched"), [(0.45, True), (0.4805, False),
                                                       (0.52, False)])
def test_the_cameras_are_compared_again_with_the_mesh_allowance(monkeypatch, sample_robot,
                                                                 depth_pair_mm, switched):
    """(pipeline._camera_with_the_mesh) The converged body's 1% depth scale, first named a
    camera moved along its axis (absolute held-out 0.55 mm, the depth scale alone 0.72):
    each camera effect fitted again with a stiffness scale bounded to the mesh's bracket
    [1 / 1.14, 1], the depth scale leaves 0.45 mm and the move 0.48, so the depth scale is
    the first effect. Pairs the data cannot tell apart (0.4805 against 0.48), or the move's
    pair the better, leave the move named. The depth scale's pair is then its second effect
    (the first-order screening of a second effect had found none for it)."""
    monkeypatch.setattr(pipeline, "element_bracket",
                        lambda solutions, cache: ElementBracket(1.14, 1.29))
    chosen = []

    def select_first(result, judge, first):  # no second effect found
        chosen.append(first)
        result.selected = [first]

    monkeypatch.setattr(pipeline, "_select_first", select_first)
    spread = np.linspace(-0.01, 0.01, 8)

    def held(rms_mm: float) -> HeldOut:
        return HeldOut(4.63, rms_mm, np.full(8, 4.63**2), rms_mm**2 + spread)

    pair_mm = {"extrinsic_offset": 0.48, "depth_bias": depth_pair_mm}
    alone_mm = {"extrinsic_offset": 0.55, "depth_bias": 0.72}
    allowances = []

    class Judge(_StubJudge):
        table, floor = None, 0.38

        def final(self, screened, near=None):
            hypotheses = screened.candidate.hypotheses
            name = hypotheses[0].name
            if len(hypotheses) > 1:
                allowances.append(hypotheses[1])
            figure = (pair_mm if len(hypotheses) > 1 else alone_mm)[name]
            fitted = Refit(screened.candidate, screened.values, None, None, UNSOLVED, 0,
                           screened.values)
            return Final(screened, fitted, held(figure), None, True, None)

    gains = np.full(8, 0.3)
    move, scale = (_screened(name, None, gains, relative=False)
                   for name in ("extrinsic_offset", "depth_bias"))
    result = Diagnosis(sample_robot, None)
    result.screened = [move, scale, _screened("gravity", None, gains)]
    result.selected = result.finals = [Judge().final(move)]
    pipeline._camera_with_the_mesh(result, Judge(), None, None)
    assert [h.name for h in allowances] == ["stiffness_scale"] * 2
    np.testing.assert_allclose([allowances[0].lower[0], allowances[0].upper[0]], [1 / 1.14, 1])
    assert result.camera_with_mesh_mm == pytest.approx(pair_mm)
    assert [f.candidate.label for f in chosen] == (["depth_bias"] if switched else [])
    # the allowance that decided the camera is its second effect, none other being found
    assert [f.candidate.label for f in result.selected] == (
        ["depth_bias", "depth_bias + stiffness_scale"] if switched else ["extrinsic_offset"])


@pytest.mark.parametrize(("name", "relative", "pair_mm", "reported"), [
    ("compliant_base", False, 0.316, True),  # the base_5 case against the 6.5 mm truth
    ("material_nonlinearity", False, 0.3292, True),  # within 1% of the effect alone
    ("compliant_base", False, 0.35, False),  # the pair's refit stopped short
    ("support_contact", False, 0.316, None),  # a plate: never refitted with it
    ("gravity", False, 0.316, None),  # a load scale: the allowance is one
    ("material_nonlinearity", True, 0.316, None),  # relative: the mesh's static error
])
def test_a_static_effect_is_reported_with_the_mesh_allowance(monkeypatch, sample_robot, name,
                                                             relative, pair_mm, reported):
    """(pipeline._with_the_mesh) A selected compliant base or law blend on absolute residuals
    is refitted with a stiffness scale bounded to the mesh's bracket [1 / 1.14, 1], and that
    fit is kept for its values when accepted and leaving no more held-out error than the
    effect alone (0.327 mm here) within 1%; a plate, a load scale and a relative fit are not
    refitted. The report then gives the pair's values, its allowance and the fit alone, and
    robot.fitted.toml carries the allowance as a stiffness scale, loadable."""
    monkeypatch.setattr(pipeline, "element_bracket",
                        lambda solutions, cache: ElementBracket(1.14, 1.29))
    spread = np.linspace(-0.01, 0.01, 8)
    refitted = []

    def held(rms_mm: float) -> HeldOut:
        return HeldOut(1.64, rms_mm, np.full(8, 1.64**2), rms_mm**2 + spread)

    class Judge(_StubJudge):
        def final(self, screened, near=None):
            refitted.append(screened.candidate)
            values = np.array([0.18, 0.98])
            fitted = Refit(screened.candidate, values, None, None, UNSOLVED, 7, values)
            return Final(screened, fitted, held(pair_mm), np.array([[0.16, 0.2], [0.97, 0.99]]),
                         True, None)

    hypothesis = Hypothesis(name, None, ("compliance_mm_per_n" if name == "compliant_base"
                                         else "blend" if name == "material_nonlinearity"
                                         else "scale",),
                            np.ones(1), np.zeros(1), np.full(1, 3.0))
    candidate = Candidate((hypothesis,))
    alone = Final(Screened(candidate, np.full(1, 0.246), held(0.327), relative,
                           np.array([[0.24, 0.25]]), None),
                  Refit(candidate, np.full(1, 0.246), None, None, UNSOLVED, 0, np.full(1, 0.246)),
                  held(0.327), np.array([[0.24, 0.25]]), True, None)
    result = Diagnosis(sample_robot, None)
    result.selected = result.finals = [alone]
    pipeline._with_the_mesh(result, Judge(), None, None)
    if reported is None:
        assert not refitted and not result.with_mesh
        return
    (pair,) = refitted
    assert [h.name for h in pair.hypotheses] == [name, "stiffness_scale"]
    np.testing.assert_allclose([pair.hypotheses[1].lower[0], pair.hypotheses[1].upper[0]],
                               [1 / 1.14, 1])
    assert (alone in result.with_mesh) is reported
    if not reported or name != "compliant_base":
        return
    entry = effect_entry(alone, 0.29, True, result.with_mesh[alone])
    assert entry["parameters"]["stiffness_n_per_mm"]["value"] == pytest.approx(1 / 0.18,
                                                                               rel=1e-5)
    assert entry["heldout_rms_after_mm"] == pytest.approx(0.316)
    allowance = entry["evidence"]["mesh_allowance"]
    assert allowance["stiffness_scale"]["value"] == pytest.approx(0.98)
    assert allowance["alone"]["parameters"]["stiffness_n_per_mm"]["value"] == pytest.approx(
        1 / 0.246, rel=1e-5)
    assert allowance["alone"]["heldout_rms_after_mm"] == pytest.approx(0.327)
    assert entry["evidence"]["fe_solves"] == 0 + 7  # the fit alone's and the pair's
    text = fitted_robot_toml(SAMPLE_ROBOT, result, SAMPLE_ROBOT.parent)
    effects = {e["name"]: e for e in tomllib.loads(text)["effect"]}
    assert effects["compliant_base"]["stiffness_n_per_mm"] == pytest.approx(1 / 0.18)
    assert effects["stiffness_scale"]["scale"] == pytest.approx(0.98)
    assert "this mesh's own stiffness error" in text


def test_a_group_says_why_its_effects_are_one_signature():
    """The summary's group line gives the known reason for a known pair, the trajectory for
    two targets of one effect, and the statistical reason otherwise."""
    assert "g / E" in group_reason(["gravity", "stiffness_scale"])
    assert "regions or cables together" in group_reason(
        ["regional_stiffness[south]", "regional_stiffness[north]"])
    assert "2 standard errors" in group_reason(["cable_slack[north]", "gravity"])


def test_a_camera_seen_by_the_markers_must_pass_their_rules_and_agree_with_table_and_clouds():
    """Judged on the markers (diagnosis.markers): the best camera effect that passes rules
    1-3 against the markers' floor, puts the table where it is seen and leaves the clouds
    explained; none when the clouds object."""
    spread = np.array([0.30, 0.25, 0.28, 0.32, 0.27, 0.24, 0.31, 0.26])
    table = Table(np.zeros((25, 3)), np.zeros(25))  # tolerance 1 mm
    tilted = _screened("extrinsic_offset", None, 1.2 * spread, False, table_misfit_mm=3.0)
    small = _screened("depth_bias", None, 0.05 * spread, False)  # explains too little
    turned = _screened("extrinsic_offset", None, spread, False)
    floor = 0.5
    assert clear_improvement(tilted.heldout, floor) and not clear_improvement(small.heldout,
                                                                                floor)
    assert camera_seen_by_markers([tilted, small, turned], floor, table,
                                  lambda s: True) is turned
    assert camera_seen_by_markers([tilted, small, turned], floor, table,
                                  lambda s: s is not turned) is None


def test_a_refit_past_what_the_model_can_solve_pulls_back_and_says_where():
    """An exact model that has no equilibrium below 0.75 of its stiffness at one state (the
    coarse Diamond snaps through there under the north cable's 9 mm): the refit of a body
    0.6 as stiff pulls back to where it can solve, and the summary says where it stopped."""
    from types import SimpleNamespace

    from softforce_cli.diagnosis.refit import NoEquilibriumError, Prediction, refit
    from softforce_cli.diagnosis.report import unreached_line

    frames, nodes = 8, 30
    pattern = np.sin(np.linspace(0, 3, nodes))[None] * np.linspace(1.0, 2.0, frames)[:, None]
    inputs = _linear_inputs(frames, nodes, pattern)
    softer = Candidate((Hypothesis("stiffness_scale", None, ("scale",), np.ones(1),
                                   np.array([0.5]), np.array([2.0])),))

    class Snapping:
        basis = SimpleNamespace(inputs_for=lambda field: inputs, table=None,
                                robot_from_camera=inputs.robot_from_camera)

        def predict(self, candidate, values, near=None):
            if values[0] < 0.75:
                raise NoEquilibriumError(candidate, values, np.array([9.0, 0.0]))
            self.values = values
            return Prediction(np.zeros((1, nodes, 3)), np.zeros(frames, dtype=int), 1)

        def field(self, prediction):
            return _field((1.0 / self.values[0] - 1.0 / 0.6) * pattern)

        @property
        def nominal_field(self):
            return _field((1.0 - 1.0 / 0.6) * pattern)

    fitted = refit(Snapping(), softer, np.array([0.6]), False, lambda f, j, v: np.zeros(1))
    assert 0.75 <= fitted.values[0] <= 0.8
    assert fitted.unreached and all(isinstance(e, NoEquilibriumError)
                                    for e in fitted.unreached)
    line = unreached_line(SimpleNamespace(candidate=softer, refit=fitted, values=fitted.values))
    assert "no equilibrium at inputs (9, 0) with stiffness_scale at (0.6)" in line
    assert f"stopped at scale = {fitted.values[0]:.4g}" in line


def test_a_refit_pulled_back_learns_from_the_exact_shift_to_where_it_could_solve():
    """A body three times as mobile as its tangent near a snap-through (no equilibrium below
    0.77 of its stiffness), 0.8 as stiff: the screening overshoots to 0.65. Pulled back
    halfway (0.825), the exact shift from the nominal model there tells the refit how far
    the body really moves, and its first step lands on the truth; uncorrected, that step
    went past the snap-through again (the study's creep: from a relaxation of 0.26 to 0.79,
    and the refit ended there)."""
    from types import SimpleNamespace

    from softforce_cli.diagnosis.refit import NoEquilibriumError, Prediction, refit

    frames, nodes, truth, mobility = 8, 30, 0.8, 3.0
    pattern = np.sin(np.linspace(0, 3, nodes))[None] * np.linspace(1.0, 2.0, frames)[:, None]
    inputs = _linear_inputs(frames, nodes, pattern)
    softer = Candidate((Hypothesis("stiffness_scale", None, ("scale",), np.ones(1),
                                   np.array([0.5]), np.array([2.0])),))

    def moved(scale: float) -> float:
        return mobility * (1.0 - 1.0 / scale)

    class Snapping:
        basis = SimpleNamespace(inputs_for=lambda field: inputs, table=None,
                                robot_from_camera=inputs.robot_from_camera)
        nominal_field = _field((moved(truth) - moved(1.0)) * pattern)

        def predict(self, candidate, values, near=None):
            if values[0] < 0.77:
                raise NoEquilibriumError(candidate, values, np.array([6.0, 0.0]))
            self.values = values
            return Prediction(np.zeros((1, nodes, 3)), np.zeros(frames, dtype=int), 1)

        def field(self, prediction):
            return _field((moved(truth) - moved(self.values[0])) * pattern)

    fitted = refit(Snapping(), softer, np.array([0.65]), False, lambda f, j, v: np.zeros(1))
    assert fitted.values[0] == pytest.approx(truth, rel=1e-3)
    assert len(fitted.unreached) == 1  # the screened start only


def test_a_step_to_a_bound_is_tried_with_that_parameter_held():
    """Creep's first-order model, whose tangent at a relaxation of 0.32 over 0.79 s sends the
    time constant to its bound (0.05 s), where every hold of 0.5 s or more is fully relaxed
    and the time constant no longer moves anything: the refit ended there (0.089 at 0.05 s
    for 0.2 at 0.5 s; the study's creep_0.2 ended at 0.123 at 0.05 s, its exact objective
    0.41 against 0.096 at the truth). The step with the time constant held is solved too and
    kept, being better, and the refit goes on from the interior."""
    from types import SimpleNamespace

    from softforce_cli.diagnosis.refit import Prediction, refit

    frames, nodes = 24, 30
    levels = np.repeat([0.0, 3.0, 6.0, 9.0, 6.0, 3.0, 0.0, 6.0], 3)
    pattern = np.sin(np.linspace(0, 3, nodes))[None] * (1.0 + levels[:, None])
    contexts = tuple(frame_contexts(np.arange(frames) * 0.5, levels[:, None]))
    holds = np.array([c.hold_s for c in contexts])  # 0, 0.5 and 1 s in each input
    inputs = replace(_linear_inputs(frames, nodes, pattern), contexts=contexts)
    creep = Candidate((Hypothesis("viscoelastic_creep", None, ("relaxation", "time_constant_s"),
                                  np.array([0.0, 1.0]), np.array([0.0, 0.05]),
                                  np.array([0.9, 1000.0])),))
    truth = (0.2, 0.5)

    def moved(relaxation: float, time_constant_s: float) -> np.ndarray:
        """The body's motion: 1 / modulus - 1, twice as far as that near a modulus of 0.5."""
        modulus = 1.0 - relaxation * (1.0 - np.exp(-holds / time_constant_s))
        return -((1.0 / modulus - 1.0) * 0.5 / (modulus - 0.5))[:, None] * pattern

    class Exact:
        basis = SimpleNamespace(inputs_for=lambda field: inputs, table=None,
                                robot_from_camera=inputs.robot_from_camera)
        nominal_field = _field(moved(*truth) - moved(0.0, 1.0))

        def predict(self, candidate, values, near=None):
            self.values = values
            return Prediction(np.zeros((1, nodes, 3)), np.zeros(frames, dtype=int), 1)

        def field(self, prediction):
            return _field(moved(*truth) - moved(*self.values))

    fitted = refit(Exact(), creep, np.array([0.3166, 0.79]), False,
                   lambda f, j, v: np.zeros(2))
    assert fitted.values[0] == pytest.approx(truth[0], abs=0.05)
    assert 0.3 < fitted.values[1] < 1.0  # not at the bound: 0.67 s


def test_the_steps_tried_beside_one_that_ends_at_bounds():
    """Which parameters a step left at their bounds (to rounding: exp(log(0.05)) and a
    relaxation 3e-17 above 0), and which are held in the steps tried beside it: those, or
    each alone when the step sent every one to a bound (creep on the second timeline went
    from (0.137, 0.23 s) to (0, 1000 s))."""
    from softforce_cli.diagnosis.refit import _holds_at_bounds, _landed_on_bounds

    creep = Candidate((Hypothesis("viscoelastic_creep", None, ("relaxation", "time_constant_s"),
                                  np.array([0.0, 1.0]), np.array([0.0, 0.05]),
                                  np.array([0.9, 1000.0])),))
    both = _landed_on_bounds(creep, np.array([0.137, 0.23]), np.array([2.8e-17, 1000 - 6e-12]))
    one = _landed_on_bounds(creep, np.array([0.32, 0.79]), np.array([0.12, 0.05 + 3e-10]))
    stays = _landed_on_bounds(creep, np.array([0.0, 0.79]), np.array([0.0, 0.5]))
    assert both.tolist() == [True, True] and one.tolist() == [False, True]
    assert stays.tolist() == [False, False]
    assert [h.tolist() for h in _holds_at_bounds(one)] == [[False, True]]
    assert [h.tolist() for h in _holds_at_bounds(both)] == [[True, False], [False, True]]
    assert _holds_at_bounds(stays) == [] and _holds_at_bounds(np.array([True])) == []


def _saturating(p: float) -> float:
    """A Diamond arm twice as stiff: the exact shift a fifth to a tenth of the tangent's."""
    return 0.25 * p / (1.0 + 2.0 * p)


def _three_times(p: float) -> float:
    """An exact model three times as mobile as its tangent: the chord step overshoots."""
    return 3.0 * p


@pytest.mark.parametrize("exact_shift", [_saturating, _three_times])
def test_the_refit_learns_how_far_the_exact_model_moves(exact_shift):
    """An exact model that moves a fifth to a tenth as far as the first-order one says (the
    nominal tangent overstates a stiffening's effect): the chord method alone crept from 1.18
    to 1.38 in three steps on the very model that made the data; with the secant update the
    refit reaches the truth, and the Jacobian it reports (from which the 95% interval comes)
    has the exact model's slope there. An exact model three times as mobile makes the first
    step overshoot and raise the residual: its midpoint is taken, and the refit goes on."""
    from types import SimpleNamespace

    from softforce_cli.diagnosis.refit import Prediction, refit

    frames, nodes, truth = 8, 30, 2.0
    pattern = np.sin(np.linspace(0, 3, nodes))[None] * np.linspace(1.0, 2.0, frames)[:, None]
    inputs = _linear_inputs(frames, nodes, pattern)
    stiffer = Candidate((Hypothesis("stiffness_scale", None, ("scale",), np.ones(1),
                                    np.array([0.5]), np.array([4.0])),))

    def moved(scale: float) -> float:  # the exact shift per unit of pattern
        return exact_shift(1.0 - 1.0 / scale)

    class Exact:
        basis = SimpleNamespace(inputs_for=lambda field: inputs, table=None,
                                robot_from_camera=inputs.robot_from_camera)

        def predict(self, candidate, values, near=None):
            self.values = values
            return Prediction(np.zeros((1, nodes, 3)), np.zeros(frames, dtype=int), 1)

        def field(self, prediction):
            return _field((moved(truth) - moved(self.values[0])) * pattern)

    fitted = refit(Exact(), stiffer, np.array([1.18]), False, lambda f, j, v: np.zeros(1))
    assert abs(fitted.values[0] - truth) < 0.02 * truth
    step = 1e-4
    slope = (moved(truth + step) - moved(truth - step)) / (2 * step)
    reported = np.linalg.lstsq(pattern.reshape(-1, 1), fitted.jacobian[:, 0], rcond=None)[0][0]
    assert abs(reported / slope - 1.0) < 0.15


def _camera_seeing(depth_mm: float, table_depth_mm: float, robot_shift_mm: float,
                   frames: int = 6, nodes: int = 40):
    """A camera at the robot frame's origin looking along +z (the calibration the identity):
    the robot's faces at `depth_mm` facing it, seen `robot_shift_mm` further than the model
    puts them in every frame, over a table at `table_depth_mm` seen where it is expected.
    Returns (inputs, field, table, depth_bias candidate)."""
    field = _field(np.full((frames, nodes), robot_shift_mm))
    count = field.frame.size
    table = Table(np.column_stack([np.linspace(-50, 50, 25), np.zeros(25),
                                   np.full(25, table_depth_mm)]), np.zeros(25))
    positions = np.column_stack([np.zeros((count, 2)), np.full(count, depth_mm)])
    normals = np.tile([0.0, 0.0, 1.0], (count, 1))
    contexts = tuple(frame_contexts(np.arange(frames) * 0.5, np.zeros((frames, 1))))
    inputs = Inputs(field, np.zeros(count, dtype=int), normals, positions, np.zeros((1, count)),
                    ColumnSet(("stiffness",)), contexts, (),
                    RigidTransform(np.eye(3), np.zeros(3)), np.zeros((1, nodes, 3)),
                    np.zeros((1, 0)), np.zeros((1, 0, nodes, 3)), table)
    scale = Candidate((Hypothesis("depth_bias", None, ("scale",), np.zeros(1),
                                  np.array([-0.1]), np.array([0.1])),))
    return inputs, field, table, scale


def test_the_refit_fits_a_camera_to_the_table_as_its_screening_does():
    """The robot seen 4.7 mm further than the model (a depth scale of 1% at 470 mm, or the
    model's own error), the table at 617 mm where it is expected: the depth scale that fits
    both, the table counting as much as the robot, is 470 x 4.7 / (470^2 + 617^2) = 0.00367
    (worked by hand). The screening and the exact refit both reach it; before the refit
    counted the table, it went to the robot's 0.01 and left the table 6.2 mm off."""
    from types import SimpleNamespace

    from softforce_cli.diagnosis.refit import Prediction, refit

    inputs, field, table, scale = _camera_seeing(470.0, 617.0, 4.7)
    expected = 470.0 * 4.7 / (470.0**2 + 617.0**2)
    assert fit_values(scale, inputs, field, False)[0] == pytest.approx(expected, rel=1e-3)

    class Exact:
        basis = SimpleNamespace(inputs_for=lambda f: inputs, table=table,
                                robot_from_camera=inputs.robot_from_camera)

        def predict(self, candidate, values, near=None):
            self.values = values
            return Prediction(np.zeros((1, 40, 3)), np.zeros(6, dtype=int), 0)

        def field(self, prediction):  # a camera's model is exact
            return Field(field.frame, field.node,
                         field.mean_mm - scale.shift(self.values, inputs), field.weight)

    fitted = refit(Exact(), scale, np.array([0.01]), False, lambda f, j, v: np.zeros(1))
    assert fitted.values[0] == pytest.approx(expected, rel=1e-3)
    # its held-out folds refit it with the table too: each lands on the same value
    folds = held_out(scale, inputs, fitted.field, np.repeat(np.arange(3), 2),
                     fitted.evaluated, False, jacobian=fitted.jacobian)
    robot_left = 4.7 - 470.0 * expected
    assert folds.rms_after_mm == pytest.approx(robot_left, rel=1e-3)


def test_the_secant_leaves_a_cameras_exact_model_alone():
    """Broyden's update corrects the first-order Jacobian where it is not the exact model:
    for a pair of a physics effect and a camera, only the physics' row and column move."""
    from softforce_cli.diagnosis.refit import secant_update

    frames, nodes = 4, 30
    pattern = np.sin(np.linspace(0, 3, nodes))[None] * np.linspace(1.0, 2.0, frames)[:, None]
    other = np.cos(np.linspace(0, 5, nodes))[None] * np.ones((frames, 1))
    jacobian = np.column_stack([pattern.ravel(), other.ravel()])
    step = np.array([0.1, 0.2])
    before = _field(np.zeros((frames, nodes)))
    # the exact model moved the first parameter's half as far as its tangent says
    after = _field(-(0.5 * 0.1 * pattern + 0.2 * other))
    free = secant_update(np.eye(2), before, after, jacobian, step, False)
    kept = secant_update(np.eye(2), before, after, jacobian, step, False,
                         np.array([False, True]))
    assert not np.allclose(free[:, 1], [0.0, 1.0])  # Broyden spreads the change over both
    np.testing.assert_allclose(kept[1], [0.0, 1.0])
    np.testing.assert_allclose(kept[:, 1], [0.0, 1.0])
    assert kept[0, 0] < 1.0


def test_one_sided_contact_is_the_quadratic_programs_answer():
    """The plate's contact forces (nnls on the compliance's Cholesky factor) against the same
    complementarity problem as a quadratic program solved by cvxpy with Clarabel, and its
    conditions: no penetration, no pull, no force where a node is off the plate."""
    cvxpy = pytest.importorskip("cvxpy")
    rng = np.random.default_rng(3)
    shape = rng.normal(size=(12, 12))
    compliance = shape @ shape.T / 12 + 0.2 * np.eye(12)
    gap = rng.normal(size=12)
    forces = one_sided_contact(contact_cholesky(compliance), gap)
    lam = cvxpy.Variable(12)
    cvxpy.Problem(cvxpy.Minimize(0.5 * cvxpy.quad_form(lam, compliance) + gap @ lam),
                  [lam >= 0]).solve(solver=cvxpy.CLARABEL)
    np.testing.assert_allclose(forces, lam.value, atol=1e-6)
    after = gap + compliance @ forces
    assert forces.min() >= 0.0 and after.min() > -1e-9
    assert np.abs(forces * after).max() < 1e-9
    assert (forces > 0).sum() not in (0, 12)  # some nodes touch, some do not


def _propped_mm(robot, actuation: np.ndarray, solution, height_mm: float) -> np.ndarray:
    """(n, 3) mm: how far the exact plate at height_mm moves the mesh nodes of an
    equilibrium (the effect library's penalty plane, fem.supports)."""
    plate = fe_model_with_effects(robot, (make_effect("support_contact",
                                                      table_z_mm=height_mm),))
    propped = solve_equilibrium(plate, robot.cable_inputs(actuation),
                                start_mm=solution.positions_mm)
    n = robot.mesh.node_count
    return propped.positions_mm[:n] - solution.positions_mm[:n]


@pytest.mark.parametrize("height_mm", [-10.0, -7.0, -3.0])
def test_the_screened_plate_matches_the_plate_solved(diamond_state, height_mm):
    """A plate under the Diamond's arms at three heights (0.2-0.7 mm RMS of the body
    propped): the screening's contact, solved on one linearisation (diagnosis.support),
    against the exact equilibrium with the penalty plane (fem.supports), within 5% (at
    -5.5 mm the body's rotation under the plate brings two more nodes onto it than the
    linearisation does: 12%, which the refit's exact solves take up)."""
    robot, actuation, solution, columns, names = diamond_state
    solutions = StateSolutions(robot, robot.element_name, actuation[None],
                               solution.positions_mm[None], solution.cable_tensions_n[None],
                               columns[None], None, names)
    support = support_basis(solutions, SolveCache(None))
    assert support.lower_mm == solution.positions_mm[support.nodes, 2].min()
    predicted = support.motion_mm(height_mm)[0]
    exact = _propped_mm(robot, actuation, solution, height_mm)
    assert np.sqrt(np.mean(np.sum(exact**2, axis=1))) > 0.2
    assert np.linalg.norm(predicted - exact) < 0.05 * np.linalg.norm(exact)
    assert not support.motion_mm(support.lower_mm).any()  # below every node: no contact


def test_plate_candidates_are_the_free_nodes_that_sink_without_facing_up(monkeypatch):
    """The nodes a plate may touch (diagnosis.support): free surface nodes, not facing up,
    that sink 0.5 mm or more, within the heights searched (from the lowest any reaches up
    40 mm); capped to the lowest reaching."""
    robot = load_robot(SAMPLE_ROBOT)
    rest = robot.mesh.nodes_mm
    sunk = rest.copy()
    sunk[:, 2] -= np.where(rest[:, 0] > 0.0, 1.0, 0.2)  # only the +x half sinks enough
    nodes, lower, upper = contact_candidates(robot, sunk[None])
    assert lower == sunk[nodes, 2].min() and lower < upper <= lower + support.SUPPORT_REACH_MM
    assert len(nodes) > 10
    assert np.all(rest[nodes, 0] > 0.0) and np.all(robot.mesh.vertex_normals[nodes, 2] < 0.5)
    assert not np.isin(nodes, robot.fixed_nodes).any()
    assert np.all(sunk[nodes, 2] < lower + support.SUPPORT_REACH_MM)
    monkeypatch.setattr(support, "MAX_CONTACT_NODES", 10)
    lowest = contact_candidates(robot, sunk[None])[0]
    assert len(lowest) == 10 and sunk[lowest, 2].max() <= sunk[np.setdiff1d(nodes, lowest), 2].min()


def test_a_plates_height_is_resolved_to_the_rest_heights_around_it():
    """The rest heights the summary gives around a fitted plate (support.rim_heights_mm) are
    where the penalty plane (model.effect_physics.support_plane) changes the surface nodes
    it props: the same nodes from the one below up to the one above, fewer past either."""
    robot = load_robot(SAMPLE_ROBOT)
    model = robot.nominal_fe_model
    mesh = robot.mesh
    facing = np.setdiff1d(mesh.surface_nodes, robot.fixed_nodes)
    facing = facing[mesh.vertex_normals[facing, 2] < support.UPWARD_NORMAL]

    def propped(height_mm: float) -> np.ndarray:
        plane = support_plane(model, robot.fixed_nodes, height_mm, 0.18)
        return np.intersect1d(plane.nodes, facing)

    for fitted in (-7.46, -3.5932625547376214):  # the study's plates (fourteenth run)
        below, above = rim_heights_mm(robot, fitted)
        assert below <= fitted < above and above - below < 2.5
        inside = np.linspace(below, above, 7)[:-1]
        for height in inside:
            np.testing.assert_array_equal(propped(height), propped(fitted))
        assert len(propped(below - 1e-6)) > len(propped(fitted)) > len(propped(above))


@pytest.mark.parametrize("height_mm", [-10.0, -9.0])
def test_a_plate_under_a_hanging_beam_is_screened(tmp_path, height_mm):
    """A cantilever (the P2 beam, clamped at one end, its underside at z = -8 mm and its tip
    sagging 2.9 mm) over a plate below its rest shape: nothing stands on the plate at rest,
    and the heights searched start from the lowest point the body reaches, not from where
    it stands. The screened contact against the exact plate, within 3%."""
    robot, actuation, solution, solutions = _hanging_beam(tmp_path)
    support = support_basis(solutions, SolveCache(None))
    assert support.lower_mm < height_mm < robot.mesh.nodes_mm[:, 2].min() < support.upper_mm
    exact = _propped_mm(robot, actuation, solution, height_mm)
    assert np.sqrt(np.mean(np.sum(exact**2, axis=1))) > 0.4
    predicted = support.motion_mm(height_mm)[0]
    assert np.linalg.norm(predicted - exact) < 0.03 * np.linalg.norm(exact)


def _hanging_beam(tmp_path):
    """The P2 beam at rest inputs, sagging under its weight: robot, actuation (2,), its
    equilibrium and its StateSolutions (one state)."""
    robot = load_robot(write_beam(tmp_path))
    model = robot.nominal_fe_model
    actuation = np.zeros(2)
    solution = solve_equilibrium(model, robot.cable_inputs(actuation))
    columns = column_set(robot)
    lin = linearize(model, solution.positions_mm, solution.cable_tensions_n)
    solutions = StateSolutions(robot, robot.element_name, actuation[None],
                               solution.positions_mm[None], solution.cable_tensions_n[None],
                               state_columns(robot, columns, lin,
                                             solution.cable_tensions_n)[None], None, columns)
    return robot, actuation, solution, solutions


def test_the_refit_starts_a_plate_from_its_screened_contact(tmp_path, monkeypatch):
    """The exact model with a plate under the hanging beam, 2 mm above its lowest point
    (diagnosis.refit): Newton starts from the contact solved on the linearisation, and
    reaches the tight solve's equilibrium in 2 or 3 iterations (as rounding falls at its
    stopping rule) where the nominal equilibrium, the plate 2 mm into the body, takes 11."""
    robot, actuation, solution, solutions = _hanging_beam(tmp_path)
    support = support_basis(solutions, SolveCache(None))
    height_mm = support.lower_mm + 2.0
    states = States(actuation[None], np.zeros((1, 2), np.int8), np.zeros(1),
                    np.zeros(1, np.int64))
    contexts = (FrameContext(0.0, actuation, np.zeros(2, np.int8), 0.0),)
    basis = build_basis(solutions.predicted_mm, solutions.mesh_columns,
                        robot.mesh.surface_faces, solutions.column_set, np.zeros(1, np.int64),
                        contexts, tuple(spec.name for spec in robot.cable_specs),
                        RigidTransform(np.eye(3), np.zeros(3)), actuation[None],
                        support=support)
    exact = ExactModel(solutions, states, contexts, [np.zeros((0, 3))], basis)
    plate = Candidate((Hypothesis("support_contact", None, ("table_z_mm",),
                                  np.array([support.lower_mm]), np.array([support.lower_mm]),
                                  np.array([support.upper_mm])),))
    iterations = []

    def counted(*args, **kwargs):
        equilibrium = solve_equilibrium(*args, **kwargs)
        iterations.append(equilibrium.iterations)
        return equilibrium

    monkeypatch.setattr(refit, "solve_equilibrium", counted)
    predicted = exact.predict(plate, np.array([height_mm]))
    model = fe_model_with_effects(robot, plate.effects(np.array([height_mm])))
    inputs = robot.cable_inputs(actuation)
    tight = solve_equilibrium(model, inputs)
    nominal_start = solve_equilibrium(model, inputs, start_mm=solution.positions_mm,
                                      settings=SETTINGS)
    n = robot.mesh.node_count
    np.testing.assert_allclose(predicted.positions_mm[0], tight.positions_mm[:n], atol=1e-3)
    assert np.abs(tight.positions_mm - solution.positions_mm).max() > 1.5
    assert len(iterations) == 1 and iterations[0] <= 3 and nominal_start.iterations >= 10


def test_a_cache_that_cannot_be_written_warns_and_the_run_goes_on(tmp_path):
    """diagnose's cache under a path that cannot be a folder: a warning, not an error (it
    had raised the OSError as a traceback); reading it finds nothing."""
    blocked = tmp_path / "a_file"
    blocked.write_text("not a folder")
    cache = SolveCache(blocked / "cache")
    with pytest.warns(UserWarning, match="cache is not kept .*cannot write"):
        cache.store("key", positions=np.zeros(3))
    assert cache.load("key") is None
