"""The reduced-order model (POD + ECSW) against its full quadratic model, on a small robot.

A clamped P2 beam with two cables trains in seconds; every check is on load cases outside
its training set (other actuations, forces between feature points, two contacts). The coarse
Diamond figures are the bench study (benchmarks/bench_reduced.py, docs/reduced_model.md).
"""

from __future__ import annotations

import dataclasses
import json
import pickle
import shutil
import warnings
from types import SimpleNamespace

import meshio
import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import nnls

from softforce_cli.calibration.linear_model import linear_model
from softforce_cli.errors import ModelError
from softforce_cli.fem import processes
from softforce_cli.fem.attachment import Attachment
from softforce_cli.fem.element import deformation_gradients
from softforce_cli.fem.materials import Material
from softforce_cli.fem.reduction.accuracy import LoadCase, between_features, case_errors
from softforce_cli.fem.reduction.ecsw import energy_weight, sparse_nnls
from softforce_cli.fem.reduction.pod import pod_basis, projection_errors
from softforce_cli.fem.reduction.reduced_model import ReducedModel, ReducedModelWarning
from softforce_cli.fem.reduction.rom_file import load_reduction, reduced_model, save_reduction
from softforce_cli.fem.reduction.snapshots import (
    TrainingSet,
    actuation_design,
    collect,
    load_training_set,
)
from softforce_cli.fem.reduction.starts import grid_levels, input_sensitivities, serpentine_grid
from softforce_cli.fem.reduction.train import (
    CLAMP_CLEARANCE_MM,
    TrainingSettings,
    contact_sites,
    ecsw_system,
    energy_norms,
    every_point,
    projected_states,
    successive_pod,
    train_robot,
)
from softforce_cli.fem.statics import PointLoads, SolverSettings, _next_step, solve_equilibrium
from softforce_cli.model.robot import load_robot, with_element
from softforce_cli.model.structured import box_mesh
from tests.cli_runner import assert_one_line_error, softforce

BEAM_TOML = """name = "beam"
[mesh]
path = "beam.vtu"
element = "p2"
{reduced}
[material]
law = "corotational"
young_modulus_mpa = 0.5
poisson_ratio = {poisson}
total_mass_kg = 0.02
gravity_mm_s2 = [0.0, 0.0, -9810.0]
[[fixed]]
box_mm = [-1.0, -10.0, -10.0, 1.0, 10.0, 10.0]
[[cable]]
name = "up"
path_mm = [[78.0, 0.0, 6.0], [40.0, 0.0, 6.0]]
pull_point_mm = [-5.0, 0.0, 6.0]
min = 0.0
max = 6.0
[[cable]]
name = "side"
path_mm = [[78.0, 6.0, 0.0]]
pull_point_mm = [-5.0, 6.0, 0.0]
min = 0.0
max = 4.0
[features]
count = 12
[[marker]]
id = "tip"
position_mm = [80.0, 0.0, 8.0]
[[marker]]
id = "mid"
position_mm = [40.0, 8.0, 0.0]
[[marker]]
id = "side"
position_mm = [60.0, -8.0, 0.0]
"""
MAX_FORCE_N = 0.1
# 40 modes: with more, the beam's 240 elements are too few to sample from
SETTINGS = TrainingSettings(max_force_n=MAX_FORCE_N, validations=1, max_modes=40)


def write_beam(directory, divisions=(10, 2, 2), poisson=0.45, reduced=""):
    """A 80 x 16 x 16 mm P2 beam robot clamped at x = 0; returns its TOML path."""
    directory.mkdir(parents=True, exist_ok=True)
    nodes, tets = box_mesh((80.0, 16.0, 16.0), divisions, (0.0, -8.0, -8.0))
    meshio.write(directory / "beam.vtu", meshio.Mesh(nodes, [("tetra", tets)]))
    path = directory / "beam.toml"
    path.write_text(BEAM_TOML.format(poisson=poisson,
                                     reduced=f'reduced = "{reduced}"' if reduced else ""))
    return path


@pytest.fixture(scope="module")
def beam(tmp_path_factory):
    """(robot, its reduction, the snapshot cache), trained once for the module."""
    directory = tmp_path_factory.mktemp("beam")
    robot = load_robot(write_beam(directory))
    cache = directory / "snapshots.npz"
    reduction = train_robot(robot, SETTINGS, cache=cache)
    return robot, reduction, cache


def cases(robot):
    """Untrained loads: an interior actuation; one force between features; two contacts."""
    points, normals = between_features(robot.mesh.nodes_mm, robot.mesh.surface_faces,
                                       robot.feature_nodes, robot.fixed_nodes, 3)
    inputs = robot.cable_inputs
    return [
        LoadCase(inputs(np.array([2.3, 1.7])), points[:0], np.zeros((0, 3))),
        LoadCase(inputs(np.array([4.9, 0.6])), points[:1], -0.8 * MAX_FORCE_N * normals[:1]),
        LoadCase(inputs(np.array([1.1, 3.2])), points[1:], -0.5 * MAX_FORCE_N * normals[1:]),
    ]


def test_training_is_small_and_validated(beam):
    robot, reduction, _ = beam
    info = reduction.info
    assert 5 <= info["modes"] <= SETTINGS.max_modes
    # contact equilibria were solved at every static snapshot (none on this beam buckles)
    assert info["contact_snapshots"] == SETTINGS.contact_states * info["static_snapshots"]
    assert info["sampled_elements"] < len(robot.full_fe_model.tets)
    # the point pass keeps single quadrature points, not every point of the kept elements
    per_element = robot.full_fe_model.shape_gradients.shape[1]
    assert info["sampled_points"] < 0.75 * per_element * info["sampled_elements"]
    assert len(np.unique(np.c_[reduction.elements, reduction.points], axis=0)) == len(
        reduction.points)
    assert info["ecsw_residual"] <= SETTINGS.ecsw_tolerance
    assert reduction.box.rms_error_mm < 0.5
    # validated at untrained actuations, and at each under a contact force
    assert len(info["validation_rms_mm"]) == 2 * SETTINGS.validations
    assert max(info["validation_rms_mm"]) < 0.5
    # clamped dofs stay clamped
    fixed = (3 * robot.full_fe_model.fixed_nodes[:, None] + np.arange(3)).ravel()
    assert np.abs(reduction.basis[fixed]).max() == 0.0


@pytest.mark.parametrize("index", [0, 1, 2])
def test_reduced_matches_full_on_untrained_loads(beam, index):
    robot, reduction, _ = beam
    full = robot.full_fe_model
    case = cases(robot)[index]
    errors = case_errors(full, ReducedModel(full, reduction), case, robot.mesh.surface_nodes,
                         robot.feature_nodes, robot.feature_normals)
    assert errors.displacement_mm > 1.0  # the case really deforms the beam
    assert errors.rms_mm <= 0.5
    for name, value in errors.W_relative.items():
        assert value <= 0.05, (name, value)
    if len(case.forces_n):  # held taut cables: the compliance sensing solves with
        assert errors.held_ef_relative <= 0.05
    else:
        assert np.isnan(errors.held_ef_relative)
    # equilibrium: the supports hold the same load, the cables pull the same
    assert errors.reaction_n <= 0.02 * (0.02 * 9.81 + MAX_FORCE_N)
    assert errors.tension_n <= 0.05 * 0.2


