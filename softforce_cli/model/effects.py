"""The effect library: physics and sensor effects a nominal model may leave out.

Each effect is a named physical model with a few parameters (docs/effects.md). A robot file
or a scenario may carry them as `[[effect]]` tables; `softforce diagnose` fits them.

Public API (this module: data and pure functions, no FE):
- EFFECT_NAMES, EFFECTS: the registry, name -> EffectSpec (kind, target kind, parameters
  with unit, neutral value, default, bounds).
- Effect(name, parameters, target): one effect with its values; parse_effects(tables,
  source, cables, regions) reads `[[effect]]` tables; effect_toml(effect) writes one back.
- FrameContext and frame_contexts(times_s, actuations): per frame, what the history
  effects need (loading direction per cable, hold time).
- effective_actuation(effects, contexts, cable_names) -> (n, a): cable_slack and
  cable_friction acting on the commanded cable displacements; slack_actuation(...) the
  memoryless part (what Robot.cable_inputs applies).
- Sensor effects: depth_scale(effects), camera_offset(effects) (a RigidTransform),
  observed_points_robot(points, effects, robot_from_camera) (where a nominal pipeline puts
  true robot points), biased_depth_mm(depth, effects).

Elsewhere: model.effect_physics.fe_model_with_effects(robot, effects, context) and
robot_with_effects(robot, effects) (the FE model with the physics effects);
model.regions.element_regions / node_regions (the named regions).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.model.mesh_io import rotation_from_euler_deg

# kind: "physics" enters the FE model, "actuation" the cable inputs, "sensor" the camera.
KINDS = ("physics", "actuation", "sensor")


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter of an effect.

    name    : the TOML key (units in the name where they exist).
    unit    : "mm", "deg", "N/mm", "s", or "" (a ratio).
    neutral : the value at which the effect vanishes (may be +-inf).
    default : the value when the key is left out, or None when it is required.
    lower, upper : physical bounds, inclusive.
    """

    name: str
    unit: str
    neutral: float
    default: float | None
    lower: float
    upper: float
    description: str


@dataclass(frozen=True)
class EffectSpec:
    """One kind of effect: how it enters, what it targets, its parameters.

    kind           : one of KINDS.
    target         : None, "cable" (a cable name) or "region" (model.regions).
    needs_history  : True when it depends on a frame's context (hold time, loading
                     direction), not on the state alone.
    vanishes_with  : the parameters whose neutral values alone make the effect vanish (all of
                     them unless given: creep vanishes at relaxation 0 whatever its tau).
    """

    name: str
    kind: str
    target: str | None
    needs_history: bool
    parameters: tuple[ParameterSpec, ...]
    description: str
    vanishes_with: tuple[str, ...] | None = None

    def parameter(self, name: str) -> ParameterSpec:
        return next(p for p in self.parameters if p.name == name)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)


def _p(name, unit, neutral, default, lower, upper, description) -> ParameterSpec:
    return ParameterSpec(name, unit, float(neutral),
                         None if default is None else float(default), float(lower),
                         float(upper), description)


