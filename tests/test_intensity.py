"""Force intensities (eq. 10-14): the QP's algebra, and the FE update loop on a known load."""

from pathlib import Path

import numpy as np
import pytest

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.estimation.intensity import IntensityProblem, solve_intensities
from softforce_cli.estimation.sensing import ForceSensor
from softforce_cli.estimation.settings import EstimationSettings, SenseSettings
from softforce_cli.fem.statics import Equilibrium, PointLoads, solve_equilibrium
from softforce_cli.model.robot import Robot, load_robot
from softforce_cli.vision.feature_matching import FeatureMatches

ROBOT = Path(__file__).parents[1] / "sample_data" / "diamond" / "diamond.toml"


def _problem(rng, e=30, a=2, f=2, unilateral=True):
    return IntensityProblem(
        W_ea=rng.normal(size=(e, a)), W_ef=rng.normal(size=(e, f)),
        delta_e_free=rng.normal(size=e), observed_mm=np.zeros(e),
        W_aa=np.eye(a) * 3 + 0.1, W_af=rng.normal(size=(a, f)),
        delta_a_free=rng.normal(size=a), unilateral=np.full(f, unilateral),
    )


def test_qp_recovers_exact_forces_under_displacement_control():
    rng = np.random.default_rng(0)
    base = _problem(rng)
    lam_a, lam_f = np.array([1.5, 0.7]), np.array([0.4, 0.25])
    observed = base.W_ea @ lam_a + base.W_ef @ lam_f + base.delta_e_free
    shortening = base.W_aa @ lam_a + base.W_af @ lam_f + base.delta_a_free
    problem = IntensityProblem(**{**vars(base), "observed_mm": observed})
    result = solve_intensities(problem, ("displacement", "displacement"), shortening, 0.0)
    np.testing.assert_allclose(result.cable_tensions_n, lam_a, atol=1e-9)
    np.testing.assert_allclose(result.contact_forces_n, lam_f, atol=1e-9)
    assert result.rms_mm < 1e-9


def test_qp_force_control_holds_tensions_and_bounds_contacts():
    rng = np.random.default_rng(1)
    base = _problem(rng)
    lam_a = np.array([1.2, 1.0])
    # observations that a pulling (negative) contact force would fit best
    observed = base.W_ea @ lam_a + base.W_ef @ np.array([-0.5, 0.3]) + base.delta_e_free
    problem = IntensityProblem(**{**vars(base), "observed_mm": observed})
    result = solve_intensities(problem, ("force", "force"), lam_a, 0.0)
    np.testing.assert_allclose(result.cable_tensions_n, lam_a, atol=1e-9)
    assert result.contact_forces_n.min() >= 0.0
    # the bounded optimum satisfies the KKT conditions: the gradient on the free contact
    # column vanishes, and on the bound one it points into the feasible side
    W = np.hstack([base.W_ea, base.W_ef])
    gradient = W.T @ (W @ np.r_[result.cable_tensions_n, result.contact_forces_n]
                      - (observed - base.delta_e_free))
    free = result.contact_forces_n > 1e-8
    assert np.all(np.abs(gradient[2:][free]) < 1e-6)
    assert np.all(gradient[2:][~free] > -1e-6)


ACTUATION = np.array([5.0, 0.0, 5.0, 0.0])


def _upper_bar_node(robot: Robot) -> int:
    """The upper bar's surface node nearest (0, 45, 90) mm."""
    surface = robot.mesh.surface_nodes
    return int(surface[np.argmin(np.linalg.norm(robot.mesh.nodes_mm[surface] - [0, 45, 90],
                                                axis=1))])


def _pushed_upper_bar(robot: Robot, newtons: float) -> tuple[int, np.ndarray, Equilibrium]:
    """(node, force (3,) N, equilibrium) of the robot at ACTUATION under a push of `newtons`
    along the inward rest normal of _upper_bar_node."""
    node = _upper_bar_node(robot)
    force = -newtons * robot.mesh.vertex_normals[node]
    loads = PointLoads(robot.attach(robot.rest_nodes_mm[node][None]), force[None])
    return node, force, solve_equilibrium(robot.fe_model, robot.cable_inputs(ACTUATION), loads)


def _exact_matches(sensor: ForceSensor, truth: Equilibrium) -> FeatureMatches:
    """Every feature matched at its position in `truth`, along the sensor's current normals."""
    true_features = truth.positions_mm[sensor.robot.feature_nodes]
    p = len(true_features)
    _, normals = sensor.feature_geometry()
    observed = np.einsum("pi,pi->p", true_features, normals)
    return FeatureMatches(np.ones(p, bool), np.zeros(p, bool), np.zeros(p, bool),
                          true_features, observed, np.zeros(p), np.zeros(p))


