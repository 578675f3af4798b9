"""Quadratic tetrahedra (P2) and P2-P0: shape functions, patch tests, tangents, scikit-fem,
the cantilever at Poisson 0.45 against Timoshenko, attachments, and the robot with P2.

The long mesh-converged comparison on the Diamond robots is benchmarks/study_locking.py
(docs/locking.md).
"""

from __future__ import annotations

import dataclasses
import functools
import shutil

import meshio
import numpy as np
import pytest
import scipy.sparse as sp
import skfem
from scipy.sparse.linalg import eigsh
from skfem.models.elasticity import linear_elasticity

from softforce_cli.errors import ModelError
from softforce_cli.fem.attachment import attach_points
from softforce_cli.fem.cables import CableInputs
from softforce_cli.fem.compliance import compliance, effector_rows, force_rows, linearize
from softforce_cli.fem.element import (
    ELEMENTS,
    P1,
    P2,
    element_mesh,
    element_stiffness,
    gradient_operators,
)
from softforce_cli.fem.materials import LAWS, Material
from softforce_cli.fem.model import FEModel, lumped_masses
from softforce_cli.fem.statics import PointLoads, SolverSettings, solve_equilibrium
from softforce_cli.fem.tet_p2 import EDGES
from softforce_cli.model.config import load_config
from softforce_cli.model.mesh import TetMesh
from softforce_cli.model.mesh_io import read_tet_mesh
from softforce_cli.model.robot import build_robot
from softforce_cli.model.structured import box_mesh
from tests.cli_runner import softforce
from tests.conftest import SAMPLE_ROBOT

YOUNG_MPA = 1.0
TIGHT = SolverSettings(step_tolerance_mm=1e-13, force_tolerance_n=1e-13)
QUADRATIC = ("p2", "p2-p0")


def perturbed_box(rng, divisions=(3, 3, 3), jitter_mm=0.2):
    """A 3 mm box of 1 mm cells, interior corner nodes moved at random: nodes, tets,
    boundary corner nodes."""
    size = np.array(divisions, dtype=float)
    nodes, tets = box_mesh(tuple(size), divisions)
    boundary = np.flatnonzero(np.any((nodes < 1e-9) | (nodes > size - 1e-9), axis=1))
    interior = np.setdiff1d(np.arange(len(nodes)), boundary)
    nodes[interior] += rng.uniform(-jitter_mm, jitter_mm, (len(interior), 3))
    return nodes, tets, boundary


def quadratic_model(nodes, tets, law, fixed_corners, element="p2", poisson=0.3, masses=None):
    """FE model of `element` on a tet mesh, the fixed corners' clamped set lifted to P2."""
    fe = element_mesh(nodes, tets, element)
    return FEModel(
        rest_nodes_mm=fe.nodes_mm,
        tets=fe.elements,
        material=Material(law, YOUNG_MPA, poisson),
        fixed_nodes=fe.with_midside(fixed_corners),
        node_masses_kg=np.zeros(fe.node_count) if masses is None else masses,
        gravity_mm_s2=np.zeros(3),
        element_name=element,
    ), fe


# --- the element ------------------------------------------------------------------------


def test_p2_shape_functions_interpolate_and_reproduce_quadratics():
    rng = np.random.default_rng(0)
    corners = np.eye(4)
    nodal = np.vstack([corners, corners[EDGES].mean(axis=1)])  # barycentric of the 10 nodes
    np.testing.assert_allclose(P2.shape_values(nodal), np.eye(10), atol=1e-15)
    points = rng.dirichlet(np.ones(4), 20)
    values = P2.shape_values(points)
    np.testing.assert_allclose(values.sum(axis=1), 1.0)
    # any quadratic polynomial of the barycentric coordinates is reproduced exactly
    matrix = rng.normal(size=(4, 4))
    quadratic = np.einsum("...i,ij,...j->...", points, matrix, points)
    nodal_values = np.einsum("...i,ij,...j->...", nodal, matrix, nodal)
    np.testing.assert_allclose(values @ nodal_values, quadratic, rtol=1e-12)
    # derivatives against central differences along each barycentric direction
    step = 1e-6
    for b in range(4):
        shift = step * np.eye(4)[b]
        difference = (P2.shape_values(points + shift) - P2.shape_values(points - shift))
        np.testing.assert_allclose(difference / (2 * step), P2.shape_derivatives(points)[:, :, b],
                                   atol=1e-8)


