"""Jumps within holds: the robot's points moving between two frames whose inputs are the same
far more than between the recording's other such frames.

With its inputs held, a body moves only as it creeps, smoothly in time. A jump is something
else: the body passed a fold and snapped through (the study's creep_0.5 body tips over in a
hold, docs/diagnosis.md), or the robot or the camera was moved. The model of a diagnosis is
solved near its nominal equilibria and follows no such jump, so its fits after one are not
to be trusted: the diagnosis reports where the recording jumps.

How far two frames' points lie apart is the median distance from each point of either
frame to the nearest point of the other. Between two noisy samplings of one surface this is
about the sampling's spacing (about 5 mm for the coarse Diamond's 6,000 points a frame);
the study's creep drift in a hold moves it to at most 2.5 times the recording's typical
value, its tip-over to 5.1-9.8 times (docs/diagnosis.md, step 14).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise

import numpy as np
from scipy.spatial import cKDTree

from softforce_cli.diagnosis.observations import FrameObservation

# A hold's motion this many times the recording's typical one is a jump: above the study's
# creep drift (2.5 times at most), below its tip-over (5.1-9.8 times).
JUMP_FACTOR = 4.0
# Holds needed for the typical motion to mean something (its median).
MIN_HOLDS = 3


@dataclass(frozen=True)
class Jump:
    """A frame whose robot points jumped from the frame before's, with the same inputs.

    frame      : the frame's index in its recording.
    recording  : the recording's index among those diagnosed.
    time_s     : its time (Observations.times_s).
    moved_mm   : how far the two frames' points lie apart (cloud_gap_mm).
    typical_mm : the same, median over the recording's holds.
    """

    frame: int
    recording: int
    time_s: float
    moved_mm: float
    typical_mm: float

    def as_dict(self) -> dict:
        return {"frame": self.frame, "recording": self.recording,
                "time_s": round(self.time_s, 6), "moved_mm": round(self.moved_mm, 3),
                "typical_mm": round(self.typical_mm, 3)}


def cloud_gap_mm(first: np.ndarray, second: np.ndarray) -> float:
    """mm: the median distance from each point of two clouds (p, 3) and (q, 3) mm to the
    nearest point of the other."""
    to_first = cKDTree(first).query(second)[0]
    to_second = cKDTree(second).query(first)[0]
    return float(np.median(np.concatenate([to_first, to_second])))


def jumps_in_holds(frames: Sequence[FrameObservation]) -> list[Jump]:
    """The frames whose points moved from the frame before's, the inputs being the same,
    more than JUMP_FACTOR times the median such motion of their recording (none where a
    recording has fewer than MIN_HOLDS pairs of held frames)."""
    jumps = []
    for recording in sorted({f.recording for f in frames}):
        own = [f for f in frames if f.recording == recording]
        held = [(before, after) for before, after in pairwise(own)
                if np.array_equal(before.actuation, after.actuation)]
        if len(held) < MIN_HOLDS:
            continue
        gaps = np.array([cloud_gap_mm(b.points_mm, a.points_mm) for b, a in held])
        typical = float(np.median(gaps))
        jumps += [Jump(after.index, recording, after.time_s, float(gap), typical)
                  for (_, after), gap in zip(held, gaps, strict=True)
                  if gap > JUMP_FACTOR * typical]
    return jumps
