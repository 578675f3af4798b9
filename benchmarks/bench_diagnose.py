"""`softforce diagnose` on a 200-frame recording with the coarse default robot (issue 10).

The recording (made once by `softforce simulate` and kept in out/bench_diagnose/; delete it
to make it again) is a 200-frame, 20 s run at 10 Hz: holds at rest, a loading and unloading
ramp of the west cable (2-8 mm), pulls of the north cable, all four cables together, with a
concealed 1 mm friction play on the west cable, of a Neo-Hookean body diagnosed through the
corotational robot file (the law's sag is a second effect). Rows: the whole command without
the solve cache (every FE state solved) and again with it (a rerun), each once; the verdict
and the selected effects' fitted values are in the result column. Alone, this script prints
the rows:

    .venv/bin/python benchmarks/bench_diagnose.py
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.timing import BenchRow  # noqa: E402
from softforce_cli.estimation.truth_errors import pose_from_truth  # noqa: E402

COARSE = ROOT / "sample_data" / "diamond" / "diamond.toml"
TRUTH_ROBOT = ROOT / "sample_data" / "diamond_truth" / "diamond.toml"
FOLDER = ROOT / "out" / "bench_diagnose"
RECORDING = FOLDER / "bench.mcap"
TARGET_S = 180.0
# (actuation, frames): 200 frames at 10 Hz, nine distinct inputs
TIMELINE = (
    ([0, 0, 0, 0], 16),
    *(([0, w, 0, 0], 14) for w in (2, 4, 6, 8, 6, 4, 2, 0)),
    ([5, 0, 0, 0], 14), ([10, 0, 0, 0], 14),
    ([4, 4, 4, 4], 16), ([5, 0, 5, 0], 14), ([0, 0, 0, 0], 14),
)
PLAY_MM = 1.0


def scenario_text() -> str:
    robot = os.path.relpath(TRUTH_ROBOT, FOLDER)
    frames = "\n".join(f"[[frame]]\nactuation = {[float(v) for v in a]}\nrepeat = {n}\n"
                       for a, n in TIMELINE)
    return (f'name = "bench_diagnose"\nrobot = "{robot}"\nlaw = "neo-hookean"\nseed = 5\n'
            "frame_interval_s = 0.1\n\n[camera]\nwidth = 424\nheight = 240\n\n"
            '[[effect]]\nname = "cable_friction"\ncable = "west"\n'
            f"play_mm = {PLAY_MM}\n\n{frames}")


def softforce(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "softforce_cli", *map(str, args)],
                          capture_output=True, text=True, check=False)


def make_recording() -> None:
    if RECORDING.exists():
        return
    FOLDER.mkdir(parents=True, exist_ok=True)
    scenario = FOLDER / "bench.toml"
    scenario.write_text(scenario_text())
    made = softforce("simulate", scenario, "-o", RECORDING)
    if made.returncode != 0:
        raise RuntimeError(made.stderr)


def calibration() -> Path:
    path = FOLDER / "pose.json"
    path.write_text(json.dumps(pose_from_truth(RECORDING.with_suffix(".truth.json"))))
    return path


def diagnose(cache: list[str]) -> tuple[float, dict]:
    output = FOLDER / "out"
    shutil.rmtree(output, ignore_errors=True)
    began = time.perf_counter()
    run = softforce("diagnose", RECORDING, "--robot", COARSE, "--calibration", calibration(),
                    "-o", output, *cache)
    elapsed = time.perf_counter() - began
    if run.returncode != 0:
        raise RuntimeError(run.stderr)
    return elapsed, json.loads((output / "diagnosis.json").read_text())


def _effect(entry: dict) -> str:
    values = ", ".join(f"{k} {v['value']:.2f}" for k, v in entry["parameters"].items())
    mode = entry["evidence"]["mode"].split()[0]  # "relative" or "absolute"
    return (f"{entry['label']}: {values}, {mode} held-out "
            f"{entry['heldout_rms_before_mm']:.2f} -> {entry['heldout_rms_after_mm']:.2f} mm")


def _result(document: dict) -> str:
    selected = [e for e in document["effects"] if e["evidence"]["selected"]]
    return f"{document['verdict']} ({'; then '.join(map(_effect, selected))})"


def run() -> list[BenchRow]:
    make_recording()
    cache = FOLDER / "cache"
    shutil.rmtree(cache, ignore_errors=True)
    cold, document = diagnose(["--cache", cache])
    warm, again = diagnose(["--cache", cache])
    evidence = document["evidence"]
    notes = (f"{evidence['frames']} frames, {evidence['states']} states, P1 robot predicted "
             f"with P2 on its mesh; concealed west play {PLAY_MM} mm; the body Neo-Hookean, "
             "the robot file corotational (the law: a second effect)")
    return [
        BenchRow("diagnose 200 frames, coarse robot, no cache", cold, 1, f"< {TARGET_S:.0f} s",
                 f"{cold:.0f} s: {_result(document)}", notes),
        BenchRow("diagnose 200 frames, coarse robot, cached solves", warm, 1, "",
                 f"{warm:.0f} s: {_result(again)}", "a rerun: every state from the cache"),
    ]


if __name__ == "__main__":
    for row in run():
        print(f"{row.name}: {row.median_s:.1f} s ({row.result}; {row.notes})")