@pytest.mark.parametrize("element", list(ELEMENTS.values()), ids=list(ELEMENTS))
def test_quadrature_integrates_degree_two_exactly(element):
    """int L_i L_j dV / V = (1 + d_ij) / 20 (Zienkiewicz & Taylor, eq. for tetrahedra): the
    P2 rule is exact for degree 2; P1's one point only for degree 1."""
    points, weights = element.quadrature_points, element.quadrature_weights
    np.testing.assert_allclose(weights @ points, 0.25)  # degree 1: int L_i = V / 4
    second = np.einsum("q,qi,qj->ij", weights, points, points)
    if element.node_count == 10:
        np.testing.assert_allclose(second, (1 + np.eye(4)) / 20, rtol=1e-14)


def test_quadratic_mesh_keeps_input_nodes_and_shares_mid_edge_nodes():
    nodes, tets = box_mesh((3.0, 2.0, 1.0), (3, 2, 1))
    fe = element_mesh(nodes, tets, "p2")
    n = len(nodes)
    np.testing.assert_array_equal(fe.nodes_mm[:n], nodes)
    np.testing.assert_array_equal(fe.elements[:, :4], tets)
    # one node per unique edge, at its midpoint; Euler for a 3-ball: V - E + F - T = 1
    faces = len(np.unique(np.sort(tets[:, [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]]
                                  .reshape(-1, 3), axis=1), axis=0))
    assert n - len(fe.edges) + faces - len(tets) == 1
    assert fe.node_count == n + len(fe.edges)
    ends = fe.nodes_mm[fe.elements[:, EDGES]]
    np.testing.assert_allclose(fe.nodes_mm[fe.elements[:, 4:]], ends.mean(axis=2))
    # a clamped face keeps its mid-edge nodes clamped, and no other
    face = np.flatnonzero(nodes[:, 0] < 1e-9)
    clamped = fe.with_midside(face)
    assert np.all(fe.nodes_mm[clamped, 0] < 1e-9)
    assert len(clamped) == np.sum(fe.nodes_mm[:, 0] < 1e-9)
    # a field given at the corners, linear along the edges, at every node
    affine = nodes @ np.array([[1.0, 2.0], [-3.0, 0.5], [0.25, 4.0]]) + 7.0
    np.testing.assert_allclose(fe.from_corners(affine), fe.nodes_mm @ np.array(
        [[1.0, 2.0], [-3.0, 0.5], [0.25, 4.0]]) + 7.0)
    np.testing.assert_array_equal(element_mesh(nodes, tets, "p1").from_corners(affine), affine)


def test_hrz_lumping_is_positive_and_exact_in_total():
    rng = np.random.default_rng(1)
    nodes, tets, _ = perturbed_box(rng)
    fe = element_mesh(nodes, tets, "p2")
    density = 1.07e-9  # silicone, kg/mm^3
    masses = lumped_masses(fe.nodes_mm, fe.elements, density)
    assert np.all(masses > 0)
    assert masses.sum() == pytest.approx(density * TetMesh(nodes, tets).volume_mm3, rel=1e-13)
    np.testing.assert_allclose(P2.lumped_mass_fractions.sum(), 1.0)


