"""A robot's vital statistics, as a plain dict ready for a table or JSON."""

from __future__ import annotations

from typing import Any

import numpy as np

from softforce_cli.fem.statics import Equilibrium
from softforce_cli.model.robot import Robot


def robot_summary(robot: Robot) -> dict[str, Any]:
    """Nodes, tetrahedra, volume, mass, supports, cables, features, markers and the file's
    effects (docs/effects.md: what `diagnose` fitted, as robot.fitted.toml carries it)."""
    mesh = robot.mesh
    material = robot.config.material
    return {
        "name": robot.name,
        "source": str(robot.config.source),
        "mesh": str(robot.config.mesh.path),
        "nodes": mesh.node_count,
        "tetrahedra": mesh.tet_count,
        "element": robot.element_name,
        "fe_nodes": robot.fe_mesh.node_count,
        "surface_triangles": len(mesh.surface_faces),
        "bounds_mm": np.round(mesh.bounds_mm, 3).tolist(),
        "volume_mm3": round(mesh.volume_mm3, 3),
        "mass_kg": round(robot.mass_kg, 6),
        "material": {
            "law": material.law,
            "young_modulus_mpa": material.young_modulus_mpa,
            "poisson_ratio": material.poisson_ratio,
            "gravity_mm_s2": list(material.gravity_mm_s2),
        },
        "fixed_nodes": len(robot.fixed_nodes),
        "cables": [
            {"name": c.name, "control": c.control, "min": c.min, "max": c.max,
             "path_mm": [list(p) for p in c.path_mm], "pull_point_mm": list(c.pull_point_mm)}
            for c in robot.cable_specs
        ],
        "features": len(robot.feature_nodes),
        "markers": {mid: np.round(p, 4).tolist()
                    for mid, p in zip(robot.marker_ids, robot.marker_positions_mm, strict=True)},
        # an infinite value (a neutral one) as its string: JSON has no infinity
        "effects": {effect.label: {name: value if np.isfinite(value) else str(value)
                                   for name, value in effect.parameters.items()}
                    for effect in robot.effects},
    }


def equilibrium_summary(robot: Robot, equilibrium: Equilibrium) -> dict[str, Any]:
    """Displacements, cable state, reactions and convergence of a static solve."""
    # over the mesh's own nodes, the first node_count FE nodes (P2 adds mid-edge nodes)
    displacement = equilibrium.positions_mm[: robot.mesh.node_count] - robot.mesh.nodes_mm
    magnitude = np.linalg.norm(displacement, axis=1)
    top = int(np.argmax(robot.mesh.nodes_mm[:, 2]))
    return {
        "max_displacement_mm": round(float(magnitude.max()), 6),
        "max_displacement_node": int(np.argmax(magnitude)),
        "top_node": top,
        "top_node_displacement_mm": np.round(displacement[top], 6).tolist(),
        "cables": [
            {"name": spec.name, "control": spec.control, "tension_n": round(float(t), 6),
             "displacement_mm": round(float(d), 6)}
            for spec, t, d in zip(robot.cable_specs, equilibrium.cable_tensions_n,
                                  equilibrium.cable_shortenings_mm, strict=True)
        ],
        "reaction_force_n": np.round(equilibrium.reaction_forces_n.sum(axis=0), 6).tolist(),
        "newton_iterations": equilibrium.iterations,
        "final_residual_n": equilibrium.residual_history_n[-1],
    }