INF = math.inf
_SPECS = (
    EffectSpec("gravity", "physics", None, False, (
        _p("scale", "", 1, 1, 0, 3, "gravity magnitude over the robot file's (over 9810 mm/s^2 "
                                     "straight down when the file has none)"),
        _p("tilt_x_deg", "deg", 0, 0, -90, 90, "gravity direction turned about the robot's x"),
        _p("tilt_y_deg", "deg", 0, 0, -90, 90, "then about the robot's y"),
    ), "the body's weight differs in magnitude or direction (mass, a tilted mount)"),
    EffectSpec("stiffness_scale", "physics", None, False, (
        _p("scale", "", 1, None, 0.05, 20, "Young's modulus over the robot file's"),
    ), "the whole body is stiffer or softer than the robot file says"),
    EffectSpec("regional_stiffness", "physics", "region", False, (
        _p("scale", "", 1, None, 0.05, 20, "Young's modulus of the region over the file's"),
    ), "one region (an arm, the apex, the base) is stiffer or softer"),
    EffectSpec("material_nonlinearity", "physics", None, False, (
        _p("blend", "", 0, None, 0, 1, "share of the other law's energy (1: the law switched, "
                                       "corotational <-> neo-hookean)"),
    ), "the material follows another hyperelastic law at large strain"),
    EffectSpec("cable_slack", "actuation", "cable", False, (
        _p("slack_mm", "mm", 0, None, 0, 50, "cable travel taken up before the cable pulls"),
    ), "a cable pulls only after slack_mm: u_eff = max(u - slack_mm, 0)"),
    EffectSpec("cable_friction", "actuation", "cable", True, (
        _p("play_mm", "mm", 0, None, 0, 20, "half-width of the play (backlash) operator"),
    ), "friction in a cable's sheath: the pull lags on loading and on unloading (hysteresis)"),
    EffectSpec("compliant_base", "physics", None, False, (
        _p("stiffness_n_per_mm", "N/mm", INF, None, 0.1, INF,
           "total stiffness of the springs that replace the clamp"),
    ), "the clamp gives: springs to the rest position instead of fixed nodes"),
    EffectSpec("viscoelastic_creep", "physics", None, True, (
        _p("relaxation", "", 0, None, 0, 0.9, "fraction a of the modulus lost in a long hold"),
        _p("time_constant_s", "s", 1, None, 0.01, 1e5, "relaxation time tau"),
    ), "the body softens during holds: E (1 - a (1 - exp(-hold / tau)))", ("relaxation",)),
    EffectSpec("support_contact", "physics", None, False, (
        _p("table_z_mm", "mm", -INF, None, -INF, 1e6, "height of a horizontal plane"),
    ), "the body rests on a plane it cannot pass (one-sided contact)"),
    EffectSpec("depth_bias", "sensor", None, False, (
        _p("scale", "", 0, None, -0.2, 0.2, "measured depth = true depth x (1 + scale)"),
    ), "the depth camera's depth scale is off"),
    EffectSpec("extrinsic_offset", "sensor", None, False, (
        *(_p(f"translation_{a}_mm", "mm", 0, 0, -200, 200,
             f"camera moved along its own {a} axis") for a in "xyz"),
        *(_p(f"rotation_{a}_deg", "deg", 0, 0, -30, 30,
             f"camera turned about its own {a} axis (x, then y, then z)") for a in "xyz"),
    ), "the camera is not where the calibration says"),
)
EFFECTS: dict[str, EffectSpec] = {spec.name: spec for spec in _SPECS}
EFFECT_NAMES = tuple(EFFECTS)


class EffectError(ValueError):
    """A bad [[effect]] table; the caller turns it into its own error with the file name."""


@dataclass(frozen=True)
class Effect:
    """One effect with its parameter values (in the units of EFFECTS[name]).

    name       : one of EFFECT_NAMES.
    parameters : {parameter name: value}, every parameter of the spec.
    target     : the cable or region name for targeted effects, else None.
    """

    name: str
    parameters: Mapping[str, float] = field(hash=False)
    target: str | None = None

    @property
    def spec(self) -> EffectSpec:
        return EFFECTS[self.name]

    def __getitem__(self, parameter: str) -> float:
        return float(self.parameters[parameter])

    @property
    def is_neutral(self) -> bool:
        """True when every parameter is at its neutral value (the effect vanishes)."""
        spec = self.spec
        names = spec.parameter_names if spec.vanishes_with is None else spec.vanishes_with
        return all(self[name] == spec.parameter(name).neutral for name in names)

    def with_parameters(self, **values: float) -> Effect:
        """The same effect with some parameters changed (not validated)."""
        return Effect(self.name, {**self.parameters, **values}, self.target)

    @property
    def label(self) -> str:
        """`name` or `name[target]`."""
        return self.name if self.target is None else f"{self.name}[{self.target}]"


def make_effect(name: str, target: str | None = None, **values: float) -> Effect:
    """An effect with defaults (neutral values) for the parameters not given; EffectError
    on an unknown name or parameter, a missing required one, or a value out of bounds."""
    if name not in EFFECTS:
        raise EffectError(f"effect {name!r} unknown; use one of {', '.join(EFFECT_NAMES)}")
    table: dict[str, Any] = {"name": name, **values}
    if EFFECTS[name].target is not None:
        table[EFFECTS[name].target] = target
    return _parse_table(table, "effect")


def parse_effects(tables: Any, cables: Sequence[str] | None = (),
                  regions: Sequence[str] | None = None) -> tuple[Effect, ...]:
    """`[[effect]]` tables -> effects; EffectError naming the table and key on bad input.

    cables  : the robot's cable names (targets of cable effects), or None to check the
              targets later (check_targets), when the robot is known.
    regions : the region names regional effects may target (model.regions.region_names);
              None accepts `base`, `apex` and the cable names.
    """
    if not isinstance(tables, list):
        raise EffectError(f"effect must be an array of tables ([[effect]]), got {tables!r}")
    effects = tuple(_parse_table(table, f"effect[{i}]") for i, table in enumerate(tables))
    if cables is not None:
        check_targets(effects, cables, regions)
    labels = [e.label for e in effects]
    for label in labels:
        if labels.count(label) > 1:
            raise EffectError(f"effect {label} appears twice; give each effect once")
    return effects


