"""Properties of the procedural Diamond mesh: size, validity, the geometry the model file needs."""

import gmsh
import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from softforce_cli.errors import ModelError
from softforce_cli.model.mesh import TET_FACES, tet_signed_volumes
from softforce_cli.model.procedural import DiamondGeometry, diamond_mesh

# The Diamond's cable attachment points and the fixed box, from the SOFA scene
# (docs/robot_model.md).
CABLE_POINTS_MM = np.array([[0, 97, 45], [-97, 0, 45], [0, -97, 45], [97, 0, 45]], float)
FIXED_BOX_MM = np.array([[-15, -15, -40], [15, 15, 10]], float)


@pytest.fixture(scope="module")
def coarse():
    return diamond_mesh("coarse")


def barycentric(nodes, tets, point):
    """(m, 4) barycentric coordinates of one point (3,) in every tetrahedron."""
    corners = nodes[tets]
    edges = np.transpose(corners[:, 1:] - corners[:, :1], (0, 2, 1))
    lam = np.linalg.solve(edges, (point - corners[:, 0])[:, :, None])[:, :, 0]
    return np.column_stack([1 - lam.sum(axis=1), lam])


def inside(nodes, tets, point):
    return bool((barycentric(nodes, tets, point) >= -1e-9).all(axis=1).any())


def radius_ratios(nodes, tets):
    """(m,) 3 * inradius / circumradius: 1 for a regular tetrahedron, 0 for a flat one."""
    corners = nodes[tets]
    u, v, w = (corners[:, k] - corners[:, 0] for k in (1, 2, 3))
    triple = np.einsum("ij,ij->i", u, np.cross(v, w))
    centre = (
        (u * u).sum(1)[:, None] * np.cross(v, w)
        + (v * v).sum(1)[:, None] * np.cross(w, u)
        + (w * w).sum(1)[:, None] * np.cross(u, v)
    ) / (2 * triple[:, None])
    faces = corners[:, TET_FACES]
    areas = 0.5 * np.linalg.norm(
        np.cross(faces[:, :, 1] - faces[:, :, 0], faces[:, :, 2] - faces[:, :, 0]), axis=2
    ).sum(axis=1)
    inradius = 3 * (triple / 6) / areas
    return 3 * inradius / np.linalg.norm(centre, axis=1)


def test_tet_counts_match_resolutions(coarse):
    fine_nodes, fine_tets = diamond_mesh("fine")
    nodes, tets = coarse
    assert 4000 <= len(tets) <= 5000
    assert 16000 <= len(fine_tets) <= 20000
    assert len(fine_nodes) > 2 * len(nodes)


def test_arrays_are_deterministic(coarse):
    nodes, tets = diamond_mesh("coarse")
    assert nodes.dtype == np.float64 and nodes.shape[1] == 3
    assert tets.dtype == np.int64 and tets.shape[1] == 4
    np.testing.assert_array_equal(nodes, coarse[0])
    np.testing.assert_array_equal(tets, coarse[1])


def test_tets_positive_well_shaped_and_every_node_used(coarse):
    nodes, tets = coarse
    assert tet_signed_volumes(nodes, tets).min() > 0
    # This is gmsh's "gamma"; getElementQualities gives the same minimum, 0.167 (coarse,
    # gmsh 4.15). Below 0.1 would mean slivers.
    assert radius_ratios(nodes, tets).min() > 0.1
    np.testing.assert_array_equal(np.unique(tets), np.arange(len(nodes)))


def test_volume_is_plausible(coarse):
    volume = tet_signed_volumes(*coarse).sum()
    # gmsh's OCC mass of the solid is 326,286 mm^3 (faceted cylinders lose ~0.5%); SOFA's
    # own Diamond mesh has about 392,000 mm^3.
    print(f"Diamond volume {volume:.0f} mm^3")
    assert 150e3 < volume < 600e3


def test_single_connected_component(coarse):
    nodes, tets = coarse
    rows = np.repeat(tets, 4, axis=1).ravel()
    cols = np.tile(tets, 4).ravel()
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(nodes),) * 2)
    count, _ = connected_components(graph, directed=False)
    assert count == 1


def test_cable_points_inside_with_margin(coarse):
    # Six axis and eight diagonal probes at 2 mm: a ball of that radius stays in the solid.
    diagonals = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T / np.sqrt(3)
    probes = 2.0 * np.vstack([np.zeros(3), np.eye(3), -np.eye(3), diagonals])
    for point in CABLE_POINTS_MM:
        for probe in probes:
            assert inside(*coarse, point + probe), (point, probe)


def test_apex_top_and_marker(coarse):
    nodes, tets = coarse
    assert 125.0 <= nodes[:, 2].max() <= 127.0
    assert inside(nodes, tets, np.array([0.0, 0.0, 125.0]))


def test_four_fold_symmetry(coarse):
    nodes, tets = coarse
    low, high = nodes.min(axis=0), nodes.max(axis=0)
    assert np.abs(low[:2] + high[:2]).max() < 0.5
    assert abs((high[0] - low[0]) - (high[1] - low[1])) < 0.5
    volumes = tet_signed_volumes(nodes, tets)
    centroids = nodes[tets].mean(axis=1)
    quadrants = [
        volumes[(sx * centroids[:, 0] > 0) & (sy * centroids[:, 1] > 0)].sum()
        for sx in (1, -1)
        for sy in (1, -1)
    ]
    assert np.ptp(quadrants) < 0.02 * np.mean(quadrants)


def test_fixed_box_holds_only_hub_nodes(coarse):
    nodes, _ = coarse
    geometry = DiamondGeometry()
    in_box = ((nodes >= FIXED_BOX_MM[0]) & (nodes <= FIXED_BOX_MM[1])).all(axis=1)
    assert in_box.sum() >= 20
    boxed = nodes[in_box]
    assert boxed[:, 2].max() <= geometry.base_top_mm + 1e-6
    assert np.hypot(boxed[:, 0], boxed[:, 1]).max() <= geometry.base_radius_mm + 1e-6
    assert boxed[:, 2].min() == pytest.approx(geometry.base_bottom_mm)


def test_unknown_resolution_is_a_model_error():
    with pytest.raises(ModelError, match="unknown mesh resolution"):
        diamond_mesh("medium")


def test_gmsh_failure_is_a_model_error_and_gmsh_is_released():
    with pytest.raises(ModelError, match="gmsh"):
        diamond_mesh("coarse", DiamondGeometry(bar_thickness_mm=0.0))
    assert not gmsh.isInitialized()


def test_runs_inside_a_caller_gmsh_session(coarse):
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        _, tets = diamond_mesh("coarse")
        assert gmsh.isInitialized()
    finally:
        gmsh.finalize()
    np.testing.assert_array_equal(tets, coarse[1])
