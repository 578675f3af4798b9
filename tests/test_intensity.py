"""Force intensities (eq. 10-14): the QP's algebra, the FE update loop on a known load, and
where a detected contact acts (estimation.sensing.contact_nodes)."""

from pathlib import Path

import meshio
import numpy as np
import pytest

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.estimation.intensity import IntensityProblem, solve_intensities
from softforce_cli.estimation.sensing import (
    CONTACT_REACH_MM,
    HELD_OBJECT_MM,
    ForceSensor,
    contact_nodes,
    held_contacts,
)
from softforce_cli.estimation.settings import EstimationSettings, SenseSettings
from softforce_cli.fem.statics import Equilibrium, PointLoads, solve_equilibrium
from softforce_cli.model.robot import Robot, load_robot
from softforce_cli.model.structured import box_mesh
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
    simulated recordings (test_intensity_truth.py, and benchmarks/study_sensing.py)."""
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


def test_qp_slackens_a_cable_that_would_push():
    """A displacement-controlled cable that eq. 14 alone would hold with a negative tension
    goes slack (zero tension, its end closer than its input); one that a released state
    would stretch beyond its input is held."""
    problem = IntensityProblem(
        W_ea=np.array([[1.0, 0.2], [0.3, 1.0], [0.5, 0.5]]), W_ef=np.zeros((3, 0)),
        delta_e_free=np.zeros(3), observed_mm=np.array([1.0, 0.3, 0.6]),
        W_aa=np.array([[2.0, 0.5], [0.5, 1.0]]), W_af=np.zeros((2, 0)),
        delta_a_free=np.array([0.0, 1.5]), unilateral=np.zeros(0, bool),
    )
    # held at input 0, the second cable needs -1.5 mm of motion: a push
    pulled = solve_intensities(problem, ("displacement", "displacement"), np.array([1.0, 0.0]))
    assert pulled.cable_tensions_n[1] == 0.0
    np.testing.assert_allclose(pulled.cable_tensions_n[0], 0.5, atol=1e-12)  # W_aa 2 x 0.5 = 1
    shortening = problem.W_aa @ pulled.cable_tensions_n + problem.delta_a_free
    assert shortening[1] > 0.0  # the slack cable's end comes closer than its input asks
    # asked for more shortening than it gets free, the same cable pulls
    held = solve_intensities(problem, ("displacement", "displacement"), np.array([1.0, 2.0]))
    assert held.cable_tensions_n.min() > 0.0
    np.testing.assert_allclose(problem.W_aa @ held.cable_tensions_n + problem.delta_a_free,
                               [1.0, 2.0], atol=1e-12)


FINGER_TOML = """name = "finger"
[mesh]
path = "finger.vtu"
element = "p1"
[material]
law = "corotational"
young_modulus_mpa = 0.6
poisson_ratio = 0.45
total_mass_kg = 0.03
gravity_mm_s2 = [0.0, 0.0, -9810.0]
[[fixed]]
box_mm = [-1.0, -10.0, -10.0, 1.0, 10.0, 10.0]
[[cable]]
name = "top"
path_mm = [[78.0, 0.0, 6.0]]
pull_point_mm = [-5.0, 0.0, 6.0]
max = 6.0
[[cable]]
name = "bottom"
path_mm = [[78.0, 0.0, -6.0]]
pull_point_mm = [-5.0, 0.0, -6.0]
max = 6.0
[features]
count = 40
"""


def test_an_antagonist_cable_goes_slack_and_the_push_is_read(tmp_path):
    """A finger with antagonistic cables, each a straight chord to the tip: pulling the top
    one curls the finger up, the bottom chord shortens and goes slack. From exact
    observations of the FE equilibrium (its own active set on the cables) under a 0.2 N
    push at the tip, the updates reach the push and the tensions, the slack cable's zero
    included. Holding every displacement-controlled cable (eq. 14 alone) made the bottom
    cable push with 3.3 N, and the push read 0.73 N along the normal (5.2 N sideways with
    the free 3D force)."""
    nodes, tets = box_mesh((80.0, 16.0, 16.0), (10, 2, 2), (0.0, -8.0, -8.0))
    meshio.write(tmp_path / "finger.vtu", meshio.Mesh(nodes, [("tetra", tets)]))
    (tmp_path / "finger.toml").write_text(FINGER_TOML)
    robot = load_robot(tmp_path / "finger.toml")
    actuation = np.array([3.0, 0.0])
    surface = robot.mesh.surface_nodes
    node = int(surface[np.argmin(np.linalg.norm(robot.mesh.nodes_mm[surface] - [70, 0, 8],
                                                axis=1))])
    force = np.array([0.0, 0.0, -0.2])
    loads = PointLoads(robot.attach(robot.rest_nodes_mm[node][None]), force[None])
    truth = solve_equilibrium(robot.fe_model, robot.cable_inputs(actuation), loads)
    assert truth.cable_tensions_n[0] > 0.5 and truth.cable_tensions_n[1] == 0.0
    settings = SenseSettings(estimation=EstimationSettings(force_model="3d",
                                                           relinearize_mm=0.0))
    sensor = ForceSensor(robot, RigidTransform(np.eye(3), np.zeros(3)), actuation, settings)
    for _ in range(6):
        update = sensor.update(_exact_matches(sensor, truth), np.array([node]))
    estimated = update.forces_n @ update.columns.directions
    assert np.linalg.norm(estimated - force) < 0.01 * 0.2
    np.testing.assert_allclose(sensor.tensions, truth.cable_tensions_n, atol=0.01)


# the camera 600 mm above the robot's base, looking down on it (contact_nodes needs only
# its position, the transform's translation)
CAMERA_ABOVE = RigidTransform(np.eye(3), np.array([0.0, 0.0, 600.0]))


def test_a_frame_finds_its_contact_again_on_the_surface_it_moved():
    """(ForceSensor.placement, settle) A 1 N push at the upper bar's node moves it 10.3 mm:
    the camera's line of sight through the pushed point then passes nearest another node
    of the surface the frame starts from. Placed again after each update, the contact
    reaches the pushed node and the updates the applied load (the same model as the
    estimator, a free 3D force, as above); left at the first node, the contact stays there.
    The camera looks at the bar's face from the side (600 mm out along y): from above, the
    line of sight through the pushed point meets the pushed node already at rest."""
    robot = load_robot(ROBOT)
    camera = RigidTransform(np.eye(3), np.array([0.0, 600.0, 90.0]))
    node, force, truth = _pushed_upper_bar(robot, 1.0)
    centre = truth.positions_mm[node][None]

    def settled(relocating: bool) -> tuple[np.ndarray, np.ndarray]:
        settings = SenseSettings(estimation=EstimationSettings(
            force_model="3d", relinearize_mm=0.0, rematch_mm=0.0))
        sensor = ForceSensor(robot, camera, ACTUATION, settings)
        axes = np.full((1, 3), np.nan)

        def matches() -> FeatureMatches:
            return _exact_matches(sensor, truth)

        first, _, relocate = sensor.placement(centre, axes)
        update = sensor.settle(matches(), matches, first, contact_axes=axes,
                               relocate=relocate if relocating else None)
        return (np.unique(update.columns.points.node_indices[:, 0]),
                update.forces_n @ update.columns.directions)

    start_nodes, _, _ = ForceSensor(robot, camera, ACTUATION,
                                    SenseSettings()).placement(centre, np.zeros((1, 3)))
    assert start_nodes[0] != node
    nodes, estimated = settled(relocating=True)
    assert list(nodes) == [node]
    assert np.linalg.norm(estimated - force) < 0.05
    nodes, _ = settled(relocating=False)
    assert list(nodes) == list(start_nodes)
    apart = np.linalg.norm(truth.positions_mm[nodes[0]] - truth.positions_mm[node])
    assert apart > 3.0  # the contact left a node's spacing off


def _dented_grid() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(positions (m, 3) mm, outward normals (m, 3), surface nodes (m,)) of a flat skin: a
    5 mm grid at z = 0 facing up, its node at the origin dented 3 mm by a point force, and
    one node of the skin's underside 6 mm below, facing down."""
    x, y = np.meshgrid(np.arange(-10.0, 15.0, 5.0), np.arange(-10.0, 15.0, 5.0))
    top = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    top[np.all(top[:, :2] == 0.0, axis=1), 2] = -3.0
    positions = np.vstack([top, [0.3, 0.0, -6.0]])
    normals = np.tile([0.0, 0.0, 1.0], (len(positions), 1))
    normals[-1] = [0.0, 0.0, -1.0]
    return positions, normals, np.arange(len(positions))