def test_robot_file_key_gives_the_reduced_model_everywhere(beam, tmp_path):
    robot, reduction, _ = beam
    (tmp_path / "models").mkdir()
    save_reduction(tmp_path / "models" / "beam.rom.npz", reduction)
    reduced_robot = load_robot(write_beam(tmp_path, reduced="models/beam.rom.npz"))
    model = reduced_robot.fe_model
    assert isinstance(model, ReducedModel)
    assert reduced_robot.config.mesh.reduced == (tmp_path / "models" / "beam.rom.npz")
    assert model.node_count == robot.full_fe_model.node_count
    inputs = robot.cable_inputs(np.array([3.0, 2.0]))
    full = solve_equilibrium(robot.full_fe_model, inputs)
    approx = solve_equilibrium(model, inputs)
    assert approx.positions_mm.shape == full.positions_mm.shape
    # calibration's linear model, through the same seam
    rows = reduced_robot.marker_points.cartesian_rows(model.node_count)
    lm_full = linear_model(robot.full_fe_model, full.positions_mm, full.cable_tensions_n, rows)
    lm_red = linear_model(model, approx.positions_mm, approx.cable_tensions_n, rows)
    np.testing.assert_allclose(lm_red.markers(approx.cable_tensions_n),
                               lm_full.markers(full.cable_tensions_n), atol=0.3)
    assert np.linalg.norm(lm_red.W_ea - lm_full.W_ea) <= 0.05 * np.linalg.norm(lm_full.W_ea)
    # a warm start from the solution converges at once
    again = solve_equilibrium(model, inputs, start_mm=approx.positions_mm)
    assert again.iterations <= 2


def test_mismatched_reduced_model_is_rejected(beam, tmp_path):
    _, reduction, _ = beam
    other_mesh = load_robot(write_beam(tmp_path / "mesh", divisions=(12, 2, 2)))
    with pytest.raises(ModelError, match="trained for another model \\(mesh"):
        reduced_model(other_mesh.full_fe_model, reduction, "beam.rom.npz")
    other_material = load_robot(write_beam(tmp_path / "nu", poisson=0.3))
    with pytest.raises(ModelError, match="material differ"):
        reduced_model(other_material.full_fe_model, reduction, "beam.rom.npz")


def test_reduced_model_holds_for_another_young_modulus(beam):
    """Forces are linear in E at a fixed Poisson's ratio, so the file is reused: a doubled E
    halves the sag under gravity in both models alike."""
    robot, reduction, _ = beam
    full = robot.full_fe_model
    stiffer = dataclasses.replace(full, material=dataclasses.replace(
        full.material, young_modulus_mpa=2 * full.material.young_modulus_mpa))
    inputs = robot.cable_inputs(np.zeros(2))
    exact = solve_equilibrium(stiffer, inputs).positions_mm
    approx = solve_equilibrium(reduced_model(stiffer, reduction), inputs).positions_mm
    sag = np.abs(exact - full.rest_nodes_mm).max()
    assert sag > 0.5
    assert np.abs(exact - approx).max() < 0.05 * sag


def test_loads_outside_the_training_box_warn(beam):
    robot, reduction, _ = beam
    model = ReducedModel(robot.full_fe_model, reduction)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        solve_equilibrium(model, robot.cable_inputs(np.array([5.5, 3.0])))  # inside: silent
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        solve_equilibrium(model, robot.cable_inputs(np.array([12.0, 0.0])))
    messages = [str(w.message) for w in caught if w.category is ReducedModelWarning]
    # the input outside the box, and the shape beyond the training's (twice its sag)
    assert len(messages) == 2
    assert "cable 'up' at 12 is outside the trained" in messages[0]
    assert "beyond its training's equilibria" in messages[1]


def test_solutions_beyond_the_trained_shapes_warn(beam, tmp_path):
    """Loads inside the box can still fold the body beyond every training equilibrium (the
    Diamond's two contacts): the solution's RMS displacement is checked against the
    training's largest, which the file keeps."""
    robot, reduction, _ = beam
    box = reduction.box
    assert 0.5 < box.max_displacement_mm < 50.0  # recorded, in mm, from the equilibria
    path = tmp_path / "beam.rom.npz"
    save_reduction(path, reduction)
    assert load_reduction(path).box.max_displacement_mm == pytest.approx(
        box.max_displacement_mm, rel=1e-12)
    inputs = robot.cable_inputs(np.array([5.5, 3.0]))
    moved = solve_equilibrium(ReducedModel(robot.full_fe_model, reduction), inputs)
    rms = np.sqrt(np.mean(np.sum((moved.positions_mm - robot.rest_nodes_mm) ** 2, axis=1)))
    assert rms <= box.max_displacement_mm  # inside the box: silent (test above)
    smaller = dataclasses.replace(reduction, box=dataclasses.replace(
        box, max_displacement_mm=0.5 * rms))
    with pytest.warns(ReducedModelWarning, match="beyond its training's equilibria"):
        solve_equilibrium(ReducedModel(robot.full_fe_model, smaller), inputs)


def test_corrupt_or_missing_file_is_a_model_error(tmp_path):
    with pytest.raises(ModelError, match="not found"):
        load_reduction(tmp_path / "none.rom.npz")
    (tmp_path / "bad.rom.npz").write_bytes(b"not a zip")
    with pytest.raises(ModelError, match="not a softforce reduced model"):
        load_reduction(tmp_path / "bad.rom.npz")


def test_early_stopped_nnls_is_scipys_at_zero_tolerance_and_sparse_otherwise():
    rng = np.random.default_rng(3)
    C = rng.uniform(0.0, 1.0, (60, 200))
    truth = np.zeros(200)
    truth[rng.choice(200, 15, replace=False)] = rng.uniform(0.5, 2.0, 15)
    b = C @ truth + rng.normal(0, 1e-3, 60)
    exact = sparse_nnls(C, b, tolerance=0.0)
    reference, _ = nnls(C, b)
    dense = np.zeros(200)
    dense[exact.elements] = exact.weights
    np.testing.assert_allclose(dense, reference, atol=1e-6)
    early = sparse_nnls(C, b, tolerance=1e-2)
    assert early.relative_residual <= 1e-2
    assert len(early.elements) < np.count_nonzero(reference)
    assert np.all(early.weights > 0)


@pytest.mark.parametrize("seed", [6, 7, 8])
def test_nnls_that_drops_columns_on_the_way_is_still_scipys(seed):
    # correlated columns and a target outside their cone: many columns enter and leave
    rng = np.random.default_rng(seed)
    C = rng.normal(size=(150, 20)) @ rng.normal(size=(20, 120)) + 0.1 * rng.normal(
        size=(150, 120))
    b = rng.normal(size=150)
    dense = np.zeros(120)
    exact = sparse_nnls(C, b, tolerance=0.0)
    dense[exact.elements] = exact.weights
    reference, _ = nnls(C, b)
    np.testing.assert_allclose(C @ dense, C @ reference, atol=1e-8 * np.linalg.norm(b))
    np.testing.assert_allclose(dense, reference, atol=1e-6 * np.abs(reference).max())


@pytest.mark.parametrize("seed", [1, 2])
def test_nnls_whose_factor_grows_and_shrinks_many_times_is_still_scipys(seed):
    # 240-250 active columns, about a hundred leaving on the way: the factor's buffer
    # regrows past its first 64 columns, and every exit restores its padding
    rng = np.random.default_rng(seed)
    C = rng.normal(size=(400, 60)) @ rng.normal(size=(60, 500)) + 0.05 * rng.normal(
        size=(400, 500))
    b = rng.normal(size=400)
    exact = sparse_nnls(C, b, tolerance=0.0)
    reference, _ = nnls(C, b, maxiter=10_000)
    assert len(exact.elements) == np.count_nonzero(reference) > 200
    dense = np.zeros(500)
    dense[exact.elements] = exact.weights
    np.testing.assert_allclose(dense, reference, atol=1e-8 * np.abs(reference).max())


