"""Settings of `softforce sense`: the vision thresholds and the estimator's, from TOML or flags.

A settings file has two optional tables, each key a field of the dataclass of the same name:

    [vision]                  # softforce_cli.vision.settings.VisionSettings
    voxel_mm = 1.1
    [estimation]              # EstimationSettings below
    force_model = "normal"
"""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from softforce_cli.errors import SensingError
from softforce_cli.vision.settings import VisionSettings

FORCE_MODELS = ("normal", "axis", "cone", "3d")
CONTACT_AT = ("node", "feature")


@dataclass(frozen=True)
class EstimationSettings:
    """The intensity estimator's settings, with why.

    force_model        : "axis": one push per contact along the axis of the object pushing
                         there (a probe, a finger: the principal direction of its points near
                         the contact, vision.contacts.object_axes), or along the inward
                         normal where the object shows no axis or its axis is more than
                         max_axis_angle_deg from the normal; "normal": one push along the
                         inward surface normal of the current configuration (the paper; a
                         probe or a finger cannot pull); "cone": a force vector inside the
                         Coulomb friction cone around the inward normal (friction_coefficient;
                         the data choose the direction); "3d": a free force vector per
                         contact (a hanging weight at an unknown angle, a pull). The intensity
                         hangs on the direction: the sample probes push 10-16 degrees from the
                         bent bar's normal, and "normal" reads them 26-33% high even from
                         perfect observations, because the bar is far stiffer along itself
                         than across; "cone" reads them right from perfect observations but
                         lets depth noise tilt the force towards the stiff direction, which
                         inflates it (docs/sensing_studies.md, "Why the probes read high").
    friction_coefficient : 0.5 (cone half-angle 27 degrees), "cone" only: the tangential force
                         is at most this times the normal force (silicone against a rigid
                         probe grips at 0.5-1; the smaller bound limits the tilt noise buys).
    max_axis_angle_deg : 60; "axis" only: an object axis further than this from the inward
                         normal is not a push into the surface (an object lying along the
                         robot, or a misfit): the normal is used instead.
    contact_at         : "node": a detected contact acts at the surface node on the camera's
                         line of sight through its centre (estimation.sensing.contact_nodes);
                         "feature": at the nearest feature point, as in the paper. The
                         nodes are 3-6 mm apart, the 51 features about 30 mm: a force moved by
                         15 mm along a bar changes the bending it causes by tens of percent.
    updates_per_frame  : 6; FE updates (linearise, QP, eq. 6) per frame, at most (a frame
                         stops once an update moves no feature more than rematch_mm). The
                         paper does one per frame and lets the configuration converge over
                         the following frames; when a load appears between two frames, the
                         P2 Diamond needs several to follow it: on the 12-location probes
                         study (3-frame holds, docs/sensing_studies.md) 2 updates read the intensity
                         21% off at the median and 75% at the 90th percentile, 4 updates 19%
                         / 39%, 6 updates 18% / 37%, at 1.25, 1.1 and 1.0 frames per second.
    rematch_mm         : 0.1; the frame's next update (matching again at the updated shape)
                         is skipped once an update has moved no feature point more than
                         this: a tenth of the depth noise, so the matching would find the
                         same points. In a steady state one update per frame then suffices.
    relinearize_mm     : 0.5; the FE model is linearised again (K(x) assembled and
                         factorised, the internal forces at x: a Newton step) when an update
                         has moved a vertex of the mesh more than this from the configuration
                         of the last linearisation; between, the compliance and the
                         configuration come from that linearisation
                         (estimation.linear_model). 0 relinearises at every update (the
                         paper's eq. 6). With P2 on the 640x480 probes of
                         benchmarks/bench_sense.py, 0.5 mm keeps the intensity errors of 0
                         (median 32% vs 30%) with 46 linearisations in 40 frames instead of
                         80; 2 mm (8) doubles them. P1 moves less: 3 in 40 frames.
    track_radius_mm    : a contact within this of one of the previous frame's keeps its index
                         (a probe slides a few mm between frames at 30 fps).
    min_matched        : fewer matched features than this (or than unknowns + 1) skips the frame.
    min_robot_points   : fewer robot points than this means the robot is not in view.
    lost_fit_mm        : 10.0; a frame whose fit (RMS normal residual of the matched
                         features) ends more than this above the first frame's (the model's
                         own offset from the robot, before any tare) has lost the robot: the
                         updates diverged (a load step overshot until elements inverted) and
                         the model no longer lies where the camera sees the robot, so later
                         frames would match nothing. The frame is skipped as `lost` and the
                         model starts again from the unloaded equilibrium at the current
                         actuation. The studies' fits stay within 6 mm (docs/sensing_studies.md).
    regularization     : relative Tikhonov weight on contact forces (estimation.intensity).
    """

    force_model: str = "axis"
    friction_coefficient: float = 0.5
    max_axis_angle_deg: float = 60.0
    contact_at: str = "node"
    updates_per_frame: int = 6
    rematch_mm: float = 0.1
    relinearize_mm: float = 0.5
    track_radius_mm: float = 15.0
    min_matched: int = 6
    min_robot_points: int = 200
    lost_fit_mm: float = 10.0
    regularization: float = 1e-6

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if isinstance(value, float) and value != value:
                raise SensingError(f"estimation.{name} is not a number (NaN)")
        if self.force_model not in FORCE_MODELS:
            raise SensingError(f"estimation.force_model {self.force_model!r} unknown; use "
                               f"one of {', '.join(FORCE_MODELS)}")
        if self.contact_at not in CONTACT_AT:
            raise SensingError(f"estimation.contact_at {self.contact_at!r} unknown; use one of "
                               f"{', '.join(CONTACT_AT)}")
        if not 0 < self.max_axis_angle_deg < 90:
            raise SensingError("estimation.max_axis_angle_deg must be in (0, 90)")
        if not self.friction_coefficient > 0:
            raise SensingError("estimation.friction_coefficient must be > 0 (use force_model = "
                               "\"normal\" for a push along the normal only)")
        if self.relinearize_mm < 0 or self.rematch_mm < 0:
            raise SensingError("estimation.relinearize_mm and rematch_mm must be >= 0")
        if not self.lost_fit_mm > 0:
            raise SensingError("estimation.lost_fit_mm must be > 0")
        if self.updates_per_frame < 1:
            raise SensingError("estimation.updates_per_frame must be at least 1")


