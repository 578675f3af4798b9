"""The calibration result and its JSON document (docs/calibration.md).

    {
      "format": "softforce.calibration", "version": 1,
      "rotation": [[...], [...], [...]],          p_robot = R p_cam + T
      "translation_mm": [x, y, z],
      "actuation": {"names": [...], "control": "displacement" | "force" | "mixed",
                    "controls": [...per cable...], "values": [...mm or N...],
                    "tensions_n": [...], "slack": [...]},
      "residual_rms_mm": r, "residual_history_mm": [...per outer iteration...],
      "pose_covariance": [[...6...] x 6] | null,  rad (about x, y, z), then mm (x, y, z)
      "markers": [{"id", "residual_mm", "residual_vector_mm", "observed_camera_mm",
                   "model_robot_mm", "used", "outlier", "left_out_mm"}, ...],
      "outliers": [...], "excluded": [...], "unobserved": [...],
      "converged", "iterations", "settings": {"outer_iterations", "inner_iterations"},
      "robot": {"name", "file"}, "source", "elapsed_s", "warnings"
    }
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from softforce_cli import __version__
from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.errors import CalibrationError

FORMAT = "softforce.calibration"
VERSION = 1


@dataclass(frozen=True)
class MarkerResidual:
    """One observed marker after calibration.

    observed_camera_mm : (3,) as observed, camera frame.
    model_robot_mm     : (3,) on the calibrated FE model, robot frame.
    residual_mm        : (3,) R p_cam + T - model, robot frame.
    used               : whether the fit used it (False when excluded as an outlier).
    outlier            : whether the outlier test flagged it.
    left_out_mm        : for a flagged marker, how far a fit without it puts it (mm).
    """

    id: str
    observed_camera_mm: np.ndarray
    model_robot_mm: np.ndarray
    residual_mm: np.ndarray
    used: bool
    outlier: bool
    left_out_mm: float | None = None

    @property
    def distance_mm(self) -> float:
        return float(np.linalg.norm(self.residual_mm))


@dataclass(frozen=True)
class CalibrationResult:
    """Calibrated robot_from_camera and actuation, with the evidence of the fit.

    actuation      : (a,) per cable in its control units: shortening (mm) for displacement
                     control, tension (N) for force control.
    tensions_n     : (a,) cable tensions at the calibrated equilibrium.
    slack          : (a,) bool, tension below SLACK_TENSION_N.
    residual_rms_mm: RMS over the used markers of |R p_cam + T - model|.
    pose_covariance: (6, 6) covariance of a small correction of the pose (rotations about the
                     robot frame's x, y, z axes through its origin, rad; then translations,
                     mm: calibration.pose_covariance), or None (a pose without markers).
    positions_mm   : (n, 3) the calibrated FE configuration (not written to JSON).
    """

    robot_name: str
    robot_file: str
    source: str
    robot_from_camera: RigidTransform
    cable_names: tuple[str, ...]
    cable_controls: tuple[str, ...]
    actuation: np.ndarray
    tensions_n: np.ndarray
    slack: np.ndarray
    residual_rms_mm: float
    residual_history_mm: tuple[float, ...]
    markers: tuple[MarkerResidual, ...]
    unobserved: tuple[str, ...]
    converged: bool
    outer_iterations: int
    inner_iterations: int
    iteration_durations_s: tuple[float, ...] = ()
    elapsed_s: float = 0.0
    warnings: tuple[str, ...] = ()
    robust: bool = False
    pose_covariance: np.ndarray | None = None
    positions_mm: np.ndarray | None = field(default=None, repr=False, compare=False)

    @property
    def control(self) -> str:
        """The cables' common control mode, or "mixed"."""
        modes = set(self.cable_controls)
        return modes.pop() if len(modes) == 1 else "mixed"

    @property
    def outliers(self) -> tuple[str, ...]:
        return tuple(m.id for m in self.markers if m.outlier)

    @property
    def excluded(self) -> tuple[str, ...]:
        return tuple(m.id for m in self.markers if not m.used)

    def replace(self, **changes: Any) -> CalibrationResult:
        return dataclasses.replace(self, **changes)


