"""The effect library (model.effects, model.effect_physics, model.regions, fem.supports)."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.errors import ModelError, ScenarioError
from softforce_cli.fem.cables import CableInputs
from softforce_cli.fem.materials import Material
from softforce_cli.fem.model import NEWTON_PER_KG_MM_S2, FEModel
from softforce_cli.fem.statics import solve_equilibrium
from softforce_cli.fem.supports import NodeSprings, SupportPlane
from softforce_cli.io.mcap_reader import iter_frames, read_summary
from softforce_cli.model.config import load_config
from softforce_cli.model.effect_physics import fe_model_with_effects
from softforce_cli.model.effects import (
    EFFECT_NAMES,
    EFFECTS,
    EffectError,
    camera_offset,
    effect_toml,
    effective_actuation,
    frame_contexts,
    make_effect,
    observed_points_robot,
    parse_effects,
    play_operator,
)
from softforce_cli.model.mesh_io import rotation_from_euler_deg
from softforce_cli.model.regions import element_regions, node_regions
from softforce_cli.model.robot import load_robot, robot_with_effects
from softforce_cli.sim.scenario import load_scenario
from softforce_cli.sim.simulate import simulate
from tests.conftest import SAMPLE_ROBOT

CABLES = ("north", "west", "south", "east")
NORTH_PULL = np.array([8.0, 0.0, 0.0, 0.0])


def _non_neutral(name: str):
    """Each effect with every parameter moved off its neutral value, inside its bounds."""
    spec = EFFECTS[name]
    values = {}
    for p in spec.parameters:
        finite = p.neutral if math.isfinite(p.neutral) else 5.0
        values[p.name] = min(max(finite + 0.37 * (1 + abs(finite)), p.lower), p.upper)
    target = {"cable": "west", "region": "apex", None: None}[spec.target]
    return make_effect(name, target, **values)


def test_every_effect_round_trips_through_toml():
    effects = tuple(_non_neutral(name) for name in EFFECT_NAMES)
    text = "\n".join(effect_toml(e) for e in effects)
    parsed = parse_effects(tomllib.loads(text)["effect"], CABLES)
    assert parsed == effects
    assert not any(e.is_neutral for e in parsed)
    # infinities (the neutral rigid base, no plane) survive too
    base = make_effect("compliant_base", stiffness_n_per_mm=math.inf)
    assert parse_effects(tomllib.loads(effect_toml(base))["effect"]) == (base,)
    assert base.is_neutral


@pytest.mark.parametrize(("table", "message"), [
    ({"name": "gravitee"}, "name 'gravitee' unknown"),
    ({"name": "stiffness_scale"}, "needs `scale`"),
    ({"name": "stiffness_scale", "scale": 1.0, "cable": "north"}, "unknown key 'cable'"),
    ({"name": "stiffness_scale", "scale": 100.0}, "outside [0.05, 20]"),
    ({"name": "cable_slack", "slack_mm": 1.0}, "needs `cable`"),
    ({"name": "cable_slack", "cable": "up", "slack_mm": 1.0}, "cable 'up' unknown"),
    ({"name": "regional_stiffness", "region": "leg", "scale": 2.0}, "region 'leg' unknown"),
    ({"name": "depth_bias", "scale": "0.1"}, "must be a number"),
])
def test_bad_effect_tables_say_what_is_wrong(table, message):
    with pytest.raises(EffectError, match=message.replace("[", r"\[")):
        parse_effects([table], CABLES)


def test_robot_file_effects_load_and_errors_name_the_file(tmp_path):
    text = SAMPLE_ROBOT.read_text().replace('path = "diamond_coarse.vtu"',
                                            f'path = "{SAMPLE_ROBOT.parent}/diamond_coarse.vtu"')
    good = tmp_path / "fitted.toml"
    good.write_text(text + "\n" + effect_toml(make_effect("cable_slack", "north", slack_mm=2.0)))
    robot = load_robot(good)
    assert [e.label for e in robot.effects] == ["cable_slack[north]"]
    # slack applies to the cable inputs every command builds
    np.testing.assert_allclose(robot.cable_inputs(np.array([5.0, 1.0, 0, 0])).values,
                               [3.0, 1.0, 0, 0])
    twice = tmp_path / "twice.toml"
    twice.write_text(good.read_text() + effect_toml(make_effect("cable_slack", "north",
                                                                slack_mm=1.0)))
    with pytest.raises(ModelError, match=r"twice.toml: effect cable_slack\[north\] appears twice"):
        load_config(twice)
    forced = tmp_path / "forced.toml"
    forced.write_text(good.read_text().replace('control = "displacement"', 'control = "force"'))
    with pytest.raises(ModelError, match=r"forced.toml: cable_slack .* force-controlled"):
        load_config(forced)


def test_frame_contexts_by_hand():
    times = np.arange(6) * 0.5
    actuation = np.array([[0, 0], [2, 0], [2, 0], [1, 0], [1, 3], [1, 3]], dtype=float)
    contexts = frame_contexts(times, actuation)
    assert [c.hold_s for c in contexts] == [0.0, 0.0, 0.5, 0.0, 0.0, 0.5]
    assert [tuple(c.loading) for c in contexts] == [(0, 0), (1, 0), (1, 0), (-1, 0), (-1, 1),
                                                    (-1, 1)]


def test_play_operator_and_slack_by_hand():
    # half-width 1: lags 1 behind on loading, holds for 2 after the reversal, then lags 1
    commanded = np.array([0, 2, 4, 5, 4, 3, 2, 0], dtype=float)[:, None]
    np.testing.assert_allclose(play_operator(commanded, np.array([1.0]))[:, 0],
                               [0, 1, 3, 4, 4, 4, 3, 1])
    contexts = frame_contexts(np.arange(8.0), np.hstack([commanded, commanded]))
    effects = parse_effects([{"name": "cable_friction", "cable": "north", "play_mm": 1.0},
                             {"name": "cable_slack", "cable": "north", "slack_mm": 2.0},
                             {"name": "cable_slack", "cable": "west", "slack_mm": 2.0}],
                            ("north", "west"))
    # north: friction, then slack; west: slack alone
    np.testing.assert_allclose(effective_actuation(effects, contexts, ("north", "west")),
                               [[0, 0], [0, 0], [1, 2], [2, 3], [2, 2], [2, 1], [1, 0], [0, 0]])


@pytest.fixture(scope="module")
def robot():
    return load_robot(SAMPLE_ROBOT)


def test_regions_partition_the_body_by_arm(robot):
    elements = element_regions(robot)
    assert sum(mask.astype(int) for mask in elements.values()).tolist() == [1] * (
        robot.mesh.tet_count)
    centroids = robot.mesh.nodes_mm[robot.mesh.tets].mean(axis=1)
    for name, (dx, dy) in zip(CABLES, [(0, 1), (-1, 0), (0, -1), (1, 0)], strict=True):
        # the arm regions lie out along their cable's direction, and are alike in size
        assert centroids[elements[name]][:, :2].mean(axis=0) @ [dx, dy] > 40.0
        assert abs(elements[name].sum() / elements["north"].sum() - 1) < 0.05
    assert centroids[elements["apex"], 2].min() > 95.0
    nodes = node_regions(robot)
    assert sum(m.astype(int) for m in nodes.values()).tolist() == [1] * robot.mesh.node_count


def test_neutral_effects_leave_the_model_unchanged(robot):
    nominal = robot.nominal_fe_model
    neutral = [make_effect(n, {"cable": "west", "region": "apex", None: None}[s.target],
                           **{p.name: p.neutral for p in s.parameters})
               for n, s in EFFECTS.items()]
    model = fe_model_with_effects(robot, neutral)
    x = nominal.rest_nodes_mm + np.random.default_rng(0).normal(0, 0.5, nominal.rest_nodes_mm.shape)
    e0, f0 = nominal.energy_and_forces(x)
    e1, f1 = model.energy_and_forces(x)
    assert e1 == pytest.approx(e0, rel=1e-12)
    np.testing.assert_allclose(f1, f0, rtol=0, atol=1e-12 * np.abs(f0).max())
    np.testing.assert_array_equal(model.gravity_forces_n, nominal.gravity_forces_n)
    np.testing.assert_array_equal(model.fixed_nodes, nominal.fixed_nodes)


def test_material_nonlinearity_blends_the_two_laws(robot):
    nominal = robot.nominal_fe_model
    x = nominal.rest_nodes_mm + np.random.default_rng(1).normal(0, 0.3, nominal.rest_nodes_mm.shape)
    neo = FEModel(nominal.rest_nodes_mm, nominal.tets,
                  Material("neo-hookean", nominal.material.young_modulus_mpa,
                           nominal.material.poisson_ratio),
                  nominal.fixed_nodes, nominal.node_masses_kg, nominal.gravity_mm_s2)
    forces = {b: fe_model_with_effects(robot, [make_effect("material_nonlinearity", blend=b)]
                                       ).internal_forces(x) for b in (0.5, 1.0)}
    assert np.isfinite(forces[1.0]).all()
    np.testing.assert_allclose(forces[1.0], neo.internal_forces(x), atol=1e-12)
    np.testing.assert_allclose(forces[0.5], 0.5 * (neo.internal_forces(x)
                                                   + nominal.internal_forces(x)), atol=1e-12)
    # and the tangent stays the derivative of the blended forces
    model = fe_model_with_effects(robot, [make_effect("material_nonlinearity", blend=0.5)])
    _, tangent = model.internal_forces_and_stiffness(x)
    step = np.zeros_like(x)
    step.ravel()[model.free_dofs] = np.random.default_rng(2).normal(size=len(model.free_dofs))
    h = 1e-6
    numeric = (model.internal_forces(x + h * step) - model.internal_forces(x - h * step)) / (2 * h)
    np.testing.assert_allclose(tangent @ step.ravel()[model.free_dofs],
                               numeric.ravel()[model.free_dofs], rtol=1e-5, atol=1e-6)


@pytest.fixture(scope="module")
def gravity_sag(robot):
    """The nominal equilibrium with slack cables under gravity alone."""
    return solve_equilibrium(robot.nominal_fe_model, robot.cable_inputs(np.zeros(4)))


def _displacement(robot, effects, inputs):
    nominal = solve_equilibrium(robot.nominal_fe_model, robot.cable_inputs(inputs))
    changed = solve_equilibrium(fe_model_with_effects(robot, effects), robot.cable_inputs(inputs))
    return changed.positions_mm - nominal.positions_mm, changed


def test_softer_body_sags_twice_as_far(robot, gravity_sag):
    # linear elasticity: half the modulus doubles the sag (geometric nonlinearity is small at
    # this sag, a few mm on a 166 mm body)
    soft = solve_equilibrium(fe_model_with_effects(robot, [make_effect("stiffness_scale",
                                                                       scale=0.5)]),
                             robot.cable_inputs(np.zeros(4)))
    sag = gravity_sag.positions_mm - robot.rest_nodes_mm
    soft_sag = soft.positions_mm - robot.rest_nodes_mm
    apex = np.argmax(robot.rest_nodes_mm[:, 2])
    assert soft_sag[apex, 2] / sag[apex, 2] == pytest.approx(2.0, rel=0.1)


def test_gravity_effect_scales_and_tilts(robot):
    effect = make_effect("gravity", scale=1.5, tilt_x_deg=10.0)
    model = fe_model_with_effects(robot, [effect])
    np.testing.assert_allclose(model.gravity_mm_s2,
                               1.5 * rotation_from_euler_deg((10.0, 0, 0)) @ [0, 0, -9810.0])
    moved, _ = _displacement(robot, [effect], NORTH_PULL)
    apex = np.argmax(robot.rest_nodes_mm[:, 2])
    assert moved[apex, 2] < -1.0  # heavier: the apex sinks
    free = np.setdiff1d(np.arange(len(moved)), robot.nominal_fe_model.fixed_nodes)
    assert moved[free, 1].mean() > 0.1  # turned about x: gravity gains a +y part


def test_regional_softening_sags_its_own_arm(robot):
    moved, _ = _displacement(robot, [make_effect("regional_stiffness", "north", scale=0.5)],
                             np.zeros(4))
    regions = node_regions(robot)
    north, south = moved[regions["north"], 2].mean(), moved[regions["south"], 2].mean()
    assert north < -1.0
    assert north < 3 * south  # the softened arm sinks far more than the opposite one


def test_compliant_base_carries_the_weight(robot):
    stiffness = 5.0
    effect = make_effect("compliant_base", stiffness_n_per_mm=stiffness)
    model = fe_model_with_effects(robot, [effect])
    springs = model.supports[0]
    assert isinstance(springs, NodeSprings)
    assert springs.stiffness_n_per_mm.sum() == pytest.approx(stiffness)
    state = solve_equilibrium(model, CableInputs.slack(4))
    # force balance: the springs hold the weight (slack cables pull nothing), sum k_i d_i = W,
    # so the stiffness-weighted mean displacement of the base is exactly W / K
    weight_n = robot.mass_kg * 9810.0 * NEWTON_PER_KG_MM_S2
    displacement = state.positions_mm[springs.nodes] - springs.anchors_mm
    mean = springs.stiffness_n_per_mm @ displacement / stiffness
    np.testing.assert_allclose(mean, [0, 0, -weight_n / stiffness], atol=1e-6)
    # a very stiff base is the clamp again
    stiff = solve_equilibrium(fe_model_with_effects(robot, [make_effect(
        "compliant_base", stiffness_n_per_mm=1e6)]), robot.cable_inputs(np.zeros(4)))
    clamped = solve_equilibrium(robot.nominal_fe_model, robot.cable_inputs(np.zeros(4)))
    assert np.abs(stiff.positions_mm - clamped.positions_mm).max() < 0.01


def test_support_plane_holds_the_pressed_arms_only(robot):
    # pulling north lifts the north arm and presses the others down: the south arm's lower
    # bar reaches z = 14 mm from 21 mm at rest; a plane at z = 20 mm stops it
    plane = make_effect("support_contact", table_z_mm=20.0)
    _, touching = _displacement(robot, [plane], NORTH_PULL)
    model = fe_model_with_effects(robot, [plane])
    support = model.supports[0]
    assert isinstance(support, SupportPlane)
    z = touching.positions_mm[support.nodes, 2]
    assert z.min() > 20.0 - 0.05  # penetration a few hundredths of a mm at most
    pressed = support.contact_nodes(touching.positions_mm)
    regions = node_regions(robot)
    assert regions["south"][pressed].any() and not regions["north"][pressed].any()
    # an actuation that lifts every elbow never reaches the plane: nothing changes
    lifted, _ = _displacement(robot, [plane], np.full(4, 8.0))
    assert np.abs(lifted).max() < 1e-6


def test_creep_softens_with_hold_time(robot):
    effect = make_effect("viscoelastic_creep", relaxation=0.3, time_constant_s=10.0)
    context = frame_contexts(np.array([0.0, 10.0]), np.zeros((2, 4)))[1]
    model = fe_model_with_effects(robot, [effect], context)
    nominal = robot.nominal_fe_model.material.young_modulus_mpa
    assert model.material.young_modulus_mpa == pytest.approx(
        nominal * (1 - 0.3 * (1 - math.exp(-1.0))))
    # without a frame context (a command's static model) creep is left out
    assert fe_model_with_effects(robot, [effect]).material.young_modulus_mpa == nominal


def test_robot_with_effects_uses_them_everywhere(robot):
    fitted = robot_with_effects(robot, (make_effect("stiffness_scale", scale=2.0),))
    assert fitted.fe_model.material.young_modulus_mpa == pytest.approx(
        2 * robot.material.young_modulus_mpa)
    assert robot.fe_model is robot.nominal_fe_model  # no effects: the very same model


def test_sensor_effects_move_points_as_a_camera_would():
    rotation = rotation_from_euler_deg((180.0, 0.0, 0.0))  # looking down
    robot_from_camera = RigidTransform(rotation, np.array([0.0, 0.0, 580.0]))
    points = np.array([[0.0, 0.0, 40.0], [30.0, -20.0, 100.0]])
    np.testing.assert_allclose(observed_points_robot(points, (), robot_from_camera), points,
                               atol=1e-9)
    # depth 10% long: points recede from the camera along their rays
    bias = (make_effect("depth_bias", scale=0.1),)
    cam = robot_from_camera.inverse().apply(points)
    np.testing.assert_allclose(observed_points_robot(points, bias, robot_from_camera),
                               robot_from_camera.apply(1.1 * cam), atol=1e-9)
    # a camera truly 5 mm further along its x than calibrated sees the world 5 mm the other way
    shift = (make_effect("extrinsic_offset", translation_x_mm=5.0),)
    np.testing.assert_allclose(observed_points_robot(points, shift, robot_from_camera),
                               points - rotation @ [5.0, 0.0, 0.0], atol=1e-9)
    # turned 30 degrees about its own z (x, then y, then z, as mesh rotations)
    turn = camera_offset((make_effect("extrinsic_offset", rotation_z_deg=30.0),))
    np.testing.assert_allclose(turn.apply(np.array([[1.0, 0.0, 0.0]])),
                               [[math.cos(math.pi / 6), 0.5, 0.0]], atol=1e-12)


def _scenario(tmp_path, effects: str, frames: str, name: str = "conceal") -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(f'robot = "{SAMPLE_ROBOT}"\nseed = 2\n[camera]\nwidth = 64\nheight = 48\n'
                    f"noise = false\n{effects}\n{frames}")
    return path


def test_simulate_conceals_effects_in_the_truth_only(tmp_path):
    effects = "\n".join(effect_toml(e) for e in (
        make_effect("cable_slack", "north", slack_mm=2.0),
        make_effect("cable_friction", "north", play_mm=1.0),
        make_effect("extrinsic_offset", translation_x_mm=5.0)))
    frames = "".join(f"[[frame]]\nactuation = [{u}, 0.0, 0.0, 0.0]\nrepeat = {r}\n"
                     for u, r in ((0.0, 1), (4.0, 2), (1.0, 1)))
    result = simulate(_scenario(tmp_path, effects, frames), tmp_path / "rec.mcap")
    truth = json.loads(result.truth.read_text())
    assert [e["name"] for e in truth["concealed_effects"]] == [
        "cable_slack", "cable_friction", "extrinsic_offset"]
    assert truth["concealed_effects"][0]["parameters"]["slack_mm"] == {"value": 2.0, "unit": "mm"}
    # north: play 1 then slack 2 on the commanded 0, 4, 4, 1 -> 0, 3, 3, 2 -> 0, 1, 1, 0
    effective = [f["effects"]["effective_actuation"][0] for f in truth["frames"]]
    assert effective == [0.0, 1.0, 1.0, 0.0]
    for record in truth["frames"][1:3]:  # the taut cable shortens by what it receives
        assert record["cable_displacements_mm"][0] == pytest.approx(1.0, abs=1e-6)
    # the recording carries the commanded actuation, nothing of the effects
    commanded = [frame.actuation.values[0] for frame in iter_frames(result.recording)]
    assert commanded == [0.0, 4.0, 4.0, 1.0]
    assert "effect" not in json.dumps(read_summary(result.recording).metadata)
    camera = truth["camera"]
    nominal = np.array(camera["rotation"])
    np.testing.assert_allclose(np.array(camera["actual_translation_mm"]),
                               np.array(camera["translation_mm"]) + nominal @ [5.0, 0, 0],
                               atol=1e-6)


def test_simulate_scales_the_depth_by_a_concealed_bias(tmp_path):
    frames = "[[frame]]\nactuation = [0.0, 0.0, 0.0, 0.0]\n"
    bias = effect_toml(make_effect("depth_bias", scale=0.05))
    markers = "[markers]\npublish = true\n"  # noise-free observations
    depths, seen = [], []
    for name, effects in (("plain", ""), ("biased", bias)):
        result = simulate(_scenario(tmp_path, f"{markers}{effects}", frames, name),
                          tmp_path / f"{name}.mcap")
        frame = next(iter(iter_frames(result.recording)))
        depths.append(frame.depth_mm.astype(float))
        seen.append(frame.markers.positions_mm)
    hit = (depths[0] > 0) & (depths[1] > 0)
    # both depths are rounded to whole mm: 1.05 times the plain one within 0.5 + 1.05 x 0.5
    assert hit.mean() > 0.9
    assert np.abs(depths[1][hit] - 1.05 * depths[0][hit]).max() <= 1.025 + 1e-9
    # the markers are located in that depth: 5% further along their rays
    np.testing.assert_allclose(seen[1], 1.05 * seen[0], atol=1e-4)


def test_scenario_effect_errors_are_one_line(tmp_path):
    frames = "[[frame]]\nactuation = [0.0, 0.0, 0.0, 0.0]\n"
    bad = _scenario(tmp_path, '[[effect]]\nname = "cable_slack"\ncable = "up"\nslack_mm = 1.0',
                    frames, "bad")
    with pytest.raises(ScenarioError, match=r"bad.toml: .*cable 'up' unknown"):
        simulate(bad, tmp_path / "bad.mcap")
    unknown = _scenario(tmp_path, '[[effect]]\nname = "magic"', frames, "unknown")
    with pytest.raises(ScenarioError, match=r"unknown.toml: effect\[0\]: name 'magic' unknown"):
        load_scenario(unknown)
