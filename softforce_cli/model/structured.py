"""Structured tetrahedral meshes of boxes: reference geometries for validation and examples."""

from __future__ import annotations

import numpy as np

# Kuhn's split of the unit cube into six tetrahedra sharing the diagonal (0,0,0)-(1,1,1);
# corners numbered by bits (x + 2y + 4z). Neighbouring cubes match face to face.
_KUHN = np.array(
    [[0, 1, 3, 7], [0, 1, 5, 7], [0, 2, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 4, 6, 7]]
)


def box_mesh(size_mm: tuple[float, float, float], divisions: tuple[int, int, int],
             origin_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
             ) -> tuple[np.ndarray, np.ndarray]:
    """Tetrahedral mesh of a box, six tetrahedra per grid cell.

    size_mm (3,), divisions (3,) cells per axis -> nodes (n, 3) mm, tets (m, 4) positively
    oriented, n = prod(divisions + 1), m = 6 prod(divisions).
    """
    nx, ny, nz = divisions
    axes = [np.linspace(o, o + s, d + 1) for o, s, d in zip(origin_mm, size_mm, divisions,
                                                              strict=True)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    index = np.arange(len(grid)).reshape(nx + 1, ny + 1, nz + 1)
    i, j, k = (a.ravel() for a in np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz),
                                              indexing="ij"))
    corners = np.stack(
        [index[i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1)] for c in range(8)], axis=1
    )
    tets = corners[:, _KUHN].reshape(-1, 4)
    corner_points = grid[tets]
    volumes = np.linalg.det(corner_points[:, 1:] - corner_points[:, :1])
    tets[volumes < 0] = tets[volumes < 0][:, [1, 0, 2, 3]]
    return grid, tets