def test_ecsw_system_stacks_each_block_in_its_state_norm_scaled_to_unit_target():
    # blocks of r rows, norms that keep r, r - 1 or r - 2 of them (taut cables held), a
    # zero target left out: the system is the blocks stacked as the method describes
    rng = np.random.default_rng(9)
    r, columns, directions = 4, 7, 2
    states = rng.normal(size=(3, 5, 3))
    data = SimpleNamespace(responses=rng.normal(size=(9, 6)), response_states=np.array([0, 2]))
    basis = rng.normal(size=(9, r))
    own = {float(x[0, 0]): rng.uniform(size=(r, columns)) for x in states}
    own[float(states[1, 0, 0])][:] = 0.0
    tangent = rng.uniform(size=(r * directions, columns))

    def contributions(x, directions_):
        return own[float(x[0, 0])] if directions_ is None else tangent

    norms = [None, rng.normal(size=(r - 1, r)), rng.normal(size=(r - 2, r))]
    C, b, targets = ecsw_system(basis, data, states, norms, directions, contributions)
    expected_C, expected_b = [], []
    blocks = [(own[float(x[0, 0])], k) for k, x in enumerate(states)]
    blocks += [(part, k) for k in (0, 2) for part in np.split(tangent, directions)]
    for (block, owner), target in zip(blocks, targets, strict=True):
        np.testing.assert_array_equal(target, block.sum(axis=1))
        if norms[owner] is not None:
            block, target = norms[owner] @ block, norms[owner] @ target
        if np.linalg.norm(target) > 0:
            expected_C.append(block / np.linalg.norm(target))
            expected_b.append(target / np.linalg.norm(target))
    assert C.shape == (4 + 2 + 2 * (4 + 2), columns)
    np.testing.assert_allclose(C, np.vstack(expected_C), rtol=1e-14)
    np.testing.assert_allclose(b, np.concatenate(expected_b), rtol=1e-14)
    # the second pass: given targets are used, not the blocks' sums (the second state's
    # block, its own sum zero, now enters with the r - 1 rows of its norm)
    given = [t + 1.0 for t in targets]
    _, b_given, kept = ecsw_system(basis, data, states, norms, directions, contributions, given)
    assert all(k is g for k, g in zip(kept, given, strict=True))
    assert len(b_given) == len(b) + r - 1
    np.testing.assert_allclose(b_given[:r], given[0] / np.linalg.norm(given[0]), rtol=1e-14)


def test_pod_recovers_a_known_subspace():
    rng = np.random.default_rng(4)
    subspace = np.linalg.qr(rng.normal(size=(300, 4)))[0]
    snapshots = subspace @ rng.normal(size=(4, 40)) + 1e-9 * rng.normal(size=(300, 40))
    basis, singular = pod_basis(snapshots, tolerance=1e-8)
    assert basis.shape == (300, 4)
    np.testing.assert_allclose(basis.T @ basis, np.eye(4), atol=1e-12)
    assert projection_errors(basis, snapshots).max() < 1e-7
    assert singular[4] < 1e-6 * singular[0]


def test_the_equilibria_keep_their_modes_against_many_responses():
    rng = np.random.default_rng(5)
    d = 400
    states = np.linalg.qr(rng.normal(size=(d, 3)))[0] @ rng.normal(size=(3, 6))
    # 300 responses of much larger norm in 60 other directions, a little of the states' span
    responses = 50.0 * np.linalg.qr(rng.normal(size=(d, 60)))[0] @ rng.normal(size=(60, 300))
    responses += 0.01 * states @ rng.normal(size=(6, 300))
    states[:10] = responses[:10] = 0.0  # clamped dofs
    basis, _ = successive_pod([states, responses], 1e-10, max_modes=20)
    assert basis.shape == (d, 20)
    np.testing.assert_allclose(basis.T @ basis, np.eye(20), atol=1e-12)
    assert projection_errors(basis, states).max() < 1e-10  # the equilibria exactly
    assert np.abs(basis[:10]).max() == 0.0
    # one POD of everything, capped alike, spends its modes on the responses
    assert projection_errors(pod_basis(np.hstack([states, responses]), 1e-10, 20)[0],
                             states).max() > 0.1
    # a second group (the loaded states' responses) keeps its modes against a larger third
    loaded = np.linalg.qr(rng.normal(size=(d, 8)))[0] @ rng.normal(size=(8, 40))
    loaded[:10] = 0.0
    basis, _ = successive_pod([states, loaded, responses, states[:, :0]], 1e-10, 20)
    assert projection_errors(basis, np.hstack([states, loaded])).max() < 1e-10
    assert projection_errors(basis, responses).max() > 0.1
    assert np.abs(basis[:10]).max() == 0.0


def test_training_presses_away_from_the_clamp(beam):
    robot, _, _ = beam
    sites = contact_sites(robot, SETTINGS.contact_states)
    rest = robot.mesh.nodes_mm
    clamped = rest[robot.fixed_nodes]
    distance = np.linalg.norm(rest[sites.nodes][:, None] - clamped[None], axis=2).min(axis=1)
    assert distance.min() > CLAMP_CLEARANCE_MM
    assert set(sites.nodes) <= set(robot.mesh.surface_nodes)
    # the rest of the surface beyond the clearance is all eligible
    beyond = robot.mesh.surface_nodes[rest[robot.mesh.surface_nodes, 0] > 20.0]
    assert set(beyond) <= set(sites.nodes)
    np.testing.assert_allclose(np.linalg.norm(sites.normals, axis=1), 1.0, atol=1e-12)


def test_training_snapshots_on_the_cores_are_those_in_turn(beam, monkeypatch):
    """(snapshots.collect) Each equilibrium's responses, loaded states and contact equilibria
    computed in worker processes are those computed in turn in this process, in the same
    order, with the same random loads; progress reaches its total."""
    robot, _, _ = beam
    specs = robot.cable_specs
    low = np.array([c.min for c in specs])
    high = low + SETTINGS.box_fraction * (np.array([c.max for c in specs]) - low)
    actuations = actuation_design(low, high, SETTINGS.extra_actuations)
    sites = contact_sites(robot, SETTINGS.contact_states)

    def training_set() -> tuple[TrainingSet, list[tuple[int, int]]]:
        steps: list[tuple[int, int]] = []
        data = collect(robot.full_fe_model, tuple(c.control for c in specs), actuations,
                       robot.feature_nodes, robot.feature_normals, MAX_FORCE_N,
                       SETTINGS.response_states, lambda done, total: steps.append((done, total)),
                       sites)
        return data, steps

    on_cores, steps = training_set()
    assert steps[-1] == (2 * len(actuations), 2 * len(actuations))
    monkeypatch.setattr(processes, "worker_count", lambda tasks: 1)
    in_turn, _ = training_set()
    assert len(in_turn.contact_mm) > len(actuations)
    for field in dataclasses.fields(TrainingSet):
        np.testing.assert_allclose(getattr(on_cores, field.name), getattr(in_turn, field.name),
                                   rtol=1e-9, atol=1e-12, err_msg=field.name)


