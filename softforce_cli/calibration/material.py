"""Material calibration: Young's modulus from a known load (`softforce calibrate --material`).

As the paper did (E = 180 kPa from a weight and the deformation it causes), the modulus of
the element in use is fitted so that the FE model under the known load matches the observed
robot surface. With an unloaded reference, the fit compares the *change* between the two
states along the feature normals, so that whatever the model gets wrong in both (the rest
shape, a calibration offset) cancels; without one, it compares the loaded shape itself.

The fit is one-dimensional in log E (bounded Brent search over a factor 10 either way). The
95% interval comes from the Gauss-Newton curvature at the optimum, with the residual variance
estimated from the fit and one degree of freedom per matched feature (the features are spread
30 mm apart, farther than the depth noise is correlated).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import minimize_scalar

from softforce_cli.errors import CalibrationError, SolverError
from softforce_cli.fem.statics import Equilibrium, PointLoads, solve_equilibrium
from softforce_cli.model.mesh import vertex_normals
from softforce_cli.model.robot import Robot, build_robot
from softforce_cli.vision.feature_matching import match_features
from softforce_cli.vision.settings import VisionSettings

# Search range of the fit, as a factor on the robot file's modulus either way.
SEARCH_FACTOR = 10.0
# The fit stops when log E is known to this (0.5% in E, a tenth of the paper's force error).
LOG_TOLERANCE = 5e-3
# Relative step in E of the finite difference that gives the fit's sensitivity (towards the
# stiffer side, where the model always has an equilibrium).
SENSITIVITY_STEP = 0.02
# Fewer matched features than this cannot support a fit with an honest interval.
MIN_FEATURES = 5


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
class LoadCase:
    """An observed static state: cable inputs (a,), the load (None: unloaded) and the robot's
    observed points (k, 3) mm in the robot frame."""

    actuation: np.ndarray
    load: KnownLoad | None
    robot_points_mm: np.ndarray


@dataclass(frozen=True)
class MaterialFit:
    young_modulus_mpa: float
    ci95_mpa: tuple[float, float]
    residual_rms_mm: float
    nominal_residual_rms_mm: float
    nominal_young_modulus_mpa: float
    features: int
    evaluations: int
    element: str
    law: str
    differenced: bool

    def to_dict(self) -> dict[str, Any]:
        """The calibration JSON's "material" object (DESIGN.md section 6)."""
        return {
            "young_modulus_mpa": round(self.young_modulus_mpa, 6),
            "young_modulus_ci95_mpa": [round(v, 6) for v in self.ci95_mpa],
            "element": self.element,
            "law": self.law,
            "residual_rms_mm": round(self.residual_rms_mm, 4),
            "nominal_young_modulus_mpa": self.nominal_young_modulus_mpa,
            "nominal_residual_rms_mm": round(self.nominal_residual_rms_mm, 4),
            "features": self.features,
            "evaluations": self.evaluations,
            "method": "change between the unloaded and loaded states along feature normals"
            if self.differenced else "loaded shape along feature normals",
        }


