"""The numbers a report opens with, computed from a sense run's tables."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softforce_cli.estimation.results import SKIP_REASONS, STAGES
from softforce_cli.report.loading import SenseRun

# Frame statuses that are not failures: tare frames zero the sensor on purpose.
STATUS_MEANINGS = {**SKIP_REASONS, "tare": "taken to zero the sensor (--tare, or the first "
                   "frames without a contact by default): no contact is estimated on it"}


@dataclass(frozen=True)
class ContactSpan:
    """A contact track: frames it appears in, force min/median/max (N), time span (s)."""

    contact: int
    frames: int
    force_min_n: float
    force_median_n: float
    force_max_n: float
    first_s: float
    last_s: float


@dataclass(frozen=True)
class Overview:
    """frames: processed; skipped: status -> count for statuses other than ok;
    frames_per_s: the run's own rate (sense.json), else 1000 / mean total_ms;
    stage_median_ms: stage -> median milliseconds over the frames;
    camera: what the vision stage made of the camera, one line (None when sense.json has no
    readable "camera" entry, as before 2026-11-30);
    poor_fit_frames: the ok frames sense found fitting the robot far worse than the first
    (sense.json's summary; none where it has no such entry, as before 2026-12-01)."""

    frames: int
    ok: int
    skipped: dict[str, int]
    contacts: tuple[ContactSpan, ...]
    frames_per_s: float
    rate_measured: bool
    stage_median_ms: dict[str, float]
    duration_s: float
    camera: str | None = None
    poor_fit_frames: tuple[int, ...] = ()


def camera_line(entry: object) -> str | None:
    """sense.json's "camera" entry as "1280x720, fx 915.6 px, robot 540 mm away: 2x2 pixel
    blocks, neighbours 20 / 3"; None when it is missing or not of that form."""
    try:
        blocks = ("every pixel" if entry["decimation"] == 1
                  else f"{entry['decimation']}x{entry['decimation']} pixel blocks")
        return (f"{entry['width']}x{entry['height']}, fx {entry['fx']:.1f} px, robot "
                f"{entry['robot_distance_mm']:.0f} mm away: {blocks}, neighbours "
                f"{entry['outlier_min_neighbours']} / {entry['contact_min_neighbours']}")
    except (TypeError, KeyError, ValueError):
        return None


def sense_overview(run: SenseRun) -> Overview:
    frames, contacts = run.frames, run.contacts
    statuses, counts = np.unique(frames["status"], return_counts=True)
    skipped = {str(s): int(n) for s, n in zip(statuses, counts, strict=True) if s != "ok"}
    spans = []
    for index in np.unique(contacts["contact"]).astype(int):
        rows = contacts["contact"] == index
        force, time = contacts["force_n"][rows], contacts["time_s"][rows]
        spans.append(ContactSpan(index, int(rows.sum()), float(force.min()),
                                 float(np.median(force)), float(force.max()),
                                 float(time.min()), float(time.max())))
    rate = run.summary.get("frames_per_s")
    measured = isinstance(rate, int | float) and rate > 0
    if not measured:
        total = frames["total_ms"][np.isfinite(frames["total_ms"])]
        rate = 1e3 / total.mean() if len(total) and total.mean() > 0 else float("nan")
    stages = {s: float(np.nanmedian(frames[f"{s}_ms"])) for s in STAGES
              if f"{s}_ms" in frames.names and len(frames)}
    times = frames["time_s"]
    poor = run.summary.get("poor_fit_frames")
    return Overview(
        frames=len(frames), ok=int(run.ok.sum()), skipped=skipped, contacts=tuple(spans),
        frames_per_s=float(rate), rate_measured=measured, stage_median_ms=stages,
        duration_s=float(times.max() - times.min()) if len(times) else 0.0,
        camera=camera_line(run.header.get("camera")),
        poor_fit_frames=tuple(int(f) for f in poor if isinstance(f, int))
        if isinstance(poor, list) else (),
    )
