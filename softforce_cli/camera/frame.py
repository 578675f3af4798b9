"""One synchronised RGB-D frame with its actuation inputs and optional marker observations."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from softforce_cli.camera.intrinsics import CameraIntrinsics


@dataclass(frozen=True)
class Actuation:
    """Actuator inputs of one frame (docs/recordings.md, topic /robot/actuation).

    names   : cable names, in the robot file's order.
    control : "displacement" (values in mm) or "force" (values in N).
    values  : (a,) float64.
    """

    names: tuple[str, ...]
    control: str
    values: np.ndarray


def actuation_mismatch(actuation: Actuation | None, names: tuple[str, ...],
                       controls: set[str]) -> str | None:
    """Why a frame's actuation (None: the recording has none) does not drive a robot's
    cables `names` (in the robot file's order) under the control modes `controls`, or None
    when it does."""
    if actuation is None:
        if not names:
            return None
        return (f"no /robot/actuation message in the first frame, but the robot's cables "
                f"({', '.join(names)}) need their inputs; record them with "
                "`softforce record --actuation ACT.csv`")
    if tuple(actuation.names) != tuple(names):
        return (f"the actuation names {list(actuation.names)} are not the robot's cables "
                f"{list(names)} (same order)")
    if controls != {actuation.control}:
        return (f"the actuation is {actuation.control}-controlled but the robot file's cables "
                f"are {', '.join(sorted(controls))}-controlled")
    return None


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
