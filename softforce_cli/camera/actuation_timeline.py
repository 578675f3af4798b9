"""Actuation inputs over time, read from a CSV file, attached to recorded frames.

The CSV has a header and one row per change of the inputs:

    time_s,north_mm,east_mm,south_mm,west_mm
    0.0,0,0,0,0
    2.5,5,5,0,0

- The first column is the clock: `time_s` (seconds since the recording's first frame) or
  `unix_time_s` (seconds since 1970-01-01 UTC, compared with the frames' absolute times).
- Every other column is a cable, named `<cable>_mm` for displacement control (mm) or `<cable>_n`
  for force control (N); all cables share one control mode, and the cable names are those of
  the robot file.
- Times do not decrease. The input at a frame's time is the last row at or before it: inputs
  hold until the next row. Frames before the first row get no actuation.
- Blank lines and lines starting with `#` are ignored.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from softforce_cli.camera.frame import Actuation, RgbdFrame
from softforce_cli.errors import RecordingError

CLOCK_COLUMNS = ("time_s", "unix_time_s")
CONTROL_SUFFIXES = {"_mm": "displacement", "_n": "force"}


@dataclass(frozen=True)
class ActuationTimeline:
    """Piecewise-constant actuator inputs.

    names    : cable names (column names without their unit suffix).
    control  : "displacement" (values in mm) or "force" (values in N).
    times_s  : (n,) float64, non-decreasing.
    values   : (n, len(names)) float64; row i holds from times_s[i] until times_s[i + 1].
    relative : True when times count from the first frame (`time_s`), False for unix time.
    """

    names: tuple[str, ...]
    control: str
    times_s: np.ndarray
    values: np.ndarray
    relative: bool = True

    @cached_property
    def times_ns(self) -> np.ndarray:
        """(n,) int64 row times in nanoseconds, compared exactly with frame times."""
        return np.rint(self.times_s * 1e9).astype(np.int64)

    def actuation_at(self, time_ns: int) -> Actuation | None:
        """The inputs of the last row at or before `time_ns`; None before the first row.

        `time_ns` counts from the first frame for a `time_s` timeline, from 1970 otherwise.
        """
        row = int(np.searchsorted(self.times_ns, time_ns, side="right")) - 1
        if row < 0:
            return None
        return Actuation(names=self.names, control=self.control, values=self.values[row].copy())


def read_actuation_csv(path: Path) -> ActuationTimeline:
    """Read an actuation CSV (see the module docstring); RecordingError says what is wrong."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"actuation file {path} does not exist")
    try:
        with open(path, newline="") as handle:
            rows = [
                (number, row)
                for number, row in enumerate(csv.reader(handle), start=1)
                if row and any(cell.strip() for cell in row)
                and not row[0].lstrip().startswith("#")
            ]
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        raise RecordingError(
            f"cannot read actuation file {path} as CSV text ({error}); save it as UTF-8 CSV"
        ) from error
    if not rows:
        raise RecordingError(f"actuation file {path} is empty; it needs a header and rows")
    (_, header), body = rows[0], rows[1:]
    header = [cell.strip() for cell in header]
    relative = _clock_is_relative(path, header[0])
    names, control = _cables(path, header[1:])
    if not body:
        raise RecordingError(f"actuation file {path} has a header but no rows")
    table = np.array([_numbers(path, number, row, len(header)) for number, row in body])
    times_s = table[:, 0]
    if np.any(np.diff(times_s) < 0):
        line = body[int(np.argmax(np.diff(times_s) < 0)) + 1][0]
        raise RecordingError(f"{path}:{line}: time goes backwards; sort the rows by time")
    return ActuationTimeline(names, control, times_s, table[:, 1:], relative)


def with_actuation(frames: Iterable[RgbdFrame], timeline: ActuationTimeline) -> Iterator[RgbdFrame]:
    """Attach to each frame the timeline's inputs at its time (relative to the first frame
    for `time_s` timelines)."""
    first_ns: int | None = None
    for frame in frames:
        first_ns = frame.time_ns if first_ns is None else first_ns
        time_ns = frame.time_ns - first_ns if timeline.relative else frame.time_ns
        yield dataclasses.replace(frame, actuation=timeline.actuation_at(time_ns))


def _clock_is_relative(path: Path, column: str) -> bool:
    if column not in CLOCK_COLUMNS:
        raise RecordingError(
            f"{path}: the first column is {column!r}; name it 'time_s' (seconds since the first "
            "frame) or 'unix_time_s' (seconds since 1970)"
        )
    return column == "time_s"


def _cables(path: Path, columns: list[str]) -> tuple[tuple[str, ...], str]:
    if not columns:
        raise RecordingError(f"{path} has no cable column after the time column")
    names, controls = [], set()
    for column in columns:
        suffix = next((s for s in CONTROL_SUFFIXES if column.endswith(s)), None)
        if suffix is None or column == suffix:
            raise RecordingError(
                f"{path}: column {column!r} should be a cable name ending in _mm "
                "(displacement) or _n (force), e.g. north_mm"
            )
        names.append(column[: -len(suffix)])
        controls.add(CONTROL_SUFFIXES[suffix])
    if len(controls) > 1:
        raise RecordingError(f"{path} mixes _mm and _n columns; all cables share one control mode")
    if len(set(names)) != len(names):
        raise RecordingError(f"{path} names a cable twice: {names}")
    return tuple(names), controls.pop()


def _numbers(path: Path, line: int, row: list[str], width: int) -> list[float]:
    if len(row) != width:
        raise RecordingError(f"{path}:{line}: {len(row)} values where the header has {width}")
    try:
        numbers = [float(cell) for cell in row]
    except ValueError as error:
        raise RecordingError(f"{path}:{line}: {error}") from error
    if not all(math.isfinite(number) for number in numbers):
        raise RecordingError(f"{path}:{line}: values must be finite numbers")
    return numbers