def test_cli_reduce_resumes_from_snapshots_and_writes_a_usable_file(beam, tmp_path):
    _, trained, cache = beam
    toml = write_beam(tmp_path)
    output = tmp_path / "beam.rom.npz"
    # a training stopped after its snapshots: the command picks them up
    resumed = tmp_path / "beam.rom.npz.snapshots.npz"
    shutil.copy(cache, resumed)
    result = softforce("model", "reduce", toml, "-o", output, "--max-force", "0.1",
                       "--max-modes", str(SETTINGS.max_modes), "--json")
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["modes"] == trained.mode_count
    assert summary["start_equilibria"] == len(trained.starts.inputs)
    assert not resumed.exists()  # deleted without --keep-snapshots
    reduction = load_reduction(output)
    np.testing.assert_allclose(np.abs(reduction.basis), np.abs(trained.basis), atol=1e-8)
    robot = load_robot(toml)
    assert isinstance(reduced_model(robot.full_fe_model, reduction), ReducedModel)
    again = softforce("model", "reduce", toml, "-o", output)
    assert_one_line_error(again, "already exists")
    bad = softforce("model", "reduce", toml, "-o", tmp_path / "x.rom.npz", "--element", "q9")
    assert_one_line_error(bad, "--element 'q9' unknown")
    no_modes = softforce("model", "reduce", toml, "-o", tmp_path / "y.rom.npz", "--max-modes",
                         "0")
    assert_one_line_error(no_modes, "--max-modes 0 must be at least 1")
    for force in ("nan", "0", "-1"):  # NaN was trained on (for minutes) before
        no_force = softforce("model", "reduce", toml, "-o", tmp_path / "y.rom.npz",
                             "--max-force", force)
        assert_one_line_error(no_force, "must be a positive number of newtons")
    assert not (tmp_path / "y.rom.npz").exists()
    loose = softforce("model", "reduce", toml, "-o", tmp_path / "z.rom.npz",
                      "--ecsw-tolerance", "1.5")
    assert_one_line_error(loose, "--ecsw-tolerance 1.5 must be in [0, 1)")
    # a passive body: its training would span no actuation box (it had failed reshaping one)
    text = toml.read_text()
    passive = tmp_path / "passive.toml"
    passive.write_text(text[:text.index("[[cable]]")] + text[text.index("[features]"):])
    no_cable = softforce("model", "reduce", passive, "-o", tmp_path / "p.rom.npz")
    assert_one_line_error(no_cable, "has no [[cable]]")


def test_a_sampling_too_loose_for_the_robot_is_reported(beam):
    """A tolerance whose points no longer hold the beam's stiffness warns with the
    validation's error (0.3: about 0.6 mm, 7% of its 9.1 mm shape); one whose reduced model
    misses its own training equilibria by more than half the shape (0.6: 19 mm, or no
    equilibrium at all, as Newton's path happens to go) or finds none (0.8) stops with one
    line; the fixture's 1e-3 does neither."""
    robot, trained, cache = beam
    assert trained.box.rms_error_mm < 0.01 * trained.box.max_displacement_mm
    with pytest.warns(ReducedModelWarning, match="its sampling is too loose"):
        loose = train_robot(robot, dataclasses.replace(SETTINGS, ecsw_tolerance=0.3),
                            cache=cache)
    assert loose.box.rms_error_mm > 0.05 * loose.box.max_displacement_mm
    for tolerance in (0.6, 0.8):
        with pytest.raises(ModelError, match=r"at one of its own training actuations.*its "
                                             r"sampling is too loose for this robot"):
            train_robot(robot, dataclasses.replace(SETTINGS, ecsw_tolerance=tolerance),
                        cache=cache)


def test_training_at_ecsw_tolerance_zero_keeps_every_point(beam):
    """No hyper-reduction at tolerance 0 (the exact Galerkin projection, for studies of the
    basis alone): every quadrature point at weight 1, on the same basis."""
    robot, trained, cache = beam
    exact = train_robot(robot, dataclasses.replace(SETTINGS, ecsw_tolerance=0.0,
                                                   validations=0), cache=cache)
    m, q = robot.full_fe_model.shape_gradients.shape[:2]
    assert exact.weights.shape == (m * q,) and np.all(exact.weights == 1.0)
    assert len(np.unique(exact.elements * q + exact.points)) == m * q
    np.testing.assert_allclose(exact.basis, trained.basis, atol=1e-12)
    assert len(trained.weights) < m * q


def test_feature_responses_span_the_compliance_columns(beam):
    """W at rest from the reduced model equals the full one on the trained feature rows."""
    robot, reduction, _ = beam
    full = robot.full_fe_model
    model = ReducedModel(full, reduction)
    features = Attachment.at_nodes(robot.feature_nodes)
    rows = features.directional_rows(robot.feature_normals, full.node_count)
    from softforce_cli.fem.compliance import compliance, linearize

    W = []
    for m in (full, model):
        eq = solve_equilibrium(m, robot.cable_inputs(np.zeros(2)))
        W.append(compliance(linearize(m, eq.positions_mm, eq.cable_tensions_n), rows,
                            rows[:3]).W_ef)
    assert np.linalg.norm(W[1] - W[0]) <= 0.02 * np.linalg.norm(W[0])


@pytest.mark.parametrize("element", ["p2", "p2-p0"])
def test_every_point_at_unit_weight_is_the_galerkin_projection(beam, element):
    """With every quadrature point sampled at weight 1 (the main and, for P2-P0, the lambda
    rule's points), the hyper-reduced forces and tangent are exactly V^T g(x) and V^T K V of
    the full model's own assembly."""
    robot, trained, _ = beam
    full = with_element(robot, element).full_fe_model
    elements, points, weights = every_point(full)  # what training at ECSW tolerance 0 keeps
    everything = dataclasses.replace(trained, element=element, elements=elements,
                                     points=points, weights=weights)
    model = ReducedModel(full, everything)
    V = everything.basis
    x = full.rest_nodes_mm + (V @ np.linspace(-0.3, 0.4, V.shape[1])).reshape(-1, 3)
    internal, stiffness = full.internal_forces_and_stiffness(x)
    free = full.free_dofs
    projected = V[free].T @ (stiffness @ V[free])
    # the float64 tangent is exact; the default float32 one rounds its per-update products
    for space, tolerance in ((ReducedModel(full, everything, np.float64).coordinates, 1e-12),
                             (model.coordinates, 1e-5)):
        forces, tangent = space.forces_and_tangent(x, np.zeros(len(full.cables)))
        assert np.allclose(forces, V.T @ internal.ravel(), rtol=1e-9, atol=1e-9)
        assert np.linalg.norm(tangent - projected) <= tolerance * np.linalg.norm(projected)


