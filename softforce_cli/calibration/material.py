"""Material calibration: Young's modulus from a known load (`softforce calibrate --material`).

As the paper did (E = 180 kPa from a weight and the deformation it causes), the modulus of
the element in use is fitted so that force sensing, run with the known contact on the frames
where the load hangs, returns the known load. The fit uses the estimator itself, so the
modulus is the one that makes *its* intensities right, whatever the element (a coarse linear
mesh locks and needs a lower, effective modulus; docs/locking.md).

The frames of an unloaded reference (another recording, or other frames of the same one) tare
the sensor first: whatever the model gets wrong in both states (the rest shape, a calibration
offset, the weight of the robot) cancels. The elastic forces of every law are proportional to E
at a fixed Poisson ratio, so the sensed intensity grows with E (proportionally for a linear
model; the robot's weight, the cables and the tare make it less so, e.g. 0.25, 0.58, 0.72 and
0.82 N at 0.11, 0.13, 0.15 and 0.18 MPa for a 0.66 N weight on the coarse P1 Diamond): the fit
brackets the modulus whose sensed intensity is the known load, stepping by the proportional
guess, and refines it by Brent's method to 0.5%. The 95% interval comes from the spread of the
per-frame intensities over the loaded frames (Student's t on their mean), carried to E to first
order by proportionality; with a single loaded frame there is no interval.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats
from scipy.optimize import brentq

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.camera.frame import RgbdFrame, robot_actuation
from softforce_cli.errors import CalibrationError
from softforce_cli.model.robot import Robot, build_robot

# The fit stops when E is known to this fraction (a tenth of the paper's 4% force error);
# bracketing the answer may take at most MAX_PASSES sensing passes.
RELATIVE_TOLERANCE = 5e-3
MAX_PASSES = 8
# The fitted modulus must reproduce the known load to this fraction; otherwise the sensed load
# jumps there by more than a frame's matching can explain (a frame flips from matched to
# unmatched, or the contact column drops out) and Brent's method stopped on a break, not on
# a root. Smaller steps are normal: on one 424x240 frame of the sample probes the sensed load
# steps by up to 20% between moduli 3% apart, as the feature matches at the settled shape
# change; the fit then reports the step as its interval.
MATCH_TOLERANCE = 0.1
# A bracketing step to a modulus where no frame can be sensed is taken back halfway (in the
# logarithm) at most this many times.
BACKOFFS = 3
# FE updates per frame in the fit: enough to reach the static state of a frame from the
# previous one (the updates converge like Newton's method: 2-3 from a nearby state).
STATIC_UPDATES = 6


def robot_with_material(robot: Robot, material: dict[str, Any]) -> Robot:
    """The robot with a calibration's "material" (young_modulus_mpa; poisson_ratio if given)."""
    spec = robot.config.material
    changes = {"young_modulus_mpa": float(material["young_modulus_mpa"])}
    if "poisson_ratio" in material:
        changes["poisson_ratio"] = float(material["poisson_ratio"])
    config = dataclasses.replace(robot.config, material=dataclasses.replace(spec, **changes))
    return build_robot(config, robot.mesh)


def read_material(path: Path) -> dict[str, Any] | None:
    """The "material" object of a calibration JSON, or None; CalibrationError when malformed."""
    data = json.loads(Path(path).read_text())
    material = data.get("material")
    if material is None:
        return None
    modulus = material.get("young_modulus_mpa") if isinstance(material, dict) else None
    if not isinstance(modulus, int | float) or not np.isfinite(modulus) or modulus <= 0:
        raise CalibrationError(f"{path}: material.young_modulus_mpa must be a positive number "
                               "(MPa); rerun `softforce calibrate --material`")
    return material


@dataclass(frozen=True)
class KnownLoad:
    """point_mm (3,) on the robot at rest, robot frame; force_n (3,) on the robot."""

    point_mm: np.ndarray
    force_n: np.ndarray


