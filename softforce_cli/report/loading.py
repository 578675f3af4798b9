"""A sense or diagnose output folder read back into dataclasses, whatever state it is in.

A sense folder (docs/sensing.md) holds contacts.csv, frames.csv and sense.json, each
flushed frame by frame: an interrupted run can leave a CSV whose last line is cut short, or a
sense.json cut mid-frame. The tables are read from the CSVs, keeping every whole row and noting
what was dropped; sense.json gives the run's header (recording, robot, calibration, settings)
and each frame's cable tensions when it is readable. A diagnose folder holds diagnosis.json
(read by diagnosis_file.py), robot.fitted.toml and figures.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from softforce_cli.errors import SoftforceError
from softforce_cli.io.sense_files import CONTACTS_HEADER, FRAMES_HEADER
from softforce_cli.report.diagnosis_file import Diagnosis, read_diagnosis

# Columns of frames.csv that hold text; every other column is a number (NaN when empty).
TEXT_COLUMNS = ("status",)
# The columns every softforce frames.csv starts with (docs/sensing.md): later columns vary.
FRAMES_REQUIRED = FRAMES_HEADER[:9]


class ReportError(SoftforceError):
    """A report cannot be made from this folder (not a softforce output, unreadable files)."""


@dataclass(frozen=True)
class Table:
    """Columns by header name, in file order: float64 arrays, or str arrays for TEXT_COLUMNS."""

    columns: dict[str, np.ndarray]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.columns)

    def __len__(self) -> int:
        return len(next(iter(self.columns.values()))) if self.columns else 0

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    def rows(self, mask: np.ndarray) -> Table:
        """The rows where mask (n,) bool is true."""
        return Table({name: values[mask] for name, values in self.columns.items()})


@dataclass(frozen=True)
class SenseRun:
    """What `softforce sense` left in `folder`.

    header         : sense.json's fields other than "frames" and "summary" ({} if unreadable).
    frames         : frames.csv, one row per processed frame.
    contacts       : contacts.csv, one row per contact, only of frames in `frames`.
    cable_tensions : frame index -> (a,) tensions N, from sense.json (empty if unreadable).
    summary        : sense.json's "summary" ({} if unreadable): wall_s, frames_per_s, ...
    notes          : one line per problem found in the files (rows dropped, sense.json cut).
    """

    folder: Path
    header: dict[str, Any]
    frames: Table
    contacts: Table
    cable_tensions: dict[int, np.ndarray]
    summary: dict[str, Any]
    notes: tuple[str, ...] = ()

    @property
    def ok(self) -> np.ndarray:
        """(n,) bool: frames whose status is ok."""
        return self.frames["status"] == "ok"

    def input_path(self, key: str) -> str | None:
        """The path the run was given for "robot" or "calibration" (header's {"file"}), or
        "recording"; None when sense.json does not say."""
        value = self.header.get(key)
        if isinstance(value, dict):
            value = value.get("file")
        return value if isinstance(value, str) else None


@dataclass(frozen=True)
class DiagnoseRun:
    """What `softforce diagnose` left in `folder`: diagnosis.json, the fitted robot file when
    present, and the PNG figures it wrote (shown as they are)."""

    folder: Path
    diagnosis: Diagnosis
    fitted_robot: Path | None
    figures: tuple[Path, ...]


@dataclass(frozen=True)
class RunFolder:
    """A folder holding a sense output, a diagnose output, or both."""

    folder: Path
    sense: SenseRun | None = None
    diagnose: DiagnoseRun | None = None


def load_run(folder: Path, report_folder_name: str = "report") -> RunFolder:
    """Read a sense and/or diagnose output folder; ReportError when it is neither."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ReportError(f"{folder} is not a folder; give the -o folder of `softforce sense` "
                          "or `softforce diagnose`")
    has_sense = any((folder / name).is_file()
                    for name in ("frames.csv", "contacts.csv", "sense.json"))
    has_diagnosis = (folder / "diagnosis.json").is_file()
    if not (has_sense or has_diagnosis):
        raise ReportError(f"{folder} is neither a sense output (frames.csv, contacts.csv, "
                          "sense.json) nor a diagnose output (diagnosis.json); give the -o "
                          "folder of `softforce sense` or `softforce diagnose`")
    sense = load_sense(folder) if has_sense else None
    diagnose = load_diagnose(folder, report_folder_name) if has_diagnosis else None
    return RunFolder(folder, sense, diagnose)


