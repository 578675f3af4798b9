"""The procedural "Diamond" robot: a parametric OpenCASCADE solid meshed by gmsh.

The reference robot is the Diamond of SOFA SoftRobots: four silicone arms at 90 degrees
around z, each a V in the vertical plane of its radial direction (a lower bar rising from a
clamped base hub to an elbow, an upper bar from the elbow back to a shared apex), so that
two opposite arms seen from the side form a rhombus. All lengths are millimetres, z is up
and the origin is the centre of the base, as in the robot model file.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass

import gmsh
import numpy as np

from softforce_cli.errors import ModelError
from softforce_cli.model.mesh import tet_signed_volumes


@dataclass(frozen=True)
class DiamondGeometry:
    """Dimensions of the procedural Diamond, in mm.

    An arm lies in the plane of its radial direction r and z. Its bars are boxes of
    `bar_thickness_mm` (perpendicular to the bar, in that plane) by `arm_width_mm`
    (tangential). The lower bar's axis runs from (`lower_root_radius_mm`,
    `lower_root_height_mm`), inside the hub, to the elbow centre; the upper bar's axis from
    the elbow centre to the axis of the apex block, half its depth below the top.
    """

    # Joint centre inside r = 97 so that the cable point (97, 0, 45) sits well inside the
    # rounded joint (which reaches r = 101) rather than on its surface.
    elbow_radius_mm: float = 92.0
    elbow_height_mm: float = 45.0
    elbow_joint_radius_mm: float = 9.0
    apex_height_mm: float = 126.0
    apex_radius_mm: float = 15.0
    apex_depth_mm: float = 20.0
    arm_width_mm: float = 24.0
    bar_thickness_mm: float = 14.0
    base_radius_mm: float = 22.0
    base_bottom_mm: float = -37.0
    # The hub top stays below z = 10 and the bars leave it beyond r = 15, so the SOFA fixed
    # box [-15, -15, -40, 15, 15, 10] holds hub nodes only.
    base_top_mm: float = -5.0
    lower_root_radius_mm: float = 12.0
    lower_root_height_mm: float = -20.0


# Characteristic length (Mesh.MeshSizeMax) per resolution. With the default geometry the
# 1-thread Delaunay mesher of gmsh 4.15 gives 1,596 nodes / 4,536 tets (coarse) and
# 5,096 / 18,125 (fine, 4.0x); the SOFA mesh the paper used has 4,147 tets.
MESH_SIZE_MM: dict[str, float] = {"coarse": 8.5, "fine": 4.8}

# gmsh keeps global state and is not thread-safe: one mesh at a time per process.
_GMSH_LOCK = threading.Lock()


def diamond_mesh(
    resolution: str = "coarse", geometry: DiamondGeometry = DiamondGeometry(),
    mesh_size_mm: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Tetrahedral mesh of the procedural Diamond robot.

    `mesh_size_mm`, if given, replaces the resolution's characteristic length (convergence
    studies mesh the same solid at other sizes).

    -> nodes (n, 3) float64 mm (z up, robot frame, origin at base centre), tets (m, 4)
    int64 positively oriented, every node used. The same arguments give identical arrays.

    Raises
    ------
    ModelError
        For an unknown resolution or when gmsh cannot build or mesh the solid.
    """
    if resolution not in MESH_SIZE_MM:
        raise ModelError(
            f"unknown mesh resolution {resolution!r}: use one of {', '.join(MESH_SIZE_MM)}"
        )
    size_mm = MESH_SIZE_MM[resolution] if mesh_size_mm is None else mesh_size_mm
    return solid_mesh(lambda: _build_solid(geometry), size_mm, "the Diamond robot")


def solid_mesh(build_solid: Callable[[], None], mesh_size_mm: float,
               what: str) -> tuple[np.ndarray, np.ndarray]:
    """Tetrahedral mesh of the one solid that build_solid() adds to the current gmsh model
    with gmsh.model.occ (and synchronizes), at characteristic length mesh_size_mm, on one
    thread so that the same solid gives identical arrays. `what` names the solid in errors.

    -> nodes (n, 3) float64 mm, tets (m, 4) int64 positively oriented, every node used.

    gmsh is initialised and finalised here unless the caller already holds a gmsh session;
    then a temporary model is added and removed, but the mesh options set here stay set.

    Raises
    ------
    ModelError
        When gmsh cannot build or mesh the solid.
    """
    with _GMSH_LOCK:
        owns_gmsh = not gmsh.isInitialized()
        if owns_gmsh:
            # Not interruptible: installing a SIGINT handler fails outside the main thread.
            gmsh.initialize(readConfigFiles=False, interruptible=False)
        try:
            gmsh.model.add("softforce_solid")
            _set_options(mesh_size_mm)
            build_solid()
            gmsh.model.mesh.generate(3)
            nodes, tets = _extract_tets(what)
        except ModelError:
            raise
        except Exception as error:  # gmsh raises bare Exception with its last message
            message = str(error).splitlines()[0] if str(error) else type(error).__name__
            raise ModelError(f"gmsh failed to mesh {what}: {message}") from error
        finally:
            if owns_gmsh:
                gmsh.finalize()
            else:
                gmsh.model.remove()
    return _oriented(*_compacted(nodes, tets))