@pytest.mark.parametrize("element", ["p1", "p2", "p2-p0"])
def test_stiffness_kernel_is_textbook_b_transpose_a_b(element):
    rng = np.random.default_rng(2)
    nodes, tets, _ = perturbed_box(rng, (1, 1, 1))
    model, _ = quadratic_model(nodes, tets, "corotational", [], element)
    positions = model.rest_nodes_mm + 0.1 * rng.normal(size=model.rest_nodes_mm.shape)
    F = model.deformation_gradients(positions)
    _, tangent = model._constitutive(F, with_tangent=True)
    B = gradient_operators(model.shape_gradients)  # (m, q, 9, 3k)
    textbook = np.einsum("mq,mqra,mqrs,mqsb->mab", model.quadrature_weights_mm3, B, tangent, B)
    ours = element_stiffness(tangent, model.shape_gradients, model.quadrature_weights_mm3)
    np.testing.assert_allclose(ours, textbook, atol=1e-12 * np.abs(textbook).max())


def test_p2_linear_stiffness_equals_scikit_fem():
    """Independent reference: scikit-fem's ElementTetP2 with its linear elasticity form."""
    rng = np.random.default_rng(3)
    nodes, tets, _ = perturbed_box(rng, (2, 2, 2))
    model, fe = quadratic_model(nodes, tets, "linear", np.array([], dtype=np.int64))
    _, ours = model.internal_forces_and_stiffness(model.rest_nodes_mm)
    mesh = skfem.MeshTet(nodes.T.copy(), tets.T.copy())
    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementTetP2()))
    lam, mu = model.material.lame
    reference = skfem.asm(linear_elasticity(lam, mu), basis).tocsr()
    # skfem dof (component c, vertex v) and (c, edge e) -> ours 3 v + c and 3 (n + j) + c
    n = len(nodes)
    keys = fe.edges[:, 0] * n + fe.edges[:, 1]
    skfem_edges = np.sort(mesh.edges.T, axis=1)
    ours_edge = n + np.searchsorted(keys, skfem_edges[:, 0] * n + skfem_edges[:, 1])
    ours_of_skfem = np.empty(basis.N, dtype=np.int64)
    ours_of_skfem[basis.nodal_dofs.T.ravel()] = (3 * np.arange(n)[:, None] + np.arange(3)).ravel()
    ours_of_skfem[basis.edge_dofs.T.ravel()] = (3 * ours_edge[:, None] + np.arange(3)).ravel()
    permutation = sp.csr_matrix((np.ones(basis.N), (ours_of_skfem, np.arange(basis.N))),
                                shape=(basis.N, basis.N))
    reference = permutation @ reference @ permutation.T
    assert np.abs(ours - reference).max() < 1e-12 * np.abs(reference).max()


# --- patch tests ------------------------------------------------------------------------


@pytest.mark.parametrize("law", LAWS)
@pytest.mark.parametrize("element", QUADRATIC)
def test_patch_test_reproduces_affine_field(law, element):
    rng = np.random.default_rng(4)
    nodes, tets, boundary = perturbed_box(rng)
    model, fe = quadratic_model(nodes, tets, law, boundary, element)
    gradient = np.eye(3) + 1e-3 * rng.uniform(-1, 1, (3, 3))
    offset = rng.uniform(-1, 1, 3)
    affine = fe.nodes_mm @ gradient.T + offset
    start = fe.nodes_mm + offset  # translated, so no quadrature point starts inverted
    start[model.fixed_nodes] = affine[model.fixed_nodes]
    equilibrium = solve_equilibrium(model, CableInputs.slack(0), start_mm=start, settings=TIGHT)
    assert np.abs(equilibrium.positions_mm - affine).max() < 1e-10


def consistent_body_loads(model, body_force):
    """(N, 3) N: int N_a b dV for a constant body force b (3,) N/mm^3; exact with the
    element's own rule (N_a is of degree 2)."""
    element = model.element
    values = element.shape_values(element.quadrature_points)  # (q, k)
    weights = model.quadrature_weights_mm3[:, : element.quadrature_count]  # (m, q)
    shares = weights @ values  # (m, k)
    integral = np.bincount(model.tets.ravel(), shares.ravel(), minlength=model.node_count)
    return np.outer(integral, body_force)


