"""Objects in the virtual scene besides the robot: probes, hanging weights, their meshes.

Meshes come from open3d's primitives; every function returns a render.SceneSurface in the
robot frame (mm).
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from softforce_cli.sim.render import SceneSurface

PROBE_RADIUS_MM = 5.0  # a 10 mm rod with a hemispherical tip
PROBE_LENGTH_MM = 90.0
STRING_RADIUS_MM = 0.8
WEIGHT_RADIUS_MM = 11.0
WEIGHT_HEIGHT_MM = 14.0
WEIGHT_DROP_MM = 30.0  # string length between the attachment point and the weight


def _rotation_z_to(direction: np.ndarray) -> np.ndarray:
    """(3, 3) rotation taking +z to the unit vector `direction`."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, direction)
    sine, cosine = np.linalg.norm(axis), float(z @ direction)
    if sine < 1e-12:
        return np.eye(3) if cosine > 0 else np.diag([1.0, -1.0, -1.0])
    k = axis / sine
    skew = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + sine * skew + (1 - cosine) * skew @ skew


def _surface(name: str, mesh: o3d.geometry.TriangleMesh, color_rgb) -> SceneSurface:
    return SceneSurface(
        name,
        np.asarray(mesh.vertices),
        np.asarray(mesh.triangles),
        np.asarray(color_rgb),
        smooth=True,
    )


def probe_surface(
    tip_mm: np.ndarray, force_direction: np.ndarray, color_rgb, name: str = "probe"
) -> SceneSurface:
    """A rod whose hemispherical tip touches `tip_mm`, pushing along `force_direction`.

    The rod lies on the side the force comes from: its axis runs from the tip against the
    force direction.
    """
    direction = np.asarray(force_direction, float) / np.linalg.norm(force_direction)
    tip_centre = np.asarray(tip_mm, float) - PROBE_RADIUS_MM * direction
    rod = o3d.geometry.TriangleMesh.create_cylinder(PROBE_RADIUS_MM, PROBE_LENGTH_MM, 24, 1)
    rod.translate((0.0, 0.0, PROBE_LENGTH_MM / 2))  # base at the origin, along +z
    tip = o3d.geometry.TriangleMesh.create_sphere(PROBE_RADIUS_MM, 12)
    probe = rod + tip
    probe.rotate(_rotation_z_to(-direction), center=(0.0, 0.0, 0.0))
    probe.translate(tip_centre)
    return _surface(name, probe, color_rgb)


def weight_surface(point_mm: np.ndarray, color_rgb, name: str = "weight") -> SceneSurface:
    """A string hanging from `point_mm` with a cylindrical weight at its end (gravity -z)."""
    point = np.asarray(point_mm, float)
    string = o3d.geometry.TriangleMesh.create_cylinder(STRING_RADIUS_MM, WEIGHT_DROP_MM, 8, 1)
    string.translate(point - np.array([0.0, 0.0, WEIGHT_DROP_MM / 2]))
    body = o3d.geometry.TriangleMesh.create_cylinder(WEIGHT_RADIUS_MM, WEIGHT_HEIGHT_MM, 32, 1)
    body.translate(point - np.array([0.0, 0.0, WEIGHT_DROP_MM + WEIGHT_HEIGHT_MM / 2]))
    return _surface(name, string + body, color_rgb)
