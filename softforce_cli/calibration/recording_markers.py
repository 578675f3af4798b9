"""Observed markers from a recording's /markers topic: one frame, or the average of the
longest static stretch (the robot held still while the camera runs)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from softforce_cli.camera.frame import Markers
from softforce_cli.errors import CalibrationError

# A frame continues a static stretch while the median marker lies within this of its mean
# position over the stretch so far: the median distance is ~1.6 sigma for marker noise sigma,
# so this passes sigma = 1 mm (a D415 at 0.6 m), while a change of the cable inputs moves the
# Diamond's markers by several mm. The median ignores one badly tracked marker.
STATIC_TOLERANCE_MM = 3.0


@dataclass(frozen=True)
class RecordedMarkers:
    """Markers taken from a recording: the (averaged) observation and where it came from.

    frames : indices (among all frames of the recording) that were averaged.
    """

    markers: Markers
    frames: tuple[int, ...]

    @property
    def description(self) -> str:
        first, last = self.frames[0], self.frames[-1]
        span = f"frame {first}" if first == last else f"frames {first}-{last} averaged"
        return span


def static_stretch(positions_mm: np.ndarray, tolerance_mm: float = STATIC_TOLERANCE_MM
                   ) -> tuple[int, int]:
    """[start, stop) of the longest run of frames (f, k, 3) in which each frame's median
    marker lies within tolerance_mm of its mean over the run's earlier frames; the earliest of
    equal runs."""
    best = (0, 1)
    start = 0
    for frame in range(1, len(positions_mm) + 1):
        moved = frame < len(positions_mm) and np.median(np.linalg.norm(
            positions_mm[frame] - positions_mm[start:frame].mean(axis=0), axis=1)) > tolerance_mm
        if frame == len(positions_mm) or moved:
            if frame - start > best[1] - best[0]:
                best = (start, frame)
            start = frame
    return best


def markers_from_recording(path: Path, frame: int | None = None,
                           tolerance_mm: float = STATIC_TOLERANCE_MM) -> RecordedMarkers:
    """The markers of frame `frame` (0-based among all frames), or by default the average over
    the longest static stretch of frames that observe the same markers."""
    from softforce_cli.io.mcap_reader import iter_frames

    observed: list[tuple[int, Markers]] = []
    for index, rgbd in enumerate(iter_frames(Path(path))):
        if frame is not None and index != frame:
            continue
        if rgbd.markers is not None and len(rgbd.markers.ids):
            observed.append((index, rgbd.markers))
        if frame is not None:
            break
    if frame is not None and not observed:
        raise CalibrationError(f"{path}: frame {frame} has no marker observations (topic "
                               "/markers); pick another --frame or use --markers M.csv")
    if not observed:
        raise CalibrationError(f"{path}: no marker observations (topic /markers); record "
                               "markers or measure them into a CSV for --markers")
    if frame is not None:
        return RecordedMarkers(observed[0][1], (observed[0][0],))
    return _average_static(observed, tolerance_mm)


def _average_static(observed: list[tuple[int, Markers]], tolerance_mm: float
                    ) -> RecordedMarkers:
    """Split the frames into runs that see the same ids, take the longest static stretch."""
    best: tuple[int, list[tuple[int, Markers]]] = (0, [])
    run: list[tuple[int, Markers]] = []
    for item in [*observed, None]:
        if item is not None and run and item[1].ids == run[-1][1].ids:
            run.append(item)
            continue
        if run:
            stack = np.stack([np.asarray(m.positions_mm, float) for _, m in run])
            start, stop = static_stretch(stack, tolerance_mm)
            if stop - start > best[0]:
                best = (stop - start, run[start:stop])
        run = [item] if item is not None else []
    frames = best[1]
    positions = np.mean([np.asarray(m.positions_mm, float) for _, m in frames], axis=0)
    return RecordedMarkers(Markers(frames[0][1].ids, positions), tuple(i for i, _ in frames))