@dataclass(frozen=True)
class MaterialFit:
    young_modulus_mpa: float
    ci95_mpa: tuple[float, float] | None
    load_n: float
    estimates_n: tuple[float, ...]
    nominal_young_modulus_mpa: float
    nominal_estimate_n: float
    fit_rms_mm: float
    passes: int
    element: str
    law: str
    tared: bool

    def to_dict(self) -> dict[str, Any]:
        """The calibration JSON's "material" object (docs/calibration.md, extended)."""
        return {
            "young_modulus_mpa": round(self.young_modulus_mpa, 6),
            "young_modulus_ci95_mpa": None if self.ci95_mpa is None
            else [round(v, 6) for v in self.ci95_mpa],
            "element": self.element,
            "law": self.law,
            "load_n": round(self.load_n, 6),
            "estimates_n": [round(v, 6) for v in self.estimates_n],
            "fit_rms_mm": round(self.fit_rms_mm, 4),
            "nominal_young_modulus_mpa": self.nominal_young_modulus_mpa,
            "nominal_estimate_n": round(self.nominal_estimate_n, 6),
            "passes": self.passes,
            "method": "known-contact intensity matched to the load"
            + (", tared on the unloaded frames" if self.tared else ""),
        }


def fit_young_modulus(
    robot: Robot,
    robot_from_camera: RigidTransform,
    loaded: list[RgbdFrame],
    reference: list[RgbdFrame],
    load: KnownLoad,
    settings: Any,
    progress: Callable[[int, float], None] | None = None,
) -> MaterialFit:
    """The Young's modulus (MPa) for which sensing the known load on `loaded` returns it.

    settings: the SenseSettings the sensor runs with; progress(pass, modulus) after a pass.
    """
    magnitude = float(np.linalg.norm(load.force_n))
    if magnitude == 0:
        raise CalibrationError("--load-n is zero; give the known load's force on the robot")
    nominal = robot.material.young_modulus_mpa
    evaluations: dict[float, tuple[np.ndarray, float]] = {}

    def excess(modulus: float) -> float:
        """Sensed minus known intensity (N) at this modulus; it grows with the modulus."""
        if modulus not in evaluations:
            evaluations[modulus] = _sensed(
                robot_with_material(robot, {"young_modulus_mpa": modulus}), robot_from_camera,
                loaded, reference, load, settings)
            if progress is not None:
                progress(len(evaluations), modulus)
        return float(np.mean(evaluations[modulus][0])) - magnitude

    def stepped(modulus: float, factor: float) -> float:
        """modulus x factor, or nearer to modulus where the model cannot be sensed there: a
        softer body may snap out of the robot's shape under its cables (the coarse Diamond's
        P2 model at 0.83 of its modulus matched no feature of the sample's rest frame)."""
        for _ in range(BACKOFFS):
            try:
                excess(modulus * factor)
                return modulus * factor
            except CalibrationError:
                factor = float(np.sqrt(factor))
        return modulus * factor  # sensing it raises the error, for the user

    low = high = nominal
    # bracket the root, stepping by the proportional guess (at least 20%, at most 3x)
    while excess(low) > 0 and len(evaluations) < MAX_PASSES:
        low = stepped(low, 1 / float(np.clip((excess(low) + magnitude) / magnitude, 1.2, 3.0)))
    while excess(high) < 0 and len(evaluations) < MAX_PASSES:
        high = stepped(high, float(np.clip(magnitude / (excess(high) + magnitude), 1.2, 3.0)))
    if excess(low) > 0 or excess(high) < 0:
        raise CalibrationError(f"no modulus within {low:.4g}-{high:.4g} MPa makes the sensed "
                               "load match --load-n; check --load-n, --load-point and the frames")
    modulus = brentq(excess, low, high, rtol=RELATIVE_TOLERANCE) if low != high else low
    estimates, rms = evaluations.get(modulus) or _sensed(
        robot_with_material(robot, {"young_modulus_mpa": modulus}), robot_from_camera, loaded,
        reference, load, settings)
    if abs(float(np.mean(estimates)) - magnitude) > MATCH_TOLERANCE * magnitude:
        raise CalibrationError(
            f"the sensed load jumps from below to above --load-n near {modulus:.4g} MPa "
            f"({float(np.mean(estimates)):.3g} N there, not {magnitude:.3g} N): the loaded "
            "frames are not sensed consistently; check the calibration pose, --load-point and "
            "the frames (`softforce sense --contact-point` on them shows each frame's status)")
    nominal_estimate = float(np.mean(evaluations[nominal][0]))
    passes = len(evaluations)
    # the frames' spread and a step the fit stopped on both make E uncertain: the union
    step = _step_interval(evaluations, modulus, magnitude)
    intervals = [] if step is None else [step]
    if len(estimates) > 1:
        spread = stats.t.ppf(0.975, len(estimates) - 1) * np.std(estimates, ddof=1) \
            / np.sqrt(len(estimates)) / np.mean(estimates)
        intervals.append((modulus / (1 + spread), modulus / max(1 - spread, 1e-9)))
    ci = (min(i[0] for i in intervals), max(i[1] for i in intervals)) if intervals else None
    return MaterialFit(modulus, ci, magnitude, tuple(estimates), nominal, nominal_estimate, rms,
                       passes, robot.element_name, robot.material.law, bool(reference))