@pytest.mark.parametrize(("element", "field"), [("p2", "general"), ("p2", "solenoidal"),
                                                ("p2-p0", "solenoidal")])
def test_quadratic_patch_test_with_consistent_body_force(element, field):
    """Linear law, u quadratic: the stress is affine and b = -div sigma constant. P2 holds
    every quadratic field exactly; P2-P0 (div u projected on constants) every one with
    constant divergence, here div u = 0."""
    rng = np.random.default_rng(5)
    nodes, tets, boundary = perturbed_box(rng)
    model, fe = quadratic_model(nodes, tets, "linear", boundary, element)
    lam, mu = model.material.lame
    alpha = 1e-3
    if field == "general":  # u = alpha (x y, y z, z x): div u = x + y + z
        def displacement(x):
            return alpha * np.stack([x[:, 0] * x[:, 1], x[:, 1] * x[:, 2], x[:, 2] * x[:, 0]], 1)
        # grad div u = alpha (1, 1, 1), laplacian u = 0
        body = -(lam + mu) * alpha * np.ones(3)
    else:  # u = alpha (y^2, z^2, x^2): div u = 0, laplacian u = 2 alpha (1, 1, 1)
        def displacement(x):
            return alpha * np.stack([x[:, 1] ** 2, x[:, 2] ** 2, x[:, 0] ** 2], 1)
        body = -mu * 2 * alpha * np.ones(3)
    exact = fe.nodes_mm + displacement(fe.nodes_mm)
    start = fe.nodes_mm.copy()
    start[model.fixed_nodes] = exact[model.fixed_nodes]
    loads_n = consistent_body_loads(model, body)
    everywhere = attach_points(fe.nodes_mm, fe.elements, fe.nodes_mm)
    loads = PointLoads(everywhere, loads_n)
    equilibrium = solve_equilibrium(model, CableInputs.slack(0), loads=loads, start_mm=start,
                                    settings=TIGHT)
    assert np.abs(equilibrium.positions_mm - exact).max() < 1e-10
    if element == "p2":  # P1 cannot: its best fit on the same corners misses by O(h^2)
        p1 = FEModel(nodes, tets, Material("linear", YOUNG_MPA, 0.3), boundary,
                     np.zeros(len(nodes)), np.zeros(3))
        start_p1 = start[: len(nodes)]
        loads_p1 = PointLoads(attach_points(nodes, tets, nodes),
                              consistent_body_loads(p1, body))
        linear = solve_equilibrium(p1, CableInputs.slack(0), loads=loads_p1, start_mm=start_p1,
                                   settings=TIGHT)
        assert np.abs(linear.positions_mm - exact[: len(nodes)]).max() > 1e-6


# --- rigid motions, tangents, definiteness ------------------------------------------------


@pytest.mark.parametrize("law", ["corotational", "neo-hookean"])
@pytest.mark.parametrize("element", QUADRATIC)
def test_rigid_motion_is_stress_free(law, element):
    rng = np.random.default_rng(6)
    nodes, tets, _ = perturbed_box(rng)
    model, fe = quadratic_model(nodes, tets, law, np.array([], dtype=np.int64), element)
    angle = np.radians(40.0)
    rotation = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0],
                         [0, 0, 1]])
    moved = fe.nodes_mm @ rotation.T + [3.0, -2.0, 1.0]
    scale = YOUNG_MPA * float(np.mean(model.tet_volumes_mm3)) ** (2 / 3)
    assert abs(model.strain_energy(moved)) < 1e-13 * YOUNG_MPA * model.tet_volumes_mm3.sum()
    assert np.abs(model.internal_forces(moved)).max() < 1e-12 * scale


