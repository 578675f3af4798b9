"""softforce's own default robot: the procedural Diamond, written as a robot TOML + mesh."""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np

from softforce_cli.io.atomic import atomic_path, atomic_write_text, check_writable, writable_folder
from softforce_cli.model.procedural import DiamondGeometry, diamond_mesh

ROBOT_FILE = "diamond.toml"
# Cable directions as in SOFA's Diamond scene: name and unit radial direction.
ARMS = (("north", (0.0, 1.0)), ("west", (-1.0, 0.0)), ("south", (0.0, -1.0)),
        ("east", (1.0, 0.0)))


def marker_positions(geometry: DiamondGeometry) -> dict[str, np.ndarray]:
    """The nine calibration markers, on the ideal surface of the solid (mm): the apex top, the
    outer point of each elbow, and the middle of each upper bar's upper face.

    They depend on the geometry only, not on the mesh, so robots of every resolution carry
    the same physical markers (each mesh attaches them barycentrically).
    """
    g = geometry
    elbow = np.array([g.elbow_radius_mm, g.elbow_height_mm])  # (r, z)
    apex_axis = np.array([0.0, g.apex_height_mm - 0.5 * g.apex_depth_mm])
    along = (apex_axis - elbow) / np.linalg.norm(apex_axis - elbow)
    outward = np.array([-along[1], along[0]])  # the upper face's normal, pointing up and out
    if outward[1] < 0:
        outward = -outward
    bar_r, bar_z = 0.5 * (elbow + apex_axis) + 0.5 * g.bar_thickness_mm * outward
    elbow_outer = g.elbow_radius_mm + g.elbow_joint_radius_mm
    markers = {"apex": np.array([0.0, 0.0, g.apex_height_mm])}
    for name, (dx, dy) in ARMS:
        markers[f"elbow_{name}"] = np.array([elbow_outer * dx, elbow_outer * dy,
                                             g.elbow_height_mm])
    for name, (dx, dy) in ARMS:
        markers[f"bar_{name}"] = np.array([bar_r * dx, bar_r * dy, bar_z])
    return markers


def robot_toml(mesh_file: str, markers: dict[str, np.ndarray], resolution: str) -> str:
    """The default robot file's text."""
    def vec(v) -> str:
        return "[" + ", ".join(f"{float(x):.4f}" for x in v) + "]"

    lines = [
        f"# softforce default robot: procedural Diamond ({resolution} mesh), docs/robot_model.md.",
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
    markers = marker_positions(geometry)
    writable_folder(directory)
    with atomic_path(mesh_path, force=force) as tmp:
        meshio.write_points_cells(tmp, nodes, [("tetra", tets)], file_format="vtu")
    atomic_write_text(robot_path, robot_toml(mesh_file, markers, resolution), force=force)
    return robot_path
