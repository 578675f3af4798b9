"""Residuals between observed robot points and a predicted FE surface.

Each observed point is associated with its nearest predicted surface node; its residual is
the signed normal distance n . (q - x) to the tangent plane there (positive outside the
model): the point-to-plane distance of ICP, exact for a flat patch and good to a fraction of
a millimetre at the coarse Diamond's node spacing. Per-frame means per node make the residual
field on the mesh that fitting and localisation use.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from softforce_cli.model.mesh import vertex_normals

# Points further than this from their nearest predicted surface node (tangentially or along
# the normal) are not this node's evidence: stray points (segmentation leftovers, the table's
# edge) or a patch of the robot the model misses entirely. 3x the largest effect of interest.
MAX_ASSOCIATION_MM = 15.0


@dataclass(frozen=True, eq=False)
class NodeResiduals:
    """A frame's residual field on the predicted surface.

    nodes     : (s,) surface node indices (mesh numbering) the field is on.
    mean_mm   : (s,) mean signed normal residual of the points associated with each node (0
                where none).
    count     : (s,) number of points associated with each node.
    """

    nodes: np.ndarray
    mean_mm: np.ndarray
    count: np.ndarray


def surface_normals(positions_mm: np.ndarray, surface_faces: np.ndarray) -> np.ndarray:
    """(n, 3) outward unit normals at every node of a configuration (zeros off the surface)."""
    return vertex_normals(positions_mm, surface_faces)


def point_residuals(points_mm: np.ndarray, surface_positions_mm: np.ndarray,
                    surface_normals_: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed normal residuals (p,) mm of points (p, 3) against surface nodes (s, 3) with unit
    normals (s, 3), and each point's node (p,) int64 into the surface arrays; points further
    than MAX_ASSOCIATION_MM get node -1 and residual NaN."""
    distance, nearest = cKDTree(surface_positions_mm).query(points_mm)
    nearest = np.asarray(nearest, dtype=np.int64)
    offset = points_mm - surface_positions_mm[nearest]
    normal = np.einsum("pi,pi->p", offset, surface_normals_[nearest])
    far = (distance > MAX_ASSOCIATION_MM) | (np.abs(normal) > MAX_ASSOCIATION_MM)
    return np.where(far, np.nan, normal), np.where(far, -1, nearest)


def node_residuals(points_mm: np.ndarray, positions_mm: np.ndarray, surface_nodes: np.ndarray,
                   normals: np.ndarray) -> NodeResiduals:
    """The residual field of points (p, 3) against the surface nodes (s,) of a configuration
    (n, 3) with node normals (n, 3)."""
    residual, node = point_residuals(points_mm, positions_mm[surface_nodes],
                                     normals[surface_nodes])
    kept = node >= 0
    count = np.bincount(node[kept], minlength=len(surface_nodes))
    total = np.bincount(node[kept], weights=residual[kept], minlength=len(surface_nodes))
    mean = np.divide(total, count, out=np.zeros(len(surface_nodes)), where=count > 0)
    return NodeResiduals(surface_nodes, mean, count)


@dataclass(frozen=True, eq=False)
class Field:
    """Residual entries of a set of frames: one per (frame, surface node) with points.

    frame  : (E,) frame index.
    node   : (E,) mesh node index.
    mean_mm: (E,) mean signed normal residual of the node's points in that frame.
    weight : (E,) number of points.
    """

    frame: np.ndarray
    node: np.ndarray
    mean_mm: np.ndarray
    weight: np.ndarray

    def rms(self, mask: np.ndarray | None = None, shift: np.ndarray | None = None) -> float:
        """Point-weighted RMS (mm) of the entries in `mask` (default all), after subtracting a
        model shift (E,) of the predicted surface along its normals."""
        values = self.mean_mm if shift is None else self.mean_mm - shift
        if mask is None:
            return weighted_rms(values, self.weight)
        return weighted_rms(values[mask], self.weight[mask])


def measure(points_mm: list[np.ndarray], positions_mm: np.ndarray, of_frame: np.ndarray,
            surface_nodes: np.ndarray, surface_faces: np.ndarray) -> Field:
    """The residual entries of frames' points (t lists of (p, 3)) against the predicted mesh
    nodes of their states (S, n, 3); of_frame (t,) the state of each frame."""
    normals = [surface_normals(p, surface_faces) for p in positions_mm]
    frames, nodes, means, weights = [], [], [], []
    for i, points in enumerate(points_mm):
        s = of_frame[i]
        field = node_residuals(points, positions_mm[s], surface_nodes, normals[s])
        seen = field.count > 0
        frames.append(np.full(int(seen.sum()), i))
        nodes.append(surface_nodes[seen])
        means.append(field.mean_mm[seen])
        weights.append(field.count[seen].astype(float))
    return Field(*(np.concatenate(a) if a else np.zeros(0) for a in (frames, nodes, means,
                                                                       weights)))


def weighted_rms(values: np.ndarray, weights: np.ndarray) -> float:
    """sqrt(sum w v^2 / sum w) over finite values; NaN when no weight."""
    values = np.asarray(values, dtype=float)
    weights = np.where(np.isfinite(values), np.asarray(weights, dtype=float), 0.0)
    total = weights.sum()
    if total <= 0:
        return float("nan")
    return float(np.sqrt(np.sum(weights * np.nan_to_num(values) ** 2) / total))