@pytest.mark.parametrize("law", ["corotational", "neo-hookean", "linear"])
def test_law_tangent_factors_are_its_tangent(law):
    """shift I + sum_j d_j z_j z_j^T is the law's tangent for every part of it, also for
    compressed, sheared and inverted points; an evaluation's energy and stress, formed
    before the factors from the same polar decomposition, are the law's own."""
    rng = np.random.default_rng(3)
    F = np.eye(3) + 0.3 * rng.standard_normal((60, 3, 3))
    F[:20] *= 0.6
    F[20:23] = -F[20:23] if law == "corotational" else F[20:23]
    material = Material(law, 0.18, 0.45)
    for part in ("all", "mu", "lambda"):
        stress, tangent = material.stress_and_tangent(F, part)
        tangent = tangent.reshape(-1, 9, 9)
        evaluation = material.evaluate(F, part)
        factors = evaluation.factors
        energy, plain_stress = material.energy_and_stress(F, part)
        assert np.array_equal(evaluation.energy, energy, equal_nan=True)
        assert np.array_equal(evaluation.stress, plain_stress, equal_nan=True)
        assert np.array_equal(stress, plain_stress, equal_nan=True)
        # a Neo-Hookean point with det F <= 0 has NaN stress and tangent, and NaN factors
        finite = np.isfinite(tangent).all(axis=(1, 2))
        assert finite.sum() >= 50 and np.isnan(factors.dense()[~finite]).all()
        error = np.abs(factors.dense() - tangent)[finite].max()
        assert error <= 1e-13 * np.abs(tangent[finite]).max()
        if law != "linear":  # the linear law's tangent is constant and positive
            assert (np.linalg.eigvalsh(tangent[finite])[:, 0] < 0).any()  # indefinite too
    if law == "corotational":
        assert factors.rows.shape[1] == 4  # 2 mu I + rank 4


@pytest.mark.parametrize("element", ["p2", "p2-p0"])
@pytest.mark.parametrize("law", ["corotational", "neo-hookean"])
@pytest.mark.parametrize("shape", ["squeezed", "half stretched"])
def test_factored_reduced_tangent_is_the_plain_sum(beam, element, law, shape):
    """ReducedTangent's shift term plus signed syrk updates equal sum_p w_p G_p^T A_p G_p
    term by term (float64 to 1e-10, float32 to 1e-5), in a squeezed state where most
    corotational A_p are indefinite (both signs of the factored terms), and in one whose far
    half is stretched 40%, where the corotational rotation terms change sign along the beam
    (tr(S - I) > 2 mu / lam): factors of one sign everywhere and of varying sign both."""
    robot, reduction, _ = beam
    full = with_element(robot, element).full_fe_model
    full = dataclasses.replace(full, material=dataclasses.replace(full.material, law=law))
    reduction = dataclasses.replace(reduction, element=element)
    x = full.rest_nodes_mm.copy()
    along = full.rest_nodes_mm[:, 0]  # the clamped end at x = 0
    if shape == "squeezed":  # 25% shorter along the beam, with a bend
        x[:, 0] *= 0.75
        x[:, 2] += 1e-3 * along**2
    else:
        x[:, 0] += 0.4 * np.maximum(along - 0.5 * along.max(), 0.0)
    for dtype, tolerance in ((np.float64, 1e-10), (np.float32, 1e-5)):
        space = ReducedModel(full, reduction, dtype).coordinates
        F = deformation_gradients(x, space.tets, space.gradients)[:, 0]
        tangents = full.constitutive_at(F, space.rule_points, with_tangent=True)[1]
        weighted = space.point_weights[:, :, None] * tangents
        plain = np.einsum("pir,pij,pjs->rs", space.points, weighted, space.points)
        _, tangent = space.forces_and_tangent(x, np.zeros(len(full.cables)))
        assert np.linalg.norm(tangent - plain) <= tolerance * np.linalg.norm(plain)
    if shape == "squeezed":
        assert (np.linalg.eigvalsh(tangents)[:, 0] < 0).mean() > 0.3
    elif law == "corotational":
        negative = full.material.evaluate(F, "all").factors.coefficients < 0
        varying = negative.any(axis=0) & ~negative.all(axis=0)
        assert varying[:3].all() and not negative[:, 3].any()


def test_float32_tangent_keeps_newtons_answer_and_rate(beam):
    """The tangent's float32 products change neither the equilibrium (set by the float64
    forces) nor Newton's iteration count (its rate), on an untrained load with a contact."""
    robot, reduction, _ = beam
    full = robot.full_fe_model
    case = cases(robot)[1]
    points = Attachment.at_nodes(robot.feature_nodes[:1])
    loads = PointLoads(points, case.forces_n)
    # to the full model's tolerance: the reduced one's (1e-3 mm) ends before the rate shows;
    # from rest (the start library lands within 3 iterations, before the rate shows)
    tight = SolverSettings(step_tolerance_mm=1e-7)
    answers = [solve_equilibrium(ReducedModel(full, reduction, dtype), case.inputs, loads,
                                 start_mm=full.rest_nodes_mm, settings=tight)
               for dtype in (np.float64, np.float32)]
    assert answers[1].iterations == answers[0].iterations >= 6
    assert np.abs(answers[1].positions_mm - answers[0].positions_mm).max() < 1e-6
    # the same residuals on the way (to 0.1% here), quadratic at the end (9.6e-3, 1.2e-4,
    # 1.9e-7 N)
    history = np.array(answers[1].residual_history_n)
    np.testing.assert_allclose(history, answers[0].residual_history_n, rtol=1e-2)
    assert history[-1] < 1e-2 * history[-2] and history[-2] < 2e-2 * history[-3]


def _plain_newton(model, inputs, loads=None, iterations=30):
    """Equilibrium by undamped Newton on the KKT system [K, -H^T; H, 0] with every cable
    taut, through node positions only: the forces and tangent at lifted positions, the
    cables' dense (a, 3n) rows projected afterwards (what fem.statics did before its states).
    Returns (positions (n, 3), tensions (a,))."""
    space = model.coordinates
    x = model.rest_nodes_mm.copy()
    lam = np.zeros(len(model.cables))
    applied = space.project_loads(loads)
    for _ in range(iterations):
        internal, tangent = space.forces_and_tangent(x, lam)
        tangent = tangent.toarray() if hasattr(tangent, "toarray") else tangent
        rows = np.asarray(space.project_rows(model.cable_jacobian(x)))
        gap = inputs.values - model.cable_shortenings(x)
        residual = applied - internal + rows.T @ lam
        if np.abs(residual).max() < 1e-11 and np.abs(gap).max() < 1e-11:
            break
        a = len(lam)
        system = np.block([[tangent, -rows.T], [rows, np.zeros((a, a))]])
        solution = np.linalg.solve(system, np.concatenate([residual, gap]))
        x = x + space.lift(solution[:-a]).reshape(-1, 3)
        lam = lam + solution[-a:]
    return x, lam


def test_reduced_state_evaluates_as_its_lifted_positions(beam):
    """A solver state (F = F_rest + G q, cables on their nodes' rows of V, no lift) gives the
    forces, tangent, cable lengths and rows that the node positions give through the full
    arrays (the sampled points' sparse gradient map, the (a, 3n) cable rows projected)."""
    robot, reduction, _ = beam
    model = ReducedModel(robot.full_fe_model, reduction)
    space = model.coordinates
    q = np.linspace(-4.0, 6.0, space.size)
    state = space.state().moved(q, 0.5)
    x = model.rest_nodes_mm + (reduction.basis @ (0.5 * q)).reshape(-1, 3)
    np.testing.assert_allclose(state.positions_mm, x, atol=1e-12)
    assert np.abs(x - model.rest_nodes_mm).max() > 1.0  # a real deformation
    energy, forces = state.energy_and_forces()
    plain_energy, plain_forces = space.energy_and_forces(x)
    assert energy == pytest.approx(plain_energy, rel=1e-11)
    np.testing.assert_allclose(forces, plain_forces, rtol=1e-9, atol=1e-11)
    tensions = np.array([0.7, 0.2])
    np.testing.assert_allclose(state.tangent(tensions),
                               space.forces_and_tangent(x, tensions)[1], rtol=1e-9, atol=1e-9)
    shortenings, rows = state.cables()
    np.testing.assert_allclose(shortenings, model.cable_shortenings(x), atol=1e-12)
    np.testing.assert_allclose(rows, space.project_rows(model.cable_jacobian(x)), atol=1e-12)
    # and a state made from positions is their projection on the basis
    np.testing.assert_allclose(space.state(x).q, 0.5 * q, atol=1e-10)


