"""Sensing results against a synthetic recording's ground truth (`<name>.truth.json`).

Each true contact of a frame is paired with the nearest estimated contact within
LOCATION_TOLERANCE_MM (one to one); the pair's location error and relative intensity error
are recorded, and a true contact with no estimate nearby is missed. An unpaired estimate
within LOCATION_TOLERANCE_MM of a located true contact (the nearest) is a part of it, one
object seen as two clusters: its force vector adds to the pair's estimate (`split` counts
them). Any other unpaired estimate is a phantom when it pushes more than PHANTOM_N (the
issue's threshold: vision may see an object near the robot that the QP then gives no force,
which reads nothing). Positions are compared on the deformed robot, robot frame.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from softforce_cli.errors import SensingError

# A located contact is within this of the true one: the acceptance distance, about
# two thirds of the feature spacing on the Diamond.
LOCATION_TOLERANCE_MM = 20.0
# An unpaired estimate pushing more than this is a phantom contact (issue 8's threshold).
PHANTOM_N = 0.05


@dataclass(frozen=True)
class ContactError:
    frame: int
    true_force_n: float
    estimated_force_n: float
    location_error_mm: float
    kind: str

    @property
    def relative_error(self) -> float:
        return abs(self.estimated_force_n - self.true_force_n) / self.true_force_n


@dataclass(frozen=True)
class TruthComparison:
    """paired: located contacts; missed: (frame, true force N) of unlocated true contacts;
    phantoms: (frame, estimated force N) of estimated contacts with no true one (any force:
    summary() counts those above PHANTOM_N, and gives the largest of all); split: estimates
    added to a located contact's (module docstring)."""

    paired: tuple[ContactError, ...]
    missed: tuple[tuple[int, float], ...]
    phantoms: tuple[tuple[int, float], ...]
    frames: int
    split: int = 0

    @property
    def located_fraction(self) -> float:
        total = len(self.paired) + len(self.missed)
        return len(self.paired) / total if total else float("nan")

    def relative_errors(self) -> np.ndarray:
        return np.array([p.relative_error for p in self.paired])

    def summary(self) -> dict[str, Any]:
        errors = self.relative_errors()
        location = np.array([p.location_error_mm for p in self.paired])

        def stat(values: np.ndarray, q: float) -> float | None:
            return round(float(np.percentile(values, q)), 4) if len(values) else None

        return {
            "frames": self.frames,
            "true_contacts": len(self.paired) + len(self.missed),
            "located": len(self.paired),
            "located_fraction": round(self.located_fraction, 4),
            "phantoms": sum(force > PHANTOM_N for _, force in self.phantoms),
            "max_phantom_n": round(max((f for _, f in self.phantoms), default=0.0), 4),
            "split": self.split,
            "intensity_error_mean": round(float(errors.mean()), 4) if len(errors) else None,
            "intensity_error_median": stat(errors, 50),
            "intensity_error_p90": stat(errors, 90),
            "location_error_median_mm": stat(location, 50),
            "location_error_max_mm": stat(location, 100),
        }


def read_truth(path: Path) -> dict[str, Any]:
    try:
        return json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as error:
        raise SensingError(f"{path}: cannot read the ground truth ({error})") from error


def pose_from_truth(truth_file: Path) -> dict[str, Any]:
    """The camera pose a simulated recording was made with (its truth file's "camera"), as a
    pose-only calibration document: what accuracy studies give to score sensing alone."""
    camera = read_truth(truth_file)["camera"]
    return {"rotation": camera["rotation"], "translation_mm": camera["translation_mm"]}


def compare_with_truth(sense: dict[str, Any], truth: dict[str, Any]) -> TruthComparison:
    """Compare a sense.json document with a truth document, frame by frame (frame indices
    are the recording's; frames not processed are left out)."""
    true_frames = {f["index"]: f for f in truth["frames"]}
    paired, missed, phantoms, split = [], [], [], 0
    processed = [f for f in sense["frames"] if f["status"] == "ok"]
    for frame in processed:
        index = frame["frame"]
        true_contacts = true_frames[index]["contacts"]
        estimates = frame["contacts"]
        true_points = np.array([c["point_mm"] for c in true_contacts]).reshape(-1, 3)
        estimated_points = np.array([c["position_mm"] for c in estimates]).reshape(-1, 3)
        distance = np.linalg.norm(true_points[:, None] - estimated_points[None], axis=2)
        rows, cols = linear_sum_assignment(distance) if distance.size else ([], [])
        located = {int(r): [int(c)] for r, c in zip(rows, cols, strict=True)
                   if distance[r, c] <= LOCATION_TOLERANCE_MM}
        assigned = {parts[0] for parts in located.values()}
        for k, estimate in enumerate(estimates):
            if k in assigned:
                continue
            near = [r for r in located if distance[r, k] <= LOCATION_TOLERANCE_MM]
            if near:
                located[min(near, key=lambda r: distance[r, k])].append(k)
                split += 1
            else:
                phantoms.append((index, estimate["force_n"]))
        for r, parts in sorted(located.items()):
            paired.append(ContactError(index, true_contacts[r]["magnitude_n"],
                                       _total_force_n([estimates[k] for k in parts]),
                                       float(distance[r, parts[0]]), true_contacts[r]["kind"]))
        missed += [(index, c["magnitude_n"]) for r, c in enumerate(true_contacts)
                   if r not in located]
    return TruthComparison(tuple(paired), tuple(missed), tuple(phantoms), len(processed), split)


def _total_force_n(estimates: list[dict[str, Any]]) -> float:
    """The magnitude of the estimates' summed force vectors (their force_n, one alone)."""
    if len(estimates) == 1:
        return estimates[0]["force_n"]
    return float(np.linalg.norm(np.sum([e["force_vector_n"] for e in estimates], axis=0)))
