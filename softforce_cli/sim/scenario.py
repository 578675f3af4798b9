"""Simulation scenarios (TOML): the truth robot, the camera, and a timeline of loads.

A scenario describes what a virtual experiment does; softforce_cli.sim.simulate turns it into
a recording and a ground-truth sidecar. The format is documented in docs/scenarios.md.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from softforce_cli.camera.lens import LensDistortion, LensModelError
from softforce_cli.errors import ScenarioError
from softforce_cli.fem.materials import LAWS
from softforce_cli.model.effects import Effect, EffectError, parse_effects
from softforce_cli.sim.camera_pose import look_at
from softforce_cli.sim.render import AMBIENT, SHININESS

LOAD_KINDS = ("weight", "probe")
# Bounds that keep a typo from asking for hours of work: a 4096-pixel image side (the D415
# gives at most 1920) and a million repeats of one frame (a week at 0.5 s a frame).
MAX_IMAGE_SIDE = 4096
MAX_REPEAT = 1_000_000

_KEYS = {
    "top": {
        "name",
        "robot",
        "law",
        "seed",
        "frame_interval_s",
        "camera",
        "scene",
        "markers",
        "frame",
        "effect",
    },
    "camera": {
        "width",
        "height",
        "horizontal_fov_deg",
        "position_mm",
        "look_at_mm",
        "up_hint",
        "noise",
        "noise_scale",
        "distortion_model",
        "distortion",
    },
    "scene": {"table_z_mm", "robot_rgb", "probe_rgb", "weight_rgb", "table_rgb", "ambient",
              "light_direction", "specular", "shininess"},
    "markers": {"publish", "sigma_mm", "sticker_rgb", "sticker_radius_mm"},
    "frame": {"actuation", "repeat", "load"},
    "load": {"kind", "point_mm", "force_n", "mass_g", "direction", "hook_radius_mm"},
}
# A weight hangs from a hook set in the material: its force is spread uniformly over the
# material within this radius of its point. A force at one material point is singular on a
# continuum (the locking-free truth's Newton solve does not converge under 1 N there).
HOOK_RADIUS_MM = 3.0
# A marker sticker's radius: a 8 mm dot, a few pixels across at 0.5 m
STICKER_RADIUS_MM = 4.0
GRAVITY_N_PER_G = 9.81e-3
# the D415's largest depth stream (width, height): the sensor model renders depth there
D415_DEPTH_SIZE = (1280, 720)


@dataclass(frozen=True)
class LoadSpec:
    """An external load on the robot.

    kind      : "weight" (hangs from the point, force straight down) or "probe" (a rigid rod
                pressing at the surface point nearest to point_mm).
    point_mm  : (3,) where it acts, on the rest shape, robot frame.
    force_n   : magnitude in N.
    direction : (3,) unit direction of the force on the robot; None for a probe means into the
                surface (minus the surface normal).
    hook_radius_mm : a weight's force is spread uniformly over the material within this
                radius of point_mm (0: at the point itself); 0 for a probe.
    """

    kind: str
    point_mm: tuple[float, float, float]
    force_n: float
    direction: tuple[float, float, float] | None
    hook_radius_mm: float = 0.0


@dataclass(frozen=True)
class FrameSpec:
    """A static state held for `repeat` frames (independent sensor noise on each)."""

    actuation: tuple[float, ...]
    loads: tuple[LoadSpec, ...]
    repeat: int


@dataclass(frozen=True)
class CameraSpec:
    width: int
    height: int
    horizontal_fov_deg: float
    position_mm: tuple[float, float, float]
    look_at_mm: tuple[float, float, float]
    up_hint: tuple[float, float, float]
    noise: bool
    # multiplies the D415's axial depth noise (sim.depth_noise.D415Noise.scaled): 0 none,
    # 1 the D415's, 2 twice
    noise_scale: float = 1.0
    # the lens' distortion (camera.lens; None: a pinhole camera), written in the recording's
    # camera_info: each pixel sees the ray its distorted position maps to
    lens: LensDistortion | None = None

    def checked(self, source: Path) -> CameraSpec:
        """This camera, or ScenarioError when no pose follows from it (a camera looking at
        its own position, an up_hint along its view) or its field of view is not below 180
        degrees."""
        if self.horizontal_fov_deg >= 180.0:
            raise ScenarioError(f"{source}: camera.horizontal_fov_deg = "
                                f"{self.horizontal_fov_deg:g} must be below 180")
        if self.noise and (self.width > D415_DEPTH_SIZE[0] or self.height > D415_DEPTH_SIZE[1]):
            # its larger colour images carry a 1280x720 depth aligned to them, which the
            # sensor model does not render: at 1920x1080 it would take the colour camera's
            # focal length for the stereo pair's and see nothing nearer than 0.61 m
            raise ScenarioError(
                f"{source}: camera {self.width}x{self.height}: a D415 measures depth at "
                f"{D415_DEPTH_SIZE[0]}x{D415_DEPTH_SIZE[1]} at most; take a smaller image, or "
                "noise = false for an ideal camera of that size")
        try:
            look_at(np.array(self.position_mm), np.array(self.look_at_mm), np.array(self.up_hint))
        except ValueError as error:
            raise ScenarioError(f"{source}: camera: {str(error).removeprefix('look_at: ')} "
                                "(position_mm, look_at_mm, up_hint)") from error
        return self


@dataclass(frozen=True)
class SceneSpec:
    table_z_mm: float
    robot_rgb: tuple[int, int, int]
    probe_rgb: tuple[int, int, int]
    weight_rgb: tuple[int, int, int]
    table_rgb: tuple[int, int, int]
    # sim.render's lighting: the share of the colour lit whatever the orientation, and the
    # direction toward a distant light in the robot frame (None: the light at the camera)
    ambient: float = AMBIENT
    light_direction: tuple[float, float, float] | None = None
    # a glossy scene's white highlight (sim.render): its strength and Blinn-Phong exponent
    specular: float = 0.0
    shininess: float = SHININESS


@dataclass(frozen=True)
class Scenario:
    """A validated scenario; `robot` is the ground-truth robot file (a fine mesh)."""

    source: Path
    name: str
    robot: Path
    law: str | None
    seed: int
    frame_interval_s: float
    camera: CameraSpec
    scene: SceneSpec
    publish_markers: bool
    marker_sigma_mm: float
    frames: tuple[FrameSpec, ...]
    # the markers drawn on the robot's skin as round stickers of this colour (None: unseen)
    sticker_rgb: tuple[int, int, int] | None = None
    sticker_radius_mm: float = STICKER_RADIUS_MM
    # effects concealed in the truth (model.effects; docs/effects.md), targets checked
    # against the truth robot by sim.simulate.prepare_simulation
    effects: tuple[Effect, ...] = ()

    @property
    def frame_count(self) -> int:
        return sum(frame.repeat for frame in self.frames)


def load_scenario(path: Path) -> Scenario:
    """Read and validate a scenario TOML file."""
    path = Path(path)
    if not path.is_file():
        raise ScenarioError(f"scenario file {path} not found")
    try:
        data = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, OSError) as error:
        raise ScenarioError(f"{path}: not valid TOML ({error})") from error
    try:
        return _scenario(data, path)
    except (TypeError, ValueError, AttributeError, KeyError, IndexError, OverflowError) as error:
        # a shape _scenario has no specific check for; still one line naming the file
        raise ScenarioError(f"{path}: malformed scenario ({type(error).__name__}: {error}); "
                            "see docs/scenarios.md") from error


def _scenario(data: dict[str, Any], path: Path) -> Scenario:
    check = _Checker(path)
    check.keys(data, "top", "top level")
    if not isinstance(data.get("robot"), str) or not data["robot"].strip():
        raise ScenarioError(f"{path}: needs `robot`, the ground-truth robot file name")
    law = data.get("law")
    if law is not None and law not in LAWS:
        raise ScenarioError(f"{path}: law {law!r} unknown; use one of {', '.join(LAWS)}")
    frames = data.get("frame", [])
    if not isinstance(frames, list):
        raise ScenarioError(f"{path}: frame must be an array of tables ([[frame]])")
    if not frames:
        raise ScenarioError(f"{path}: no [[frame]]; a scenario needs at least one")
    camera = data.get("camera", {})
    check.keys(camera, "camera", "[camera]")
    if camera.get("noise") is False and "noise_scale" in camera:
        raise ScenarioError(f"{path}: camera.noise_scale scales the sensor noise that "
                            "noise = false turns off; remove one of them")
    scene = data.get("scene", {})
    check.keys(scene, "scene", "[scene]")
    markers = data.get("markers", {})
    check.keys(markers, "markers", "[markers]")
    try:
        effects = parse_effects(data.get("effect", []), cables=None)
    except EffectError as error:
        raise ScenarioError(f"{path}: {error}") from error
    return Scenario(
        source=path,
        name=str(data.get("name", path.stem)),
        robot=(path.parent / data["robot"]).resolve(),
        law=law,
        seed=check.integer(data.get("seed", 0), "seed", 0, 2**63 - 1),
        frame_interval_s=check.positive(data.get("frame_interval_s", 0.5), "frame_interval_s"),
        camera=CameraSpec(
            width=check.integer(camera.get("width", 640), "camera.width", 1, MAX_IMAGE_SIDE),
            height=check.integer(camera.get("height", 480), "camera.height", 1, MAX_IMAGE_SIDE),
            # the D415's colour camera: 69 x 42 degrees
            horizontal_fov_deg=check.positive(
                camera.get("horizontal_fov_deg", 69.0), "camera.horizontal_fov_deg"
            ),
            position_mm=check.vector(camera.get("position_mm", [0, 0, 580]), "camera.position_mm"),
            look_at_mm=check.vector(camera.get("look_at_mm", [0, 0, 40]), "camera.look_at_mm"),
            up_hint=check.vector(camera.get("up_hint", [0, 1, 0]), "camera.up_hint"),
            noise=bool(camera.get("noise", True)),
            noise_scale=check.non_negative(camera.get("noise_scale", 1.0), "camera.noise_scale"),
            lens=check.lens(camera.get("distortion_model", "plumb_bob"),
                            camera.get("distortion", []), "camera.distortion"),
        ).checked(path),
        scene=SceneSpec(
            table_z_mm=check.number(scene.get("table_z_mm", -37.5), "scene.table_z_mm"),
            robot_rgb=check.rgb(scene.get("robot_rgb", [40, 90, 210]), "scene.robot_rgb"),
            probe_rgb=check.rgb(scene.get("probe_rgb", [220, 50, 40]), "scene.probe_rgb"),
            weight_rgb=check.rgb(scene.get("weight_rgb", [230, 190, 40]), "scene.weight_rgb"),
            table_rgb=check.rgb(scene.get("table_rgb", [150, 118, 84]), "scene.table_rgb"),
            ambient=check.fraction(scene.get("ambient", AMBIENT), "scene.ambient"),
            light_direction=None if "light_direction" not in scene else check.direction(
                scene["light_direction"], "scene.light_direction"),
            specular=check.fraction(scene.get("specular", 0.0), "scene.specular"),
            shininess=check.positive(scene.get("shininess", SHININESS), "scene.shininess"),
        ),
        publish_markers=bool(markers.get("publish", False)),
        marker_sigma_mm=check.non_negative(markers.get("sigma_mm", 0.0), "markers.sigma_mm"),
        sticker_rgb=None if "sticker_rgb" not in markers else check.rgb(
            markers["sticker_rgb"], "markers.sticker_rgb"),
        sticker_radius_mm=check.positive(markers.get("sticker_radius_mm", STICKER_RADIUS_MM),
                                         "markers.sticker_radius_mm"),
        frames=tuple(_frame(frame, i, check) for i, frame in enumerate(frames)),
        effects=effects,
    )


def _frame(frame: dict[str, Any], index: int, check: _Checker) -> FrameSpec:
    label = f"frame[{index}]"
    check.keys(frame, "frame", label)
    actuation = frame.get("actuation", [])
    if not isinstance(actuation, list):
        raise ScenarioError(f"{check.source}: {label}.actuation must be a list of numbers")
    repeat = frame.get("repeat", 1)
    if isinstance(repeat, bool) or not isinstance(repeat, int) or not 1 <= repeat <= MAX_REPEAT:
        raise ScenarioError(f"{check.source}: {label}.repeat must be an integer in 1..{MAX_REPEAT}")
    loads = []
    if not isinstance(frame.get("load", []), list):
        raise ScenarioError(f"{check.source}: {label}.load must be a list of loads")
    for j, load in enumerate(frame.get("load", [])):
        where = f"{label}.load[{j}]"
        check.keys(load, "load", where)
        kind = load.get("kind")
        if kind not in LOAD_KINDS:
            raise ScenarioError(f"{check.source}: {where}.kind must be one of {LOAD_KINDS}")
        if ("force_n" in load) == ("mass_g" in load):
            raise ScenarioError(f"{check.source}: {where} needs exactly one of force_n, mass_g")
        force = (
            check.positive(load["force_n"], f"{where}.force_n")
            if "force_n" in load
            else check.positive(load["mass_g"], f"{where}.mass_g") * GRAVITY_N_PER_G
        )
        direction = load.get("direction")
        hook = 0.0
        if "hook_radius_mm" in load and kind != "weight":
            raise ScenarioError(f"{check.source}: {where}.hook_radius_mm is for weights only")
        if kind == "weight":
            direction = (0.0, 0.0, -1.0)
            hook = check.number(load.get("hook_radius_mm", HOOK_RADIUS_MM),
                                f"{where}.hook_radius_mm")
            if hook < 0:
                raise ScenarioError(f"{check.source}: {where}.hook_radius_mm must be >= 0")
        elif direction is not None:
            vector = np.array(check.vector(direction, f"{where}.direction"))
            if np.linalg.norm(vector) == 0:
                raise ScenarioError(f"{check.source}: {where}.direction is zero")
            direction = tuple(vector / np.linalg.norm(vector))
        loads.append(
            LoadSpec(
                kind, check.vector(load.get("point_mm"), f"{where}.point_mm"), force, direction,
                hook,
            )
        )
    return FrameSpec(
        tuple(check.number(v, f"{label}.actuation") for v in actuation), tuple(loads), repeat
    )


@dataclass(frozen=True)
class _Checker:
    source: Path

    def keys(self, table: Any, kind: str, label: str) -> None:
        if not isinstance(table, dict):
            raise ScenarioError(f"{self.source}: {label} must be a table")
        unknown = sorted(set(table) - _KEYS[kind])
        if unknown:
            raise ScenarioError(
                f"{self.source}: unknown key {unknown[0]!r} in {label}; "
                f"expected one of {', '.join(sorted(_KEYS[kind]))}"
            )

    def integer(self, value: Any, key: str, low: int, high: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise ScenarioError(f"{self.source}: {key} must be an integer in {low}..{high}, "
                                f"got {value!r}")
        return value

    def number(self, value: Any, key: str) -> float:
        if (
            isinstance(value, bool)
            or not isinstance(value, int | float)
            or not math.isfinite(value)
        ):
            raise ScenarioError(f"{self.source}: {key} must be a finite number, got {value!r}")
        return float(value)

    def positive(self, value: Any, key: str) -> float:
        number = self.number(value, key)
        if number <= 0:
            raise ScenarioError(f"{self.source}: {key} must be positive, got {number:g}")
        return number

    def non_negative(self, value: Any, key: str) -> float:
        number = self.number(value, key)
        if number < 0:
            raise ScenarioError(f"{self.source}: {key} must be >= 0, got {number:g}")
        return number

    def fraction(self, value: Any, key: str) -> float:
        number = self.number(value, key)
        if not 0.0 <= number <= 1.0:
            raise ScenarioError(f"{self.source}: {key} must be in [0, 1], got {number:g}")
        return number

    def direction(self, value: Any, key: str) -> tuple[float, float, float]:
        vector = self.vector(value, key)
        if not any(vector):
            raise ScenarioError(f"{self.source}: {key} must not be zero")
        return vector

    def lens(self, model: Any, coefficients: Any, key: str) -> LensDistortion | None:
        if not isinstance(model, str):
            raise ScenarioError(f"{self.source}: {key}_model must be a string, got {model!r}")
        if not isinstance(coefficients, list):
            raise ScenarioError(f"{self.source}: {key} must be an array of numbers, got "
                                f"{coefficients!r}")
        values = [self.number(c, key) for c in coefficients]
        try:
            return LensDistortion.from_camera_info(model, values)
        except LensModelError as error:
            raise ScenarioError(f"{self.source}: {key}: {error}") from error

    def vector(self, value: Any, key: str) -> tuple[float, float, float]:
        if not isinstance(value, list) or len(value) != 3:
            raise ScenarioError(f"{self.source}: {key} must be 3 numbers, got {value!r}")
        return tuple(self.number(v, key) for v in value)  # type: ignore[return-value]

    def rgb(self, value: Any, key: str) -> tuple[int, int, int]:
        if (
            not isinstance(value, list)
            or len(value) != 3
            or not all(isinstance(v, int) and 0 <= v <= 255 for v in value)
        ):
            raise ScenarioError(f"{self.source}: {key} must be 3 integers in 0..255")
        return tuple(value)  # type: ignore[return-value]
