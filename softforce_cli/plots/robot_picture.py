"""A picture of a robot model: surface, clamped nodes, cables, feature points, markers."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from softforce_cli.io.atomic import atomic_path
from softforce_cli.model.robot import Robot


def save_robot_picture(robot: Robot, path: Path, positions_mm: np.ndarray | None = None,
                       force: bool = False) -> None:
    """PNG of the robot (rest shape, or FE node positions `positions_mm` (N, 3)) from two
    viewpoints."""
    nodes = robot.rest_nodes_mm if positions_mm is None else positions_mm
    faces = robot.mesh.surface_faces
    figure = plt.figure(figsize=(12, 6), dpi=110)
    for column, (elevation, azimuth) in enumerate(((25, -60), (90, -90))):
        axes = figure.add_subplot(1, 2, column + 1, projection="3d")
        normals = np.cross(nodes[faces[:, 1]] - nodes[faces[:, 0]],
                           nodes[faces[:, 2]] - nodes[faces[:, 0]])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        shade = 0.45 + 0.5 * np.clip(normals @ np.array([0.3, -0.4, 0.85]), 0, 1)
        colours = np.outer(shade, [0.35, 0.55, 0.9])
        axes.add_collection3d(Poly3DCollection(nodes[faces], facecolors=colours,
                                               edgecolors="none", alpha=0.55))
        fixed = nodes[robot.fixed_nodes]
        axes.scatter(*fixed.T, s=4, c="black", label=f"clamped ({len(fixed)})")
        features = nodes[robot.feature_nodes]
        axes.scatter(*features.T, s=10, c="orange", label=f"features ({len(features)})")
        markers = robot.marker_points.positions(nodes)
        if len(markers):
            axes.scatter(*markers.T, s=40, c="red", marker="^",
                         label=f"markers ({len(markers)})")
        for cable in robot.cables:
            points = cable.points(nodes)
            axes.plot(*points.T, c="green", lw=2)
        axes.plot([], [], c="green", lw=2, label=f"cables ({len(robot.cables)})")
        low, high = nodes.min(axis=0), nodes.max(axis=0)
        centre, half = (low + high) / 2, (high - low).max() / 2
        axes.set(xlim=(centre[0] - half, centre[0] + half),
                 ylim=(centre[1] - half, centre[1] + half),
                 zlim=(centre[2] - half, centre[2] + half),
                 xlabel="x (mm)", ylabel="y (mm)", zlabel="z (mm)")
        axes.view_init(elev=elevation, azim=azimuth)
        if column == 0:
            axes.legend(loc="upper left", fontsize=8)
    figure.suptitle(f"{robot.name}: {robot.mesh.tet_count} tetrahedra, "
                    f"{robot.mesh.node_count} nodes, {robot.mass_kg:.3f} kg")
    figure.tight_layout()
    with atomic_path(Path(path), force=force) as tmp:
        figure.savefig(tmp, format="png")
    plt.close(figure)