@pytest.mark.parametrize(("force_model", "relinearize_mm", "tolerance"),
                         [("3d", 0.0, 0.01), ("3d", 0.5, 0.02), ("normal", 0.5, 0.10)])
def test_fe_updates_converge_to_the_applied_load(force_model, relinearize_mm, tolerance):
    """Same model as the estimator, observations from its own equilibrium (a 0.4 N push on
    the upper bar): the updates of eq. 10-14 and 6 must reach the load. With a free 3D force
    they reach it exactly; with a push along the current normal (the paper) to within the
    surface's rotation, since the load was applied along the rest normal. Relinearising only
    when the configuration has moved more than relinearize_mm (estimation.linear_model)
    leaves the answer linearised up to that far from the end state: 1.2% on the 3D force
    here, whose tangential components the normal observations hardly fix. This checks the
    algebra and the update loop; accuracy against an independent truth is measured on
    simulated recordings (test_sense_accuracy.py)."""
    robot = load_robot(ROBOT)
    settings = SenseSettings(estimation=EstimationSettings(force_model=force_model,
                                                           relinearize_mm=relinearize_mm))
    sensor = ForceSensor(robot, RigidTransform(np.eye(3), np.zeros(3)), ACTUATION, settings)
    node, force, truth = _pushed_upper_bar(robot, 0.4)
    for _ in range(6):
        update = sensor.update(_exact_matches(sensor, truth), np.array([node]))
    estimated = update.forces_n @ update.columns.directions
    assert np.linalg.norm(estimated - force) < tolerance * 0.4
    np.testing.assert_allclose(sensor.tensions, truth.cable_tensions_n, rtol=tolerance)


def test_a_frame_finds_its_contact_again_on_the_surface_it_moved():
    """(ForceSensor.placement, settle) A 1 N push at the upper bar's node moves it 10.3 mm:
    the pushed point is then nearer another node of the surface the frame starts from, 14 mm
    away at rest. Placed again after each update (its first node drifts more than
    RELOCATE_MM further from it than the nearest), the contact reaches the pushed node and
    the updates the applied load (the same model as the estimator, a free 3D force, as
    above); left at the first node, the contact stays there."""
    robot = load_robot(ROBOT)
    node, force, truth = _pushed_upper_bar(robot, 1.0)
    centre = truth.positions_mm[node][None]

    def settled(relocating: bool) -> tuple[np.ndarray, np.ndarray]:
        settings = SenseSettings(estimation=EstimationSettings(
            force_model="3d", relinearize_mm=0.0, rematch_mm=0.0))
        sensor = ForceSensor(robot, RigidTransform(np.eye(3), np.zeros(3)), ACTUATION,
                             settings)
        axes = np.full((1, 3), np.nan)

        def matches() -> FeatureMatches:
            return _exact_matches(sensor, truth)

        first, _, relocate = sensor.placement(centre, axes)
        update = sensor.settle(matches(), matches, first, contact_axes=axes,
                               relocate=relocate if relocating else None)
        return (np.unique(update.columns.points.node_indices[:, 0]),
                update.forces_n @ update.columns.directions)

    start_nodes, _, _ = ForceSensor(robot, RigidTransform(np.eye(3), np.zeros(3)), ACTUATION,
                                    SenseSettings()).placement(centre, np.zeros((1, 3)))
    assert start_nodes[0] != node
    nodes, estimated = settled(relocating=True)
    assert list(nodes) == [node]
    assert np.linalg.norm(estimated - force) < 0.05
    nodes, _ = settled(relocating=False)
    assert list(nodes) == list(start_nodes)
    apart = np.linalg.norm(truth.positions_mm[nodes[0]] - truth.positions_mm[node])
    assert apart > 3.0  # the contact left a node's spacing off


def test_a_contact_keeps_its_node_until_it_drifts_beyond_the_margin():
    """(ForceSensor._contact_nodes, RELOCATE_MM) A centre a little nearer a neighbouring
    node (as under a point force's dent) keeps the contact's node; one that has drifted a
    whole edge beyond it moves the contact to the nearest node."""
    robot = load_robot(ROBOT)
    sensor = ForceSensor(robot, RigidTransform(np.eye(3), np.zeros(3)), ACTUATION,
                         SenseSettings())
    positions = sensor.mesh_geometry()[0]
    node = _upper_bar_node(robot)
    faces = robot.mesh.surface_faces
    neighbour = next(int(v) for v in faces[np.any(faces == node, axis=1)].ravel() if v != node)
    edge = positions[neighbour] - positions[node]
    near = positions[node] + 0.6 * edge
    assert sensor._contact_nodes(near[None])[0] != node
    assert sensor._contact_nodes(near[None], np.array([node]))[0] == node
    beyond = positions[node] + 2.0 * edge
    moved = sensor._contact_nodes(beyond[None], np.array([node]))[0]
    assert moved != node and moved == sensor._contact_nodes(beyond[None])[0]
