"""The cached linearisation of sensing (estimation.linear_model) against direct solves."""

from __future__ import annotations

import numpy as np
import pytest

from softforce_cli.estimation.linear_model import LinearizedModel
from softforce_cli.fem.attachment import Attachment
from softforce_cli.fem.compliance import compliance, linearize
from softforce_cli.fem.statics import solve_equilibrium
from softforce_cli.model.mesh import vertex_normals


@pytest.fixture(scope="module")
def state(sample_robot):
    model = sample_robot.fe_model
    equilibrium = solve_equilibrium(model, sample_robot.cable_inputs(np.array([5.0, 0, 5.0, 0])))
    return sample_robot, model, equilibrium


def _geometry(robot, positions):
    mesh = robot.mesh
    normals = vertex_normals(positions[: mesh.node_count], mesh.surface_faces)
    surface = mesh.surface_nodes
    nodes = surface[np.argsort(np.linalg.norm(positions[surface] - [0, 45, 90], axis=1))[[0, 7]]]
    inside = robot.attach(np.array([[0.0, 40.0, 80.0]]))  # a point inside an element
    points = Attachment(np.vstack([Attachment.at_nodes(nodes).node_indices, inside.node_indices]),
                        np.vstack([Attachment.at_nodes(nodes).weights, inside.weights]),
                        np.ones(3, bool))
    directions = np.vstack([-normals[nodes], [[0.0, 0.6, -0.8]]])
    features = Attachment.at_nodes(robot.feature_nodes)
    effectors = features.directional_rows(normals[robot.feature_nodes], robot.fe_model.node_count)
    return points, directions, effectors


def test_cached_compliance_and_update_equal_a_direct_linearisation(state):
    """W matrices, free displacements and the eq. 6 update from cached columns (x, y, z per
    contact node, combined along the direction) against fem.compliance's direct solve of the
    force rows, at the same configuration."""
    robot, model, equilibrium = state
    x, tensions = equilibrium.positions_mm, equilibrium.cable_tensions_n
    points, directions, effectors = _geometry(robot, x)
    force_rows = points.directional_rows(directions, model.node_count)
    linear = LinearizedModel(model, model.coordinates.state(x), tensions)
    responses = linear.force_responses(points, directions)
    cached = linear.compliance(effectors, responses)
    direct_lin = linearize(model, x, tensions)
    direct = compliance(direct_lin, effectors, force_rows)
    for name in ("W_ea", "W_ef", "W_aa", "W_af", "delta_e_free", "delta_a_free"):
        np.testing.assert_allclose(getattr(cached, name), getattr(direct, name), rtol=1e-8,
                                   atol=1e-9 * np.abs(getattr(direct, name)).max(), err_msg=name)
    lam_a, lam_f = tensions + np.array([0.1, -0.05, 0.02, 0.0]), np.array([0.2, 0.1, 0.3])
    loads = lam_a @ model.cable_jacobian(x) + force_rows.T @ lam_f
    expected = x + direct_lin.free_motion_mm + direct_lin.responses(loads[None]).reshape(-1, 3)
    np.testing.assert_allclose(linear.configuration(lam_a, responses, lam_f).positions_mm,
                               expected, atol=1e-9)
    assert linear.moved_mm(x) == 0.0


def test_contact_nodes_are_solved_once_and_combined_linearly(state):
    robot, model, equilibrium = state
    linear = LinearizedModel(model, model.coordinates.state(equilibrium.positions_mm),
                             equilibrium.cable_tensions_n)
    node = robot.mesh.surface_nodes[:1]
    at = Attachment.at_nodes(node)
    x_axis = linear.force_responses(at, np.array([[1.0, 0, 0]]))
    z_axis = linear.force_responses(at, np.array([[0, 0, 1.0]]))
    slanted = linear.force_responses(at, np.array([[0.6, 0, 0.8]]))
    assert linear.cached_nodes == 1
    np.testing.assert_allclose(slanted, 0.6 * x_axis + 0.8 * z_axis, atol=1e-12)
    # a unit force's own displacement along it is positive (K positive definite there)
    assert model.coordinates.lift(x_axis)[3 * node[0], 0] > 0