def _grid_node(positions: np.ndarray, x: float, y: float) -> int:
    return int(np.flatnonzero((positions[:, 0] == x) & (positions[:, 1] == y)
                              & (positions[:, 2] > -5.0))[0])


def test_a_contact_acts_where_the_cameras_line_of_sight_meets_the_skin():
    """(contact_nodes) The camera sees the object above the touch, which the object hides:
    the contact's centre lies 5.5 mm up the line of sight from the dented node, nearer its
    neighbour in space (7.1 mm against 8.5). The node on the line is taken, and not the
    underside's, nearer the line but facing away."""
    positions, normals, surface = _dented_grid()
    camera = np.array([0.0, 0.0, 500.0])
    centre = np.array([[0.5, 0.0, 5.5]])
    dented, neighbour = _grid_node(positions, 0, 0), _grid_node(positions, 5, 0)
    distances = np.linalg.norm(positions - centre, axis=1)
    assert np.argmin(distances) == neighbour  # what the nearest node in space would take
    underside = len(positions) - 1
    sight = (centre[0] - camera) / np.linalg.norm(centre[0] - camera)
    off_line = np.linalg.norm(np.cross(positions - centre, sight), axis=1)
    assert off_line[underside] < off_line[dented]  # nearer the line, within reach, facing away
    assert distances[underside] < distances.min() + CONTACT_REACH_MM
    assert contact_nodes(centre, camera, positions, normals, surface)[0] == dented


