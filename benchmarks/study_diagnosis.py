"""The confusion study of `softforce diagnose` (issue 10): every effect concealed in the
truth at two magnitudes and several seeds, a clean control, and a hidden mass outside the
library; each recording diagnosed with the coarse default (P1) robot.

Every case is a 20-frame recording of the same timeline (rest, a loading and unloading ramp
of the north cable, the west and east cables, all four, rest: six distinct inputs, so the
estimator's FE states are solved once for the whole study, through diagnose's cache), made
by `softforce simulate` on the locking-free P2 truth (its own mesh, Neo-Hookean law). The
recordings and the results (out/study_diagnosis/results.jsonl, one line per case) are kept:
a rerun continues where the last stopped. `--table` prints the markdown table of what ran
(docs/diagnosis.md).

    .venv/bin/python benchmarks/study_diagnosis.py [--cases NAME,...] [--seeds 3] [--table]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from softforce_cli.estimation.truth_errors import pose_from_truth

ROOT = Path(__file__).resolve().parents[1]
COARSE = ROOT / "sample_data" / "diamond" / "diamond.toml"
TRUTH_ROBOT = ROOT / "sample_data" / "diamond_truth" / "diamond.toml"
FOLDER = ROOT / "out" / "study_diagnosis"
RESULTS = FOLDER / "results.jsonl"
TIMELINE = (([0, 0, 0, 0], 2), ([3, 0, 0, 0], 2), ([6, 0, 0, 0], 3), ([9, 0, 0, 0], 2),
            ([6, 0, 0, 0], 2), ([3, 0, 0, 0], 2), ([0, 6, 0, 6], 2), ([6, 6, 6, 6], 3),
            ([0, 0, 0, 0], 2))
# case name -> (expected verdict, expected target, [[effect]] TOML body or a load, parameter
# checked, its true value)
CASES: dict[str, tuple] = {
    "clean": ("none", None, "", None, None),
    "slack_west_2": ("cable_slack", "west", 'name = "cable_slack"\ncable = "west"\n'
                     "slack_mm = 2.0", "slack_mm", 2.0),
    "slack_north_4": ("cable_slack", "north", 'name = "cable_slack"\ncable = "north"\n'
                      "slack_mm = 4.0", "slack_mm", 4.0),
    "friction_north_1": ("cable_friction", "north", 'name = "cable_friction"\n'
                         'cable = "north"\nplay_mm = 1.0', "play_mm", 1.0),
    "friction_north_2": ("cable_friction", "north", 'name = "cable_friction"\n'
                         'cable = "north"\nplay_mm = 2.0', "play_mm", 2.0),
    "regional_south_0.5": ("regional_stiffness", "south", 'name = "regional_stiffness"\n'
                           'region = "south"\nscale = 0.5', "scale", 0.5),
    "regional_south_2": ("regional_stiffness", "south", 'name = "regional_stiffness"\n'
                         'region = "south"\nscale = 2.0', "scale", 2.0),
    "gravity_1.3": ("gravity", None, 'name = "gravity"\nscale = 1.3', "scale", 1.3),
    "gravity_tilt_10": ("gravity", None, 'name = "gravity"\ntilt_x_deg = 10.0',
                        "tilt_x_deg", 10.0),
    "stiffness_0.7": ("stiffness_scale", None, 'name = "stiffness_scale"\nscale = 0.7',
                      "scale", 0.7),
    "stiffness_1.5": ("stiffness_scale", None, 'name = "stiffness_scale"\nscale = 1.5',
                      "scale", 1.5),
    "base_5": ("compliant_base", None, 'name = "compliant_base"\nstiffness_n_per_mm = 5.0',
               "stiffness_n_per_mm", 5.0),
    "base_2": ("compliant_base", None, 'name = "compliant_base"\nstiffness_n_per_mm = 2.0',
               "stiffness_n_per_mm", 2.0),
    "creep_0.3": ("viscoelastic_creep", None, 'name = "viscoelastic_creep"\n'
                  "relaxation = 0.3\ntime_constant_s = 0.5", "relaxation", 0.3),
    "depth_bias_0.01": ("depth_bias", None, 'name = "depth_bias"\nscale = 0.01', "scale",
                        0.01),
    "depth_bias_-0.02": ("depth_bias", None, 'name = "depth_bias"\nscale = -0.02', "scale",
                         -0.02),
    "extrinsic_x_3": ("extrinsic_offset", None, 'name = "extrinsic_offset"\n'
                      "translation_x_mm = 3.0", "translation_x_mm", 3.0),
    "extrinsic_rz_1": ("extrinsic_offset", None, 'name = "extrinsic_offset"\n'
                       "rotation_z_deg = 1.0", "rotation_z_deg", 1.0),
    "material_blend": ("material_nonlinearity", None, 'name = "material_nonlinearity"\n'
                       "blend = 1.0", "blend", 1.0),
    "hidden_mass_north": ("unexplained", "north", "load", None, None),
}
# A 40 g mass hidden on the north arm's elbow (outside the library: a regional load).
HIDDEN_LOAD = '[{ kind = "weight", point_mm = [0.0, 97.0, 40.0], force_n = 0.4 }]'


def scenario_text(case: str, seed: int) -> str:
    body = CASES[case][2]
    robot = os.path.relpath(TRUTH_ROBOT, FOLDER)
    # the material case conceals the blend towards the law the estimator lacks: the truth's
    # law is then the estimator's own (corotational) blended fully to Neo-Hookean
    law = "corotational" if case == "material_blend" else "neo-hookean"
    load = f"load = {HIDDEN_LOAD}\n" if body == "load" else ""
    frames = "\n".join(f"[[frame]]\nactuation = {[float(v) for v in a]}\nrepeat = {n}\n{load}"
                       for a, n in TIMELINE)
    effect = f"[[effect]]\n{body}\n\n" if body and body != "load" else ""
    return (f'name = "{case}"\nrobot = "{robot}"\nlaw = "{law}"\nseed = {seed}\n'
            "frame_interval_s = 0.5\n\n[camera]\nwidth = 424\nheight = 240\n\n"
            f"{effect}{frames}")


def softforce(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "softforce_cli", *map(str, args)],
                          capture_output=True, text=True, check=False)


def run_case(case: str, seed: int) -> dict:
    name = f"{case}-s{seed}"
    recording = FOLDER / f"{name}.mcap"
    if not recording.exists():
        scenario = FOLDER / f"{name}.toml"
        scenario.write_text(scenario_text(case, seed))
        made = softforce("simulate", scenario, "-o", recording)
        if made.returncode != 0:
            return {"case": case, "seed": seed, "error": made.stderr.strip()[-300:]}
    pose = FOLDER / "pose.json"
    pose.write_text(json.dumps(pose_from_truth(recording.with_suffix(".truth.json"))))
    output = FOLDER / f"{name}.out"
    shutil.rmtree(output, ignore_errors=True)
    began = time.perf_counter()
    run = softforce("diagnose", recording, "--robot", COARSE, "--calibration", pose, "-o",
                    output, "--cache", FOLDER / "cache")
    elapsed = time.perf_counter() - began
    if run.returncode != 0:
        return {"case": case, "seed": seed, "error": run.stderr.strip()[-300:]}
    document = json.loads((output / "diagnosis.json").read_text())
    expected, target, _, parameter, true_value = CASES[case]
    first = document["effects"][0] if document["effects"] else {}
    fitted = first.get("parameters", {}).get(parameter, {}).get("value") if parameter else None
    return {
        "case": case, "seed": seed, "expected": expected, "verdict": document["verdict"],
        "label": first.get("label") if document["verdict"] not in ("none",) else None,
        "target_ok": (target is None or target in document["location"]["regions"][:1]
                      or target in (first.get("target"),)),
        "parameter": parameter, "true": true_value, "fitted": fitted,
        "heldout_before_mm": first.get("heldout_rms_before_mm"),
        "heldout_after_mm": first.get("heldout_rms_after_mm"),
        "noise_floor_mm": document["noise_floor_mm"],
        "regions": document["location"]["regions"], "seconds": round(elapsed, 1),
    }


def table(rows: list[dict]) -> str:
    lines = ["| case | seed | verdict (expected) | fitted / true | held-out before -> after "
             "(mm) | floor (mm) | location |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['case']} | {r['seed']} | error: {r['error'][-80:]} | | | | |")
            continue
        mark = "ok" if r["verdict"] == r["expected"] else "WRONG"
        value = (f"{r['fitted']:.3g} / {r['true']:.3g}" if r["fitted"] is not None
                 and r["true"] is not None else "-")
        lines.append(f"| {r['case']} | {r['seed']} | {r['verdict']} ({r['expected']}, {mark}) "
                     f"| {value} | {r['heldout_before_mm']} -> {r['heldout_after_mm']} | "
                     f"{r['noise_floor_mm']:.2f} | {', '.join(r['regions']) or '-'} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--cases", help="comma-separated case names (default all)")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--table", action="store_true", help="print the table of what ran")
    args = parser.parse_args()
    FOLDER.mkdir(parents=True, exist_ok=True)
    done = [json.loads(line) for line in RESULTS.read_text().splitlines()] \
        if RESULTS.exists() else []
    if args.table:
        print(table(done))
        return
    cases = args.cases.split(",") if args.cases else list(CASES)
    finished = {(r["case"], r["seed"]) for r in done}
    for seed in range(1, args.seeds + 1):
        for case in cases:
            if (case, seed) in finished:
                continue
            result = run_case(case, seed)
            with RESULTS.open("a") as stream:
                stream.write(json.dumps(result) + "\n")
            print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
