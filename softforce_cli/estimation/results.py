"""What force sensing finds in one frame: contacts, their forces, the frame's diagnostics."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Frame statuses other than "ok": one word each, as frames.csv's status column shows them.
SKIP_REASONS = {
    "nodepth": "no valid depth pixel in the frame",
    "norobot": "too few robot-coloured points: the robot is not in view",
    "fewmatches": "too few feature points matched to the point cloud for the unknowns",
    "noactuation": "the frame has no actuation message and none came before",
    "solver": "the FE update or the intensity QP failed",
    "lost": "the FE model diverged from the observed robot; it starts again unloaded",
}


@dataclass(frozen=True)
class ContactEstimate:
    """One contact in one frame.

    contact        : index kept while the contact persists across frames.
    feature        : index of the feature point it is mapped to (into Robot.feature_nodes).
    position_mm    : (3,) the contact on the deformed robot, robot frame.
    force_vector_n : (3,) force on the robot, robot frame.
    residual_mm    : RMS normal fit residual of the matched features near the contact.
    """

    contact: int
    feature: int
    position_mm: np.ndarray
    force_vector_n: np.ndarray
    residual_mm: float

    @property
    def force_n(self) -> float:
        return float(np.linalg.norm(self.force_vector_n))


@dataclass(frozen=True)
class FrameEstimate:
    """The result of one frame; status is "ok" or a key of SKIP_REASONS.

    cable_tensions_n : (a,) tensions at the updated configuration (NaN when skipped).
    timings_ms       : stage name -> milliseconds spent on it in this frame.
    """

    frame: int
    time_s: float
    status: str
    contacts: tuple[ContactEstimate, ...] = ()
    points_kept: int = 0
    robot_points: int = 0
    object_points: int = 0
    features_matched: int = 0
    features_hidden: int = 0
    features_rejected: int = 0
    fit_rms_mm: float = float("nan")
    cable_tensions_n: np.ndarray = field(default_factory=lambda: np.zeros(0))
    timings_ms: dict[str, float] = field(default_factory=dict)

    @property
    def total_ms(self) -> float:
        return float(sum(self.timings_ms.values()))


# The pipeline's stages, in order, as frames.csv's timing columns and sense.json's timings_ms
# name them ("decode" is the recording reader's share; writing a frame's results is timed in
# the run's summary, since a frame's files are written after its own timings).
STAGES = ("decode", "cloud", "table", "voxel", "outliers", "segmentation", "contacts",
          "matching", "fe", "qp", "update")