def test_a_hidden_tip_takes_the_node_nearest_in_space():
    """(contact_nodes, sighted) A hidden tip (vision.contacts.occluded_tips) is found on the
    robot's surface, on a side the camera may not face: just under the underside node, it
    acts there, where a contact seen from the camera would be put on the skin above."""
    positions, normals, surface = _dented_grid()
    camera = np.array([0.0, 0.0, 500.0])
    tip = np.array([[0.3, 0.0, -7.0]])
    underside = len(positions) - 1
    assert contact_nodes(tip, camera, positions, normals, surface)[0] != underside
    hidden = contact_nodes(tip, camera, positions, normals, surface, sighted=np.array([False]))
    assert hidden[0] == underside


def test_a_rod_pushes_only_faces_it_can_press():
    """(contact_nodes, axes) A rod pressing a top face 6 mm from its edge, seen from the
    side and above, dents the skin 4 mm below where the model's face still is: the line of
    sight through the contact's centre passes nearest a node of the side face below the
    edge (1.6 mm against 3.8 for the top face's), which the rod's axis, straight down,
    cannot push. Given the axis, the contact acts on the top face; without it, on the side
    face, as the line alone would have it."""
    x = np.array([-5.0, 0.0, 5.0])
    top = np.column_stack([np.tile(x, 2), np.repeat([-5.0, 0.0], 3), np.zeros(6)])
    side = np.column_stack([np.tile(x, 2), np.full(6, -10.0), np.repeat([-3.0, -8.0], 3)])
    positions = np.vstack([top, side])
    normals = np.vstack([np.tile([0.0, 0.0, 1.0], (6, 1)), np.tile([0.0, -1.0, 0.0], (6, 1))])
    surface = np.arange(12)
    camera = np.array([0.0, -400.0, 300.0])
    touch = np.array([0.0, -6.0, -4.0])
    sight = (touch - camera) / np.linalg.norm(touch - camera)
    centre = (touch - 5.0 * sight)[None]
    down = np.array([[0.0, 0.0, -1.0]])
    assert contact_nodes(centre, camera, positions, normals, surface)[0] == 7  # side (0, -10, -3)
    assert contact_nodes(centre, camera, positions, normals, surface, axes=down)[0] == 1
    unknown = np.full((1, 3), np.nan)
    assert contact_nodes(centre, camera, positions, normals, surface, axes=unknown)[0] == 7


