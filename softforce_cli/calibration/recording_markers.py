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
    equal runs. NaN rows are markers a frame did not see: the median is over the markers seen
    both in the frame and earlier in the run, and a frame that shares none ends the run."""
    best = (0, 1)
    start = 0
    for frame in range(1, len(positions_mm) + 1):
        moved = frame < len(positions_mm) and _moved(positions_mm[frame],
                                                     positions_mm[start:frame], tolerance_mm)
        if frame == len(positions_mm) or moved:
            if frame - start > best[1] - best[0]:
                best = (start, frame)
            start = frame
    return best


def _moved(frame_mm: np.ndarray, run_mm: np.ndarray, tolerance_mm: float) -> bool:
    """Whether a frame's markers (k, 3) left the run's (f, k, 3) mean (NaN: not seen)."""
    mean = _nan_mean(run_mm)
    distances = np.linalg.norm(frame_mm - mean, axis=1)
    shared = distances[np.isfinite(distances)]
    return len(shared) == 0 or float(np.median(shared)) > tolerance_mm


def _nan_mean(positions_mm: np.ndarray) -> np.ndarray:
    """(k, 3) each marker's mean over the frames (f, k, 3) that saw it; NaN if none did."""
    seen = np.isfinite(positions_mm[..., 0])
    total = np.where(seen[..., None], positions_mm, 0.0).sum(axis=0)
    counts = seen.sum(axis=0)[:, None]
    return np.where(counts > 0, total / np.maximum(counts, 1), np.nan)


def markers_from_recording(path: Path, frame: int | None = None,
                           tolerance_mm: float = STATIC_TOLERANCE_MM) -> RecordedMarkers:
    """The markers of frame `frame` (0-based among all frames), or by default the average over
    the longest static stretch of frames that observe the same markers."""
    from softforce_cli.io.mcap_reader import iter_frames

    if frame is not None and frame < 0:
        raise CalibrationError(f"--frame {frame}: frames are counted from 0")
    observed: list[tuple[int, Markers]] = []
    frames = 0
    for index, rgbd in enumerate(iter_frames(Path(path))):
        frames = index + 1
        if frame is not None and index != frame:
            continue
        if rgbd.markers is not None and len(rgbd.markers.ids):
            observed.append((index, rgbd.markers))
        if frame is not None:
            break
    if frame is not None and frame >= frames:
        raise CalibrationError(f"{path} holds {frames} frames (0 to {frames - 1}); --frame "
                               f"{frame} is not one of them")
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
    """The longest static stretch of the observed frames, each marker averaged over the
    frames of it that saw it: a marker that drops out of some frames (occluded, lost by the
    tracker) neither breaks the stretch nor is lost."""
    ids = tuple(dict.fromkeys(marker for _, markers in observed for marker in markers.ids))
    column = {marker: i for i, marker in enumerate(ids)}
    stack = np.full((len(observed), len(ids), 3), np.nan)
    for row, (_, markers) in enumerate(observed):
        stack[row, [column[marker] for marker in markers.ids]] = markers.positions_mm
    start, stop = static_stretch(stack, tolerance_mm)
    positions = _nan_mean(stack[start:stop])
    seen = np.isfinite(positions[:, 0])
    return RecordedMarkers(Markers(tuple(m for m, keep in zip(ids, seen, strict=True) if keep),
                                   positions[seen]),
                           tuple(index for index, _ in observed[start:stop]))
