"""Supports that are not clamps: springs to anchor points and a one-sided rigid plane.

Both are conservative node forces with a diagonal stiffness, so FEModel adds them to its
internal forces, energy and tangent (fem.model); the static solver needs nothing else. The
plane is a penalty contact: its energy 1/2 k (h - z)_+^2 is C1, so Newton's method on it is a
semi-smooth Newton method whose active set (the nodes below the plane) follows the iterates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class NodeSprings:
    """Linear springs tying nodes to fixed anchors: energy 1/2 sum_i k_i |x_i - a_i|^2.

    nodes              : (s,) int64 node indices.
    stiffness_n_per_mm : (s,) float64 spring stiffness of each node, N/mm (every direction).
    anchors_mm         : (s, 3) float64 anchor points (the nodes' rest positions for a base).
    """

    nodes: np.ndarray
    stiffness_n_per_mm: np.ndarray
    anchors_mm: np.ndarray

    def terms(self, positions_mm: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """Energy (mJ), forces dE/dx (s, 3) N on `nodes`, and the diagonal of d2E/dx2 (s, 3)
        N/mm at positions (n, 3)."""
        stretch = positions_mm[self.nodes] - self.anchors_mm
        k = self.stiffness_n_per_mm[:, None]
        energy = 0.5 * float(np.sum(k * stretch**2))
        return energy, k * stretch, np.broadcast_to(k, stretch.shape)


@dataclass(frozen=True)
class SupportPlane:
    """A rigid horizontal plane z = height_mm that `nodes` cannot pass downwards.

    A one-sided penalty: each node below the plane is pushed up by k (h - z), energy
    1/2 k (h - z)_+^2; a node above it feels nothing.

    nodes              : (s,) int64 nodes the plane acts on.
    height_mm          : z of the plane, robot frame.
    stiffness_n_per_mm : penalty stiffness per node, N/mm.
    """

    nodes: np.ndarray
    height_mm: float
    stiffness_n_per_mm: float

    def terms(self, positions_mm: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """Energy (mJ), forces dE/dx (s, 3) N on `nodes`, and the diagonal of d2E/dx2 (s, 3)
        N/mm at positions (n, 3)."""
        depth = np.maximum(self.height_mm - positions_mm[self.nodes, 2], 0.0)
        k = self.stiffness_n_per_mm
        forces = np.zeros((len(self.nodes), 3))
        forces[:, 2] = -k * depth  # dE/dz: the energy falls as the node rises
        diagonal = np.zeros_like(forces)
        diagonal[:, 2] = np.where(depth > 0.0, k, 0.0)
        return 0.5 * k * float(depth @ depth), forces, diagonal

    def contact_nodes(self, positions_mm: np.ndarray) -> np.ndarray:
        """(c,) the nodes of `nodes` below the plane at positions (n, 3)."""
        return self.nodes[positions_mm[self.nodes, 2] < self.height_mm]


Support = NodeSprings | SupportPlane
