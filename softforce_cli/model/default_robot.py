"""softforce's own default robot: the procedural Diamond, written as a robot TOML + mesh."""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np

from softforce_cli.io.atomic import atomic_path, atomic_write_text, check_writable
from softforce_cli.model.features import nearest_surface_nodes
from softforce_cli.model.mesh import TetMesh
from softforce_cli.model.procedural import DiamondGeometry, diamond_mesh

ROBOT_FILE = "diamond.toml"
# Cable directions as in SOFA's Diamond scene: name and unit radial direction.
ARMS = (("north", (0.0, 1.0)), ("west", (-1.0, 0.0)), ("south", (0.0, -1.0)),
        ("east", (1.0, 0.0)))


def marker_targets(geometry: DiamondGeometry) -> dict[str, np.ndarray]:
    """Where the nine calibration markers go (snapped to surface nodes): the apex top, the
    outer point of each elbow, and the middle of each upper bar's upper face."""
    elbow_outer = geometry.elbow_radius_mm + geometry.elbow_joint_radius_mm
    bar_mid_r = 0.5 * geometry.elbow_radius_mm
    bar_mid_z = 0.5 * (geometry.elbow_height_mm + geometry.apex_height_mm) + 8.0
    targets = {"apex": np.array([0.0, 0.0, geometry.apex_height_mm])}
    for name, (dx, dy) in ARMS:
        targets[f"elbow_{name}"] = np.array([elbow_outer * dx, elbow_outer * dy,
                                             geometry.elbow_height_mm])
    for name, (dx, dy) in ARMS:
        targets[f"bar_{name}"] = np.array([bar_mid_r * dx, bar_mid_r * dy, bar_mid_z])
    return targets


def robot_toml(mesh_file: str, markers: dict[str, np.ndarray], resolution: str) -> str:
    """The default robot file's text."""
    def vec(v) -> str:
        return "[" + ", ".join(f"{float(x):.4f}" for x in v) + "]"

    lines = [
        f"# softforce default robot: procedural Diamond ({resolution} mesh), DESIGN.md section 4.",
        'name = "diamond"', "",
        "[mesh]", f'path = "{mesh_file}"', "scale = 1.0", "rotation_deg = [0.0, 0.0, 0.0]",
        "translation_mm = [0.0, 0.0, 0.0]", "",
        "[material]", 'law = "corotational"', "young_modulus_mpa = 0.18", "poisson_ratio = 0.45",
        "total_mass_kg = 0.5", "gravity_mm_s2 = [0.0, 0.0, -9810.0]", "",
        "[[fixed]]", "box_mm = [-15.0, -15.0, -40.0, 15.0, 15.0, 10.0]", "",
    ]
    for name, (dx, dy) in ARMS:
        lines += [
            "[[cable]]", f'name = "{name}"', f"path_mm = [{vec([97 * dx, 97 * dy, 45])}]",
            f"pull_point_mm = {vec([10 * dx, 10 * dy, 30])}", 'control = "displacement"',
            "min = 0.0", "max = 20.0", "",
        ]
    lines += ["[features]", "count = 51", ""]
    for marker_id, position in markers.items():
        lines += ["[[marker]]", f'id = "{marker_id}"', f"position_mm = {vec(position)}", ""]
    return "\n".join(lines)


def write_default_robot(directory: Path, resolution: str = "coarse",
                        force: bool = False) -> Path:
    """Mesh the procedural Diamond and write ROBOT_FILE and its .vtu into `directory`.

    Returns the robot file's path. Nothing is overwritten unless `force`.
    """
    directory = Path(directory)
    mesh_file = f"diamond_{resolution}.vtu"
    robot_path, mesh_path = directory / ROBOT_FILE, directory / mesh_file
    for path in (robot_path, mesh_path):
        check_writable(path, force)
    geometry = DiamondGeometry()
    nodes, tets = diamond_mesh(resolution, geometry)
    mesh = TetMesh(nodes, tets)
    targets = marker_targets(geometry)
    indices, _ = nearest_surface_nodes(nodes, mesh.surface_nodes, np.array(list(targets.values())))
    markers = dict(zip(targets, nodes[indices], strict=True))
    directory.mkdir(parents=True, exist_ok=True)
    with atomic_path(mesh_path, force=force) as tmp:
        meshio.write_points_cells(tmp, nodes, [("tetra", tets)], file_format="vtu")
    atomic_write_text(robot_path, robot_toml(mesh_file, markers, resolution), force=force)
    return robot_path