@pytest.mark.parametrize("law", LAWS)
@pytest.mark.parametrize("element", QUADRATIC)
def test_stiffness_is_derivative_of_forces_and_forces_of_energy(law, element):
    rng = np.random.default_rng(7)
    nodes, tets, _ = perturbed_box(rng, (2, 2, 2))
    model, fe = quadratic_model(nodes, tets, law, np.flatnonzero(nodes[:, 0] < 1e-9), element)
    positions = fe.nodes_mm @ np.diag([1.2, 0.9, 1.05]).T + rng.uniform(-1, 1, fe.nodes_mm.shape
                                                                        ) * 0.08
    _, stiffness = model.internal_forces_and_stiffness(positions)
    free = model.free_dofs
    step = 1e-6
    direction = np.zeros(3 * model.node_count)
    direction[free] = rng.normal(size=len(free))
    moved = [positions + sign * step * direction.reshape(-1, 3) for sign in (1, -1)]
    difference = (model.internal_forces(moved[0]).ravel()[free]
                  - model.internal_forces(moved[1]).ravel()[free]) / (2 * step)
    exact = stiffness @ direction[free]
    assert np.abs(difference - exact).max() < 1e-6 * np.abs(exact).max()
    slope = (model.strain_energy(moved[0]) - model.strain_energy(moved[1])) / (2 * step)
    assert slope == pytest.approx(model.internal_forces(positions).ravel() @ direction, rel=1e-6)
    assert np.abs(stiffness - stiffness.T).max() <= 1e-12 * np.abs(stiffness).max()


@pytest.mark.parametrize("element", QUADRATIC)
def test_clamped_stiffness_is_positive_definite_and_free_one_has_six_rigid_modes(element):
    nodes, tets = box_mesh((2.0, 1.0, 1.0), (2, 1, 1))
    free_model, _ = quadratic_model(nodes, tets, "linear", np.array([], dtype=np.int64),
                                    element, poisson=0.45)
    eigenvalues = np.linalg.eigvalsh(free_model.internal_forces_and_stiffness(
        free_model.rest_nodes_mm)[1].toarray())
    assert np.all(np.abs(eigenvalues[:6]) < 1e-12 * eigenvalues[-1])
    assert eigenvalues[6] > 1e-4 * eigenvalues[-1]
    clamped, _ = quadratic_model(nodes, tets, "corotational", np.flatnonzero(nodes[:, 0] < 1e-9),
                                 element, poisson=0.45)
    _, stiffness = clamped.internal_forces_and_stiffness(clamped.rest_nodes_mm + 0.01)
    assert eigsh(stiffness, k=1, which="SA", return_eigenvectors=False)[0] > 0


# --- the cantilever at Poisson 0.45 ----------------------------------------------------

LENGTH_MM, SIDE_MM, POISSON = 100.0, 10.0, 0.45
SHEAR_MPA = YOUNG_MPA / (2 * (1 + POISSON))
# Timoshenko tip deflection per N of tip load, shear coefficient 5/6 (as test_fem_beams).
TIMOSHENKO_MM_PER_N = LENGTH_MM**3 / (3 * YOUNG_MPA * SIDE_MM**4 / 12) + LENGTH_MM / (
    5 / 6 * SHEAR_MPA * SIDE_MM**2)


@functools.cache
def cantilever_tip_mm_per_n(element, divisions):
    """Mean downward tip-face displacement per N of a uniform tip traction (linear law)."""
    nodes, tets = box_mesh((LENGTH_MM, SIDE_MM, SIDE_MM), divisions)
    model, fe = quadratic_model(nodes, tets, "linear", np.flatnonzero(nodes[:, 0] < 1e-9),
                                element, poisson=POISSON)
    faces = TetMesh(nodes, tets).surface_faces
    tip = faces[np.all(nodes[faces, 0] > LENGTH_MM - 1e-9, axis=1)]
    areas = TetMesh(nodes, tets).surface_face_areas_mm2[
        np.all(nodes[faces, 0] > LENGTH_MM - 1e-9, axis=1)]
    # consistent shares of a uniform traction: a third of each triangle's area at its corners
    # (P1), or at its mid-edge nodes (P2: int N_corner dA = 0, int N_edge dA = A / 3)
    carriers = fe.surface_triangles(tip).reshape(len(tip), -1, 3)[:, -1] if len(fe.edges) else tip
    weights = np.bincount(carriers.ravel(), np.repeat(areas / 3, 3), minlength=fe.node_count)
    weights /= weights.sum()
    carrying = np.flatnonzero(weights)
    row = sp.csr_matrix((-weights[carrying], (np.zeros(len(carrying), dtype=int),
                                              3 * carrying + 2)), shape=(1, 3 * fe.node_count))
    return compliance(linearize(model, model.rest_nodes_mm), row, row).W_ef[0, 0]


