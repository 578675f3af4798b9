"""Robot TOML loading, validation errors, meshes from meshio, features and attachments."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import meshio
import numpy as np
import pytest

from softforce_cli.errors import ModelError
from softforce_cli.fem.attachment import attach_points, barycentric_coordinates
from softforce_cli.model.features import face_nodes
from softforce_cli.model.mesh import TetMesh
from softforce_cli.model.mesh_io import read_tet_mesh, rotation_from_euler_deg
from softforce_cli.model.robot import load_robot
from softforce_cli.model.structured import box_mesh
from tests.conftest import SAMPLE_ROBOT


def test_sample_robot_matches_the_design(sample_robot):
    robot = sample_robot
    assert 4000 <= robot.mesh.tet_count <= 5000
    assert robot.mass_kg == pytest.approx(0.5)
    assert len(robot.cables) == 4 and len(robot.feature_nodes) == 51
    assert robot.marker_ids[0] == "apex" and len(robot.marker_ids) == 9
    # clamped nodes all lie in the design's box
    fixed = robot.mesh.nodes_mm[robot.fixed_nodes]
    assert np.all(np.abs(fixed[:, :2]) <= 15) and np.all(fixed[:, 2] <= 10)
    # every feature point is a surface node away from the clamp, the apex among them
    assert set(robot.feature_nodes) <= set(robot.mesh.surface_nodes)
    assert not set(robot.feature_nodes) & set(robot.fixed_nodes)
    assert np.argmax(robot.mesh.nodes_mm[:, 2]) in robot.feature_nodes
    # outward normals: at the apex the normal points up
    apex = robot.feature_nodes[np.argmax(robot.mesh.nodes_mm[robot.feature_nodes, 2])]
    assert robot.mesh.vertex_normals[apex, 2] > 0.7


def test_feature_points_are_spread_evenly(sample_robot):
    features = sample_robot.mesh.nodes_mm[sample_robot.feature_nodes]
    distance = np.linalg.norm(features[:, None] - features[None], axis=2)
    np.fill_diagonal(distance, np.inf)
    nearest = distance.min(axis=1)
    # farthest-point sampling: no two features much closer than the typical spacing
    assert nearest.min() > 0.3 * np.median(nearest)


def test_face_nodes_of_a_box_are_its_nodes_off_edges_and_corners():
    nodes, tets = box_mesh((40.0, 30.0, 20.0), (4, 3, 2))
    mesh = TetMesh(nodes, tets)
    on_faces = face_nodes(nodes, mesh.surface_faces)
    # a node is on an edge or corner when two or more of its coordinates are at the box's
    # bounds; on a face when exactly one is
    at_bound = (np.isclose(nodes, 0.0) | np.isclose(nodes, [40.0, 30.0, 20.0])).sum(axis=1)
    np.testing.assert_array_equal(on_faces, np.flatnonzero(at_bound == 1))


def test_features_placed_on_faces_keep_off_the_edges(tmp_path):
    path = _copy_robot(tmp_path)
    path.write_text(path.read_text().replace("count = 51", 'count = 101\nplacement = "faces"'))
    robot = load_robot(path)
    spread = load_robot(SAMPLE_ROBOT)
    assert len(robot.feature_nodes) == 101
    assert not np.isin(robot.fixed_nodes, robot.feature_nodes).any()

    on_faces = face_nodes(robot.mesh.nodes_mm, robot.mesh.surface_faces)  # the box test's
    # the Diamond's bars are box sections: spread evenly, most features land on their edges
    assert np.isin(spread.feature_nodes, on_faces).mean() < 0.3
    assert np.isin(robot.feature_nodes, on_faces).all()
    apex = robot.mesh.nodes_mm[:, 2].max()
    assert robot.mesh.nodes_mm[robot.feature_nodes, 2].max() == apex


def test_sofa_diamond_loads_with_its_transform(sofa_diamond_dir):
    robot = load_robot(sofa_diamond_dir / "diamond.toml")
    assert (robot.mesh.node_count, robot.mesh.tet_count) == (1628, 4147)  # README of the mesh
    assert len(robot.fixed_nodes) == 58  # README: 58 nodes in the clamped box
    assert robot.mesh.bounds_mm[1, 2] == pytest.approx(125.7, abs=0.1)  # apex height
    assert np.all(robot.mesh.tet_volumes_mm3 > 0)


def test_sofa_fine_mesh_loads(sofa_diamond_dir):
    mesh = read_tet_mesh(sofa_diamond_dir / "diamond_34k_tet.vtu", 1.0, (90, 0, 0), (0, 0, 35))
    assert (mesh.node_count, mesh.tet_count) == (8646, 33719)
    box = np.all((mesh.nodes_mm >= [-15, -15, -40]) & (mesh.nodes_mm <= [15, 15, 10]), axis=1)
    assert box.sum() == 379  # README: 379 nodes of the 34k mesh in the clamped box


def test_rotation_order_is_x_then_y_then_z():
    R = rotation_from_euler_deg((90, 90, 0))
    # x first takes y to z, then y takes z to x
    np.testing.assert_allclose(R @ [0, 1, 0], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0)


def test_meshes_round_trip_through_meshio_formats(tmp_path):
    nodes, tets = box_mesh((10, 20, 30), (2, 2, 3))
    for suffix in (".vtu", ".vtk", ".msh", ".mesh"):
        path = tmp_path / f"box{suffix}"
        meshio.write_points_cells(path, nodes, [("tetra", tets)])
        mesh = read_tet_mesh(path, 2.0, (0, 0, 90), (1, 2, 3))
        assert mesh.tet_count == len(tets)
        assert mesh.volume_mm3 == pytest.approx(8 * 10 * 20 * 30)  # scale 2 in 3D


def test_barycentric_attachment_reproduces_points():
    nodes, tets = box_mesh((10, 10, 10), (3, 3, 3))
    rng = np.random.default_rng(0)
    points = rng.uniform(0.5, 9.5, (50, 3))
    attachment = attach_points(nodes, tets, points)
    assert attachment.inside.all()
    assert np.all(attachment.weights >= -1e-12)
    np.testing.assert_allclose(attachment.positions(nodes), points, atol=1e-12)
    # the attachment moves affinely with an affine deformation of the mesh
    A = np.array([[1.1, 0.2, 0], [0, 0.9, 0.1], [0.05, 0, 1.2]])
    np.testing.assert_allclose(attachment.positions(nodes @ A.T), points @ A.T, atol=1e-12)
    outside = attach_points(nodes, tets, np.array([[5.0, 5.0, 11.0]]))
    assert not outside.inside[0]
    np.testing.assert_allclose(outside.positions(nodes), [[5, 5, 11]], atol=1e-9)
    corners = nodes[tets[:3]]
    coords = barycentric_coordinates(corners.mean(axis=1), corners)
    np.testing.assert_allclose(coords, 0.25)


def _copy_robot(tmp_path: Path) -> Path:
    for file in SAMPLE_ROBOT.parent.iterdir():
        shutil.copy(file, tmp_path / file.name)
    return tmp_path / SAMPLE_ROBOT.name


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ('law = "corotational"', 'law = "hyperfoam"', "material.law 'hyperfoam' unknown"),
        ("young_modulus_mpa = 0.18", "young_modulus_mpa = 180000", "looks like Pa or kPa"),
        ("poisson_ratio = 0.45", "poisson_ratio = 0.5", "must be in [0, 0.5)"),
        ("gravity_mm_s2 = [0.0, 0.0, -9810.0]", "gravity_mm_s2 = [0.0, 0.0, -9.81]",
         "looks like m/s^2"),
        ("total_mass_kg = 0.5", "density_kg_m3 = 1.07", "looks like g/cm^3"),
        ("total_mass_kg = 0.5", "total_mass_kg = 0.5\ncolour = 3", "unknown key 'colour'"),
        ("box_mm = [-15.0, -15.0, -40.0, 15.0, 15.0, 10.0]",
         "box_mm = [200.0, 200.0, 200.0, 300.0, 300.0, 300.0]", "catches no node"),
        ("path_mm = [[0.0000, 97.0000, 45.0000]]", "path_mm = [[0.0000, 140.0000, 45.0000]]",
         "outside the mesh"),
        # the marker's position was printed as [np.float64(0.0), ...]
        ("position_mm = [0.0000, 0.0000, 126.0000]", "position_mm = [0.0000, 0.0000, 500.0]",
         "marker 'apex' at [0.0, 0.0, 500.0] mm is 374.1 mm outside the mesh"),
        # a segment of no length: the cable's rows were NaN, a ValueError traceback
        ("pull_point_mm = [0.0000, 10.0000, 30.0000]", "pull_point_mm = [0.0, 97.0, 45.0]",
         "cable 'north' has two consecutive points (path_mm, then pull_point_mm) 0 mm apart"),
        ('path = "diamond_coarse.vtu"', 'path = "missing.vtu"', "not found"),
        ("count = 51", "count = -3", "positive integer"),
        ("count = 51", 'count = 51\nplacement = "edges"', "features.placement must be one of"),
        ("count = 51", 'points_mm = [[0.0, 0.0, 126.0]]\nplacement = "faces"',
         "placement applies to `count`"),
    ],
)
def test_bad_robot_files_give_one_clear_line(tmp_path, old, new, message):
    path = _copy_robot(tmp_path)
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(ModelError, match=re.escape(message)) as err:
        load_robot(path)
    assert "\n" not in str(err.value)


def test_meshes_without_tetrahedra_or_with_inverted_ones_are_rejected(tmp_path):
    nodes, tets = box_mesh((10, 10, 10), (2, 2, 2))
    triangles = tmp_path / "surface.vtu"
    meshio.write_points_cells(triangles, nodes, [("triangle", tets[:, :3])])
    with pytest.raises(ModelError, match="no tetrahedra"):
        read_tet_mesh(triangles)
    flipped = tets.copy()
    flipped[:5] = flipped[:5][:, [1, 0, 2, 3]]
    inverted = tmp_path / "inverted.vtu"
    meshio.write_points_cells(inverted, nodes, [("tetra", flipped)])
    with pytest.raises(ModelError, match="5 inverted tetrahedra"):
        read_tet_mesh(inverted)
    # consistently negative orientation (some exporters) is accepted and reoriented
    negative = tmp_path / "negative.vtu"
    meshio.write_points_cells(negative, nodes, [("tetra", tets[:, [1, 0, 2, 3]])])
    assert np.all(read_tet_mesh(negative).tet_volumes_mm3 > 0)
    flat = nodes.copy()
    flat[:, 2] = 0.0
    degenerate = tmp_path / "flat.vtu"
    meshio.write_points_cells(degenerate, flat, [("tetra", tets)])
    with pytest.raises(ModelError):
        read_tet_mesh(degenerate)
    garbage = tmp_path / "garbage.vtu"
    garbage.write_text("not a mesh")
    with pytest.raises(ModelError, match="cannot read mesh"):
        read_tet_mesh(garbage)