def _set_options(mesh_size_mm: float) -> None:
    """Silence gmsh and fix everything that could make two runs differ."""
    for name, value in {
        "General.Terminal": 0,
        "General.Verbosity": 0,
        "General.NumThreads": 1,
        "Mesh.MaxNumThreads1D": 1,
        "Mesh.MaxNumThreads2D": 1,
        "Mesh.MaxNumThreads3D": 1,
        "Mesh.RandomSeed": 1,
        "Mesh.Algorithm": 6,  # Frontal-Delaunay surfaces: well-shaped boundary triangles
        "Mesh.Algorithm3D": 1,  # Delaunay: deterministic on one thread
        "Mesh.Optimize": 1,
        "Mesh.MeshSizeMin": 0.5 * mesh_size_mm,
        "Mesh.MeshSizeMax": mesh_size_mm,
        "Mesh.MeshSizeFromPoints": 0,
        "Mesh.MeshSizeFromCurvature": 0,
        "Mesh.ElementOrder": 1,
    }.items():
        gmsh.option.setNumber(name, value)


def _build_solid(geometry: DiamondGeometry) -> None:
    """One arm extruded from its side profile, three rotated copies, hub and apex, fused."""
    occ = gmsh.model.occ
    g = geometry
    apex_axis_z = g.apex_height_mm - 0.5 * g.apex_depth_mm
    elbow = (g.elbow_radius_mm, g.elbow_height_mm)
    profile = [
        _bar_profile((g.lower_root_radius_mm, g.lower_root_height_mm), elbow, g.bar_thickness_mm),
        _bar_profile(elbow, (0.0, apex_axis_z), g.bar_thickness_mm),
        occ.addDisk(*elbow, 0.0, g.elbow_joint_radius_mm, g.elbow_joint_radius_mm),
    ]
    fused, _ = occ.fuse([(2, profile[0])], [(2, tag) for tag in profile[1:]])
    # The profile was drawn in the xy plane with y as height: turn it upright into y = 0,
    # then extrude it symmetrically across the arm width.
    occ.rotate(fused, 0, 0, 0, 1, 0, 0, math.pi / 2)
    occ.translate(fused, 0, -0.5 * g.arm_width_mm, 0)
    arm = [dt for dt in occ.extrude(fused, 0, g.arm_width_mm, 0) if dt[0] == 3]
    arms = list(arm)
    for quarter in (1, 2, 3):
        copy = occ.copy(arm)
        occ.rotate(copy, 0, 0, 0, 0, 0, 1, quarter * math.pi / 2)
        arms += copy
    hub = occ.addCylinder(
        0, 0, g.base_bottom_mm, 0, 0, g.base_top_mm - g.base_bottom_mm, g.base_radius_mm
    )
    apex = occ.addCylinder(
        0, 0, g.apex_height_mm - g.apex_depth_mm, 0, 0, g.apex_depth_mm, g.apex_radius_mm
    )
    solid, _ = occ.fuse([(3, hub)], [*arms, (3, apex)])
    occ.synchronize()
    if len(solid) != 1:
        raise ModelError(
            f"the Diamond geometry fused into {len(solid)} solids instead of one: "
            "check that the bars reach the hub and the apex"
        )


def _bar_profile(start: tuple[float, float], end: tuple[float, float], thickness: float) -> int:
    """A rectangle around the segment start -> end in the xy plane; returns its surface tag."""
    occ = gmsh.model.occ
    dx, dy = end[0] - start[0], end[1] - start[1]
    tag = occ.addRectangle(0, -0.5 * thickness, 0, math.hypot(dx, dy), thickness)
    occ.rotate([(2, tag)], 0, 0, 0, 0, 0, 1, math.atan2(dy, dx))
    occ.translate([(2, tag)], start[0], start[1], 0)
    return tag


def _extract_tets(what: str) -> tuple[np.ndarray, np.ndarray]:
    """All nodes and linear tetrahedra of the current gmsh model, as 0-based indices."""
    node_tags, coords, _ = gmsh.model.mesh.getNodes()
    tet_tags = gmsh.model.mesh.getElementsByType(4)[1]
    if len(tet_tags) == 0:
        raise ModelError(f"gmsh produced no tetrahedra for {what}")
    index = np.zeros(int(node_tags.max()) + 1, dtype=np.int64)
    index[node_tags.astype(np.int64)] = np.arange(len(node_tags))
    nodes = np.asarray(coords, dtype=np.float64).reshape(-1, 3)
    return nodes, index[np.asarray(tet_tags, dtype=np.int64).reshape(-1, 4)]


def _compacted(nodes: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop nodes no tetrahedron uses (gmsh keeps geometry points), keeping node order."""
    used, renumbered = np.unique(tets, return_inverse=True)
    return nodes[used], renumbered.reshape(tets.shape).astype(np.int64)


def _oriented(nodes: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Swap two vertices of every negatively oriented tetrahedron."""
    tets = tets.copy()
    negative = tet_signed_volumes(nodes, tets) < 0
    tets[negative] = tets[negative][:, [0, 1, 3, 2]]
    return nodes, tets