class _NormalResiduals:
    """Observed minus modelled normal coordinates of the feature points, per load case, as a
    function of E; equilibria are carried from one E to the next as starting points."""

    def __init__(self, robot: Robot, cases: tuple[LoadCase, ...], vision: VisionSettings):
        self.robot, self.cases, self.vision = robot, cases, vision
        self.starts: list[np.ndarray | None] = [None] * len(cases)
        self.features: np.ndarray | None = None
        self.evaluations = 0

    def normal_gaps(self, young_modulus_mpa: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per case: (matched (p,) bool, observed - model normal coordinate (p,) mm)."""
        robot = robot_with_material(self.robot, {"young_modulus_mpa": young_modulus_mpa})
        gaps = []
        for i, case in enumerate(self.cases):
            state = self._solve(robot, case, self.starts[i])
            self.starts[i] = state.positions_mm
            nodes = state.positions_mm[: robot.mesh.node_count]
            normals = vertex_normals(nodes, robot.mesh.surface_faces)[robot.feature_nodes]
            points = nodes[robot.feature_nodes]
            matches = match_features(points, normals, case.robot_points_mm, self.vision)
            gaps.append((matches.matched,
                         matches.normal_mm - np.einsum("pi,pi->p", points, normals)))
        self.evaluations += 1
        return gaps

    def residual(self, young_modulus_mpa: float) -> np.ndarray:
        """(f,) mm over self.features: the loaded gap, less the unloaded one when given."""
        gaps = self.normal_gaps(young_modulus_mpa)
        if self.features is None:
            self.features = np.logical_and.reduce([m for m, _ in gaps])
        out = gaps[0][1] - gaps[1][1] if len(gaps) == 2 else gaps[0][1]
        # a feature that no longer matches at this modulus has moved away from the observed
        # surface by at least the match limit: count it so, not as a perfect fit
        return np.nan_to_num(out[self.features], nan=self.vision.match_limit_mm)

    @staticmethod
    def _solve(robot: Robot, case: LoadCase, start: np.ndarray | None) -> Equilibrium:
        loads = None
        if case.load is not None:
            loads = PointLoads(robot.attach(case.load.point_mm[None]), case.load.force_n[None])
        inputs = robot.cable_inputs(case.actuation)
        try:
            return solve_equilibrium(robot.fe_model, inputs, loads, start)
        except SolverError:
            if start is None:
                raise
            # the previous modulus's state was too far from this one's: start from rest
            return solve_equilibrium(robot.fe_model, inputs, loads)


def fit_young_modulus(
    robot: Robot,
    loaded: LoadCase,
    reference: LoadCase | None,
    vision: VisionSettings,
    progress: Callable[[int], None] | None = None,
) -> MaterialFit:
    """The Young's modulus (MPa) that makes the model's response to loaded.load match."""
    nominal = robot.material.young_modulus_mpa
    cases = (loaded,) if reference is None else (loaded, reference)
    residuals = _NormalResiduals(robot, cases, vision)
    try:
        nominal_rms = _rms(residuals.residual(nominal))
        if residuals.features.sum() < MIN_FEATURES:
            raise CalibrationError(f"only {int(residuals.features.sum())} feature points matched "
                                   "the observed robot in every state; is the robot in view and "
                                   "the calibration right?")

        def objective(log_e: float) -> float:
            try:
                value = float(np.sum(residuals.residual(float(np.exp(log_e))) ** 2))
            except SolverError:
                # too soft to hold the load (or its own weight): no equilibrium near there
                residuals.starts = [None] * len(cases)
                value = np.inf
            if progress is not None:
                progress(residuals.evaluations)
            return value

        span = np.log(SEARCH_FACTOR)
        best = minimize_scalar(objective, bounds=(np.log(nominal) - span, np.log(nominal) + span),
                               method="bounded", options={"xatol": LOG_TOLERANCE})
        if not np.isfinite(best.fun):
            raise SolverError("no modulus in the search range holds the load")
        modulus = float(np.exp(best.x))
        fitted = residuals.residual(modulus)
        step = np.log1p(SENSITIVITY_STEP)
        slope = (residuals.residual(modulus * np.exp(step)) - fitted) / step
    except SolverError as error:
        raise CalibrationError(f"the FE model could not hold the known load while fitting E "
                               f"({error}); check --load-n and --load-point") from error
    dof = max(len(fitted) - 1, 1)
    spread = np.sqrt(float(fitted @ fitted) / dof / max(float(slope @ slope), 1e-300))
    return MaterialFit(
        young_modulus_mpa=modulus,
        ci95_mpa=(modulus * float(np.exp(-1.96 * spread)), modulus * float(np.exp(1.96 * spread))),
        residual_rms_mm=_rms(fitted),
        nominal_residual_rms_mm=nominal_rms,
        nominal_young_modulus_mpa=nominal,
        features=int(residuals.features.sum()),
        evaluations=residuals.evaluations,
        element=robot.config.mesh.element,
        law=robot.material.law,
        differenced=reference is not None,
    )


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2))) if len(values) else float("nan")