@pytest.mark.parametrize("reduced", [False, True])
def test_static_solve_is_plain_newtons_equilibrium(beam, reduced):
    """fem.statics (states, reused evaluations, line search, held starting tensions) lands
    on the equilibrium of an undamped Newton through node positions, for the full and the
    reduced model, on an untrained load with both cables taut."""
    robot, reduction, _ = beam
    model = ReducedModel(robot.full_fe_model, reduction) if reduced else robot.full_fe_model
    inputs = robot.cable_inputs(np.array([4.0, 3.0]))
    loads = PointLoads(Attachment.at_nodes(robot.feature_nodes[:1]), cases(robot)[1].forces_n)
    fast = solve_equilibrium(model, inputs, loads)
    x, lam = _plain_newton(model, inputs, loads)
    assert np.all(lam > 0.01)  # taut: the plain Newton's active set is the solver's
    assert np.abs(fast.positions_mm - model.rest_nodes_mm).max() > 1.0
    np.testing.assert_allclose(fast.positions_mm, x, atol=1e-7)
    np.testing.assert_allclose(fast.cable_tensions_n, lam, atol=1e-8)
    np.testing.assert_allclose(fast.cable_shortenings_mm, inputs.values, atol=1e-9)


@pytest.mark.parametrize("reduced", [False, True])
def test_start_at_an_equilibrium_is_converged_at_once(beam, reduced):
    """Starting from an equilibrium of the same inputs, the tensions that hold the start
    balance it: no Newton step is taken (before: one, at zero tensions)."""
    robot, reduction, _ = beam
    model = ReducedModel(robot.full_fe_model, reduction) if reduced else robot.full_fe_model
    inputs = robot.cable_inputs(np.array([3.0, 2.0]))
    first = solve_equilibrium(model, inputs)
    again = solve_equilibrium(model, inputs, start_mm=first.positions_mm)
    assert again.iterations == 1
    np.testing.assert_allclose(again.cable_tensions_n, first.cable_tensions_n, atol=1e-7)
    np.testing.assert_allclose(again.positions_mm, first.positions_mm, atol=1e-12)


@pytest.mark.parametrize("reduced", [False, True])
def test_an_equilibrium_forms_positions_and_reactions_when_first_read(beam, reduced,
                                                                      monkeypatch):
    """A solve returns its state: a reduced solve never lifts its coordinates to the nodes,
    and the node positions and support reactions are formed when first read. The reactions
    balance every load exactly and are the elastic forces the full model finds at the lifted
    positions, up to the Galerkin residual's share; a pickle carries both without the model.
    A next solve from it starts at its state and, for the reduced model (the full model's
    large sparse factor is not kept), takes its first Newton step on its last tangent: one
    tangent fewer than from its positions, for the same answer, and the earlier solve's
    factorisation left as it was."""
    robot, reduction, _ = beam
    model = ReducedModel(robot.full_fe_model, reduction) if reduced else robot.full_fe_model
    inputs = robot.cable_inputs(np.array([4.0, 3.0]))
    loads = PointLoads(Attachment.at_nodes(robot.feature_nodes[:1]), cases(robot)[1].forces_n)
    solved = solve_equilibrium(model, inputs, loads)
    if reduced:
        assert "positions_mm" not in vars(solved.state)
    positions, reactions = solved.positions_mm, solved.reaction_forces_n
    pulls = (model.cable_jacobian(positions).T @ solved.cable_tensions_n).reshape(-1, 3)
    applied = solved.external_n + pulls
    np.testing.assert_allclose(reactions.sum(axis=0), -applied.sum(axis=0), atol=1e-10)
    full = robot.full_fe_model
    elastic = -(applied - full.internal_forces(positions))[full.fixed_nodes]
    scale = np.abs(elastic).max()
    # (0.9% on this beam: the free nodes beside the clamp keep the Galerkin residual)
    assert np.abs(reactions - elastic).max() < (0.02 if reduced else 1e-12) * scale
    carried = pickle.loads(pickle.dumps(solved))
    assert carried.state is None
    np.testing.assert_array_equal(carried.positions_mm, positions)
    np.testing.assert_array_equal(carried.reaction_forces_n, reactions)
    moved = robot.cable_inputs(np.array([4.5, 3.0]))
    assert (solved.tangent is not None) == reduced
    probe = np.random.default_rng(0).normal(size=model.coordinates.size)
    before = solved.tangent.factorization.solve(probe) if reduced else None
    tangents = []
    state_type = type(solved.state)
    plain_tangent_of = state_type.tangent
    monkeypatch.setattr(state_type, "tangent",
                        lambda self, tensions: tangents.append(1) or plain_tangent_of(self,
                                                                                   tensions))
    from_previous = solve_equilibrium(model, moved, loads, start=solved)
    chained = len(tangents)
    from_positions = solve_equilibrium(model, moved, loads, start_mm=positions)
    # the full model keeps no factor (large): it continues at the state with Newton's step
    assert chained == len(tangents) - chained - reduced and chained >= 1
    assert from_previous.iterations == from_positions.iterations
    np.testing.assert_allclose(from_previous.positions_mm, from_positions.positions_mm,
                               atol=1e-6)
    if reduced:
        np.testing.assert_array_equal(solved.tangent.factorization.solve(probe), before)
    with pytest.raises(ValueError, match="not both"):
        solve_equilibrium(model, moved, start_mm=positions, start=solved)


@pytest.mark.parametrize("reduced", [False, True])
def test_compliance_cable_rows_are_the_projected_jacobian(beam, reduced):
    """W_aa, W_af and delta_a_free from the cables' projected rows equal those from the dense
    (a, 3n) cable Jacobian through node responses K^-1 H^T."""
    from softforce_cli.fem.compliance import compliance, linearize

    robot, reduction, _ = beam
    model = ReducedModel(robot.full_fe_model, reduction) if reduced else robot.full_fe_model
    eq = solve_equilibrium(model, robot.cable_inputs(np.array([4.0, 1.0])))
    lin = linearize(model, eq.positions_mm, eq.cable_tensions_n)
    features = Attachment.at_nodes(robot.feature_nodes)
    forces = features.directional_rows(robot.feature_normals, model.node_count)[:2]
    W = compliance(lin, features.directional_rows(robot.feature_normals, model.node_count),
                   forces)
    H = model.cable_jacobian(eq.positions_mm)
    responses = lin.responses(np.vstack([H, forces.toarray()]))
    scale = np.abs(H @ responses).max()
    np.testing.assert_allclose(W.W_aa, (H @ responses)[:, :2], atol=1e-10 * scale)
    np.testing.assert_allclose(W.W_af, (H @ responses)[:, 2:], atol=1e-10 * scale)
    np.testing.assert_allclose(W.delta_a_free, model.cable_shortenings(eq.positions_mm)
                               + H @ lin.free_motion_mm.ravel(), atol=1e-10)


