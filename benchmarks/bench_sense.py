"""Speed and memory of `softforce sense`, decode to forces written, at the D415's 640x480."""

from __future__ import annotations

import resource
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.timing import BenchRow
from softforce_cli.estimation.results import STAGES
from softforce_cli.estimation.session import run_sensing
from softforce_cli.estimation.setup import SenseInputs, prepare_sensing
from softforce_cli.sim.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "out" / "bench_sense"
ROBOT = ROOT / "sample_data" / "diamond" / "diamond.toml"
TRUTH_ROBOT = ROOT / "sample_data" / "diamond_truth" / "diamond.toml"
FRAMES_PER_STATE = 20

SCENARIO = f"""name = "bench_sense"
robot = "{TRUTH_ROBOT}"
law = "neo-hookean"
seed = 4
frame_interval_s = 0.0333

[[frame]]
actuation = [5.0, 0.0, 5.0, 0.0]
repeat = {FRAMES_PER_STATE}

[[frame]]
actuation = [5.0, 0.0, 5.0, 0.0]
repeat = {FRAMES_PER_STATE}
load = [{{ kind = "probe", point_mm = [0.0, 48.5, 85.5], force_n = 0.5 }}]
"""


def _recording() -> Path:
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / "probe_640x480.mcap"
    if not path.exists():
        scenario = OUT / "bench_sense.toml"
        scenario.write_text(SCENARIO)
        simulate(scenario, path)
    return path


def _calibration(recording: Path) -> Path:
    """The truth's camera pose as a pose-only calibration: the bench times sensing alone."""
    import json

    truth = json.loads(recording.with_suffix(".truth.json").read_text())
    path = OUT / "pose.json"
    path.write_text(json.dumps({"rotation": truth["camera"]["rotation"],
                                "translation_mm": truth["camera"]["translation_mm"]}))
    return path


def sense_run(robot: Path, overrides: dict | None = None) -> dict:
    recording = _recording()
    with tempfile.TemporaryDirectory() as folder:
        inputs = SenseInputs(recording=recording, robot=robot,
                             calibration=_calibration(recording), output=Path(folder) / "out",
                             overrides=overrides or {})
        prepared = prepare_sensing(inputs)
        summary = run_sensing(prepared.frames, prepared.sensor, inputs.output,
                              prepared.header)
    totals = np.sum([summary.stage_ms[s] for s in STAGES], axis=0)
    # the first frames learn the colour and settle the FE state: time the steady state
    steady = totals[2:]
    return {"median_ms": float(np.median(steady)), "frames": len(totals),
            "stages": {s: float(np.median(summary.stage_ms[s][2:])) for s in STAGES},
            "write_ms": float(np.median(summary.stage_ms["write"][2:]))}


def run() -> list[BenchRow]:
    rows = []
    for updates in (1, 2):
        result = sense_run(ROBOT, {"estimation.updates_per_frame": updates})
        stages = ", ".join(f"{s} {v:.1f}" for s, v in result["stages"].items() if v >= 0.5)
        peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        rows.append(BenchRow(
            f"sense, whole pipeline 640x480, coarse p1 robot, 51 features, "
            f"{updates} FE update(s) per frame",
            result["median_ms"] * 1e-3, result["frames"] - 2, ">= 30 fps",
            f"{1e3 / result['median_ms']:.0f} fps",
            f"stages (ms): {stages}; write {result['write_ms']:.1f} ms; peak RSS of the "
            f"benchmark process {peak_mb:.0f} MB; paper: 7 Hz",
        ))
        print(rows[-1], file=sys.stderr)
    return rows