def check_targets(effects: Iterable[Effect], cables: Sequence[str],
                  regions: Sequence[str] | None = None) -> None:
    """EffectError when an effect targets a cable or region the robot does not have."""
    regions = ("base", "apex", *cables) if regions is None else tuple(regions)
    for i, effect in enumerate(effects):
        allowed = {"cable": tuple(cables), "region": regions}.get(effect.spec.target)
        if allowed is not None and effect.target not in allowed:
            raise EffectError(f"effect[{i}] ({effect.name}): {effect.spec.target} "
                              f"{effect.target!r} unknown; use one of {', '.join(allowed)}")


def _parse_table(table: Any, where: str) -> Effect:
    if not isinstance(table, dict):
        raise EffectError(f"{where} must be a table")
    name = table.get("name")
    if name not in EFFECTS:
        raise EffectError(f"{where}: name {name!r} unknown; use one of {', '.join(EFFECT_NAMES)}"
                          " (docs/effects.md)")
    spec = EFFECTS[name]
    target_key = spec.target
    allowed = {"name", *spec.parameter_names} | ({target_key} if target_key else set())
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise EffectError(f"{where} ({name}): unknown key {unknown[0]!r}; expected "
                          f"{', '.join(sorted(allowed))}")
    target = None
    if target_key is not None:
        target = table.get(target_key)
        if not isinstance(target, str) or not target:
            raise EffectError(f"{where} ({name}): needs `{target_key}`, the {target_key} name")
    values = {}
    for parameter in spec.parameters:
        value = table.get(parameter.name, parameter.default)
        if value is None:
            raise EffectError(f"{where} ({name}): needs `{parameter.name}` "
                              f"({parameter.description})")
        if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
            raise EffectError(f"{where} ({name}): {parameter.name} must be a number, "
                              f"got {value!r}")
        if not parameter.lower <= value <= parameter.upper:
            unit = f" {parameter.unit}" if parameter.unit else ""
            raise EffectError(f"{where} ({name}): {parameter.name} = {value:g}{unit} is outside "
                              f"[{parameter.lower:g}, {parameter.upper:g}]")
        values[parameter.name] = float(value)
    return Effect(name, values, target)


def effect_toml(effect: Effect) -> str:
    """One `[[effect]]` table, every parameter written (round trips through parse_effects)."""
    lines = ["[[effect]]", f'name = "{effect.name}"']
    if effect.target is not None:
        lines.append(f'{effect.spec.target} = "{effect.target}"')
    for parameter in effect.spec.parameters:
        value = effect[parameter.name]
        text = ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
        unit = f"  # {parameter.unit}" if parameter.unit else ""
        lines.append(f"{parameter.name} = {text}{unit}")
    return "\n".join(lines) + "\n"


def effects_of_kind(effects: Iterable[Effect], *kinds: str) -> tuple[Effect, ...]:
    """The effects whose spec kind is one of `kinds`."""
    return tuple(e for e in effects if e.spec.kind in kinds)


@dataclass(frozen=True)
class FrameContext:
    """What history effects need to know about one frame.

    time_s    : frame time, s.
    actuation : (a,) commanded cable values (mm or N).
    loading   : (a,) int8: +1 when the cable's last change was a pull, -1 a release, 0 when
                it has not changed since the first frame.
    hold_s    : time since any cable's command last changed, s (0 at the first frame: the
                first frame starts a hold).
    """

    time_s: float
    actuation: np.ndarray
    loading: np.ndarray
    hold_s: float


def frame_contexts(times_s: np.ndarray, actuations: np.ndarray) -> list[FrameContext]:
    """Per frame contexts from frame times (n,) s and commanded actuations (n, a)."""
    times = np.asarray(times_s, dtype=float).reshape(-1)
    actuations = np.asarray(actuations, dtype=float).reshape(len(times), -1)
    steps = np.diff(actuations, axis=0, prepend=actuations[:1])  # (n, a), first row zero
    frames = np.arange(len(times))
    changed_any = np.abs(steps).max(axis=1, initial=0.0) > 0.0
    hold_start = np.maximum.accumulate(np.where(changed_any, frames, 0))
    # per cable, the frame of its last change, and the sign of that change
    last_change = np.maximum.accumulate(np.where(steps != 0.0, frames[:, None], -1), axis=0)
    loading = np.where(last_change >= 0,
                       np.sign(steps[np.maximum(last_change, 0), np.arange(steps.shape[1])]),
                       0).astype(np.int8)
    return [FrameContext(float(times[i]), actuations[i], loading[i],
                         float(times[i] - times[hold_start[i]])) for i in frames]


