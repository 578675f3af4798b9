"""Speed and memory of `softforce sense`, decode to forces written, at the D415's 640x480."""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.timing import BenchRow
from softforce_cli.estimation.results import STAGES
from softforce_cli.estimation.session import run_sensing
from softforce_cli.estimation.setup import SenseInputs, prepare_sensing
from softforce_cli.estimation.truth_errors import compare_with_truth, pose_from_truth, read_truth
from softforce_cli.sim.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "out" / "bench_sense"
ROBOT = ROOT / "sample_data" / "diamond" / "diamond.toml"
TRUTH_ROBOT = ROOT / "sample_data" / "diamond_truth" / "diamond.toml"
FRAMES_PER_STATE = 10
TARE_FRAMES = FRAMES_PER_STATE

# The sample probes (sample_data/scenarios/probes.toml) at the D415's 640x480, each state held
# for FRAMES_PER_STATE frames: forces the soft locking-free truth holds (0.6 N bends its bar
# 37 mm, beyond what feature matching follows), the first state unloaded for taring.
SCENARIO = f"""name = "bench_sense"
robot = "{TRUTH_ROBOT}"
law = "neo-hookean"
seed = 4
frame_interval_s = 0.0333

[camera]
width = 640
height = 480

[[frame]]
actuation = [5.0, 0.0, 5.0, 0.0]
repeat = {FRAMES_PER_STATE}

[[frame]]
actuation = [5.0, 0.0, 5.0, 0.0]
repeat = {FRAMES_PER_STATE}
load = [{{ kind = "probe", point_mm = [0.0, 45.0, 90.0], force_n = 0.15 }}]

[[frame]]
actuation = [5.0, 0.0, 5.0, 0.0]
repeat = {FRAMES_PER_STATE}
load = [{{ kind = "probe", point_mm = [0.0, 45.0, 90.0], force_n = 0.25 }}]

[[frame]]
actuation = [5.0, 0.0, 5.0, 0.0]
repeat = {FRAMES_PER_STATE}
load = [
    {{ kind = "probe", point_mm = [0.0, 45.0, 90.0], force_n = 0.25 }},
    {{ kind = "probe", point_mm = [-45.0, 0.0, 90.0], force_n = 0.2 }},
]
"""


def _recording() -> Path:
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / "probes_640x480.mcap"
    if not path.exists():
        scenario = OUT / "bench_sense.toml"
        scenario.write_text(SCENARIO)
        simulate(scenario, path)
    return path


def _calibration(recording: Path) -> Path:
    """The truth's camera pose as a pose-only calibration: the bench times sensing alone."""
    path = OUT / "pose.json"
    path.write_text(json.dumps(pose_from_truth(recording.with_suffix(".truth.json"))))
    return path


def robot_with_element(element: str) -> Path:
    """The sample robot file with `[mesh] element` set (p1 is the file as shipped); "p2-rom":
    the p2 element through its reduced model (benchmarks/bench_reduced.py trains and caches
    it, about 10 minutes on 2 free cores the first time); "p2-shipped": the sample P2 robot
    file as shipped (sample_data/diamond/diamond_p2.toml, 151 features); "p2-shipped-rom":
    that file through the same reduced model (trained at 51 features: a reduction is tied to
    the mesh, element, law and cables, not to the features)."""
    if element == "p1":
        return ROBOT
    if element == "p2-shipped":
        return ROBOT.parent / "diamond_p2.toml"
    source = ROBOT.parent / ("diamond_p2.toml" if element == "p2-shipped-rom" else ROBOT.name)
    if element.endswith("-rom"):
        from benchmarks.bench_reduced import reduced_robot

        return robot_reading(source, reduced_robot()[1].config.mesh.reduced,
                             f"diamond_{element}.toml")
    return _robot_copy(source, f'element = "{element}"', f"diamond_{element}.toml")


def robot_reading(source: Path, reduced: Path, name: str) -> Path:
    """A copy of the sample robot file `source` (in OUT, as `name`) that reads the reduced
    model `reduced`."""
    return _robot_copy(source, f'element = "p2"\nreduced = "{Path(reduced).resolve()}"', name)


def _robot_copy(source: Path, mesh_keys: str, name: str) -> Path:
    """`source` with its [mesh] element replaced by `mesh_keys`, its mesh path absolute."""
    OUT.mkdir(parents=True, exist_ok=True)
    text = source.read_text().replace('element = "p2"\n', "")
    mesh = f'path = "{ROBOT.parent / "diamond_coarse.vtu"}"\n{mesh_keys}'
    path = OUT / name
    path.write_text(text.replace('path = "diamond_coarse.vtu"', mesh))
    return path


