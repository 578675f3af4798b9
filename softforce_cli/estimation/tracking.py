"""Contact identities across frames: the same contact keeps its index while it stays near."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment


@dataclass
class ContactTracker:
    """Gives each frame's contacts the index of the previous frame's nearest contact within
    radius_mm (a one-to-one assignment), or a new index."""

    radius_mm: float
    _positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    _indices: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    _next: int = 0

    def assign(self, positions_mm: np.ndarray) -> np.ndarray:
        """(c,) contact indices for positions (c, 3) mm; remembers them for the next frame."""
        positions_mm = np.asarray(positions_mm, dtype=float).reshape(-1, 3)
        indices = np.full(len(positions_mm), -1)
        if len(positions_mm) and len(self._positions):
            distance = np.linalg.norm(positions_mm[:, None] - self._positions[None], axis=2)
            rows, cols = linear_sum_assignment(distance)
            near = distance[rows, cols] <= self.radius_mm
            indices[rows[near]] = self._indices[cols[near]]
        for i in np.flatnonzero(indices < 0):
            indices[i] = self._next
            self._next += 1
        self._positions, self._indices = positions_mm.copy(), indices.copy()
        return indices