def load_sense(folder: Path) -> SenseRun:
    """Read a sense output folder (see the module docstring for damaged files)."""
    notes: list[str] = []
    for name in ("frames.csv", "contacts.csv"):
        if not (folder / name).is_file():
            raise ReportError(f"{folder / name} is missing: the sense run did not start writing "
                              "(run `softforce sense` again)")
    frames = read_table(folder / "frames.csv", FRAMES_REQUIRED, notes)
    contacts = read_table(folder / "contacts.csv", CONTACTS_HEADER, notes)
    known = np.isin(contacts["frame"], frames["frame"])
    if not known.all():
        notes.append(f"contacts.csv: {int((~known).sum())} rows of a frame frames.csv lacks "
                     "(the run stopped between the two files): left out")
        contacts = contacts.rows(known)
    document = _read_sense_json(folder / "sense.json", notes)
    header = {k: v for k, v in document.items() if k not in ("frames", "summary")}
    tensions = {int(f["frame"]): np.asarray(f.get("cable_tensions_n", []), dtype=float)
                for f in document.get("frames", []) if isinstance(f, dict) and "frame" in f}
    summary = document.get("summary") if isinstance(document.get("summary"), dict) else {}
    if summary.get("error"):
        notes.append(f"the run ended on an error after {summary.get('frames')} frames, before "
                     f"the recording's end: {summary['error']}")
    elif summary.get("interrupted"):
        notes.append(f"the run was interrupted after {summary.get('frames')} frames, before "
                     "the recording's end")
    return SenseRun(folder, header, frames, contacts, tensions, summary, tuple(notes))


def load_diagnose(folder: Path, report_folder_name: str = "report") -> DiagnoseRun:
    fitted = folder / "robot.fitted.toml"
    figures = sorted(path for path in folder.rglob("*.png")
                     if report_folder_name not in path.relative_to(folder).parts)
    try:
        diagnosis = read_diagnosis(folder / "diagnosis.json")
    except ValueError as error:
        raise ReportError(str(error)) from error
    return DiagnoseRun(folder, diagnosis, fitted if fitted.is_file() else None, tuple(figures))


def read_table(path: Path, required: tuple[str, ...], notes: list[str]) -> Table:
    """A softforce CSV as a Table. Rows cut short or unreadable (an interrupted run's last
    line) are dropped and noted; a header other than softforce's is a ReportError."""
    try:
        with open(path, newline="") as handle:
            lines = list(csv.reader(handle))
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        raise ReportError(f"{path}: cannot read it ({error})") from error
    if not lines or tuple(lines[0][: len(required)]) != required:
        raise ReportError(f"{path}: not a softforce sense table (its header should start "
                          f"{','.join(required[:4])},...); give a `softforce sense` output folder")
    header, kept, dropped = lines[0], [], 0
    for row in lines[1:]:
        values = _parsed_row(header, row)
        if values is None:
            dropped += 1
        else:
            kept.append(values)
    if dropped:
        notes.append(f"{path.name}: {dropped} incomplete row{'s' * (dropped > 1)} dropped "
                     "(an interrupted run); the rest is reported")
    columns = {}
    for index, name in enumerate(header):
        values = [row[index] for row in kept]
        columns[name] = (np.array(values, dtype=str) if name in TEXT_COLUMNS
                         else np.array(values, dtype=float).reshape(-1))
    return Table(columns)


def _parsed_row(header: list[str], row: list[str]) -> list[Any] | None:
    if len(row) != len(header):
        return None
    parsed: list[Any] = []
    for name, text in zip(header, row, strict=True):
        if name in TEXT_COLUMNS:
            if not text:
                return None
            parsed.append(text)
            continue
        try:
            parsed.append(float(text) if text else math.nan)
        except ValueError:
            return None
    return parsed


def _read_sense_json(path: Path, notes: list[str]) -> dict[str, Any]:
    if not path.is_file():
        notes.append("sense.json is missing: no robot, recording or truth for this report")
        return {}
    try:
        document = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        notes.append(f"sense.json is unreadable ({error.__class__.__name__}: cut short?): the "
                     "tables are reported without the run's header")
        return {}
    if not isinstance(document, dict):
        notes.append("sense.json is not a JSON object: ignored")
        return {}
    return document
