"""Writing meshes: a deformed configuration as VTU with the displacement as point data."""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np

from softforce_cli.io.atomic import atomic_path
from softforce_cli.model.mesh import TetMesh


def write_deformed_mesh(path: Path, rest: TetMesh, positions_mm: np.ndarray,
                        force: bool = False) -> None:
    """Deformed mesh in the robot frame, input node order kept, `displacement_mm` per node.

    The format follows the suffix (.vtu, .vtk, .msh, ... anything meshio writes).
    """
    mesh = meshio.Mesh(
        points=np.asarray(positions_mm, dtype=float),
        cells=[("tetra", rest.tets)],
        point_data={"displacement_mm": positions_mm - rest.nodes_mm},
    )
    with atomic_path(Path(path), force=force) as tmp:
        mesh.write(tmp)  # the temporary name keeps the suffix, so meshio picks the format
