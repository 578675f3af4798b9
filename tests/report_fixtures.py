"""Inputs of the report tests: one sense run on the sample probes (made once per session),
and a hand-made diagnose folder following docs/diagnosis.md field by field."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from tests.cli_runner import softforce
from tests.conftest import ROOT, SAMPLE_ROBOT
from tests.test_sense_cli import PROBES, pose_calibration

PROBES_TRUTH = ROOT / "sample_data" / "recordings" / "probes.truth.json"
ARTIFACTS = ROOT / "out" / "test_artifacts"

# A diagnosis as `softforce diagnose` writes it (docs/diagnosis.md): a verdict, the noise
# floor, two ranked effects with their parameters and held-out residuals, and a location; plus
# fields beyond the contract that diagnose also writes (format, selected, target, evidence).
DIAGNOSIS = {
    "format": "softforce.diagnosis",
    "version": 1,
    "verdict": "cable_slack",
    "selected": ["cable_slack (north)"],
    "noise_floor_mm": 0.8,
    "effects": [
        {"name": "cable_slack", "target": "north",
         "parameters": {"slack_north_mm": {"value": 2.1, "ci95": [1.8, 2.4], "unit": "mm"}},
         "heldout_rms_before_mm": 3.2, "heldout_rms_after_mm": 0.9,
         "evidence": "residual grows with the north cable's pull, zero below 2 mm"},
        {"name": "stiffness_scale",
         "parameters": {"scale": {"value": 1.05, "ci95": [0.98, 1.12], "unit": ""}},
         "heldout_rms_before_mm": 3.2, "heldout_rms_after_mm": 3.0,
         "evidence": {"correlation": 0.12}},
    ],
    "indistinguishable_groups": [],
    "location": {"regions": ["north"], "cables": ["north"], "nodes": [3, 5, 8],
                 "region_rms_mm": {"north": 2.9}},
    "evidence": {"frames": 18, "states": 6},
}


def sense_folder(base: Path) -> Path:
    """`softforce sense` on the sample probes (tare 1) into base/sense, once: a later call
    finds the finished run there."""
    folder = base / "sense"
    if (folder / "sense.json").is_file():
        return folder
    base.mkdir(parents=True, exist_ok=True)
    calibration = pose_calibration(PROBES_TRUTH, base)
    result = softforce("sense", PROBES, "--robot", SAMPLE_ROBOT, "--calibration", calibration,
                       "-o", folder, "--tare", "1")
    assert result.returncode == 0, result.stderr
    return folder


def diagnose_folder(folder: Path) -> Path:
    """diagnosis.json, robot.fitted.toml (the sample robot, its mesh beside it) and one PNG
    figure, as diagnose leaves them."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "diagnosis.json").write_text(json.dumps(DIAGNOSIS, indent=1))
    shutil.copy(SAMPLE_ROBOT, folder / "robot.fitted.toml")
    shutil.copy(SAMPLE_ROBOT.parent / "diamond_coarse.vtu", folder)
    figure, axes = plt.subplots(figsize=(3, 2))
    axes.plot([0, 1, 2], [3.2, 1.5, 0.9])
    axes.set_title("signature")
    (folder / "figures").mkdir(exist_ok=True)
    figure.savefig(folder / "figures" / "signature.png")
    plt.close(figure)
    return folder