def test_cantilever_at_poisson_045_on_a_coarse_mesh():
    """10 x 2 x 2 cells (240 tets). Measured ratios to Timoshenko: P1 0.236 (locked), P2 0.944,
    P2-P0 0.998. The mesh-converged 3D value is itself 0.983 (Richardson on P2 meshes of
    10x1x1 / 20x2x2 / 40x4x4 cells, order 2.0): the clamped face cannot contract sideways,
    which stiffens a nu = 0.45 beam by 1.7%; P2 is 4% stiffer than that, P2-P0 1.5% softer."""
    ratios = {e: cantilever_tip_mm_per_n(e, (10, 2, 2)) / TIMOSHENKO_MM_PER_N
              for e in ("p1", "p2", "p2-p0")}
    print(f"\ncantilever nu = 0.45, 10x2x2 cells, ratio to Timoshenko: {ratios}")
    assert ratios["p1"] < 0.3
    assert ratios["p2-p0"] == pytest.approx(1.0, abs=0.03)
    assert ratios["p2"] == pytest.approx(1.0, abs=0.06)
    # P2 on cubic cells (20 x 2 x 2, 480 tets): measured 0.969
    assert cantilever_tip_mm_per_n("p2", (20, 2, 2)) / TIMOSHENKO_MM_PER_N == pytest.approx(
        1.0, abs=0.035)


# --- attachments and the robot ----------------------------------------------------------


def test_attachment_follows_the_quadratic_field():
    rng = np.random.default_rng(8)
    nodes, tets = box_mesh((4.0, 4.0, 4.0), (2, 2, 2))
    fe = element_mesh(nodes, tets, "p2")
    points = rng.uniform(0.2, 3.8, (30, 3))
    quadratic = attach_points(fe.nodes_mm, fe.elements, points)
    linear = attach_points(nodes, tets, points)
    assert quadratic.node_indices.shape == (30, 10) and quadratic.inside.all()
    np.testing.assert_allclose(quadratic.weights.sum(axis=1), 1.0)
    np.testing.assert_array_equal(quadratic.node_indices[:, :4], linear.node_indices)

    def bend(x):  # a quadratic deformation
        return x + 0.05 * np.stack([x[:, 1] * x[:, 2], x[:, 0] ** 2, x[:, 1] ** 2], axis=1)

    np.testing.assert_allclose(quadratic.positions(bend(fe.nodes_mm)), bend(points), atol=1e-12)
    assert np.abs(linear.positions(bend(nodes)) - bend(points)).max() > 1e-3


@pytest.fixture(scope="module")
def p2_robot():
    """The sample robot with P2-P0 elements and without gravity: with the file's gravity and
    the cables held, the P2 Diamond's equilibrium is unstable (W_aa has two negative
    eigenvalues, the apex tipping sideways; docs/locking.md), which P1's locking hides."""
    config = load_config(SAMPLE_ROBOT)
    config = dataclasses.replace(
        config, mesh=dataclasses.replace(config.mesh, element="p2-p0"),
        material=dataclasses.replace(config.material, gravity_mm_s2=(0.0, 0.0, 0.0)))
    return build_robot(config, read_tet_mesh(config.mesh.path))


