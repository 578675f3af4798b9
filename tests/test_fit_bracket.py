"""diagnosis.fit_bracket: the mesh's two quadratic elements compared at a fitted effect."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from softforce_cli.diagnosis import pipeline
from softforce_cli.diagnosis.fit_bracket import (
    MESH_REST_SHARE,
    FitBracket,
    fit_bracket,
    nominal_bracket,
)
from softforce_cli.diagnosis.fitting import Candidate
from softforce_cli.diagnosis.hypotheses import Hypothesis
from softforce_cli.diagnosis.pipeline import Diagnosis
from softforce_cli.diagnosis.refit import ExactModel, Refit
from softforce_cli.diagnosis.report import (
    mesh_rest_line,
    mismatch_within_mesh_line,
    static_beyond_line,
)
from softforce_cli.diagnosis.residuals import Field, surface_normals
from softforce_cli.diagnosis.sensitivities import column_set
from softforce_cli.diagnosis.solves import ElementBracket, StateSolutions
from softforce_cli.diagnosis.states import States
from softforce_cli.fem.statics import solve_equilibrium
from softforce_cli.model.effect_physics import fe_model_with_effects
from softforce_cli.model.effects import FrameContext
from softforce_cli.model.robot import load_robot, with_element
from tests.test_reduced_model import write_beam

SOFTER = Candidate((Hypothesis("stiffness_scale", None, ("scale",), np.array([1.0]),
                               np.array([0.2]), np.array([5.0])),))


def _exact_beam(tmp_path, actuation: np.ndarray) -> tuple:
    """A P2 beam's exact model at states `actuation` (S, 2), one frame each, and every
    surface node an entry of each frame (one point)."""
    robot = load_robot(write_beam(tmp_path))
    nominal = [solve_equilibrium(robot.fe_model, robot.cable_inputs(a)) for a in actuation]
    columns = column_set(robot)
    count = len(actuation)
    solutions = StateSolutions(
        robot, "p2", actuation, np.stack([e.positions_mm for e in nominal]),
        np.stack([e.cable_tensions_n for e in nominal]),
        np.zeros((count, len(columns.names), robot.fe_model.node_count, 3)), None, columns)
    states = States(actuation, np.zeros((count, 2), np.int8), np.zeros(count),
                    np.arange(count))
    contexts = tuple(FrameContext(0.0, a, np.zeros(2, np.int8), 0.0) for a in actuation)
    exact = ExactModel(solutions, states, contexts, [np.zeros((0, 3))] * count, None)
    surface = robot.mesh.surface_nodes
    field = Field(np.repeat(np.arange(count), len(surface)), np.tile(surface, count),
                  np.zeros(count * len(surface)), np.ones(count * len(surface)))
    return robot, exact, field


def test_the_elements_disagreement_at_a_fit_is_the_two_elements_solved_apart(tmp_path):
    """A P2 beam 30% softer at two actuations: the bracket is the normal component of the
    P2-P0 equilibrium minus the P2 one, each solved from rest with the effect (not from each
    other, as fit_bracket solves), split into each node's mean over the two frames (static)
    and the deviation from it (half the change between the states)."""
    actuation = np.array([[1.0, 0.5], [4.0, 0.0]])
    robot, exact, field = _exact_beam(tmp_path, actuation)
    values = np.array([0.7])
    prediction = exact.predict(SOFTER, values)
    # the fit leaves 0 mm in the first frame and 1 mm in the second at every node: 0.5 mm
    # across frames and 0.5 mm static
    left = Field(field.frame, field.node, field.frame.astype(float), field.weight)
    fitted = Refit(SOFTER, values, left, np.zeros((len(field.frame), 1)), prediction, 2,
                   values)
    bracket = fit_bracket(exact, fitted)
    assert bracket.rest_relative_mm == pytest.approx(0.5)
    assert bracket.rest_static_mm == pytest.approx(0.5)

    n, surface = robot.mesh.node_count, robot.mesh.surface_nodes
    effects = SOFTER.effects(values)
    apart = []
    for a in actuation:
        p2 = solve_equilibrium(fe_model_with_effects(robot, effects), robot.cable_inputs(a))
        other = with_element(robot, "p2-p0")
        p2p0 = solve_equilibrium(fe_model_with_effects(other, effects), other.cable_inputs(a))
        normals = surface_normals(p2.positions_mm[:n], robot.mesh.surface_faces)
        apart.append(np.einsum("ij,ij->i", (p2p0.positions_mm[:n] - p2.positions_mm[:n])[surface],
                               normals[surface]))
    first, second = apart
    static = np.sqrt(np.mean(((first + second) / 2) ** 2))
    relative = np.sqrt(np.mean(((first - second) / 2) ** 2))
    assert bracket.groups == 2 and bracket.unsolved == 0
    assert bracket.static_mm == pytest.approx(static, rel=1e-3)
    assert bracket.relative_mm == pytest.approx(relative, rel=1e-3)
    # the locking-prone P2 beam is stiffer than P2-P0: a bracket the tolerance cannot hide
    assert relative > 0.01 and static > 0.1


def test_a_camera_effect_is_left_out_and_one_state_has_no_bracket(tmp_path):
    """A camera's shift is not the mesh's: with a physics effect, the bracket is the physics
    alone's (solved again without the camera), a camera alone has none; what changes across
    frames needs two states."""
    actuation = np.array([[2.0, 1.0], [3.0, 0.0]])
    _, exact, field = _exact_beam(tmp_path, actuation)
    values = np.array([0.8])
    prediction = exact.predict(SOFTER, values)
    alone = fit_bracket(exact, Refit(SOFTER, values, field, np.zeros((len(field.frame), 1)),
                                     prediction, 2, values))
    depth = Hypothesis("depth_bias", None, ("scale",), np.array([0.0]), np.array([-0.05]),
                       np.array([0.05]))
    assert depth.kind == "sensor"
    # the refit's own prediction (with the camera) is not used: the physics is solved again
    both = Candidate((SOFTER.hypotheses[0], depth))
    with_camera = fit_bracket(exact, Refit(both, np.array([0.8, 0.01]), field,
                                           np.zeros((len(field.frame), 2)), prediction, 2,
                                           np.array([0.8, 0.01])))
    assert with_camera == alone and alone.relative_mm > 0
    assert fit_bracket(exact, Refit(Candidate((depth,)), np.array([0.01]), field,
                                    np.zeros((len(field.frame), 1)), prediction, 1,
                                    np.array([0.01]))) is None
    one = field.frame == 0
    single = Field(field.frame[one], field.node[one], field.mean_mm[one], field.weight[one])
    _, exact_one, _ = _exact_beam(tmp_path / "one", actuation[:1])
    assert fit_bracket(exact_one, Refit(SOFTER, values, single, np.zeros((one.sum(), 1)),
                                        exact_one.predict(SOFTER, values), 1, values)) is None


@pytest.mark.parametrize(("rest_relative", "rest_static", "relative_named", "static_named",
                          "expected"), [
    (1.80, 1.50, False, False, True),    # a body 30% softer: the coarse Diamond near buckling
    (2.00, 1.50, False, False, False),   # more across frames than half the disagreement
    (1.80, 2.60, False, False, False),   # more static than half of it
    (9.00, 2.60, True, True, True),      # nothing to excuse
    (9.00, 1.50, False, True, False),
])
def test_the_rest_is_left_to_the_mesh_within_half_the_disagreement(
        rest_relative, rest_static, relative_named, static_named, expected):
    """Across frames the noise floor is taken off what is left first (0.45 mm here:
    sqrt(1.8^2 - 0.45^2) = 1.74 <= 0.5 * 3.6; sqrt(2^2 - 0.45^2) = 1.95 is not)."""
    bracket = FitBracket(relative_mm=3.6, static_mm=5.0, rest_relative_mm=rest_relative,
                         rest_static_mm=rest_static, groups=4, unsolved=2)
    assert MESH_REST_SHARE == 0.5
    assert bracket.explains_rest(0.45, relative_named, static_named) is expected


def test_the_summary_gives_the_rest_and_the_disagreement():
    """The line a fit named with its rest left to the mesh adds to the summary."""
    bracket = FitBracket(relative_mm=3.6, static_mm=5.0, rest_relative_mm=1.8,
                         rest_static_mm=1.5, groups=7, unsolved=3)
    line = mesh_rest_line(Diagnosis(None, None, noise_floor_mm=0.45, fit_bracket=bracket,
                                    mesh_rest=True))
    for figure in ("1.80 mm across frames", "0.45 mm", "1.50 mm static in 7 states",
                   "3.60 mm across frames, 5.00 mm static", "3 of the 10 states"):
        assert figure in line


def test_states_of_equal_inputs_share_the_other_elements_solve(tmp_path):
    """Loading and unloading to the same inputs are two states but one equilibrium of the
    other element (without creep): solved once, as predict solves them, and equal to the
    P2-P0 beam solved from rest with the effect."""
    actuation = np.array([[2.0, 1.0], [2.0, 1.0], [3.0, 0.0]])
    robot, exact, _ = _exact_beam(tmp_path, actuation)
    values = np.array([0.8])
    others = exact.other_element(SOFTER, values, exact.predict(SOFTER, values))
    assert others[0] is others[1] and others[2] is not others[0]
    other = with_element(robot, "p2-p0")
    direct = solve_equilibrium(fe_model_with_effects(other, SOFTER.effects(values)),
                               other.cable_inputs(actuation[0]))
    n = robot.mesh.node_count
    assert np.abs(others[0] - direct.positions_mm[:n]).max() < 1e-4


def test_the_nominal_bracket_is_the_elements_apart_without_effects(tmp_path):
    """(nominal_bracket) The P2 beam's recording seen from above, its top face's interior
    nodes observed 0.3 mm above the predicted surface in the first state and on it in the
    second: the nominal residual is 0.15 mm across frames and 0.15 mm static, and the
    disagreement is the P2-P0 beam minus the P2 one, each solved from rest without effects,
    along the normals at those nodes."""
    actuation = np.array([[1.0, 0.5], [4.0, 0.0]])
    robot, exact, _ = _exact_beam(tmp_path, actuation)
    n, faces = robot.mesh.node_count, robot.mesh.surface_faces
    p2 = exact.solutions.positions_mm[:, :n]
    normals = [surface_normals(p, faces) for p in p2]
    top = np.intersect1d(*(np.flatnonzero(m[:, 2] > 0.99) for m in normals))
    points = [p[top] + [0.0, 0.0, lift] for p, lift in zip(p2, (0.3, 0.0), strict=True)]
    camera = SimpleNamespace(robot_from_camera=SimpleNamespace(
        translation_mm=np.array([40.0, 0.0, 1000.0])))
    exact = ExactModel(exact.solutions, exact.states, exact.contexts, points, camera)

    bracket = nominal_bracket(exact)
    assert bracket.groups == 2 and bracket.unsolved == 0
    assert bracket.rest_relative_mm == pytest.approx(0.15, abs=1e-4)
    assert bracket.rest_static_mm == pytest.approx(0.15, abs=1e-4)
    other = with_element(robot, "p2-p0")
    apart = np.array([np.einsum("ij,ij->i", (solve_equilibrium(other.fe_model, other.cable_inputs(
        a)).positions_mm[:n] - p)[top], m[top]) for a, p, m in zip(actuation, p2, normals,
                                                                   strict=True)])
    assert bracket.static_mm == pytest.approx(np.sqrt(np.mean(apart.mean(axis=0) ** 2)),
                                              rel=1e-3)
    assert bracket.relative_mm == pytest.approx(
        np.sqrt(np.mean((apart - apart.mean(axis=0)) ** 2)), rel=1e-3)
    # the beam locks little at its own stiffness (0.0076 and 0.047 mm), still far above
    # the comparison's tolerance
    assert bracket.relative_mm > 0.005 and bracket.static_mm > 0.03


@pytest.mark.parametrize(("rest_relative", "rest_static", "expected"), [
    (0.187, 1.06, True),   # the converged body's clean recording at 640x480: 0.12 mm above
    (0.61, 1.30, False),   # a hidden mass: what changes across frames beyond the mesh's
    (0.187, 1.40, False),  # more static than the elements disagree by
])
def test_a_mismatch_within_the_elements_disagreement_is_the_mesh(rest_relative, rest_static,
                                                                 expected):
    """(FitBracket.holds_mismatch) The whole disagreement bounds the nominal mismatch: the
    noise floor (0.144 mm) is taken off across frames (sqrt(0.187^2 - 0.144^2) = 0.12 <=
    0.19), not MESH_REST_SHARE of it, which a named fit is held to."""
    bracket = FitBracket(relative_mm=0.19, static_mm=1.36, rest_relative_mm=rest_relative,
                         rest_static_mm=rest_static, groups=9, unsolved=0)
    assert bracket.holds_mismatch(0.144) is expected


@pytest.mark.parametrize(("systematic", "within", "asked"), [(1.07, True, True),
                                                            (1.07, False, True),
                                                            (1.40, True, False)])
def test_a_mismatch_within_the_meshs_error_is_none(monkeypatch, systematic, within, asked):
    """(pipeline._mismatch_within_mesh) The other element is solved at the nominal states
    only when the nominal residual (1.07 mm above the noise, the converged body's clean
    recording) is within the elements' distance at rest (1.29 mm); the mismatch is the
    mesh's where that bracket holds it; a hidden mass's 1.40 mm is not asked."""
    bracket = FitBracket(0.19, 1.36, 0.187 if within else 0.61, 1.06, 9, 0)
    calls = []
    monkeypatch.setattr(pipeline, "nominal_bracket",
                        lambda exact: calls.append(exact) or bracket)
    result = Diagnosis(None, None, noise_floor_mm=0.144, mesh_bracket_sought=True,
                       mesh_bracket=ElementBracket(1.14, 1.29))
    mean = np.full((2, 5), np.hypot(systematic, 0.144))
    frame, node = np.meshgrid(np.arange(2), np.arange(5), indexing="ij")
    result.nominal = Field(frame.ravel(), node.ravel(), mean.ravel(), np.ones(mean.size))
    assert pipeline._mismatch_within_mesh(result, "exact", None, None) is (within and asked)
    assert bool(calls) is asked
    assert (result.nominal_bracket is bracket) is asked


def test_the_summary_says_the_mismatch_is_the_meshs():
    """The line of a `none` whose mismatch is the mesh's, with a partial fit or none."""
    bracket = FitBracket(relative_mm=0.19, static_mm=1.36, rest_relative_mm=0.187,
                         rest_static_mm=1.06, groups=9, unsolved=0)
    diagnosis = Diagnosis(None, None, noise_floor_mm=0.144, nominal_bracket=bracket,
                          mismatch_within_mesh=True, partial=["gravity"],
                          evidence={"rms_nominal_mm": 1.08})
    line = mismatch_within_mesh_line(diagnosis)
    for figure in ("1.08 mm RMS", "0.14 mm", "0.12 mm above the noise", "1.06 mm static",
                   "0.19 and 1.36 mm; gravity fits part of it"):
        assert figure in line
    diagnosis.partial = []
    assert "1.36 mm: the mesh is the likely cause" in mismatch_within_mesh_line(diagnosis)


