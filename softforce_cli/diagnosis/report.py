"""diagnosis.json (DESIGN.md section 6) and robot.fitted.toml (the robot file plus the fitted
`[[effect]]` tables, loadable by every command)."""

from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Any

from softforce_cli import __version__
from softforce_cli.diagnosis.pipeline import Candidate, Diagnosis
from softforce_cli.model.effects import EFFECTS, effect_toml


def _finite(value: float) -> float | None:
    return round(float(value), 6) if math.isfinite(value) else None


def candidate_dict(candidate: Candidate) -> dict[str, Any]:
    """One ranked effect: parameters with 95% intervals, held-out RMS, evidence."""
    hypothesis = candidate.fit.hypothesis
    spec = EFFECTS[hypothesis.name]
    parameters = {
        name: {"value": _finite(value), "ci95": [_finite(lo), _finite(hi)],
               "unit": spec.parameter(name).unit}
        for name, value, (lo, hi) in zip(hypothesis.free, candidate.fit.values, candidate.ci95,
                                         strict=True)}
    return {
        "name": hypothesis.name,
        "target": hypothesis.target,
        "parameters": parameters,
        "heldout_rms_before_mm": _finite(candidate.heldout.rms_before_mm),
        "heldout_rms_after_mm": _finite(candidate.heldout.rms_after_mm),
        "evidence": {
            "accepted": candidate.accepted,
            "segment_gain_z": _finite(candidate.heldout.gain_z),
            "fit_rms_mm": _finite(candidate.fit.fields.rms()),
        },
    }


def diagnosis_document(diagnosis: Diagnosis, inputs: dict[str, Any]) -> dict[str, Any]:
    """The diagnosis.json document."""
    selected = {id(c) for c in diagnosis.selected}
    ranked = list(diagnosis.selected) + [c for c in diagnosis.ranked if id(c) not in selected]
    return {
        "format": "softforce.diagnosis",
        "version": 1,
        "softforce_version": __version__,
        "inputs": inputs,
        "verdict": diagnosis.verdict,
        "noise_floor_mm": _finite(diagnosis.noise_floor_mm),
        "selected": [c.fit.hypothesis.label for c in diagnosis.selected],
        "effects": [candidate_dict(c) for c in ranked],
        "indistinguishable_groups": [list(g) for g in diagnosis.groups],
        "location": diagnosis.location,
        "evidence": diagnosis.evidence,
    }


def fitted_robot_toml(robot_file: Path, diagnosis: Diagnosis, output_dir: Path) -> str:
    """The robot file's text with paths made relative to output_dir and the selected effects
    appended as `[[effect]]` tables (none for `none` / `unexplained`)."""
    text = Path(robot_file).read_text()
    base = Path(robot_file).resolve().parent

    def relocate(match: re.Match) -> str:
        path = (base / match.group(2)).resolve()
        return f'{match.group(1)}"{Path(os.path.relpath(path, output_dir.resolve())).as_posix()}"'

    # [mesh] path and reduced are relative to the robot file: rebase them on the output
    text = re.sub(r'(?m)^(\s*(?:path|reduced)\s*=\s*)"([^"]+)"', relocate, text)
    if diagnosis.verdict in ("none", "unexplained"):
        return text
    tables = "\n".join(effect_toml(c.fit.effect) for c in diagnosis.selected)
    header = f"\n# fitted by softforce diagnose {__version__} (diagnosis.json)\n"
    return text.rstrip("\n") + "\n" + header + tables
