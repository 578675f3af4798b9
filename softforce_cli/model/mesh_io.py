"""Reading tetrahedral meshes with meshio, placing them in the robot frame, checking them."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import meshio
import numpy as np

from softforce_cli.errors import ModelError
from softforce_cli.model.mesh import TetMesh, tet_signed_volumes

# An element smaller than this fraction of the mean element volume is degenerate: its
# stiffness would dominate the system's conditioning.
DEGENERATE_VOLUME_FRACTION = 1e-6


def rotation_from_euler_deg(angles_deg: tuple[float, float, float]) -> np.ndarray:
    """(3, 3) rotation about fixed x, then fixed y, then fixed z: R = Rz Ry Rx."""
    x, y, z = np.radians(angles_deg)
    rx = np.array([[1, 0, 0], [0, np.cos(x), -np.sin(x)], [0, np.sin(x), np.cos(x)]])
    ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    rz = np.array([[np.cos(z), -np.sin(z), 0], [np.sin(z), np.cos(z), 0], [0, 0, 1]])
    return rz @ ry @ rx


def placed(points: np.ndarray, scale: float, rotation_deg: tuple[float, float, float],
           translation_mm: tuple[float, float, float]) -> np.ndarray:
    """Points (n, 3) scaled, then rotated, then translated into the robot frame."""
    return scale * points @ rotation_from_euler_deg(rotation_deg).T + np.asarray(translation_mm)


def read_tet_mesh(path: Path, scale: float = 1.0,
                  rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0),
                  translation_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> TetMesh:
    """Read any meshio format, keep its linear tetrahedra, place them, check orientation.

    A mesh whose tetrahedra are all negatively oriented (a convention of some exporters) is
    reordered; one with mixed orientations has inverted elements and is rejected.
    """
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"mesh file {path} not found (mesh.path is relative to the robot file)")
    try:
        # meshio prints its own complaint and may even sys.exit() on an unreadable file
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            mesh = meshio.read(path)
    except (Exception, SystemExit) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise ModelError(f"cannot read mesh {path} ({reason}); is it a tetrahedral mesh in a "
                         "format meshio knows (.vtu, .vtk, .msh, .mesh...)?") from None
    blocks = [block.data for block in mesh.cells if block.type == "tetra"]
    if not blocks:
        kinds = ", ".join(sorted({block.type for block in mesh.cells})) or "none"
        raise ModelError(f"mesh {path} has no tetrahedra (cells: {kinds}); softforce needs a "
                         "tetrahedral volume mesh, e.g. from gmsh -3")
    tets = np.concatenate(blocks).astype(np.int64)
    nodes = placed(np.asarray(mesh.points[:, :3], dtype=float), scale, rotation_deg,
                   translation_mm)
    return checked_mesh(nodes, tets, str(path))


def checked_mesh(nodes: np.ndarray, tets: np.ndarray, label: str) -> TetMesh:
    """A TetMesh with positive orientation, or ModelError for inverted/degenerate elements."""
    volumes = tet_signed_volumes(nodes, tets)
    if np.all(volumes < 0):
        tets = tets[:, [1, 0, 2, 3]]
        volumes = -volumes
    threshold = DEGENERATE_VOLUME_FRACTION * np.abs(volumes).mean()
    inverted = np.flatnonzero(volumes < -threshold)
    if len(inverted):
        raise ModelError(f"mesh {label}: {len(inverted)} inverted tetrahedra (first: "
                         f"#{inverted[0]}); repair the mesh or re-export it consistently oriented")
    degenerate = np.flatnonzero(np.abs(volumes) <= threshold)
    if len(degenerate):
        raise ModelError(f"mesh {label}: {len(degenerate)} degenerate (flat) tetrahedra (first: "
                         f"#{degenerate[0]}); remesh with a quality optimisation")
    return TetMesh(nodes, tets)
