"""The robot model file (docs/robot_model.md): TOML parsed into validated, frozen data.

Every check raises ModelError with one line naming the file, the key and the fix.
"""

from __future__ import annotations

import itertools
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from softforce_cli.errors import ModelError
from softforce_cli.fem.cables import CONTROLS
from softforce_cli.fem.element import ELEMENTS
from softforce_cli.fem.materials import LAWS
from softforce_cli.model.effects import Effect, EffectError, parse_effects
from softforce_cli.model.features import PLACEMENTS
from softforce_cli.model.regions import names_for_cables

_KEYS = {
    "top": {"name", "mesh", "material", "fixed", "cable", "features", "marker", "effect"},
    "mesh": {"path", "scale", "rotation_deg", "translation_mm", "element", "reduced"},
    "material": {"law", "young_modulus_mpa", "poisson_ratio", "total_mass_kg", "density_kg_m3",
                 "gravity_mm_s2"},
    "fixed": {"box_mm"},
    "cable": {"name", "path_mm", "pull_point_mm", "control", "min", "max"},
    "features": {"count", "points_mm", "placement"},
    "marker": {"id", "position_mm"},
}


@dataclass(frozen=True)
class MeshSpec:
    path: Path
    scale: float = 1.0
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    translation_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    element: str = "p1"
    # a reduced-order model (.rom.npz from `softforce model reduce`), resolved like `path`
    reduced: Path | None = None


@dataclass(frozen=True)
class MaterialSpec:
    law: str
    young_modulus_mpa: float
    poisson_ratio: float
    total_mass_kg: float | None
    density_kg_m3: float | None
    gravity_mm_s2: tuple[float, float, float]


@dataclass(frozen=True)
class CableSpec:
    name: str
    path_mm: tuple[tuple[float, float, float], ...]
    pull_point_mm: tuple[float, float, float]
    control: str
    min: float
    max: float


@dataclass(frozen=True)
class MarkerSpec:
    id: str
    position_mm: tuple[float, float, float]


@dataclass(frozen=True)
class RobotConfig:
    """The robot file's content, validated for form and units (not yet against the mesh)."""

    source: Path
    name: str
    mesh: MeshSpec
    material: MaterialSpec
    fixed_boxes_mm: tuple[tuple[float, ...], ...]
    cables: tuple[CableSpec, ...]
    feature_count: int | None
    feature_points_mm: tuple[tuple[float, float, float], ...] | None
    markers: tuple[MarkerSpec, ...]
    # [[effect]] tables (model.effects; docs/effects.md), in file order
    effects: tuple[Effect, ...] = ()
    # where `count` features go: "spread" over the whole surface, or "faces" (off edges)
    feature_placement: str = "spread"


def load_config(path: Path) -> RobotConfig:
    """Read and validate a robot TOML file."""
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"robot file {path} not found; create one with `softforce model init`")
    try:
        data = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, OSError) as error:
        raise ModelError(f"{path}: not valid TOML ({error})") from error
    try:
        return parse_config(data, path)
    except (TypeError, ValueError, AttributeError, KeyError, IndexError) as error:
        # a shape parse_config has no specific check for; still one line naming the file
        raise ModelError(f"{path}: malformed robot file ({type(error).__name__}: {error}); "
                         "see docs/robot_model.md") from error


