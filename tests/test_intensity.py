"""Force intensities (eq. 10-14): the QP's algebra, and the FE update loop on a known load."""

from pathlib import Path

import numpy as np
import pytest

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.estimation.intensity import IntensityProblem, solve_intensities
from softforce_cli.estimation.sensing import ForceSensor
from softforce_cli.estimation.settings import EstimationSettings, SenseSettings
from softforce_cli.fem.statics import PointLoads, solve_equilibrium
from softforce_cli.model.robot import load_robot
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
    actuation = np.array([5.0, 0.0, 5.0, 0.0])
    settings = SenseSettings(estimation=EstimationSettings(force_model=force_model,
                                                           relinearize_mm=relinearize_mm))
    sensor = ForceSensor(robot, RigidTransform(np.eye(3), np.zeros(3)), actuation, settings)
    surface = robot.mesh.surface_nodes
    node = surface[np.argmin(np.linalg.norm(robot.mesh.nodes_mm[surface] - [0, 45, 90], axis=1))]
    force = -0.4 * robot.mesh.vertex_normals[node]
    loads = PointLoads(robot.attach(robot.rest_nodes_mm[node][None]), force[None])
    truth = solve_equilibrium(robot.fe_model, robot.cable_inputs(actuation), loads)
    true_features = truth.positions_mm[robot.feature_nodes]
    p = len(true_features)
    for _ in range(6):
        _, normals = sensor.feature_geometry()
        observed = np.einsum("pi,pi->p", true_features, normals)
        matches = FeatureMatches(np.ones(p, bool), np.zeros(p, bool), np.zeros(p, bool),
                                 true_features, observed, np.zeros(p), np.zeros(p))
        update = sensor.update(matches, np.array([node]))
    estimated = update.forces_n @ update.columns.directions
    assert np.linalg.norm(estimated - force) < tolerance * 0.4
    np.testing.assert_allclose(sensor.tensions, truth.cable_tensions_n, rtol=tolerance)


def test_a_frame_finds_its_contact_again_on_the_surface_it_moved():
    """(ForceSensor.settle) A 1 N push at the upper bar's node moves it 10.3 mm: the pushed
    point is then nearer another node of the surface the frame starts from. Found again
    after each update, the contact reaches the pushed node and the updates the applied
    load (the same model as the estimator, a free 3D force, as above); left at the first
    node, the contact stays there, a node's spacing off."""
    robot = load_robot(ROBOT)
    actuation = np.array([5.0, 0.0, 5.0, 0.0])
    surface = robot.mesh.surface_nodes
    node = surface[np.argmin(np.linalg.norm(robot.mesh.nodes_mm[surface] - [0, 45, 90], axis=1))]
    force = -1.0 * robot.mesh.vertex_normals[node]
    loads = PointLoads(robot.attach(robot.rest_nodes_mm[node][None]), force[None])
    truth = solve_equilibrium(robot.fe_model, robot.cable_inputs(actuation), loads)
    true_features = truth.positions_mm[robot.feature_nodes]
    centre = truth.positions_mm[node][None]
    p = len(true_features)

    def settled(relocating: bool) -> tuple[np.ndarray, np.ndarray]:
        settings = SenseSettings(estimation=EstimationSettings(
            force_model="3d", relinearize_mm=0.0, rematch_mm=0.0))
        sensor = ForceSensor(robot, RigidTransform(np.eye(3), np.zeros(3)), actuation,
                             settings)
        axes = np.full((1, 3), np.nan)

        def matches() -> FeatureMatches:
            _, normals = sensor.feature_geometry()
            observed = np.einsum("pi,pi->p", true_features, normals)
            return FeatureMatches(np.ones(p, bool), np.zeros(p, bool), np.zeros(p, bool),
                                  true_features, observed, np.zeros(p), np.zeros(p))

        first, _ = sensor._contact_nodes(centre, axes)
        update = sensor.settle(matches(), matches, first, contact_axes=axes,
                               relocate=(lambda: sensor._contact_nodes(centre, axes))
                               if relocating else None)
        return (np.unique(update.columns.points.node_indices[:, 0]),
                update.forces_n @ update.columns.directions)

    start_nodes, _ = ForceSensor(robot, RigidTransform(np.eye(3), np.zeros(3)), actuation,
                                 SenseSettings())._contact_nodes(centre, np.zeros((1, 3)))
    assert start_nodes[0] != node
    nodes, estimated = settled(relocating=True)
    assert list(nodes) == [node]
    assert np.linalg.norm(estimated - force) < 0.05
    nodes, _ = settled(relocating=False)
    assert list(nodes) == list(start_nodes)
    apart = np.linalg.norm(truth.positions_mm[nodes[0]] - truth.positions_mm[node])
    assert apart > 3.0  # the contact left a node's spacing off
