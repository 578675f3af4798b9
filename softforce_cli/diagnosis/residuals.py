"""Residuals between observed robot points and a predicted FE surface.

Each observed point's residual is its signed distance to the predicted surface: the distance
to the closest point of the closest predicted triangle, positive outside the model. The point
is evidence of that triangle's corner nearest the closest point; per-frame means per node
make the residual field on the mesh that fitting and localisation use.

The distance is to the triangles, not to the nearest node's tangent plane (ICP's
point-to-plane distance): on the coarse Diamond, whose arms are boxes meshed at 8.5 mm, the
averaged normal of a node on an edge leans 45 degrees off both faces, and the tangent planes
put about 0.7 mm RMS of their own into every frame, which the static effects had taken for
physics (docs/diagnosis.md, limits).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from softforce_cli.calibration.rigid import rigid_motion_basis
from softforce_cli.model.mesh import vertex_normals

# Points further than this from the predicted surface are not its evidence: stray points
# (segmentation leftovers, the table's edge) or a patch of the robot the model misses
# entirely. 3x the largest effect of interest.
MAX_ASSOCIATION_MM = 15.0
# A camera pose is corrected within this many standard deviations (a Mahalanobis radius) of
# its calibration's covariance: sqrt of chi^2's 95% quantile with 6 degrees of freedom.
POSE_RADIUS = 3.55


def surface_normals(positions_mm: np.ndarray, surface_faces: np.ndarray) -> np.ndarray:
    """(n, 3) outward unit normals at every node of a configuration (zeros off the surface)."""
    return vertex_normals(positions_mm, surface_faces)


def camera_facing(positions_mm: np.ndarray, surface_faces: np.ndarray,
                  camera_mm: np.ndarray) -> np.ndarray:
    """The triangles (k, 3) of a configuration (n, 3) whose outward side faces a camera at
    camera_mm (3,) (robot frame)."""
    corners = positions_mm[surface_faces]
    outward = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return surface_faces[np.einsum("ki,ki->k", outward, camera_mm - corners.mean(axis=1)) > 0]


def point_residuals(points_mm: np.ndarray, positions_mm: np.ndarray,
                    surface_faces: np.ndarray, camera_mm: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Signed distances (p,) mm of points (p, 3) to the surface triangles (k, 3) of a
    configuration (n, 3), positive outside, and each point's node (p,) int64 (mesh
    numbering): the corner of its closest triangle nearest the closest point. Points further
    than MAX_ASSOCIATION_MM from the surface get node -1 and residual NaN.

    With camera_mm (3,), the camera's centre in the robot frame, only the triangles facing
    it are candidates: a seen point lies on a face the camera sees, and an arm 14 mm thick
    that sags 8 mm more than predicted would otherwise put its seen top on the predicted
    underside (and the fit would lift that)."""
    if camera_mm is not None:
        surface_faces = camera_facing(positions_mm, surface_faces, camera_mm)
    if len(surface_faces) == 0:  # nothing of the model faces the camera: no evidence
        return np.full(len(points_mm), np.nan), np.full(len(points_mm), -1, dtype=np.int64)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(positions_mm, dtype=np.float32)),
                        o3d.core.Tensor(np.asarray(surface_faces, dtype=np.uint32)))
    closest = scene.compute_closest_points(
        o3d.core.Tensor(np.asarray(points_mm, dtype=np.float32)))
    triangle = closest["primitive_ids"].numpy().astype(np.int64)
    uv = closest["primitive_uvs"].numpy().astype(float)
    corners = positions_mm[surface_faces[triangle]]
    outward = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    offset = points_mm - closest["points"].numpy().astype(float)
    distance = np.linalg.norm(offset, axis=1)
    signed = np.where(np.einsum("pi,pi->p", offset, outward) < 0, -distance, distance)
    barycentric = np.column_stack([1.0 - uv.sum(axis=1), uv])
    node = surface_faces[triangle, np.argmax(barycentric, axis=1)].astype(np.int64)
    far = distance > MAX_ASSOCIATION_MM
    return np.where(far, np.nan, signed), np.where(far, -1, node)


