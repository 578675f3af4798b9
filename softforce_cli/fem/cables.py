"""Cable actuators, as SOFA's CableConstraint.

A cable runs through points attached to the body (distal first) and ends at a pull point
fixed in space. Its displacement is the shortening delta = L0 - L(x); a tension lam >= 0
pulls each attached point along the cable towards its neighbour nearer the pull point, i.e.
the force is lam * d(delta)/dx, so H_a = d(delta)/dx.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from softforce_cli.fem.attachment import Attachment

CONTROLS = ("displacement", "force")


@dataclass(frozen=True)
class Cable:
    """One cable.

    name          : as in the robot file.
    path          : the k points it passes through on the body, distal first.
    pull_point_mm : (3,) the fixed point it is pulled towards.
    rest_length_mm: cable length in the rest configuration.
    """

    name: str
    path: Attachment
    pull_point_mm: np.ndarray
    rest_length_mm: float

    @classmethod
    def through(cls, name: str, path: Attachment, pull_point_mm: np.ndarray,
                rest_nodes_mm: np.ndarray) -> Cable:
        pull = np.asarray(pull_point_mm, dtype=float)
        rest_length = _polyline_length(np.vstack([path.positions(rest_nodes_mm), pull]))
        return cls(name, path, pull, rest_length)

    def points(self, positions_mm: np.ndarray) -> np.ndarray:
        """(k + 1, 3) the cable's points in the current configuration, pull point last."""
        return np.vstack([self.path.positions(positions_mm), self.pull_point_mm])

    def shortening(self, positions_mm: np.ndarray) -> float:
        """delta = L0 - L(x) in mm (positive when pulled in)."""
        return self.rest_length_mm - _polyline_length(self.points(positions_mm))

    def point_gradients(self, positions_mm: np.ndarray) -> np.ndarray:
        """d(delta)/d(p_i) (k, 3) for the attached points: unit vectors towards the pull side."""
        directions = _segment_directions(self.points(positions_mm))  # (k, 3): p_i -> p_{i+1}
        gradients = directions.copy()
        gradients[1:] -= directions[:-1]  # an interior point is pulled both ways
        return gradients

    @property
    def dofs(self) -> np.ndarray:
        """(3 w k,) global dofs of the w nodes carrying each attached point, point-major."""
        return (3 * self.path.node_indices[:, :, None] + np.arange(3)).ravel()

    def jacobian_row(self, positions_mm: np.ndarray, node_count: int) -> np.ndarray:
        """H_a row (3n,): d(delta)/dx."""
        gradients = self.point_gradients(positions_mm)  # (k, 3)
        values = self.path.weights[:, :, None] * gradients[:, None, :]  # (k, w, 3)
        return np.bincount(self.dofs, weights=values.ravel(), minlength=3 * node_count)

    def geometric_stiffness(self, positions_mm: np.ndarray, tension_n: float) -> np.ndarray:
        """(3 w k, 3 w k) stiffness over `dofs` added by a tension: lam d2(L)/dx2, the sum over
        segments of D_s^T S_s D_s (segment_stiffness S_s, segment_differences D_s)."""
        differences = self.segment_differences
        blocks = self.segment_stiffness(positions_mm, tension_n)
        return (differences.transpose(0, 2, 1) @ (blocks @ differences)).sum(axis=0)

    def segment_stiffness(self, positions_mm: np.ndarray, tension_n: float) -> np.ndarray:
        """(k, 3, 3) N/mm, segment_stiffness() of each of its segments (segment i runs from
        point i to point i + 1, the last to the fixed pull point)."""
        segments = np.diff(self.points(positions_mm), axis=0)
        return segment_stiffness(segments, np.full(len(segments), tension_n))

    @cached_property
    def segment_differences(self) -> np.ndarray:
        """(k, 3, 3 w k) each segment's end-point difference p_i+1 - p_i as a map of the dofs
        `dofs` (the pull point is fixed: the last segment's is -p_k)."""
        k, width = self.path.weights.shape
        steps = np.eye(k + 1, k)[1:] - np.eye(k + 1, k)[:-1]  # (segments, points)
        # coordinate c of point i is sum_a w_ia x_(node a of point i, c)
        per_node = steps[:, :, None] * self.path.weights[None]  # (segment, point, node)
        return np.einsum("spa,cd->scpad", per_node, np.eye(3)).reshape(k, 3, 3 * width * k)


def segment_stiffness(segments_mm: np.ndarray, tensions_n: np.ndarray) -> np.ndarray:
    """(s, 3, 3) N/mm: lam (I - t t^T) / l for segments (s, 3) mm of tensions (s,) N, on the
    difference of each segment's end points: a taut cable resists sideways motion of its
    points."""
    lengths = np.linalg.norm(segments_mm, axis=1)
    t = segments_mm / lengths[:, None]
    return (tensions_n / lengths)[:, None, None] * (np.eye(3) - t[:, :, None] * t[:, None, :])


def _segment_directions(points: np.ndarray) -> np.ndarray:
    segments = np.diff(points, axis=0)
    return segments / np.linalg.norm(segments, axis=1, keepdims=True)


def _polyline_length(points: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


@dataclass(frozen=True)
class CableInputs:
    """What each cable is told to do.

    control : per cable, "displacement" (value = shortening, mm) or "force" (tension, N).
    values  : (a,) float64.
    """

    control: tuple[str, ...]
    values: np.ndarray

    def __post_init__(self) -> None:
        unknown = set(self.control) - set(CONTROLS)
        if unknown:
            raise ValueError(f"unknown cable control {sorted(unknown)}; expected {CONTROLS}")
        if len(self.control) != len(self.values):
            raise ValueError(f"{len(self.values)} cable values for {len(self.control)} cables")

    @classmethod
    def slack(cls, count: int) -> CableInputs:
        """Every cable at zero tension."""
        return cls(("force",) * count, np.zeros(count))

    @property
    def displacement_controlled(self) -> np.ndarray:
        """(a,) bool mask of displacement-controlled cables."""
        return np.array([c == "displacement" for c in self.control], dtype=bool)

    def held(self, tensions_n: np.ndarray) -> np.ndarray:
        """(a,) bool: the displacement-controlled cables that pull at tensions (a,) N, which
        hold their lengths; a slack one holds nothing."""
        return self.displacement_controlled & (np.asarray(tensions_n) > 0.0)
