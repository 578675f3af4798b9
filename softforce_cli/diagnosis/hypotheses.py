"""The candidate effects diagnosis screens: each an effect of model.effects on one target,
with its free parameters and how they move the predicted surface to first order.

A Hypothesis maps its free parameters (k,) to the normal shift (E,) of the predicted surface
at every residual entry (a frame and a surface node, diagnosis.residuals.Field), from the
sensitivity columns of diagnosis.sensitivities:

- gravity, material_nonlinearity, compliant_base: linear in their parameters
  (compliant_base in compliance 1/k, which vanishes at the clamp); stiffness_scale and
  regional_stiffness linear in the compliance change 1 - 1/scale (exact for the part of
  the shape a load holds, where a first order in the modulus halves a 50% softening);
- viscoelastic_creep: each frame's modulus scale 1 - a (1 - exp(-hold / tau)) on the
  stiffness column, in compliance as stiffness_scale;
- cable_slack, cable_friction: u_eff from the exact slack and play operators over the
  recording's history (model.effects), and the body at u_eff interpolated from the solved
  state nearest to it: x_k + J_k (u_eff - u_k) (J_k its cable columns). The states are a
  library of exact equilibria along the recording's inputs, so a frame whose effective input
  is another state's input is predicted exactly (a first-order model about the frame's own
  state underestimates a 3 mm slack by 20%: the cable's response changes along the pull);
- depth_bias, extrinsic_offset: exact, the predicted nodes moved as the camera would show them
  (model.effects.observed_points_robot);
- support_contact: the plate's contact solved on each state's linearisation
  (diagnosis.support), for a plate height between where the robot stands and the highest
  node that may touch one.

Several targets of one effect (cable_slack on each cable) are separate hypotheses; the best
one is the effect's location.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.diagnosis.background import Table
from softforce_cli.diagnosis.residuals import Field
from softforce_cli.diagnosis.sensitivities import ColumnSet
from softforce_cli.diagnosis.support import SupportBasis
from softforce_cli.model.effects import (
    EFFECTS,
    Effect,
    FrameContext,
    effective_actuation,
    make_effect,
    observed_points_robot,
)
from softforce_cli.model.robot import Robot

# Fitted parameters per effect and their bounds in the first-order screening: the spec's
# bounds cut to where one tangent still describes the body (a modulus halved or doubled, a
# tilt of 20 degrees); the nonlinear refit (diagnosis.refit) works within the spec's.
# compliance_mm_per_n = 1 / compliant_base.stiffness_n_per_mm.
FREE: dict[str, tuple[tuple[str, float, float], ...]] = {
    "gravity": (("scale", 0.3, 2.0), ("tilt_x_deg", -20.0, 20.0), ("tilt_y_deg", -20.0, 20.0)),
    "stiffness_scale": (("scale", 0.5, 2.0),),
    "regional_stiffness": (("scale", 0.3, 3.0),),
    "material_nonlinearity": (("blend", 0.0, 1.0),),
    "cable_slack": (("slack_mm", 0.0, 20.0),),
    "cable_friction": (("play_mm", 0.0, 10.0),),
    "compliant_base": (("compliance_mm_per_n", 0.0, 1.0),),
    "viscoelastic_creep": (("relaxation", 0.0, 0.9), ("time_constant_s", 0.05, 1000.0)),
    "depth_bias": (("scale", -0.1, 0.1),),
    "extrinsic_offset": tuple((f"translation_{a}_mm", -20.0, 20.0) for a in "xyz")
    + tuple((f"rotation_{a}_deg", -5.0, 5.0) for a in "xyz"),
}
# Effects whose signature is mostly a static shape change: besides relative to a static
# baseline per node (what every effect is screened against, so that the accurate model's
# own static mismatch with the body is not taken for physics), they are screened on the
# absolute residual too, where they must explain most of that mismatch to be accepted.
ABSOLUTE = frozenset({"gravity", "stiffness_scale", "compliant_base", "depth_bias",
                      "extrinsic_offset", "support_contact", "material_nonlinearity"})
# Where creep's fit starts its time constant (s): the geometric middle of its bounds in the
# holds of a typical recording (0.5-30 s).
CREEP_START_S = 3.0


@dataclass(frozen=True)
class Inputs:
    """What the shift functions need, per residual entry and per state.

    field      : the nominal residual entries (E of them).
    state      : (E,) state of each entry's frame.
    normals    : (E, 3) predicted unit normal at each entry's node.
    positions  : (E, 3) predicted position of each entry's node (mm, robot frame).
    columns    : (C, E) normal shift per unit of each sensitivity column at each entry.
    column_set : the columns' names.
    contexts   : per frame, model.effects.FrameContext (t of them).
    cables     : the robot's cable names.
    robot_from_camera : the calibration's transform.
    library    : (S, n, 3) every state's predicted mesh nodes.
    library_inputs : (S, a) every state's commanded inputs.
    cable_columns  : (S, n, a, 3) every state's cable columns (mm per unit input), node-major.
    table      : the table under the robot as observed (diagnosis.background), or None.
    support    : the plate's screening data (diagnosis.support), or None.
    """

    field: Field
    state: np.ndarray
    normals: np.ndarray
    positions: np.ndarray
    columns: np.ndarray
    column_set: ColumnSet
    contexts: tuple[FrameContext, ...]
    cables: tuple[str, ...]
    robot_from_camera: RigidTransform
    library: np.ndarray
    library_inputs: np.ndarray
    cable_columns: np.ndarray
    table: Table | None = None
    support: SupportBasis | None = None

    @cached_property
    def own_cable_columns(self) -> np.ndarray:
        """(E, a) mm per unit input: each entry's normal shift per unit of each cable's input
        at its own state (the cable columns an actuation effect mostly reads)."""
        return np.einsum("eai,ei->ea",
                         at_state_nodes(self.cable_columns, self.state, self.field.node),
                         self.normals)

    def column(self, name: str) -> np.ndarray:
        return self.columns[self.column_set.index(name)]


@dataclass(frozen=True)
class Hypothesis:
    """Effect `name` on `target` (a cable, a region or None), free parameters `free` (k,)
    fitted from `start` within [lower, upper]."""

    name: str
    target: str | None
    free: tuple[str, ...]
    start: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    @property
    def label(self) -> str:
        return self.name if self.target is None else f"{self.name}[{self.target}]"

    @property
    def kind(self) -> str:
        return EFFECTS[self.name].kind

    def effect(self, values: np.ndarray) -> Effect:
        """The model.effects Effect at the free values (k,)."""
        named = dict(zip(self.free, (float(v) for v in values), strict=True))
        if "compliance_mm_per_n" in named:
            compliance = named.pop("compliance_mm_per_n")
            lowest = EFFECTS["compliant_base"].parameter("stiffness_n_per_mm").lower
            named["stiffness_n_per_mm"] = (math.inf if compliance <= 0.0
                                           else max(1.0 / compliance, lowest))
        return make_effect(self.name, self.target, **_clipped(self.name, named))

    def shift(self, values: np.ndarray, inputs: Inputs) -> np.ndarray:
        """(E,) mm: how far the predicted surface moves along its normal at every entry."""
        v = dict(zip(self.free, np.asarray(values, dtype=float), strict=True))
        if self.name == "gravity":
            return ((v["scale"] - 1.0) * inputs.column("gravity.scale")
                    + v["tilt_x_deg"] * inputs.column("gravity.tilt_x_deg")
                    + v["tilt_y_deg"] * inputs.column("gravity.tilt_y_deg"))
        if self.name == "stiffness_scale":
            return _softening(v["scale"]) * inputs.column("stiffness")
        if self.name == "regional_stiffness":
            return _softening(v["scale"]) * inputs.column(f"region.{self.target}")
        if self.name == "material_nonlinearity":
            return v["blend"] * inputs.column("blend")
        if self.name == "compliant_base":
            return v["compliance_mm_per_n"] * inputs.column("base_compliance")
        if self.name == "viscoelastic_creep":
            hold = np.array([c.hold_s for c in inputs.contexts])[inputs.field.frame]
            relaxed = 1.0 - np.exp(-hold / v["time_constant_s"])
            return _softening(1.0 - v["relaxation"] * relaxed) * inputs.column("stiffness")
        if self.name == "support_contact":
            motion = inputs.support.motion_mm(v["table_z_mm"])
            return np.einsum("ei,ei->e", at_state_nodes(motion, inputs.state, inputs.field.node),
                             inputs.normals)
        if self.kind == "actuation":
            return interpolated_shift(effective_actuation(
                (self.effect(values),), inputs.contexts, inputs.cables), inputs)
        # sensor effects: where the miscalibrated camera shows the predicted nodes
        moved = observed_points_robot(inputs.positions, (self.effect(values),),
                                      inputs.robot_from_camera)
        return np.einsum("ei,ei->e", moved - inputs.positions, inputs.normals)


def _softening(scale: float | np.ndarray) -> float | np.ndarray:
    """1 - 1/scale: a modulus scale's first-order weight on its column (d x / d scale at 1),
    taken in compliance: under a load the body's give is proportional to 1/E, so this is
    exact for the loaded part where (scale - 1) halves a 50% softening."""
    return 1.0 - 1.0 / scale


def interpolated_shift(effective: np.ndarray, inputs: Inputs) -> np.ndarray:
    """(E,) normal shift of the body at the effective inputs (t, a) of every frame, from the
    nearest solved state k: x_k + J_k (u_eff - u_k). At a frame whose nearest state is its
    own, x_k is the predicted position itself and J_k's normal shifts are kept
    (Inputs.own_cable_columns): only the other frames' entries gather another state's."""
    distance = np.abs(effective[:, None, :] - inputs.library_inputs[None]).sum(axis=2)
    nearest = np.argmin(distance, axis=1)  # (t,)
    delta = effective - inputs.library_inputs[nearest]  # (t, a)
    frame = inputs.field.frame
    shift = np.einsum("ea,ea->e", delta[frame], inputs.own_cable_columns)
    other = np.flatnonzero(nearest[frame] != inputs.state)
    if len(other):
        states, nodes = nearest[frame[other]], inputs.field.node[other]
        moved = at_state_nodes(inputs.library, states, nodes) + np.einsum(
            "ea,eai->ei", delta[frame[other]],
            at_state_nodes(inputs.cable_columns, states, nodes))
        shift[other] = np.einsum("ei,ei->e", moved - inputs.positions[other],
                                 inputs.normals[other])
    return shift


def at_state_nodes(per_state_node: np.ndarray, states: np.ndarray, nodes: np.ndarray
                   ) -> np.ndarray:
    """(E, ...) the entries of a per-state, per-node array (S, n, ...) at (states, nodes)
    (E,) each: np.take of whole rows of the array flattened to (S n, ...), several times
    faster than a two-index gather (0.33 against 4.3 ms for 30,000 rows)."""
    s, n = per_state_node.shape[:2]
    flat = per_state_node.reshape(s * n, -1)
    return flat.take(states * n + nodes, axis=0).reshape(len(states), *per_state_node.shape[2:])


def _clipped(name: str, values: dict[str, float]) -> dict[str, float]:
    """Values inside the spec's bounds (a fit may end on a screening bound)."""
    spec = EFFECTS[name]
    return {k: float(np.clip(v, spec.parameter(k).lower, spec.parameter(k).upper))
            for k, v in values.items()}