def play_operator(values: np.ndarray, half_width: np.ndarray,
                  start: np.ndarray | None = None) -> np.ndarray:
    """The play (backlash) operator along a history: y_k = clip(y_{k-1}, u_k - w, u_k + w).

    values (n, a), half_width (a,) >= 0, start (a,) the output before the first frame
    (default 0: the cable at rest) -> (n, a). The output follows the input with a lag of w
    while it moves in one direction and stays put for 2w after a reversal: hysteresis.
    """
    values = np.asarray(values, dtype=float)
    width = np.asarray(half_width, dtype=float)
    output = np.empty_like(values)
    previous = np.zeros(values.shape[1]) if start is None else np.asarray(start, dtype=float)
    for k, value in enumerate(values):  # inherently sequential: the state is the history
        previous = np.clip(previous, value - width, value + width)
        output[k] = previous
    return output


def _per_cable(effects: Iterable[Effect], name: str, parameter: str,
               cable_names: Sequence[str]) -> np.ndarray:
    values = np.zeros(len(cable_names))
    for effect in effects:
        if effect.name == name:
            values[list(cable_names).index(effect.target)] = effect[parameter]
    return values


def slack_actuation(effects: Iterable[Effect], actuations: np.ndarray,
                    cable_names: Sequence[str]) -> np.ndarray:
    """cable_slack alone: u_eff = max(u - slack, 0) on the slack cables, (..., a) -> (..., a)
    mm; the others unchanged."""
    slack = _per_cable(effects, "cable_slack", "slack_mm", cable_names)
    actuations = np.asarray(actuations, dtype=float)
    return np.where(slack > 0.0, np.maximum(actuations - slack, 0.0), actuations)


def effective_actuation(effects: Iterable[Effect], contexts: Sequence[FrameContext],
                        cable_names: Sequence[str]) -> np.ndarray:
    """(n, a) mm: the cable displacements the body receives for the commanded ones of
    `contexts`: first the sheath's friction (play operator of half-width play_mm, from rest),
    then the slack (u_eff = max(u - slack_mm, 0)). Cables without effects pass unchanged."""
    effects = tuple(effects)
    commanded = np.array([c.actuation for c in contexts], dtype=float).reshape(
        len(contexts), len(cable_names))
    play = _per_cable(effects, "cable_friction", "play_mm", cable_names)
    transmitted = play_operator(commanded, play) if play.any() else commanded
    return slack_actuation(effects, transmitted, cable_names)


def creep_factor(effects: Iterable[Effect], hold_s: float) -> float:
    """Modulus multiplier 1 - a (1 - exp(-hold / tau)) of viscoelastic_creep (1 without)."""
    factor = 1.0
    for effect in effects:
        if effect.name == "viscoelastic_creep":
            relaxed = 1.0 - math.exp(-hold_s / effect["time_constant_s"])
            factor *= 1.0 - effect["relaxation"] * relaxed
    return factor


def depth_scale(effects: Iterable[Effect]) -> float:
    """measured depth / true depth: 1 + depth_bias.scale (1 without)."""
    return math.prod(1.0 + e["scale"] for e in effects if e.name == "depth_bias")


def biased_depth_mm(depth_mm: np.ndarray, effects: Iterable[Effect]) -> np.ndarray:
    """A true depth image (h, w) mm -> the measured one, float64 (0 stays 0: no return)."""
    return np.asarray(depth_mm, dtype=float) * depth_scale(effects)


def camera_offset(effects: Iterable[Effect]) -> RigidTransform:
    """nominal_camera_from_actual_camera of extrinsic_offset (identity without).

    The actual camera sits translation_{x,y,z}_mm from the nominal one along the nominal
    camera's axes, turned by rotation_{x,y,z}_deg about them (x, then y, then z): so
    robot_from_actual = robot_from_nominal * this.
    """
    for effect in effects:
        if effect.name == "extrinsic_offset":
            rotation = rotation_from_euler_deg(tuple(effect[f"rotation_{a}_deg"] for a in "xyz"))
            translation = np.array([effect[f"translation_{a}_mm"] for a in "xyz"])
            return RigidTransform(rotation, translation)
    return RigidTransform(np.eye(3), np.zeros(3))


def observed_points_robot(points_robot_mm: np.ndarray, effects: Iterable[Effect],
                          robot_from_camera: RigidTransform) -> np.ndarray:
    """(p, 3) mm: where a pipeline using the nominal calibration `robot_from_camera` puts true
    robot-frame points (p, 3) seen by a camera with these sensor effects.

    The actual camera sees p_act = (C D)^-1 x (C the calibration, D = camera_offset), its
    depth scales the point along its ray by depth_scale, and the pipeline maps it with C.
    """
    effects = tuple(effects)
    offset = camera_offset(effects)
    actual_from_robot = offset.inverse().as_matrix() @ robot_from_camera.inverse().as_matrix()
    seen = RigidTransform(actual_from_robot[:3, :3], actual_from_robot[:3, 3]).apply(
        points_robot_mm) * depth_scale(effects)
    return robot_from_camera.apply(seen)
