"""The markers as evidence about the camera where the point clouds are blind.

The clouds' residuals (diagnosis.residuals) are distances along the surface normals: a camera
turned about the vertical slides the Diamond's faces along themselves and moves hardly any of
them (a 1 degree turn: 0.81 mm RMS absolute against 0.84 mm on clean recordings). A marker is
seen as a point: its three coordinates move with the camera whatever the surface does.

Each marker seen in a frame gives three residual entries, observed minus predicted along the
robot frame's x, y and z, in a Field of their own whose "nodes" are pseudo-nodes 3 k + axis
(marker k), with the axes as their "normals" and weight 1. So the screening's fit, its
held-out validation by trajectory segments, the noise floor (the markers' scatter within
states) and the intervals (diagnosis.fitting, diagnosis.selection) work on them unchanged.
Only the camera effects are judged on them: their shift is exact
(model.effects.observed_points_robot), while physics would need the FE columns at the markers.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from softforce_cli.diagnosis.basis import Basis
from softforce_cli.diagnosis.hypotheses import Inputs
from softforce_cli.diagnosis.residuals import Field

# Frames seeing this few markers on average are no evidence about a turn (two points fix no
# rotation about the line through them).
MIN_MARKERS_PER_FRAME = 3


def marker_field(observed_mm: Sequence[np.ndarray], predicted_mm: np.ndarray,
                 of_frame: np.ndarray) -> Field | None:
    """The markers' residual entries: observed (t lists of (k, 3), robot frame, NaN where a
    marker is unseen; (0, 3) for a frame of a recording without markers) less predicted
    (S, k, 3) at each frame's state (of_frame (t,)); None when the recordings have no
    markers or show fewer than MIN_MARKERS_PER_FRAME a frame on average."""
    markers = predicted_mm.shape[1]
    if not markers:
        return None
    observed = np.stack([o if len(o) else np.full((markers, 3), np.nan) for o in observed_mm])
    seen = np.all(np.isfinite(observed), axis=2)  # (t, k)
    if seen.sum() < MIN_MARKERS_PER_FRAME * len(observed):
        return None
    frame, marker = np.nonzero(seen)
    left = observed[frame, marker] - predicted_mm[of_frame[frame], marker]  # (m, 3)
    return Field(np.repeat(frame, 3), (3 * marker[:, None] + np.arange(3)).ravel(),
                 left.ravel(), np.ones(3 * len(frame)))


def marker_inputs(field: Field, predicted_mm: np.ndarray, basis: Basis) -> Inputs:
    """The screening's Inputs at the marker entries (camera effects only: the physics columns
    are zero there), predicted_mm (S, k, 3) the markers at each state."""
    state = basis.of_frame[field.frame]
    marker, axis = np.divmod(field.node, 3)
    count = len(field.frame)
    return Inputs(field, state, np.eye(3)[axis], predicted_mm[state, marker],
                  np.zeros((len(basis.column_set.names), count)), basis.column_set,
                  basis.contexts, basis.cables, basis.robot_from_camera, basis.predicted_mm,
                  basis.state_inputs, basis.cable_columns, basis.table)


def marker_rms_mm(field: Field, marker_ids: Sequence[str]) -> dict[str, float]:
    """{marker id: RMS distance (mm) between where it was seen and where the model puts it,
    over the frames that saw it} of a marker field; markers never seen are left out."""
    marker = field.node // 3
    squares = np.bincount(marker, weights=field.mean_mm**2, minlength=len(marker_ids))
    entries = np.bincount(marker, minlength=len(marker_ids))
    return {name: float(np.sqrt(3.0 * squares[k] / entries[k]))
            for k, name in enumerate(marker_ids) if entries[k]}