def test_p2_robot_model(p2_robot):
    robot = p2_robot
    model = robot.fe_model
    n = robot.mesh.node_count
    assert model.element.name == "p2-p0" and model.tets.shape[1] == 10
    np.testing.assert_array_equal(model.rest_nodes_mm[:n], robot.mesh.nodes_mm)
    assert model.node_count == robot.fe_mesh.node_count > 5 * n
    assert np.all(model.fixed_nodes[: len(robot.fixed_nodes)] == robot.fixed_nodes)
    assert model.node_masses_kg.sum() == pytest.approx(0.5, rel=1e-12)
    assert np.all(model.node_masses_kg[np.unique(model.tets)] > 0)
    assert robot.cables[0].path.node_indices.shape == (1, 10)
    # markers snapped to mesh nodes keep their exact position under either element
    np.testing.assert_allclose(robot.marker_positions_mm,
                               [m.position_mm for m in robot.config.markers], atol=1e-9)


def test_p2_robot_equilibrium_and_compliance(p2_robot):
    """Cables pulled (5, 5, 0, 0) mm: forces balance, and W is the symmetric positive
    definite compliance of eq. 5 at the P2-P0 equilibrium."""
    robot = p2_robot
    model = robot.fe_model
    equilibrium = solve_equilibrium(model, robot.cable_inputs(np.array([5.0, 5.0, 0.0, 0.0])))
    cables = model.cable_jacobian(equilibrium.positions_mm).T @ equilibrium.cable_tensions_n
    total = (model.gravity_forces_n.sum(axis=0) + cables.reshape(-1, 3).sum(axis=0)
             + equilibrium.reaction_forces_n.sum(axis=0))
    assert np.abs(total).max() < 1e-8
    assert equilibrium.cable_shortenings_mm[:2] == pytest.approx([5.0, 5.0], abs=1e-6)
    features = robot.attach(robot.mesh.nodes_mm[robot.feature_nodes])
    normals = robot.feature_normals
    linear = linearize(model, equilibrium.positions_mm, equilibrium.cable_tensions_n)
    W = compliance(linear, effector_rows(features, model.node_count, normals),
                   force_rows(features.subset(np.array([0, 20])), normals[[0, 20]],
                              model.node_count))
    assert np.abs(W.W_aa - W.W_aa.T).max() < 1e-10 * np.abs(W.W_aa).max()
    assert np.linalg.eigvalsh(W.W_aa).min() > 0
    np.testing.assert_allclose(W.W_ef[[0, 20]], W.W_ef[[0, 20]].T, rtol=1e-9)


def test_robot_file_rejects_an_unknown_element(tmp_path):
    text = SAMPLE_ROBOT.read_text().replace("scale = 1.0", 'scale = 1.0\nelement = "p3"')
    (tmp_path / "robot.toml").write_text(text)
    with pytest.raises(ModelError, match=r"mesh\.element 'p3' unknown"):
        load_config(tmp_path / "robot.toml")


def test_p1_is_the_default_and_the_same_code_path():
    config = load_config(SAMPLE_ROBOT)
    assert config.mesh.element == "p1"
    assert ELEMENTS["p1"] is P1 and P1.quadrature_count == 1


def test_model_solve_with_p2_writes_the_mesh_nodes_in_input_order(tmp_path):
    for file in SAMPLE_ROBOT.parent.iterdir():
        shutil.copy(file, tmp_path / file.name)
    robot_file = tmp_path / SAMPLE_ROBOT.name
    robot_file.write_text(robot_file.read_text().replace(
        "scale = 1.0", 'scale = 1.0\nelement = "p2-p0"'))
    output = tmp_path / "deformed.vtu"
    result = softforce("model", "solve", robot_file, "--actuation", "5,5,5,5", "-o", output,
                       "--json")
    assert result.returncode == 0, result.stderr
    rest = meshio.read(tmp_path / "diamond_coarse.vtu")
    deformed = meshio.read(output)
    np.testing.assert_allclose(deformed.points - deformed.point_data["displacement_mm"],
                               rest.points, atol=1e-9)
    np.testing.assert_array_equal(deformed.cells_dict["tetra"], rest.cells_dict["tetra"])
    shown = softforce("model", "show", robot_file, "--json")
    assert '"element": "p2-p0"' in shown.stdout