def sense_run(robot: Path, overrides: dict | None = None) -> dict:
    """Sense the bench recording (tared on its unloaded state): per-frame timings and the
    errors against its truth (estimation.truth_errors)."""
    recording = _recording()
    with tempfile.TemporaryDirectory() as folder:
        inputs = SenseInputs(recording=recording, robot=robot,
                             calibration=_calibration(recording), output=Path(folder) / "out",
                             overrides=overrides or {}, tare_frames=TARE_FRAMES)
        prepared = prepare_sensing(inputs)
        cpu = time.process_time()
        summary = run_sensing(prepared.frames, prepared.sensor, inputs.output,
                              prepared.header)
        cpu_s = time.process_time() - cpu
        document = json.loads((inputs.output / "sense.json").read_text())
    errors = compare_with_truth(document, read_truth(recording.with_suffix(".truth.json")))
    totals = np.sum([summary.stage_ms[s] for s in STAGES], axis=0)
    # the first frames learn the colour and settle the FE state: time the steady state, as
    # the interval between frames' results (with the look-ahead, less than a frame's stages)
    steady = np.asarray(summary.interval_ms[2:])
    return {"median_ms": float(np.median(steady)), "p90_ms": float(np.percentile(steady, 90)),
            "stages_ms": float(np.median(totals[2:])),
            "frames": len(totals), "cpu_ms": 1e3 * cpu_s / len(totals),
            "stages": {s: float(np.median(summary.stage_ms[s][2:])) for s in STAGES},
            "write_ms": float(np.median(summary.stage_ms["write"][2:])),
            "relinearizations": prepared.sensor.relinearizations,
            "accuracy": errors.summary()}


# `softforce sense` in a process of its own, which reports its peak resident set (kB) last:
# /proc's VmHWM, since getrusage's ru_maxrss keeps the parent's peak across fork and exec
_PEAK = ("import re, sys\n"
         "from softforce_cli.cli.main import main\n"
         "try:\n    main()\n"
         "finally:\n"
         "    status = open('/proc/self/status').read()\n"
         "    print(re.search(r'VmHWM:\\s*(\\d+)', status).group(1), file=sys.stderr)\n")


def sense_peak_mb(robot: Path, overrides: dict | None = None) -> float:
    """Peak resident memory (MB) of `softforce sense` on the bench recording, run alone in a
    process of its own (this process holds every benchmark's memory)."""
    recording = _recording()
    with tempfile.TemporaryDirectory() as folder:
        settings = Path(folder) / "settings.toml"
        sections: dict[str, list[str]] = {}
        for key, value in (overrides or {}).items():
            section, name = key.split(".")
            sections.setdefault(section, []).append(f"{name} = {json.dumps(value)}")
        settings.write_text("".join(f"[{k}]\n" + "\n".join(v) + "\n"
                                    for k, v in sections.items()))
        run = subprocess.run(
            [sys.executable, "-c", _PEAK, "sense", str(recording), "--robot", str(robot),
             "--calibration", str(_calibration(recording)), "--tare", str(TARE_FRAMES),
             "--settings", str(settings), "-o", str(Path(folder) / "out")],
            capture_output=True, text=True, check=True)
    return int(run.stderr.strip().splitlines()[-1]) / 1024


# (name, robot element, settings overrides): the defaults with either element, and the P1
# robot with a coarser VoxelGrid (neighbour counts scaled to the points per area it keeps),
# the vision stage's main cost lever (docs/sensing_studies.md, "Speed and accuracy at 640x480").
CASES = (
    ("default settings", "p1", {}),
    ("default settings", "p2", {}),
    ("default settings", "p2-rom", {}),
    ("default settings", "p2-shipped", {}),
    ("default settings", "p2-shipped-rom", {}),
    ("voxel 1.8 mm, outlier 10 / contact 1 neighbours", "p1",
     {"vision.voxel_mm": 1.8, "vision.outlier_min_neighbours": 10,
      "vision.contact_min_neighbours": 1}),
)


def run() -> list[BenchRow]:
    rows = []
    for label, element, overrides in CASES:
        result = sense_run(robot_with_element(element), overrides)
        stages = ", ".join(f"{s} {v:.1f}" for s, v in result["stages"].items() if v >= 0.5)
        peak_mb = sense_peak_mb(robot_with_element(element), overrides)
        accuracy = result["accuracy"]

        def percent(value: float | None) -> str:
            return "-" if value is None else f"{100 * value:.0f}%"

        robot = {"p2-shipped": "p2 robot as shipped (diamond_p2.toml), 151 features",
                 "p2-shipped-rom": "p2 robot as shipped (diamond_p2.toml, 151 features) "
                                   "through its reduced model"}.get(
            element, f"{element.replace('-rom', ' reduced')} robot, 51 features")
        rows.append(BenchRow(
            f"sense, whole pipeline 640x480, coarse {robot}, {label}",
            result["median_ms"] * 1e-3, result["frames"] - 2, ">= 30 fps",
            f"{1e3 / result['median_ms']:.0f} fps",
            f"median interval between frames' results (vision of the next frame beside the "
            f"FE of this one); 90th percentile {result['p90_ms']:.0f} ms; one frame's stages "
            f"in sequence {result['stages_ms']:.0f} ms (median); CPU time per frame, both "
            f"threads, {result['cpu_ms']:.0f} ms (mean); "
            f"{result['relinearizations']} "
            f"FE linearisations in {result['frames']} frames; stages (ms): {stages}; write "
            f"{result['write_ms']:.1f} ms; peak RSS of `softforce sense` alone {peak_mb:.0f} MB; "
            f"vs the locking-free truth: {accuracy['located']}/{accuracy['true_contacts']} "
            f"contacts located (median {accuracy['location_error_median_mm']} mm), intensity "
            f"error median {percent(accuracy['intensity_error_median'])}, 90th percentile "
            f"{percent(accuracy['intensity_error_p90'])}, {accuracy['phantoms']} phantoms; "
            "paper: 7 Hz",
        ))
        print(rows[-1], file=sys.stderr)
    return rows