def _step_interval(evaluations: dict[float, tuple[np.ndarray, float]], modulus: float,
                   magnitude: float) -> tuple[float, float] | None:
    """The moduli (MPa) that the two sides of a step in the sensed load would give, when the
    fit stopped on one: the evaluations that bracket the root (the largest modulus sensing
    less than the known load, the smallest sensing more), each asking for E_side * magnitude
    / F_side since sensed loads scale with E at a fixed shape; None on a continuous root
    (both sides ask for the same modulus within the fit's tolerance)."""
    sensed = {e: float(np.mean(values[0])) for e, values in evaluations.items()}
    below = [e for e, f in sensed.items() if f < magnitude]
    above = [e for e, f in sensed.items() if f > magnitude]
    if not below or not above:
        return None
    low, high = sorted(e * magnitude / sensed[e] for e in (max(below), min(above)))
    if high - low <= 2 * RELATIVE_TOLERANCE * modulus:
        return None
    return low, high


def _sensed(robot: Robot, robot_from_camera: RigidTransform, loaded: list[RgbdFrame],
            reference: list[RgbdFrame], load: KnownLoad,
            settings: Any) -> tuple[np.ndarray, float]:
    """Intensities (k,) N of the known contact on the loaded frames, after taring on the
    reference frames, and the mean fit RMS (mm) over the loaded frames."""
    from softforce_cli.estimation.sensing import ForceSensor, KnownContact

    direction = load.force_n / np.linalg.norm(load.force_n)
    # each frame is a static state: let the FE updates reach it, whatever the frame rate
    settings = dataclasses.replace(settings, estimation=dataclasses.replace(
        settings.estimation, updates_per_frame=max(settings.estimation.updates_per_frame,
                                                   STATIC_UPDATES)))
    first = (reference or loaded)[0]
    actuation = robot_actuation(first.actuation, robot.cable_specs, "the first frame")
    sensor = ForceSensor(robot, robot_from_camera, actuation, settings,
                         KnownContact(load.point_mm, direction), tare_frames=len(reference))
    for index, frame in enumerate(reference):
        sensor.process(index, frame)
    results = [sensor.process(len(reference) + i, frame) for i, frame in enumerate(loaded)]
    usable = [r for r in results if r.status == "ok" and r.contacts]
    if not usable:
        reasons = sorted({r.status for r in results})
        raise CalibrationError(f"no loaded frame could be sensed ({', '.join(reasons)}); is the "
                               "robot in view and the calibration right?")
    forces = np.array([float(r.contacts[0].force_vector_n @ direction) for r in usable])
    return forces, float(np.mean([r.fit_rms_mm for r in usable]))
