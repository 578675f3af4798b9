"""A running summary of a sensing run: frames, skips, contacts' force ranges, speed."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from softforce_cli.estimation.results import STAGES, FrameEstimate

# An ok frame whose fit (RMS normal residual of the matched features) is more than this above
# the run's first fit is one where the model did not follow the robot: a deformation beyond
# what it could reach from the frame before, a contact it was not given. The studies' frames
# fit within 2 mm of the first (4 mm with an oblique camera and a probe it cannot see); a bar
# snapped 47 mm down, out of sight, 8-10 mm (docs/sensing_studies.md, "Large deformations").
# Beyond lost_fit_mm (estimation settings) a frame is skipped as lost instead.
POOR_FIT_MM = 5.0
# poor_fit_text names at most this many frames.
POOR_FIT_LISTED = 8


def poor_fit_text(frames: list[int] | tuple[int, ...]) -> str:
    """The frames that fit poorly as "3 frames fit ... (16, 17, 18): ..." for the end of a
    run and its report."""
    listed = ", ".join(map(str, frames[:POOR_FIT_LISTED])) + (
        ", ..." if len(frames) > POOR_FIT_LISTED else "")
    return (f"{len(frames)} frame(s) fit the robot more than {POOR_FIT_MM:g} mm worse than "
            f"the first ({listed}): the model did not follow the body there (a deformation "
            "beyond it, a contact out of sight), so their forces are unreliable")


@dataclass
class ContactRange:
    frames: int = 0
    min_n: float = float("inf")
    max_n: float = 0.0
    sum_n: float = 0.0


@dataclass
class SenseSummary:
    """Accumulates FrameEstimates; to_dict() is sense.json's "summary"."""

    frames: int = 0
    ok: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    contacts: dict[int, ContactRange] = field(default_factory=dict)
    stage_ms: dict[str, list[float]] = field(
        default_factory=lambda: {s: [] for s in (*STAGES, "write")})
    first_time_s: float | None = None
    last_time_s: float | None = None
    wall_s: float = 0.0
    interrupted: bool = False
    # the error line that ended the run before the recording's end (None: it ended there)
    error: str | None = None
    # wall time between one frame's results and the next's (ms): the rate frames come out at,
    # which with the look-ahead (estimation.lookahead) is less than a frame's stage times
    interval_ms: list[float] = field(default_factory=list)
    # ok frames that fit more than POOR_FIT_MM worse than the run's first frame
    poor_fit_frames: list[int] = field(default_factory=list)
    _first_fit_mm: float | None = None
    _last_done_s: float | None = None

    def add(self, estimate: FrameEstimate) -> None:
        self.frames += 1
        if self.first_time_s is None:
            self.first_time_s = estimate.time_s
        self.last_time_s = estimate.time_s
        fitted = not np.isnan(estimate.fit_rms_mm)
        if self._first_fit_mm is None and fitted:
            self._first_fit_mm = estimate.fit_rms_mm
        if estimate.status == "ok":
            self.ok += 1
            if fitted and estimate.fit_rms_mm > self._first_fit_mm + POOR_FIT_MM:
                self.poor_fit_frames.append(estimate.frame)
        else:
            self.skipped[estimate.status] = self.skipped.get(estimate.status, 0) + 1
        for contact in estimate.contacts:
            span = self.contacts.setdefault(contact.contact, ContactRange())
            span.frames += 1
            span.min_n = min(span.min_n, contact.force_n)
            span.max_n = max(span.max_n, contact.force_n)
            span.sum_n += contact.force_n
        for stage in STAGES:
            self.stage_ms[stage].append(estimate.timings_ms.get(stage, 0.0))

    def add_write_ms(self, milliseconds: float) -> None:
        self.stage_ms["write"].append(milliseconds)

    def frame_done(self, wall_s: float) -> None:
        """A frame's results are out at wall_s (s, any fixed origin)."""
        if self._last_done_s is not None:
            self.interval_ms.append(1e3 * (wall_s - self._last_done_s))
        self._last_done_s = wall_s

    @property
    def frames_per_s(self) -> float:
        return self.frames / self.wall_s if self.wall_s > 0 else float("nan")

    def stage_medians_ms(self) -> dict[str, float]:
        return {s: float(np.median(v)) if v else 0.0 for s, v in self.stage_ms.items()}

    def to_dict(self) -> dict[str, Any]:
        totals = np.sum([self.stage_ms[s] for s in STAGES], axis=0) if self.frames else []
        return {
            "frames": self.frames,
            "ok": self.ok,
            "skipped": dict(sorted(self.skipped.items())),
            "interrupted": self.interrupted,
            "error": self.error,
            "contacts": [
                {"contact": index, "frames": span.frames, "force_min_n": round(span.min_n, 6),
                 "force_max_n": round(span.max_n, 6),
                 "force_mean_n": round(span.sum_n / span.frames, 6)}
                for index, span in sorted(self.contacts.items())
            ],
            "wall_s": round(self.wall_s, 3),
            "frames_per_s": round(self.frames_per_s, 2) if self.wall_s > 0 else None,
            "median_total_ms": round(float(np.median(totals)), 3) if self.frames else None,
            "median_interval_ms": (round(float(np.median(self.interval_ms)), 3)
                                   if self.interval_ms else None),
            "median_stage_ms": {k: round(v, 3) for k, v in self.stage_medians_ms().items()},
            "poor_fit_frames": list(self.poor_fit_frames),
        }