@dataclass(frozen=True)
class SenseSettings:
    vision: VisionSettings = field(default_factory=VisionSettings)
    estimation: EstimationSettings = field(default_factory=EstimationSettings)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def load_settings(path: Path | None, overrides: dict[str, Any] | None = None) -> SenseSettings:
    """Settings from a TOML file (or the defaults), then `overrides` {"table.key": value}."""
    tables: dict[str, dict[str, Any]] = {"vision": {}, "estimation": {}}
    if path is not None:
        if not Path(path).is_file():
            what = "is not a file" if Path(path).exists() else "not found"
            raise SensingError(f"settings file {path} {what}")
        try:
            data = tomllib.loads(Path(path).read_text())
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
            raise SensingError(f"{path}: not valid TOML ({error})") from error
        unknown = sorted(set(data) - set(tables))
        if unknown:
            raise SensingError(f"{path}: unknown table [{unknown[0]}]; expected [vision] or "
                               "[estimation]")
        for name in tables:
            if not isinstance(data.get(name, {}), dict):
                raise SensingError(f"{path}: {name} must be a table")
            tables[name].update(data.get(name, {}))
    for key, value in (overrides or {}).items():
        table, _, name = key.partition(".")
        tables[table][name] = value
    where = path if path is not None else "settings"
    return SenseSettings(
        vision=_build(VisionSettings, tables["vision"], f"{where} [vision]"),
        estimation=_build(EstimationSettings, tables["estimation"], f"{where} [estimation]"),
    )


def _build(kind: type, values: dict[str, Any], where: str) -> Any:
    fields = {f.name: f for f in dataclasses.fields(kind)}
    unknown = sorted(set(values) - set(fields))
    if unknown:
        raise SensingError(f"{where}: unknown key {unknown[0]!r}; expected one of "
                           f"{', '.join(sorted(fields))}")
    defaults = kind()
    checked = {}
    for name, value in values.items():
        default = getattr(defaults, name)
        expected = type(default) if default is not None else None
        if expected is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if expected is tuple and isinstance(value, list):
            value = tuple(value)
        wrong_type = expected is not None and not isinstance(value, expected)
        if wrong_type or (isinstance(value, bool) and expected is not bool):
            raise SensingError(f"{where}: {name} must be {expected.__name__}, got {value!r}")
        checked[name] = value
    try:
        return dataclasses.replace(defaults, **checked)
    except ValueError as error:
        raise SensingError(f"{where}: {error}") from error