def hypotheses(robot: Robot, column_set: ColumnSet, support: SupportBasis | None = None
               ) -> tuple[Hypothesis, ...]:
    """Every candidate diagnosis screens for `robot`; support_contact only with the plate's
    screening data (`support`: no node of the robot may touch a plate without it), its
    height from where the robot stands (which touches nothing that stays above it) to the
    highest node that may touch one."""
    regions = [c.removeprefix("region.") for c in column_set.names if c.startswith("region.")]
    cables = [spec.name for spec in robot.cable_specs if spec.control == "displacement"]
    out = []
    for name, free in FREE.items():
        targets = {"cable": cables, "region": regions, None: [None]}[EFFECTS[name].target]
        start = np.array([_start(name, p) for p, _, _ in free])
        lower = np.array([lo for _, lo, _ in free])
        upper = np.array([hi for _, _, hi in free])
        for target in targets:
            out.append(Hypothesis(name, target, tuple(p for p, _, _ in free), start, lower,
                                  upper))
    if support is not None:
        lowest = np.array([support.lower_mm])
        out.append(Hypothesis("support_contact", None, ("table_z_mm",), lowest, lowest,
                              np.array([support.upper_mm])))
    return tuple(out)


def _start(name: str, parameter: str) -> float:
    if parameter == "compliance_mm_per_n":
        return 0.0
    if parameter == "time_constant_s":
        return CREEP_START_S
    return EFFECTS[name].parameter(parameter).neutral