@dataclass(frozen=True, eq=False)
class Field:
    """Residual entries of a set of frames: one per (frame, surface node) with points.

    frame  : (E,) frame index.
    node   : (E,) mesh node index.
    mean_mm: (E,) mean signed distance of the node's points in that frame.
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
            surface_nodes: np.ndarray, surface_faces: np.ndarray,
            camera_mm: np.ndarray | None = None) -> Field:
    """The residual entries of frames' points (t lists of (p, 3)) against the predicted mesh
    nodes of their states (S, n, 3), seen from camera_mm (3,); of_frame (t,) the state of
    each frame. Entries are ordered by frame, then as surface_nodes (s,)."""
    of_frame = np.asarray(of_frame)
    slot = np.full(positions_mm.shape[1], -1, dtype=np.int64)
    slot[surface_nodes] = np.arange(len(surface_nodes))
    keys, residuals = [], []
    for state in np.unique(of_frame):  # one query of all the frames a state predicts
        frames = np.flatnonzero(of_frame == state)
        counts = [len(points_mm[i]) for i in frames]
        if sum(counts) == 0:
            continue
        residual, node = point_residuals(np.concatenate([points_mm[i] for i in frames]),
                                         positions_mm[state], surface_faces, camera_mm)
        kept = node >= 0
        frame = np.repeat(frames, counts)[kept]
        keys.append(frame * len(surface_nodes) + slot[node[kept]])
        residuals.append(residual[kept])
    if not keys:
        return Field(*(np.zeros(0) for _ in range(4)))
    entry, of_entry, weight = np.unique(np.concatenate(keys), return_inverse=True,
                                        return_counts=True)
    total = np.bincount(of_entry, weights=np.concatenate(residuals), minlength=len(entry))
    return Field(entry // len(surface_nodes), surface_nodes[entry % len(surface_nodes)],
                 total / weight, weight.astype(float))


def weighted_rms(values: np.ndarray, weights: np.ndarray) -> float:
    """sqrt(sum w v^2 / sum w) over finite values; NaN when no weight."""
    values = np.asarray(values, dtype=float)
    weights = np.where(np.isfinite(values), np.asarray(weights, dtype=float), 0.0)
    total = weights.sum()
    if total <= 0:
        return float("nan")
    return float(np.sqrt(np.sum(weights * np.nan_to_num(values) ** 2) / total))


def node_systematic_mm(field: Field, node_count: int) -> tuple[np.ndarray, np.ndarray]:
    """(n,) per mesh node the point-weighted mean residual over all frames (mm; 0 where
    unseen), and (n,) the points behind it."""
    weight = np.bincount(field.node, weights=field.weight, minlength=node_count)
    total = np.bincount(field.node, weights=field.weight * field.mean_mm, minlength=node_count)
    return np.divide(total, weight, out=np.zeros(node_count), where=weight > 0), weight


def static_mm(field: Field, node_count: int) -> float:
    """The residual that stays the same in every frame: the RMS over the seen nodes of each
    node's mean residual (node_systematic_mm), weighted by their points (mm)."""
    mean, weight = node_systematic_mm(field, node_count)
    return node_rms(mean, weight, weight > 0)


def static_after_pose_mm(field: Field, node_count: int, nodes_mm: np.ndarray,
                         normals: np.ndarray, pose_covariance: np.ndarray) -> float:
    """static_mm (mm) after the correction of the camera pose that removes the most of it
    within POSE_RADIUS standard deviations of the pose's covariance (6, 6) (dtheta rad, dt
    mm: calibration.pose_covariance): what a calibration as uncertain as its markers leave it
    cannot account for. nodes_mm (n, 3): where each of the node_count nodes is (the shapes
    of the frames that see it: pipeline._seen_shape), and normals (n, 3) its unit outward
    normal there. The correction moves a node along its normal by
    n . (dtheta x p + dt); it is a trust-region least-squares step in the pose's whitened
    coordinates (a pose known exactly along a direction is not moved along it)."""
    mean, weight = node_systematic_mm(field, node_count)
    seen = weight > 0
    if not seen.any():
        return 0.0
    motions = rigid_motion_basis(nodes_mm[seen], np.zeros(3)).reshape(-1, 3, 6)
    along_normal = np.einsum("mk,mkj->mj", normals[seen], motions)
    spread, directions = np.linalg.eigh(pose_covariance)
    whitened = along_normal @ (directions * np.sqrt(np.clip(spread, 0.0, None)))
    share = weight[seen] / weight[seen].sum()
    normal = whitened.T @ (share[:, None] * whitened)
    pulled = whitened.T @ (share * mean[seen])
    step = _trust_region_step(normal, pulled, POSE_RADIUS)
    return weighted_rms(mean[seen] - whitened @ step, weight[seen])


def _trust_region_step(normal: np.ndarray, gradient: np.ndarray, radius: float) -> np.ndarray:
    """argmin |A z - b|^2 over |z| <= radius, given A^T A (k, k) and A^T b (k,): the least
    squares step (least norm), or (A^T A + lam I)^-1 A^T b with |z| = radius."""
    free = np.linalg.lstsq(normal, gradient, rcond=None)[0]
    if np.linalg.norm(free) <= radius:
        return free
    eye = np.eye(len(normal))
    low, high = 0.0, float(np.linalg.norm(gradient)) / radius
    for _ in range(100):  # |z(lam)| falls with lam; |z(high)| <= |A^T b| / high = radius
        middle = 0.5 * (low + high)
        if np.linalg.norm(np.linalg.solve(normal + middle * eye, gradient)) > radius:
            low = middle
        else:
            high = middle
    return np.linalg.solve(normal + high * eye, gradient)


def node_rms(mean_mm: np.ndarray, weight: np.ndarray, mask: np.ndarray) -> float:
    """RMS (mm) of per-node means (n,) over the nodes in mask (n,), weighted by their points
    (n,); 0 for none."""
    return (float(np.sqrt(np.average(mean_mm[mask] ** 2, weights=weight[mask])))
            if mask.any() else 0.0)