def test_a_contact_keeps_its_node_within_the_margin():
    """(contact_nodes, RELOCATE_MM) A line of sight that has moved 0.8 mm nearer a
    neighbouring node than the contact's keeps the contact's node; one 2 mm nearer moves
    it there, as it does for a contact placed afresh."""
    positions, normals, surface = _dented_grid()
    camera = np.array([0.0, 0.0, 500.0])
    dented, neighbour = _grid_node(positions, 0, 0), _grid_node(positions, 5, 0)
    placed = np.array([dented])
    for x, kept in ((2.9, dented), (3.5, neighbour)):
        centre = np.array([[x, 0.0, 5.5]])
        assert contact_nodes(centre, camera, positions, normals, surface)[0] == neighbour
        assert contact_nodes(centre, camera, positions, normals, surface, placed)[0] == kept


def test_a_held_contact_starts_a_frame_at_the_last_frames_node():
    """(ForceSensor.placement, placed_nodes) A contact whose line of sight has moved within
    the margin towards a neighbouring node between two frames stays at its node; a sensor
    placing it afresh takes the neighbour."""
    robot = load_robot(ROBOT)
    node = _upper_bar_node(robot)
    sensor = ForceSensor(robot, CAMERA_ABOVE, ACTUATION, SenseSettings())
    positions = sensor.mesh_geometry()[0]
    centre = positions[node][None] + [0.0, 0.0, 5.0]
    axes = np.full((1, 3), np.nan)
    assert list(sensor.placement(centre, axes)[0]) == [node]
    faces = robot.mesh.surface_faces
    neighbours = np.unique(faces[np.any(faces == node, axis=1)])
    neighbour = next(int(v) for v in neighbours
                     if v != node and abs(positions[v, 2] - positions[node, 2]) < 3.0)
    # 0.6 of the way across: the neighbour is the nearer by less than the margin
    shifted = centre + 0.6 * (positions[neighbour] - positions[node]) * [1.0, 1.0, 0.0]
    fresh = ForceSensor(robot, CAMERA_ABOVE, ACTUATION, SenseSettings())
    assert sensor.placement(shifted, axes)[0][0] == node
    assert fresh.placement(shifted, axes)[0][0] != node


def test_a_pushing_contact_is_held_while_its_object_stays_near():
    """(held_contacts) A probe folding a bar hides its tip and the bar around it, and the
    vision finds no contact: the last frame's pushing contact is held while the probe's
    points stay within HELD_OBJECT_MM of it; not once they have gone further, nor where the
    vision found a contact again (within the tracker's radius), nor without objects."""
    pushing = np.array([[-35.0, 0.0, 69.0], [40.0, 0.0, 80.0]])
    rod = pushing[0] + np.outer(np.arange(4.0, 30.0, 1.0), [-0.6, 0.0, 0.8])
    held = held_contacts(pushing, np.zeros((0, 3)), rod, same_mm=15.0)
    assert held.tolist() == [True, False]
    lifted = rod + np.array([0.0, 0.0, HELD_OBJECT_MM])
    assert not held_contacts(pushing, np.zeros((0, 3)), lifted, 15.0).any()
    found_again = pushing[:1] + np.array([0.0, 8.0, 12.0])
    assert not held_contacts(pushing, found_again, rod, 15.0).any()
    assert held_contacts(pushing, pushing[1:] + 10.0, rod, 15.0).tolist() == [True, False]
    assert held_contacts(pushing, np.zeros((0, 3)), np.zeros((0, 3)), 15.0).tolist() == [
        False, False]
