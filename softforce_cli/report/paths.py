"""The input files a run names (robot, calibration, recording), found again for its report."""

from __future__ import annotations

from pathlib import Path

PAGE_NAME = "report.html"  # the page, in the report's folder


def resolve_input(text: str | None, folder: Path) -> Path | None:
    """The file a run was given as `text`, or None when it cannot be found.

    sense.json keeps paths as they were typed, so a relative one is relative to where the run
    was started: the current folder is tried first, then each folder above the output folder
    (a report made from elsewhere in the same project).
    """
    if not text:
        return None
    path = Path(text)
    if path.is_absolute():
        return path if path.is_file() else None
    for base in (Path.cwd(), *Path(folder).resolve().parents):
        if (base / path).is_file():
            return base / path
    return None



def truth_path(recording: Path) -> Path:
    """rec.mcap -> rec.truth.json beside it (docs/recordings.md), the name
    sim.simulate.truth_path_for gives; not imported from there, whose rendering imports
    cost seconds."""
    return recording.with_name(recording.stem + ".truth.json")