def parse_config(data: dict[str, Any], source: Path) -> RobotConfig:
    where = _Where(source)
    where.keys(data, "top", "")
    for section in ("mesh", "material"):
        if section not in data:
            raise ModelError(f"{source}: missing [{section}] section (see docs/robot_model.md)")
    mesh = data["mesh"]
    where.keys(mesh, "mesh", "mesh")
    if not isinstance(mesh.get("path"), str) or not mesh["path"].strip():
        raise ModelError(f"{source}: [mesh] needs `path`, the tetrahedral mesh file name")
    element = mesh.get("element", "p1")
    if not isinstance(element, str) or element not in ELEMENTS:
        raise ModelError(f"{source}: mesh.element {element!r} unknown; use "
                         f"{' or '.join(repr(e) for e in ELEMENTS)} (see docs/robot_model.md)")
    mesh_spec = MeshSpec(
        path=(source.parent / mesh["path"]).resolve(),
        scale=where.positive(mesh.get("scale", 1.0), "mesh.scale"),
        rotation_deg=where.vector(mesh.get("rotation_deg", [0, 0, 0]), "mesh.rotation_deg"),
        translation_mm=where.vector(mesh.get("translation_mm", [0, 0, 0]),
                                    "mesh.translation_mm"),
        element=element,
        reduced=_reduced_path(mesh.get("reduced"), source),
    )
    fixed = where.tables(data.get("fixed", []), "fixed")
    boxes = []
    for i, box in enumerate(fixed):
        where.keys(box, "fixed", f"fixed[{i}]")
        values = where.numbers(box.get("box_mm"), 6, f"fixed[{i}].box_mm")
        if any(values[k] >= values[k + 3] for k in range(3)):
            raise ModelError(f"{source}: fixed[{i}].box_mm must be [xmin ymin zmin xmax ymax zmax]"
                             " with each min below its max")
        boxes.append(values)
    if not boxes:
        raise ModelError(f"{source}: no [[fixed]] box; a robot must be clamped somewhere")
    features = data.get("features", {"count": 51})
    where.keys(features, "features", "features")
    if ("count" in features) == ("points_mm" in features):
        raise ModelError(f"{source}: [features] needs exactly one of `count` or `points_mm`")
    count = features.get("count")
    if count is not None and (not isinstance(count, int) or count < 1):
        raise ModelError(f"{source}: features.count must be a positive integer, got {count!r}")
    points = features.get("points_mm")
    placement = features.get("placement", "spread")
    if placement not in PLACEMENTS:
        raise ModelError(f"{source}: features.placement must be one of {', '.join(PLACEMENTS)}"
                         f", got {placement!r}")
    if placement != "spread" and points is not None:
        raise ModelError(f"{source}: features.placement applies to `count`, not `points_mm`")
    cables = _cables(where.tables(data.get("cable", []), "cable"), where)
    return RobotConfig(
        source=source,
        name=str(data.get("name", source.stem)),
        mesh=mesh_spec,
        material=_material(data["material"], where),
        fixed_boxes_mm=tuple(boxes),
        cables=cables,
        feature_count=count,
        feature_points_mm=None if points is None else tuple(
            where.vector(p, f"features.points_mm[{i}]") for i, p in enumerate(points)),
        markers=_markers(where.tables(data.get("marker", []), "marker"), where),
        effects=_effects(where.tables(data.get("effect", []), "effect"), cables, where),
        feature_placement=placement,
    )


def _effects(tables: list, cables: tuple[CableSpec, ...], where: _Where) -> tuple[Effect, ...]:
    names = tuple(c.name for c in cables)
    try:
        effects = parse_effects(tables, names, names_for_cables(names))
    except EffectError as error:
        raise ModelError(f"{where.source}: {error}") from error
    controls = {c.name: c.control for c in cables}
    for effect in effects:
        if effect.spec.target == "cable" and controls[effect.target] != "displacement":
            raise ModelError(f"{where.source}: {effect.name} acts on a cable's displacement; "
                             f"cable {effect.target!r} is force-controlled")
    return effects


def _reduced_path(value: Any, source: Path) -> Path | None:
    """mesh.reduced: a .rom.npz path relative to the robot file, or None."""
    if value is None:
        return None
    if not isinstance(value, str) or not value.strip():
        raise ModelError(f"{source}: mesh.reduced must be a file name (a .rom.npz from "
                         f"`softforce model reduce`), got {value!r}")
    return (source.parent / value).resolve()


def _material(material: dict[str, Any], where: _Where) -> MaterialSpec:
    source = where.source
    where.keys(material, "material", "material")
    law = material.get("law", "corotational")
    if law not in LAWS:
        raise ModelError(f"{source}: material.law {law!r} unknown; use one of {', '.join(LAWS)}")
    young = where.positive(material.get("young_modulus_mpa"), "material.young_modulus_mpa")
    if young > 1e4:
        raise ModelError(f"{source}: material.young_modulus_mpa = {young:g} looks like Pa or kPa;"
                         " softforce uses MPa (180 kPa silicone is 0.18)")
    nu = where.number(material.get("poisson_ratio"), "material.poisson_ratio")
    if not 0.0 <= nu < 0.5:
        raise ModelError(f"{source}: material.poisson_ratio = {nu:g} must be in [0, 0.5)")
    mass = material.get("total_mass_kg")
    density = material.get("density_kg_m3")
    if (mass is None) == (density is None):
        raise ModelError(f"{source}: [material] needs exactly one of total_mass_kg or "
                         "density_kg_m3")
    if density is not None and where.positive(density, "material.density_kg_m3") < 50:
        raise ModelError(f"{source}: material.density_kg_m3 = {density:g} looks like g/cm^3;"
                         " silicone is about 1070 kg/m^3")
    if mass is not None:
        where.positive(mass, "material.total_mass_kg")
    gravity = where.vector(material.get("gravity_mm_s2", [0, 0, 0]), "material.gravity_mm_s2")
    if 1.0 < math.hypot(*gravity) < 100.0:
        raise ModelError(f"{source}: material.gravity_mm_s2 = {list(gravity)} looks like m/s^2;"
                         " softforce uses mm/s^2 (9810)")
    return MaterialSpec(law, young, nu, mass, density, gravity)


