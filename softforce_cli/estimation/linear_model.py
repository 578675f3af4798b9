"""The FE model linearised at one configuration and reused across frames (eq. 3-6 at x0).

Relinearising, i.e. assembling K(x) and factorising it, is most of what a sensing update
costs (P1 coarse Diamond: ~45 ms; P2 on the same mesh: ~300 ms). Between frames of a camera
the configuration moves little, so the compliance of eq. 10 is taken from the factorisation
at a configuration x0 while the model stays near it:

- the responses Z_a = K0^-1 H_a^T to the cables are solved once per linearisation;
- the responses to unit forces along x, y and z at each node where a contact acts are solved
  the first time a contact lands there and kept (a contact moves over a few neighbouring
  nodes from frame to frame), so a force along any direction there is a combination of 3
  cached columns; other attachments (a known contact inside an element) cache their column;
- a frame's matrices are then products: W_ea = H_e Z_a, W_ef = H_e Z_f (H_e the matched
  features along the current normals), W_aa = H_a Z_a, W_af = H_a Z_f, and
  delta_e_free = H_e (x0 + dx_free), delta_a_free = delta_a(x0) + H_a dx_free;
- the configuration follows linearly, x = x0 + dx_free + Z_a lam_a + Z_f lam_f (eq. 6 with
  K(x0)), which is eq. 6 exactly right after a relinearisation.

Everything is held in the model's coordinates (fem.coordinates: x = x_0 + T q), and the
configuration is a State: a reduced model's responses are r numbers, not 3n, and a frame
forms the positions of the nodes it looks at (the mesh's, the features'), never all of them
(lifting V q reads all of V: more than the rest of a reduced update).

The caller relinearises (K and the internal forces at the new x: a Newton step) when the
configuration has moved more than a tolerance from x0 (EstimationSettings.relinearize_mm).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from softforce_cli.fem.attachment import Attachment
from softforce_cli.fem.compliance import Compliance, Linearization, linearize_state, rows_at
from softforce_cli.fem.coordinates import Factor, State
from softforce_cli.fem.model import FEModel


class LinearizedModel:
    """K(x0) factorised, the free motion and the cable responses at x0, and the contact
    responses solved so far, all in the model's coordinates (c of them).

    origin is x0 (a State); free (c,) the free motion K0^-1 (f_ext - g(x0)); cable_rows
    (a, c) H_a T at x0; cable_responses (c, a) K0^-1 (H_a T)^T (mm/N); watched_nodes (k,)
    the nodes moved_mm measures (all of them by default).
    """

    def __init__(self, model: FEModel, origin: State, tensions_n: np.ndarray,
                 factorization: Factor | None = None,
                 watched_nodes: np.ndarray | None = None) -> None:
        self.model = model
        self.linearization: Linearization = linearize_state(model, origin, tensions_n,
                                                            factorization=factorization)
        self.origin = origin
        self.free = self.linearization.free_motion
        self.shortenings_mm, self.cable_rows = origin.cables()
        self.cable_responses = self.linearization.factorization.solve(self.cable_rows.T)
        self.watched_nodes = (np.arange(model.node_count) if watched_nodes is None
                              else np.asarray(watched_nodes, dtype=np.int64))
        self._watched_mm = origin.nodes_mm(self.watched_nodes)
        self._node_responses: dict[int, np.ndarray] = {}
        self._point_responses: dict[bytes, np.ndarray] = {}

    @property
    def factorization(self) -> Factor:
        return self.linearization.factorization

    def moved_mm(self, watched_mm: np.ndarray) -> float:
        """The largest distance (mm) between the watched nodes' positions (k, 3) at a
        configuration and at x0."""
        return float(np.sqrt(np.max(np.sum((watched_mm - self._watched_mm) ** 2, axis=1))))

    @property
    def cached_nodes(self) -> int:
        return len(self._node_responses)

    def force_responses(self, points: Attachment, directions: np.ndarray) -> np.ndarray:
        """K0^-1 (H_f T)^T (c, f) mm/N for unit forces along directions (f, 3) at points (f).

        Points at a node (Attachment.at_nodes) combine that node's cached x, y, z responses;
        other points cache the column of their exact row.
        """
        node_count = self.model.node_count
        single = np.count_nonzero(points.weights, axis=1) == 1
        node_of = points.node_indices[np.arange(len(points)), np.argmax(points.weights, axis=1)]
        missing = np.unique([n for n in node_of[single] if int(n) not in self._node_responses])
        if len(missing):
            rows = Attachment.at_nodes(missing).cartesian_rows(node_count)
            solved = self.linearization.solve_rows(rows)  # (c, 3m): x, y, z of each node
            for k, node in enumerate(missing):
                self._node_responses[int(node)] = solved[:, 3 * k: 3 * k + 3]
        columns = np.empty((len(self.free), len(points)))
        for j in range(len(points)):
            direction = np.asarray(directions[j], dtype=float)
            if single[j]:
                columns[:, j] = self._node_responses[int(node_of[j])] @ direction
                continue
            row = points.subset(np.array([j])).directional_rows(direction[None], node_count)
            key = row.indices.tobytes() + row.data.tobytes()
            if key not in self._point_responses:
                self._point_responses[key] = self.linearization.solve_rows(row)[:, 0]
            columns[:, j] = self._point_responses[key]
        return columns

    def compliance(self, effectors: sp.spmatrix, force_responses: np.ndarray) -> Compliance:
        """The matrices of eq. 3-5 at x0 for effector rows H_e (e, 3n) (the current normals)
        and the force responses (c, f) of force_responses()."""
        projected = self.model.coordinates.project_rows(effectors)  # H_e T (e, c)
        cables = self.cable_responses
        return Compliance(
            W_ea=np.asarray(projected @ cables),
            W_ef=np.asarray(projected @ force_responses),
            W_aa=self.cable_rows @ cables,
            W_af=self.cable_rows @ force_responses,
            delta_e_free=np.asarray(rows_at(effectors, self.origin) + projected @ self.free),
            delta_a_free=self.shortenings_mm + self.cable_rows @ self.free,
        )

    def configuration(self, tensions_n: np.ndarray, force_responses: np.ndarray,
                      forces_n: np.ndarray) -> State:
        """x0 + dx_free + Z_a lam_a + Z_f lam_f: the linear model's configuration under cable
        tensions (a,) and contact forces (f,) along the columns of force_responses (c, f)."""
        step = self.free + self.cable_responses @ tensions_n + force_responses @ forces_n
        return self.origin.moved(step, 1.0)
