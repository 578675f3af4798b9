"""The output folder of `softforce sense` (docs/sensing.md), written frame by frame.

contacts.csv and frames.csv get one flushed row per contact / frame. sense.json is kept a
valid JSON document after every frame: the frames array and the summary that closes it are
rewritten in place from the end of the last frame, so the file grows by one frame each time
and memory stays flat however long the recording. An interrupted run leaves all three files
readable up to the last whole frame.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import IO, Any

from softforce_cli.errors import OutputError, OutputExistsError
from softforce_cli.estimation.results import STAGES, FrameEstimate
from softforce_cli.io.atomic import writable_folder

CONTACTS_HEADER = ("frame", "time_s", "contact", "feature", "x_mm", "y_mm", "z_mm", "force_n",
                   "fx_n", "fy_n", "fz_n", "residual_mm")
FRAMES_HEADER = ("frame", "time_s", "status", "contacts", "points_kept", "features_matched",
                 "features_hidden", "fit_rms_mm", "total_ms", "robot_points", "object_points",
                 "features_rejected", *(f"{stage}_ms" for stage in STAGES))
OUTPUT_NAMES = ("contacts.csv", "frames.csv", "sense.json")


def check_output_folder(folder: Path, force: bool) -> None:
    """OutputExistsError if the folder already holds a sense output and force is not set."""
    existing = [name for name in OUTPUT_NAMES if (Path(folder) / name).exists()]
    if existing and not force:
        raise OutputExistsError(f"{folder} already holds {', '.join(existing)}; pass --force to "
                                "overwrite, or choose another -o folder")


def _number(value: float, digits: int = 4) -> float | None:
    return None if value is None or not math.isfinite(value) else round(float(value), digits)


def frame_to_dict(estimate: FrameEstimate) -> dict[str, Any]:
    """One entry of sense.json's "frames"."""
    return {
        "frame": estimate.frame,
        "time_s": round(estimate.time_s, 6),
        "status": estimate.status,
        "contacts": [
            {"contact": c.contact, "feature": c.feature,
             "position_mm": [round(float(v), 3) for v in c.position_mm],
             "force_n": round(c.force_n, 6),
             "force_vector_n": [round(float(v), 6) for v in c.force_vector_n],
             "residual_mm": _number(c.residual_mm)}
            for c in estimate.contacts
        ],
        "points_kept": estimate.points_kept,
        "robot_points": estimate.robot_points,
        "object_points": estimate.object_points,
        "features_matched": estimate.features_matched,
        "features_hidden": estimate.features_hidden,
        "features_rejected": estimate.features_rejected,
        "fit_rms_mm": _number(estimate.fit_rms_mm),
        "cable_tensions_n": [round(float(v), 6) for v in estimate.cable_tensions_n],
        "timings_ms": {k: round(v, 3) for k, v in estimate.timings_ms.items()},
    }


class SenseWriter:
    """Writes contacts.csv, frames.csv and sense.json into `folder` as frames arrive.

    header: sense.json's fields before "frames" (recording, robot, calibration, settings).
    """

    def __init__(self, folder: Path, header: dict[str, Any], force: bool = False) -> None:
        folder = Path(folder)
        check_output_folder(folder, force)
        self.folder = writable_folder(folder)
        try:
            self._contacts_file = open(folder / "contacts.csv", "w", newline="")  # noqa: SIM115
            self._frames_file = open(folder / "frames.csv", "w", newline="")  # noqa: SIM115
            self._json: IO[str] = open(folder / "sense.json", "w")  # noqa: SIM115
        except OSError as error:
            raise OutputError(f"cannot write in {folder}: {error.strerror or error}") from error
        self._contacts = csv.writer(self._contacts_file)
        self._frames = csv.writer(self._frames_file)
        self._contacts.writerow(CONTACTS_HEADER)
        self._frames.writerow(FRAMES_HEADER)
        fields = json.dumps(header, indent=1)[1:-1].strip()  # the header's fields, no braces
        opening = "{\n " + (fields + ",\n " if fields else "") + '"frames": ['
        self._json.write(opening)
        self._frames_end = self._json.tell()
        self._first = True
        self.close_json({})

    def write(self, estimate: FrameEstimate, summary: dict[str, Any]) -> None:
        """Append one frame to the three files and flush them."""
        e = estimate
        for c in e.contacts:
            self._contacts.writerow([
                e.frame, f"{e.time_s:.6f}", c.contact, c.feature,
                *(f"{v:.3f}" for v in c.position_mm), f"{c.force_n:.6f}",
                *(f"{v:.6f}" for v in c.force_vector_n), _text(c.residual_mm),
            ])
        self._frames.writerow([
            e.frame, f"{e.time_s:.6f}", e.status, len(e.contacts), e.points_kept,
            e.features_matched, e.features_hidden, _text(e.fit_rms_mm), f"{e.total_ms:.3f}",
            e.robot_points, e.object_points, e.features_rejected,
            *(f"{e.timings_ms.get(stage, 0.0):.3f}" for stage in STAGES),
        ])
        self._contacts_file.flush()
        self._frames_file.flush()
        self._json.seek(self._frames_end)
        self._json.write(("\n  " if self._first else ",\n  ") + json.dumps(frame_to_dict(e)))
        self._first = False
        self._frames_end = self._json.tell()
        self.close_json(summary)

    def close_json(self, summary: dict[str, Any]) -> None:
        """Rewrite what closes sense.json after the last frame: "]", the summary, "}"."""
        self._json.seek(self._frames_end)
        self._json.write("\n ],\n \"summary\": " + json.dumps(summary, indent=1) + "\n}\n")
        self._json.truncate()
        self._json.flush()

    def close(self, summary: dict[str, Any]) -> None:
        self.close_json(summary)
        for handle in (self._contacts_file, self._frames_file, self._json):
            handle.close()


def _text(value: float) -> str:
    return "" if value is None or not math.isfinite(value) else f"{value:.4f}"