# The converged body's camera moved 3 mm sideways at 640x480 (floor 0.145 mm): the nominal
# model and the camera's fit, each with what the elements disagree by there.
CAMERA_NOMINAL = FitBracket(relative_mm=0.17, static_mm=1.35, rest_relative_mm=0.21,
                            rest_static_mm=1.60, groups=9, unsolved=0)
CAMERA_FIT = FitBracket(relative_mm=0.18, static_mm=1.57, rest_relative_mm=0.19,
                        rest_static_mm=0.27, groups=9, unsolved=0)


@pytest.mark.parametrize(("nominal", "fit", "static_named", "expected"), [
    ({}, {}, True, True),
    # a clean recording: the nominal model's static residual within the mesh's too (`none`)
    ({"rest_static_mm": 1.06}, {}, True, False),
    # a hidden mass: what changes across frames beyond the mesh's without the fit
    ({"rest_relative_mm": 0.61}, {"rest_relative_mm": 0.35}, True, False),
    # the fit leaving more across frames than the elements disagree by
    ({}, {"rest_relative_mm": 0.26}, True, False),
    # ... or too much static: more than half the disagreement where the limit is passed
    ({}, {"rest_static_mm": 0.9}, False, False),
    ({}, {"rest_static_mm": 0.7}, False, True),
])
def test_a_fit_of_what_every_frame_shares_leaves_the_rest_to_the_mesh(nominal, fit,
                                                                      static_named, expected):
    """(FitBracket.explains_static_beyond) Where the nominal model is beyond the mesh's own
    error only in what every frame shares, a fit may leave across frames what the elements
    disagree by (sqrt(0.19^2 - 0.145^2) = 0.12 <= 0.18), not half of it (0.09)."""
    fitted = dataclasses.replace(CAMERA_FIT, **fit)
    assert not fitted.explains_rest(0.145, False, static_named)
    assert fitted.explains_static_beyond(dataclasses.replace(CAMERA_NOMINAL, **nominal), 0.145,
                                         static_named) is expected


def test_the_summary_says_only_the_static_shape_was_beyond_the_mesh():
    """The line of a fit named since only what every frame shares was beyond the mesh."""
    diagnosis = Diagnosis(None, None, noise_floor_mm=0.145, fit_bracket=CAMERA_FIT,
                          nominal_bracket=CAMERA_NOMINAL, mesh_rest=True,
                          mesh_rest_static=True)
    line = static_beyond_line(diagnosis)
    for figure in ("0.15 mm above the noise across frames", "1.60 mm static",
                   "0.17 and 1.35 mm", "0.27 mm static is left", "0.12 mm across frames",
                   "0.18 mm there"):
        assert figure in line