@pytest.mark.parametrize("reduced", [False, True])
def test_held_compliance_solves_the_bordered_system(beam, reduced):
    """Compliance.held_ef, the Schur complement W_ef - W_eh W_hh^-1 W_hf, equals the
    effectors' motion from the saddle-point system [K H_h^T; H_h 0] [u; mu] = [H_f^T; 0]
    (the held cables' lengths fixed by multipliers), solved whole; holding no cable leaves
    W_ef."""
    from softforce_cli.fem.compliance import compliance, linearize

    robot, reduction, _ = beam
    model = ReducedModel(robot.full_fe_model, reduction) if reduced else robot.full_fe_model
    eq = solve_equilibrium(model, robot.cable_inputs(np.array([4.0, 1.0])))
    lin = linearize(model, eq.positions_mm, eq.cable_tensions_n)
    features = Attachment.at_nodes(robot.feature_nodes)
    effectors = features.directional_rows(robot.feature_normals, model.node_count)
    forces = features.directional_rows(-robot.feature_normals, model.node_count)[3:5]
    W = compliance(lin, effectors, forces)
    space = model.coordinates
    _, K = space.forces_and_tangent(eq.positions_mm, eq.cable_tensions_n)
    K = K.toarray() if sp.issparse(K) else np.asarray(K)

    def projected(rows) -> np.ndarray:
        rows = space.project_rows(rows)
        return rows.toarray() if sp.issparse(rows) else np.asarray(rows)

    cables = projected(model.cable_jacobian(eq.positions_mm))
    for held in (np.array([True, True]), np.array([True, False]), np.array([False, False])):
        H = cables[held]
        bordered = np.block([[K, H.T], [H, np.zeros((len(H), len(H)))]])
        rhs = np.vstack([projected(forces).T, np.zeros((len(H), forces.shape[0]))])
        motion = np.linalg.solve(bordered, rhs)[: len(K)]
        expected = projected(effectors) @ motion
        np.testing.assert_allclose(W.held_ef(held), expected,
                                   atol=1e-9 * np.abs(expected).max())
    np.testing.assert_array_equal(W.held_ef(np.array([False, False])), W.W_ef)


def test_sensing_linearisation_works_in_the_reduced_coordinates(beam):
    """estimation.linear_model on a reduced model: its compliance and eq. 6 configuration
    equal fem.compliance's at the same configuration, and neither the configuration it was
    made at nor the one it moves to forms all the node positions (a lift reads all of V,
    more than the rest of a reduced update): they answer for the nodes asked about."""
    from softforce_cli.estimation.linear_model import LinearizedModel
    from softforce_cli.fem.compliance import compliance, linearize

    robot, reduction, _ = beam
    model = ReducedModel(robot.full_fe_model, reduction)
    eq = solve_equilibrium(model, robot.cable_inputs(np.array([3.0, 2.0])))
    state = model.coordinates.state(eq.positions_mm)
    nodes = robot.feature_nodes
    linear = LinearizedModel(model, state, eq.cable_tensions_n, watched_nodes=nodes)
    effectors = Attachment.at_nodes(nodes).directional_rows(robot.feature_normals,
                                                            model.node_count)
    contact, direction = Attachment.at_nodes(nodes[3:4]), -robot.feature_normals[3:4]
    responses = linear.force_responses(contact, direction)
    cached = linear.compliance(effectors, responses)
    direct = compliance(linearize(model, eq.positions_mm, eq.cable_tensions_n), effectors,
                        contact.directional_rows(direction, model.node_count))
    for name in ("W_ea", "W_ef", "W_aa", "W_af", "delta_e_free", "delta_a_free"):
        expected = getattr(direct, name)
        np.testing.assert_allclose(getattr(cached, name), expected, rtol=1e-8,
                                   atol=1e-9 * np.abs(expected).max(), err_msg=name)
    moved = linear.configuration(eq.cable_tensions_n + 0.01, responses, np.array([0.05]))
    at_nodes = moved.nodes_mm(nodes)
    assert "positions_mm" not in state.__dict__ and "positions_mm" not in moved.__dict__
    assert 0.01 < linear.moved_mm(at_nodes) < 5.0
    np.testing.assert_allclose(at_nodes, moved.positions_mm[nodes], atol=1e-12)


def test_held_starting_tensions_balance_the_start_and_ignore_idle_cables():
    """The starting tensions are the non-negative least-squares balance of the start's
    residual (scipy's nnls on the whole system as reference); a cable moving no coordinate
    (on clamped nodes only) holds nothing, and a cable that would have to push stays at 0."""
    from softforce_cli.fem.statics import _Evaluation, _held_tensions

    rng = np.random.default_rng(5)
    rows = np.zeros((3, 40))
    rows[0, :6] = rng.normal(size=6)
    rows[1, 4:10] = rng.normal(size=6)  # rows[2] stays 0: an idle cable
    truth = np.array([0.8, 0.3, 0.0])
    internal = rows.T @ truth + rng.normal(scale=1e-3, size=40)
    current = _Evaluation(0.0, internal, np.zeros(3), rows)
    controlled = np.ones(3, dtype=bool)
    held = _held_tensions(current, np.zeros(40), controlled, np.zeros(3))
    reference, _ = nnls(rows.T, internal)
    np.testing.assert_allclose(held, reference, atol=1e-12)
    np.testing.assert_allclose(held, truth, atol=1e-2)
    assert held[2] == 0.0
    # pushing is not holding: the opposite load leaves every cable slack
    assert np.all(_held_tensions(dataclasses.replace(current, internal=-internal),
                                 np.zeros(40), controlled, np.zeros(3)) == 0.0)
    idle = _Evaluation(0.0, internal, np.zeros(1), np.zeros((1, 40)))
    assert _held_tensions(idle, np.zeros(40), controlled[:1], np.zeros(1))[0] == 0.0


def test_input_sensitivities_solve_the_saddle_point_system():
    """dq/du for a displacement-held and a force-controlled cable, against the saddle-point
    system [K, -H_d^T; H_d, 0] [dq; dlam] = [H_f^T dT; du] solved whole."""
    rng = np.random.default_rng(3)
    c = 12
    root = rng.normal(size=(c, c))
    K = root @ root.T + c * np.eye(c)
    H = rng.normal(size=(3, c))
    held = np.array([True, False, True])
    J = input_sensitivities(H, np.linalg.solve(K, H.T), held)
    system = np.block([[K, -H[held].T], [H[held], np.zeros((2, 2))]])
    for cable in range(3):
        rhs = np.zeros(c + 2)
        if held[cable]:
            rhs[c + int(np.flatnonzero(np.flatnonzero(held) == cable)[0])] = 1.0
        else:
            rhs[:c] = H[cable]
        np.testing.assert_allclose(J[:, cable], np.linalg.solve(system, rhs)[:c], atol=1e-12)


def test_energy_weight_measures_the_held_displacement_error():
    """|M df|^2 is df . dq, dq from the saddle-point system [K, H^T; H, 0] solved whole, for
    a tangent that is indefinite until the held rows stabilise it (the cable-held Diamond);
    with nothing held the same K has no energy norm."""
    rng = np.random.default_rng(5)
    c = 10
    root = rng.normal(size=(c, c))
    H = rng.normal(size=(2, c))
    # positive on H's null space, negative along H's rows
    null = np.linalg.svd(H)[2][2:]
    K = null.T @ (root[:8, :8] @ root[:8, :8].T + np.eye(8)) @ null - 3.0 * H.T @ H
    assert np.linalg.eigvalsh(K).min() < 0.0
    M = energy_weight(K, H)
    assert M.shape == (c - 2, c)
    system = np.block([[K, H.T], [H, np.zeros((2, 2))]])
    for _ in range(3):
        df = rng.normal(size=c)
        dq = np.linalg.solve(system, np.r_[df, 0.0, 0.0])[:c]
        assert np.linalg.norm(M @ df) ** 2 == pytest.approx(df @ dq, rel=1e-10)
    assert energy_weight(K, H[:0]) is None


