"""One synchronised RGB-D frame with its actuation inputs and optional marker observations."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from softforce_cli.camera.intrinsics import CameraIntrinsics
from softforce_cli.errors import RecordingError

if TYPE_CHECKING:
    from softforce_cli.model.config import CableSpec


@dataclass(frozen=True)
class Actuation:
    """Actuator inputs of one frame (docs/recordings.md, topic /robot/actuation).

    names   : cable names (softforce writes them in the robot file's order; another tool
              may not: values_in puts them in a robot's order).
    control : "displacement" (values in mm) or "force" (values in N).
    values  : (a,) float64.
    """

    names: tuple[str, ...]
    control: str
    values: np.ndarray

    def values_in(self, names: Sequence[str]) -> np.ndarray:
        """(a,) float64 the values in the order of `names` (a robot's cables); ValueError
        when they are not the same names (actuation_mismatch says why, in a line)."""
        if tuple(names) == tuple(self.names):
            return np.asarray(self.values, dtype=float)
        position = {name: i for i, name in enumerate(self.names)}
        if len(position) != len(self.names) or sorted(position) != sorted(names):
            raise ValueError(f"actuation names {list(self.names)} are not {list(names)}")
        return np.asarray(self.values, dtype=float)[[position[name] for name in names]]


def actuation_mismatch(actuation: Actuation | None,
                       cables: Sequence[CableSpec]) -> str | None:
    """Why a frame's actuation (None: the recording has none) does not drive a robot's
    cables (their names, in any order, and their control modes), or None when it does."""
    names = tuple(cable.name for cable in cables)
    controls = {cable.control for cable in cables}
    if actuation is None:
        if not names:
            return None
        return (f"no /robot/actuation message, but the robot's cables "
                f"({', '.join(names)}) need their inputs; record them with "
                "`softforce record --actuation ACT.csv`")
    if (sorted(actuation.names) != sorted(names)
            or len(set(actuation.names)) != len(actuation.names)):
        return (f"the actuation names {list(actuation.names)} are not the robot's cables "
                f"{list(names)}")
    if names and controls != {actuation.control}:  # a robot without cables takes any
        return (f"the actuation is {actuation.control}-controlled but the robot file's cables "
                f"are {', '.join(sorted(controls))}-controlled")
    return None


def robot_actuation(actuation: Actuation | None, cables: Sequence[CableSpec],
                    where: str) -> np.ndarray:
    """(a,) float64 a frame's actuation values in the order of the robot's cables (their
    names, in any order in the recording); RecordingError, one line "where: why", when it
    does not drive them (actuation_mismatch)."""
    why = actuation_mismatch(actuation, cables)
    if why is not None:
        raise RecordingError(f"{where}: {why}")
    if actuation is None:  # a robot without cables
        return np.zeros(0)
    return actuation.values_in([cable.name for cable in cables])


@dataclass(frozen=True)
class Markers:
    """Observed marker positions in the camera frame (topic /markers).

    ids          : marker ids as in the robot file.
    positions_mm : (k, 3) float64 in the camera optical frame.
    """

    ids: tuple[str, ...]
    positions_mm: np.ndarray


@dataclass(frozen=True)
class RgbdFrame:
    """A colour image and the depth aligned to it, taken at one instant.

    time_ns    : log time in nanoseconds (shared by every message of the frame).
    color      : (h, w, 3) uint8 RGB.
    depth_mm   : (h, w) uint16 depth in millimetres aligned to colour, 0 = no data.
    intrinsics : of the colour image (and so of the aligned depth).
    """

    time_ns: int
    color: np.ndarray
    depth_mm: np.ndarray
    intrinsics: CameraIntrinsics
    actuation: Actuation | None = None
    markers: Markers | None = field(default=None)
