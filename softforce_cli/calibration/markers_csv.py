"""Observed marker positions from a CSV file: `id,x_mm,y_mm,z_mm`, camera frame, one marker a
line. Lines starting with # and blank lines are skipped; the header is required."""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from softforce_cli.camera.frame import Markers
from softforce_cli.errors import CalibrationError

HEADER = ("id", "x_mm", "y_mm", "z_mm")


def read_markers_csv(path: Path) -> Markers:
    """Read a marker CSV; CalibrationError naming the file and line for anything malformed."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"marker file {path} not found")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as error:
        raise CalibrationError(f"{path}: cannot read it as text ({error})") from error
    return parse_markers_csv(text, str(path))


def parse_markers_csv(text: str, where: str = "markers") -> Markers:
    """Markers from the CSV text (see the module docstring)."""
    try:
        rows = [(number, row) for number, row in enumerate(csv.reader(io.StringIO(text)), start=1)
                if row and any(cell.strip() for cell in row)
                and not row[0].lstrip().startswith("#")]
    except csv.Error as error:  # e.g. a field over the csv module's size limit
        raise CalibrationError(f"{where}: not a marker CSV ({error})") from error
    if not rows:
        raise CalibrationError(f"{where}: no markers; expected a header "
                               f"`{','.join(HEADER)}` and one line per marker")
    number, header = rows[0]
    if tuple(cell.strip().lower() for cell in header) != HEADER:
        raise CalibrationError(f"{where}:{number}: header is {','.join(header)!r}; expected "
                               f"`{','.join(HEADER)}` (camera frame, millimetres)")
    ids: list[str] = []
    positions: list[list[float]] = []
    for number, row in rows[1:]:
        if len(row) != 4:
            raise CalibrationError(f"{where}:{number}: {len(row)} fields; expected 4 "
                                   f"({','.join(HEADER)})")
        marker_id = row[0].strip()
        if not marker_id:
            raise CalibrationError(f"{where}:{number}: missing marker id")
        if marker_id in ids:
            raise CalibrationError(f"{where}:{number}: marker {marker_id!r} appears twice "
                                   f"(first on another line); keep one")
        coordinates = []
        for name, cell in zip(HEADER[1:], row[1:], strict=True):
            try:
                value = float(cell)
            except ValueError:
                raise CalibrationError(f"{where}:{number}: {name} of marker {marker_id!r} is "
                                       f"{cell.strip()!r}, not a number") from None
            if not math.isfinite(value):
                raise CalibrationError(f"{where}:{number}: {name} of marker {marker_id!r} is "
                                       f"{cell.strip()}; remove the marker or re-measure it")
            coordinates.append(value)
        ids.append(marker_id)
        positions.append(coordinates)
    if not ids:
        raise CalibrationError(f"{where}: a header but no markers")
    return Markers(tuple(ids), np.array(positions, dtype=float))


def markers_to_csv(markers: Markers) -> str:
    """The CSV text of `markers` (the inverse of parse_markers_csv, 4 decimals = 0.1 um)."""
    lines = [",".join(HEADER)]
    for marker_id, (x, y, z) in zip(markers.ids, markers.positions_mm, strict=True):
        lines.append(f"{marker_id},{x:.4f},{y:.4f},{z:.4f}")
    return "\n".join(lines) + "\n"