def test_the_sampling_weighs_each_state_in_its_held_error_energy(beam):
    """Each training state's ECSW rows (train.energy_norms) hold the cables taut there: a
    force along a taut held cable's row carries no error energy, one row fewer per such
    cable, and a slack cable holds nothing."""
    robot, reduction, cache = beam
    model = robot.full_fe_model
    with np.load(cache) as stored:
        data = load_training_set(cache, str(stored["key"]))
    controls = tuple(spec.control for spec in robot.cable_specs)
    assert controls == ("displacement", "displacement")
    states = projected_states(model, reduction.basis, data.states_mm)
    tensions = data.state_tensions_n
    weights = energy_norms(model, reduction.basis, states, tensions, controls)
    assert len(weights) == len(states) == len(data.positions_mm) + len(data.loaded_mm) + len(
        data.contact_mm)
    r = reduction.mode_count
    for x, pulls, weight in zip(states, tensions, weights, strict=True):
        rows = model.cable_jacobian(x) @ reduction.basis
        taut = pulls > 0.0
        assert weight.shape == (r - taut.sum(), r)
        moved = np.linalg.norm(weight @ rows.T, axis=0)  # (a,) the energy a cable's pull makes
        scale = np.linalg.norm(weight, 2) * np.linalg.norm(rows, axis=1)
        assert np.all(moved[taut] <= 1e-9 * scale[taut])
        assert np.all(moved[~taut] > 1e-3 * scale[~taut])


def test_solves_start_at_the_nearest_training_equilibrium_moved_to_first_order(beam):
    """A reduced solve given no start begins at the training equilibrium nearest to its
    inputs moved to first order: exact at a training actuation, with an error that falls
    as the square of the distance from it (the sensitivities are the equilibria's
    derivative), and fewer Newton iterations than from rest to the same equilibrium."""
    robot, reduction, _ = beam
    model = ReducedModel(robot.full_fe_model, reduction)
    space = model.coordinates
    starts = reduction.starts
    trained = reduction.info["static_snapshots"]
    # the training equilibria, then every point of the grid (none fails on this beam)
    assert starts.inputs.shape == (trained + SETTINGS.start_levels**2, 2)
    box = reduction.box
    np.testing.assert_allclose(starts.inputs[trained:], serpentine_grid(
        box.cable_min, box.cable_max, SETTINGS.start_levels))
    corner = starts.inputs[np.argmax(starts.inputs.sum(axis=1))]  # both cables pulled
    assert np.all(corner > 3.0)
    for values in (corner, starts.inputs[trained + 7]):  # both kinds are equilibria
        assert solve_equilibrium(model, robot.cable_inputs(values)).iterations == 1

    # near the corner, the training equilibria alone (the grid has points nearer)
    sparse = ReducedModel(robot.full_fe_model,
                          dataclasses.replace(reduction, starts=starts.first(trained)))

    def error(offset):
        inputs = robot.cable_inputs(corner - offset)
        x, _ = _plain_newton(model, inputs)
        return np.abs(sparse.coordinates.start(inputs).q - space.state(x).q).max()

    errors = [error(np.array([1.0, 0.6]) * scale) for scale in (1.0, 0.5)]
    assert errors[0] > 1e-3  # the body is nonlinear over this offset
    assert 3.0 < errors[0] / errors[1] < 5.0  # second order
    inputs = robot.cable_inputs(np.array([3.7, 1.3]))  # between training actuations
    predicted = solve_equilibrium(model, inputs)
    from_rest = solve_equilibrium(model, inputs, start_mm=model.rest_nodes_mm)
    assert predicted.iterations < from_rest.iterations
    np.testing.assert_allclose(predicted.positions_mm, from_rest.positions_mm, atol=1e-4)
    # the grid brings the nearest start closer than the training equilibria alone (here
    # the side cable is slack: the grid point's own input moves nothing)
    assert from_rest.cable_tensions_n[1] == 0.0
    exact = from_rest.state.q
    assert (np.abs(space.start(inputs).q - exact).max()
            < 0.5 * np.abs(sparse.coordinates.start(inputs).q - exact).max())
    # a file keeps them; one from before them loads without and starts at rest
    path = robot.config.source.parent / "starts.rom.npz"
    save_reduction(path, reduction, force=True)
    np.testing.assert_array_equal(load_reduction(path).starts.sensitivities,
                                  starts.sensitivities)
    with np.load(path) as data:
        arrays = dict(data)
    arrays["start_coordinates"] = arrays["start_coordinates"][:, 1:]  # a damaged file
    np.savez(path, **arrays)
    with pytest.raises(ModelError, match="start equilibria do not fit"):
        load_reduction(path)
    bare = ReducedModel(robot.full_fe_model, dataclasses.replace(reduction, starts=None))
    np.testing.assert_array_equal(bare.coordinates.start(inputs).q, 0.0)


def test_the_start_grid_steps_one_cable_at_a_time():
    """The grid of start equilibria covers every combination of levels once, consecutive
    points one grid step apart in one cable (each solve continues from the one before);
    many cables get fewer levels."""
    low, high = np.array([0.0, 1.0, -2.0]), np.array([4.0, 3.0, 2.0])
    grid = serpentine_grid(low, high, 3)
    assert len(np.unique(grid, axis=0)) == len(grid) == 27
    for cable in range(3):
        np.testing.assert_allclose(np.unique(grid[:, cable]),
                                   np.linspace(low[cable], high[cable], 3))
    moves = np.abs(np.diff(grid, axis=0)) / ((high - low) / 2)
    np.testing.assert_allclose(np.sort(moves, axis=1), [[0.0, 0.0, 1.0]] * 26, atol=1e-12)
    assert [grid_levels(5, cables) for cables in (1, 4, 5, 6, 8)] == [5, 5, 5, 4, 2]
    assert grid_levels(1, 4) == 1


def test_a_solve_ends_on_its_predicted_next_step():
    """The next step predicted from the last full steps' sizes in quadratic convergence
    (s_k+1 = C s_k^2, C the larger of the last two ratios), none before three steps that
    shrink in a row."""
    assert _next_step([10.0, 1.0, 0.1]) == pytest.approx(0.1 * 0.1**2)
    assert _next_step([5.0, 1.0, 0.1]) == pytest.approx(0.1 * 0.1**2)
    assert _next_step([10.0, 4.0, 0.1]) == pytest.approx(4.0 / 100.0 * 0.1**2)
    assert _next_step([1.0, 0.1]) == np.inf
    assert _next_step([1.0, 2.0, 0.1]) == np.inf


@pytest.mark.parametrize("reduced", [False, True])
def test_a_solve_stops_within_its_precision(beam, reduced):
    """Ending on the predicted step, at the full model's 1e-7 mm or the reduced model's
    1e-3 mm, leaves each at the equilibrium of 30 undamped Newton iterations (here 1e-7 mm
    and 3e-9 mm)."""
    robot, reduction, _ = beam
    model = ReducedModel(robot.full_fe_model, reduction) if reduced else robot.full_fe_model
    inputs = robot.cable_inputs(np.array([5.2, 2.9]))
    answer = solve_equilibrium(model, inputs, start_mm=model.rest_nodes_mm)
    x, _ = _plain_newton(model, inputs)
    assert np.abs(answer.positions_mm - x).max() < 1e-6