def result_to_dict(result: CalibrationResult) -> dict[str, Any]:
    """The JSON document of a result (module docstring)."""
    transform = result.robot_from_camera
    return {
        "format": FORMAT,
        "version": VERSION,
        "softforce_version": __version__,
        "robot": {"name": result.robot_name, "file": result.robot_file},
        "source": result.source,
        "rotation": transform.rotation.tolist(),
        "translation_mm": transform.translation_mm.tolist(),
        "actuation": {
            "names": list(result.cable_names),
            "control": result.control,
            "controls": list(result.cable_controls),
            "values": result.actuation.tolist(),
            "tensions_n": result.tensions_n.tolist(),
            "slack": [bool(s) for s in result.slack],
        },
        "residual_rms_mm": result.residual_rms_mm,
        "residual_history_mm": list(result.residual_history_mm),
        "pose_covariance": (None if result.pose_covariance is None
                            else result.pose_covariance.tolist()),
        "markers": [
            {
                "id": m.id,
                "residual_mm": m.distance_mm,
                "residual_vector_mm": m.residual_mm.tolist(),
                "observed_camera_mm": m.observed_camera_mm.tolist(),
                "model_robot_mm": m.model_robot_mm.tolist(),
                "used": m.used,
                "outlier": m.outlier,
                "left_out_mm": m.left_out_mm,
            }
            for m in result.markers
        ],
        "outliers": list(result.outliers),
        "excluded": list(result.excluded),
        "unobserved": list(result.unobserved),
        "robust": result.robust,
        "converged": result.converged,
        "iterations": len(result.residual_history_mm),
        "settings": {"outer_iterations": result.outer_iterations,
                     "inner_iterations": result.inner_iterations},
        "elapsed_s": result.elapsed_s,
        "warnings": list(result.warnings),
    }


def result_to_json(result: CalibrationResult) -> str:
    return json.dumps(result_to_dict(result), indent=2) + "\n"


def _pose_covariance(value: Any) -> np.ndarray | None:
    """The document's pose_covariance (6 x 6 numbers, symmetric) or None where absent."""
    if value is None:
        return None
    try:
        covariance = np.array(value, dtype=float)
    except (TypeError, ValueError):
        covariance = np.zeros(0)
    if covariance.shape != (6, 6) or not np.allclose(covariance, covariance.T):
        raise ValueError("pose_covariance must be a symmetric 6x6 matrix of numbers")
    return covariance


def result_from_dict(data: dict[str, Any], where: str = "calibration") -> CalibrationResult:
    """Inverse of result_to_dict; CalibrationError naming the first missing or bad field."""
    try:
        if data.get("format", FORMAT) != FORMAT:
            raise ValueError(f"format is {data.get('format')!r}, not {FORMAT!r}")
        rotation = np.array(data["rotation"], dtype=float)
        translation = np.array(data["translation_mm"], dtype=float)
        if rotation.shape != (3, 3) or translation.shape != (3,):
            raise ValueError("rotation must be 3x3 and translation_mm 3 numbers")
        if not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-6) or np.linalg.det(
                rotation) < 0:
            raise ValueError("rotation is not a proper rotation matrix")
        # a pose from elsewhere (rotation and translation only) is a valid calibration
        actuation = data.get("actuation", {"values": [], "control": "displacement"})
        values = np.array(actuation["values"], dtype=float)
        names = tuple(actuation.get("names", [f"cable{i}" for i in range(len(values))]))
        controls = tuple(actuation.get("controls", [actuation["control"]] * len(values)))
        settings = data.get("settings", {})
        return CalibrationResult(
            robot_name=data.get("robot", {}).get("name", ""),
            robot_file=data.get("robot", {}).get("file", ""),
            source=data.get("source", ""),
            robot_from_camera=RigidTransform(rotation, translation),
            cable_names=names,
            cable_controls=controls,
            actuation=values,
            tensions_n=np.array(actuation.get("tensions_n", [np.nan] * len(values)), float),
            slack=np.array(actuation.get("slack", [False] * len(values)), dtype=bool),
            residual_rms_mm=float(data.get("residual_rms_mm", "nan")),
            residual_history_mm=tuple(float(r) for r in data.get("residual_history_mm", [])),
            markers=tuple(
                MarkerResidual(m["id"], np.array(m["observed_camera_mm"], float),
                               np.array(m["model_robot_mm"], float),
                               np.array(m["residual_vector_mm"], float),
                               bool(m["used"]), bool(m["outlier"]), m.get("left_out_mm"))
                for m in data.get("markers", [])
            ),
            unobserved=tuple(data.get("unobserved", [])),
            converged=bool(data.get("converged", True)),
            outer_iterations=int(settings.get("outer_iterations", 0)),
            inner_iterations=int(settings.get("inner_iterations", 0)),
            elapsed_s=float(data.get("elapsed_s", 0.0)),
            warnings=tuple(data.get("warnings", [])),
            robust=bool(data.get("robust", False)),
            pose_covariance=_pose_covariance(data.get("pose_covariance")),
        )
    except (KeyError, TypeError, ValueError, AttributeError, IndexError, OverflowError) as error:
        # AttributeError: a field that should be an object is a list, number or string
        missing = f"missing field {error}" if isinstance(error, KeyError) else str(error)
        raise CalibrationError(f"{where}: not a softforce calibration ({missing}); run "
                               "`softforce calibrate` to make one") from error


def read_calibration(path: Path) -> CalibrationResult:
    """Read a calibration JSON file written by `softforce calibrate`."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"calibration file {path} not found; run `softforce calibrate`")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError, OSError, RecursionError) as error:
        raise CalibrationError(f"{path}: not valid JSON ({error})") from error
    if not isinstance(data, dict):
        raise CalibrationError(f"{path}: not a softforce calibration (expected a JSON object)")
    return result_from_dict(data, str(path))