def _cables(cables: list[dict[str, Any]], where: _Where) -> tuple[CableSpec, ...]:
    specs = []
    for i, cable in enumerate(cables):
        where.keys(cable, "cable", f"cable[{i}]")
        name = str(cable.get("name", f"cable{i}"))
        control = cable.get("control", "displacement")
        if control not in CONTROLS:
            raise ModelError(f"{where.source}: cable {name!r} control {control!r} unknown; use "
                             f"{' or '.join(CONTROLS)}")
        path = cable.get("path_mm")
        if not isinstance(path, list) or not path:
            raise ModelError(f"{where.source}: cable {name!r} needs path_mm, a list of points")
        low = where.number(cable.get("min", 0.0), f"cable {name!r} min")
        high = where.number(cable.get("max", math.inf), f"cable {name!r} max")
        if low > high:
            raise ModelError(f"{where.source}: cable {name!r} has min {low:g} > max {high:g}")
        spec = CableSpec(
            name=name,
            path_mm=tuple(where.vector(p, f"cable {name!r} path_mm") for p in path),
            pull_point_mm=where.vector(cable.get("pull_point_mm"), f"cable {name!r} pull_point_mm"),
            control=control, min=low, max=high,
        )
        points = [*spec.path_mm, spec.pull_point_mm]
        shortest = min(math.dist(a, b) for a, b in itertools.pairwise(points))
        if shortest < MIN_SEGMENT_MM:
            # a segment of no length has no direction: the cable's force and rows are NaN
            raise ModelError(f"{where.source}: cable {name!r} has two consecutive points "
                             f"(path_mm, then pull_point_mm) {shortest:.3g} mm apart; each "
                             "segment needs a length")
        specs.append(spec)
    _unique([c.name for c in specs], "cable name", where.source)
    return tuple(specs)


def _markers(markers: list[dict[str, Any]], where: _Where) -> tuple[MarkerSpec, ...]:
    specs = []
    for i, marker in enumerate(markers):
        where.keys(marker, "marker", f"marker[{i}]")
        if "id" not in marker:
            raise ModelError(f"{where.source}: marker[{i}] needs an `id`")
        position = where.vector(marker.get("position_mm"), f"marker[{i}].position_mm")
        specs.append(MarkerSpec(str(marker["id"]), position))
    _unique([m.id for m in specs], "marker id", where.source)
    return tuple(specs)


def _unique(names: list[str], what: str, source: Path) -> None:
    seen = set()
    for name in names:
        if name in seen:
            raise ModelError(f"{source}: {what} {name!r} appears twice")
        seen.add(name)


# Points farther than this from the origin are a unit mistake (m taken for mm, or worse), and
# would overflow the nearest-element search.
MAX_COORDINATE_MM = 1e6
# Consecutive points of a cable (its path, then its pull point) closer than this (mm) make
# a segment with no direction.
MIN_SEGMENT_MM = 1e-3


@dataclass(frozen=True)
class _Where:
    """Validators that name the file and key in their error."""

    source: Path

    def keys(self, table: Any, kind: str, label: str) -> None:
        if not isinstance(table, dict):
            raise ModelError(f"{self.source}: [{label}] must be a table")
        unknown = sorted(set(table) - _KEYS[kind])
        if unknown:
            place = f"[{label}]" if label else "top level"
            raise ModelError(f"{self.source}: unknown key {unknown[0]!r} in {place}; expected "
                             f"one of {', '.join(sorted(_KEYS[kind]))}")

    def number(self, value: Any, key: str) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(
                value):
            raise ModelError(f"{self.source}: {key} must be a finite number, got {value!r}")
        return float(value)

    def positive(self, value: Any, key: str) -> float:
        number = self.number(value, key)
        if number <= 0:
            raise ModelError(f"{self.source}: {key} must be positive, got {number:g}")
        return number

    def numbers(self, value: Any, count: int, key: str) -> tuple[float, ...]:
        if not isinstance(value, list) or len(value) != count:
            raise ModelError(f"{self.source}: {key} must be a list of {count} numbers, got "
                             f"{value!r}")
        return tuple(self.number(v, key) for v in value)

    def vector(self, value: Any, key: str) -> tuple[float, float, float]:
        vector = self.numbers(value, 3, key)
        if max(abs(v) for v in vector) > MAX_COORDINATE_MM:
            raise ModelError(f"{self.source}: {key} = {list(vector)} is over 1 km from the "
                             "origin; coordinates are in mm")
        return vector  # type: ignore[return-value]

    def tables(self, value: Any, key: str) -> list:
        if not isinstance(value, list):
            raise ModelError(f"{self.source}: {key} must be an array of tables ([[{key}]]), "
                             f"got {value!r}")
        return value
