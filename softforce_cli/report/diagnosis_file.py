"""diagnosis.json (docs/diagnosis.md) read into dataclasses, checked field by field.

    {"verdict": EFFECT | "none" | "unexplained", "noise_floor_mm": float,
     "effects": [{"name", "parameters": {NAME: {"value", "ci95": [lo, hi], "unit"}},
                  "heldout_rms_before_mm", "heldout_rms_after_mm", "evidence"}, ...],
     "location": {"regions": [...], "cables": [...], "nodes": [...]}}

Fields beyond these are kept in Diagnosis.extra and shown as they are; an effect's optional
"target" (the cable or region it was fitted on) is kept, and so are the effects its "label"
names before it when it is a pair. A number written as null (diagnose
writes null for a value that is not finite) reads as NaN.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

LOCATION_KEYS = ("regions", "cables", "nodes")


@dataclass(frozen=True)
class Parameter:
    """A fitted parameter: value with its 95 % confidence interval (lo, hi), in unit."""

    name: str
    value: float
    ci95: tuple[float, float]
    unit: str


@dataclass(frozen=True)
class Effect:
    """One candidate effect, ranked: held-out residual RMS (mm) before and after fitting it."""

    name: str
    parameters: tuple[Parameter, ...]
    heldout_rms_before_mm: float
    heldout_rms_after_mm: float
    evidence: Any
    target: str | None = None
    # in a pair (diagnose's "label": "cable_slack[north] + material_nonlinearity"), the
    # effect fitted before this one, as its label; empty for a single effect
    with_effects: tuple[str, ...] = ()

    @property
    def channel(self) -> str:
        """The residuals it was judged on: "clouds", or "markers" (a camera effect the
        clouds cannot see; its held-out figures are the markers')."""
        evidence = self.evidence if isinstance(self.evidence, dict) else {}
        return str(evidence.get("channel", "clouds"))

    @property
    def label(self) -> str:
        """"cable_slack (north)", or the name alone without a target; a pair's effects joined
        ("cable_slack (north) + material_nonlinearity"); "[markers]" after an effect judged
        on the markers."""
        label = " + ".join((*self.with_effects,
                            self.name if not self.target else f"{self.name} ({self.target})"))
        return label if self.channel == "clouds" else f"{label} [{self.channel}]"

    @property
    def improvement(self) -> float:
        """Fraction of the held-out RMS the effect removes (0: none, 1: all; NaN unknown)."""
        before = self.heldout_rms_before_mm
        return 1.0 - self.heldout_rms_after_mm / before if before > 0 else math.nan


@dataclass(frozen=True)
class Location:
    """Where the mismatch concentrates: region names, cable names, mesh node indices, and
    what else diagnose says about it (extra, e.g. an RMS per region)."""

    regions: tuple[Any, ...] = ()
    cables: tuple[Any, ...] = ()
    nodes: tuple[Any, ...] = ()
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Diagnosis:
    verdict: str
    noise_floor_mm: float
    effects: tuple[Effect, ...]
    location: Location
    extra: dict[str, Any] = field(default_factory=dict)


def read_diagnosis(path: Path) -> Diagnosis:
    """Read and check diagnosis.json; ValueError naming the file and the field otherwise."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"{path}: cannot read it ({error}); run `softforce diagnose` "
                         "again") from error
    return diagnosis_from_dict(data, str(path))


def diagnosis_from_dict(data: Any, where: str = "diagnosis.json") -> Diagnosis:
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected a JSON object")
    # the verdict is shown as written: a name this reader does not know is still the verdict
    verdict = _field(data, "verdict", where, str)
    effects = tuple(_effect(item, f"{where} effects[{i}]")
                    for i, item in enumerate(_field(data, "effects", where, list)))
    location = _field(data, "location", where, dict)
    known = ("verdict", "noise_floor_mm", "effects", "location")
    return Diagnosis(
        verdict=verdict,
        noise_floor_mm=_number(data, "noise_floor_mm", where),
        effects=effects,
        location=Location(*(tuple(location.get(key) or ()) for key in LOCATION_KEYS),
                          extra={k: v for k, v in location.items() if k not in LOCATION_KEYS}),
        extra={k: v for k, v in data.items() if k not in known},
    )


def _effect(item: Any, where: str) -> Effect:
    if not isinstance(item, dict):
        raise ValueError(f"{where}: expected an object")
    parameters = []
    for name, spec in _field(item, "parameters", where, dict).items():
        at = f"{where} parameters.{name}"
        if not isinstance(spec, dict):
            raise ValueError(f"{at}: expected an object with value, ci95, unit")
        ci95 = _field(spec, "ci95", at, list)
        if len(ci95) != 2 or not all(isinstance(v, int | float) for v in ci95):
            raise ValueError(f"{at}: ci95 must be [lo, hi]")
        parameters.append(Parameter(name, _number(spec, "value", at),
                                    (float(ci95[0]), float(ci95[1])), str(spec.get("unit", ""))))
    return Effect(
        name=_field(item, "name", where, str),
        parameters=tuple(parameters),
        heldout_rms_before_mm=_number(item, "heldout_rms_before_mm", where),
        heldout_rms_after_mm=_number(item, "heldout_rms_after_mm", where),
        evidence=item.get("evidence"),
        target=None if item.get("target") is None else str(item["target"]),
        with_effects=_effects_before(item.get("label")),
    )


def _effects_before(label: Any) -> tuple[str, ...]:
    """The effects a pair's label names before its last ("cable_slack[north] + gravity":
    ("cable_slack (north)",)), written as Effect.label writes them; () for one effect."""
    if not isinstance(label, str) or " + " not in label:
        return ()
    return tuple(re.sub(r"\[(.+)\]$", r" (\1)", part.strip())
                 for part in label.split(" + ")[:-1])


def _field(data: dict, key: str, where: str, kind: type) -> Any:
    if key not in data:
        raise ValueError(f"{where}: the field {key!r} is missing; run `softforce diagnose` "
                         "again")
    if not isinstance(data[key], kind):
        raise ValueError(f"{where}: {key} must be a {kind.__name__}")
    return data[key]


def _number(data: dict, key: str, where: str) -> float:
    value = _field(data, key, where, object)
    if value is None:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{where}: {key} must be a number, got {value!r}")
    return float(value)
