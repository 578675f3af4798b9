"""The candidate effects diagnosis fits, each a few free parameters of model.effects.

A Hypothesis is an effect of the library (model.effects.EFFECTS) on one target (a cable, a
region, or none), with the parameters diagnosis frees, their starting (neutral) values, the
finite step of their secant sensitivities and their bounds. Hypotheses of one effect with
different targets (cable_slack on each cable) are fitted separately and the best kept: that
is the effect's location.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from softforce_cli.fem.model import FEModel
from softforce_cli.model.effects import EFFECTS, Effect, creep_factor
from softforce_cli.model.regions import element_regions
from softforce_cli.model.robot import Robot

# Secant steps: large enough to be far above solver round-off and to reach a one-sided effect
# (a slack cable, a contact), small against the bounds. Per parameter name.
STEPS = {"scale": 0.1, "tilt_x_deg": 3.0, "tilt_y_deg": 3.0, "blend": 1.0, "slack_mm": 1.5,
         "play_mm": 1.0, "relaxation": 0.15, "depth_bias.scale": 0.01}
# Free parameters per effect (the others stay at their defaults): compliant_base's stiffness
# and support_contact's height are fitted in their own units; creep's time constant is held
# at a typical 2 s (a hold of a few seconds cannot resolve it from the amplitude).
FREE = {
    "gravity": ("scale", "tilt_x_deg", "tilt_y_deg"),
    "stiffness_scale": ("scale",),
    "regional_stiffness": ("scale",),
    "material_nonlinearity": ("blend",),
    "cable_slack": ("slack_mm",),
    "cable_friction": ("play_mm",),
    "viscoelastic_creep": ("relaxation",),
    "depth_bias": ("scale",),
    "extrinsic_offset": tuple(f"translation_{a}_mm" for a in "xyz")
    + tuple(f"rotation_{a}_deg" for a in "xyz"),
}
CREEP_TIME_CONSTANT_S = 2.0


@dataclass(frozen=True)
class Hypothesis:
    """One candidate: effect `name` on `target`, parameters `free` fitted from `start`."""

    name: str
    target: str | None
    free: tuple[str, ...]
    start: np.ndarray
    step: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    @property
    def label(self) -> str:
        return self.name if self.target is None else f"{self.name}[{self.target}]"

    @property
    def kind(self) -> str:
        return EFFECTS[self.name].kind

    def effect(self, values: np.ndarray) -> Effect:
        """The model.effects Effect with the free parameters at values (k,)."""
        spec = EFFECTS[self.name]
        parameters = {p.name: (p.default if p.default is not None else p.neutral)
                      for p in spec.parameters}
        if self.name == "viscoelastic_creep":
            parameters["time_constant_s"] = CREEP_TIME_CONSTANT_S
        parameters.update({n: float(v) for n, v in zip(self.free, values, strict=True)})
        return Effect(self.name, parameters, self.target)


def hypotheses(robot: Robot) -> tuple[Hypothesis, ...]:
    """Every candidate this diagnosis evaluates for `robot`."""
    out = []
    regions = [r for r in element_regions(robot) if r != "base"]
    cables = [spec.name for spec in robot.cable_specs]
    for name, free in FREE.items():
        spec = EFFECTS[name]
        targets = {"cable": cables, "region": regions, None: [None]}[spec.target]
        params = [spec.parameter(p) for p in free]
        start = np.array([p.neutral for p in params])
        step = np.array([STEPS.get(f"{name}.{p.name}", STEPS.get(p.name, 1.0)) for p in params])
        lower = np.array([p.lower for p in params])
        upper = np.array([p.upper for p in params])
        for target in targets:
            out.append(Hypothesis(name, target, free, start, step, lower, upper))
    return tuple(out)


def physics_model(robot: Robot, effects: tuple[Effect, ...], hold_s: float = 0.0) -> FEModel:
    """The robot's FE model with the physics effects among `effects` (the others ignored)."""
    model = robot.fe_model
    scale = np.ones(len(model.tets))
    gravity = np.asarray(model.gravity_mm_s2, dtype=float)
    material = model.material
    regions = None
    for effect in effects:
        if effect.name == "stiffness_scale":
            scale *= effect["scale"]
        elif effect.name == "regional_stiffness":
            regions = element_regions(robot) if regions is None else regions
            scale[regions[effect.target]] *= effect["scale"]
        elif effect.name == "gravity":
            gravity = _gravity(gravity, effect)
        elif effect.name == "material_nonlinearity":
            material = _blended(material, effect["blend"])
    scale *= creep_factor(effects, hold_s)
    changes = {}
    if not np.all(scale == 1.0):
        changes["element_stiffness_scale"] = scale
    if not np.array_equal(gravity, model.gravity_mm_s2):
        changes["gravity_mm_s2"] = gravity
    if material is not model.material:
        changes["material"] = material
    return dataclasses.replace(model, **changes) if changes else model


def _gravity(gravity: np.ndarray, effect: Effect) -> np.ndarray:
    base = gravity if np.any(gravity) else np.array([0.0, 0.0, -9810.0])
    ax, ay = np.radians(effect["tilt_x_deg"]), np.radians(effect["tilt_y_deg"])
    rx = np.array([[1, 0, 0], [0, np.cos(ax), -np.sin(ax)], [0, np.sin(ax), np.cos(ax)]])
    ry = np.array([[np.cos(ay), 0, np.sin(ay)], [0, 1, 0], [-np.sin(ay), 0, np.cos(ay)]])
    return effect["scale"] * (ry @ rx @ base)


def _blended(material, blend: float):
    from softforce_cli.fem.blended_material import BlendedMaterial

    if blend == 0.0:
        return material
    other = "neo-hookean" if material.law != "neo-hookean" else "corotational"
    return BlendedMaterial(material, dataclasses.replace(material, law=other), blend)
