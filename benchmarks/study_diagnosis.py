"""The confusion study of `softforce diagnose` (issue 10): every effect concealed in the
truth at two magnitudes and several seeds, a clean control, and a hidden mass outside the
library; each recording diagnosed with the coarse (P1) robot file, its law the truth's.

Every case is a 20-frame recording of the same timeline (rest, a loading and unloading ramp
of the north cable, the west and east cables, all four, rest: six distinct inputs, so the
estimator's FE states are solved once for the whole study, through diagnose's cache), made
by `softforce simulate` on the locking-free P2 truth (its own mesh, Neo-Hookean law). The
recordings and the results (out/study_diagnosis/results.jsonl, one line per case) are kept:
a rerun continues where the last stopped. `--table` prints the markdown table of what ran
(docs/diagnosis.md; every run: docs/diagnosis_history.md).

    .venv/bin/python benchmarks/study_diagnosis.py [--cases NAME,...] [--seeds 3]
        [--first-seed 1] [--redo] [--recordings-only] [--table] [--markers] [--self]
        [--converged [--finer-estimator]] [--other-timeline] [--camera WxH]

--markers: the recordings publish the robot's nine markers too (/markers, 0.5 mm noise), as
a setup calibrated from markers would; their cases are kept as NAME+markers. The sensor's
images are the same as without (simulate draws the markers' noise either way).

--self: the truth is the estimator's own model (the coarse mesh with quadratic elements and
the robot file's law) instead of the locking-free body on another mesh, cases NAME+self:
what goes wrong there is the method's, not the mesh's.

--converged: the truth is closer to the mesh-converged body than the 6.5 mm P2 one: the
P2-P0 element on the 4.8 mm mesh (sample_data/diamond_fine, docs/locking.md's reference,
sagging 14.55 mm under gravity where the 6.5 mm P2 body sags 13.18 and the coarse P2 model
12.84, corotational), cases NAME+converged.

--other-timeline: the cases on a second timeline the method was not tuned on (the south and
east cables ramped, then pairs of cables: OTHER_TIMELINE) seen by a 640x480 camera, cases
NAME+t2: what a user's recording, which no one here chose, asks of it.

--camera WxH: the recordings seen by a camera of that size instead of the timeline's
(424x240, or 640x480 with --other-timeline), cases NAME+camWxH (after +t2): the converged
body's clean recording at 640x480 and 1280x720 (docs/diagnosis.md, "Limits").

--finer-estimator (with --converged only): diagnose with a copy of the 6.5 mm mesh's robot
file (sample_data/diamond_truth, P2, 8,674 tets) instead of the coarse one, cases
NAME+converged+finer: how much of what the coarse estimator misses is its mesh's. Without
--converged the truth would be on the estimator's own mesh, so the option is refused.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

from softforce_cli.estimation.truth_errors import pose_from_truth
from softforce_cli.io.atomic import atomic_write_text
from softforce_cli.sim.simulate import truth_path_for

ROOT = Path(__file__).resolve().parents[1]
COARSE = ROOT / "sample_data" / "diamond" / "diamond.toml"
TRUTH_ROBOT = ROOT / "sample_data" / "diamond_truth" / "diamond.toml"
FINE = ROOT / "sample_data" / "diamond_fine" / "diamond.toml"
FOLDER = ROOT / "out" / "study_diagnosis"
RESULTS = FOLDER / "results.jsonl"
TIMELINE = (([0, 0, 0, 0], 2), ([3, 0, 0, 0], 2), ([6, 0, 0, 0], 3), ([9, 0, 0, 0], 2),
            ([6, 0, 0, 0], 2), ([3, 0, 0, 0], 2), ([0, 6, 0, 6], 2), ([6, 6, 6, 6], 3),
            ([0, 0, 0, 0], 2))
# The second timeline (--other-timeline) and its camera: 22 frames, nine distinct inputs.
OTHER_TIMELINE = (([0, 0, 0, 0], 2), ([0, 0, 4, 0], 2), ([0, 0, 8, 0], 3), ([0, 0, 4, 0], 2),
                  ([0, 0, 0, 5], 2), ([0, 0, 0, 9], 2), ([0, 0, 0, 5], 2), ([5, 5, 0, 0], 2),
                  ([2, 7, 7, 2], 3), ([0, 0, 0, 0], 2))
OTHER_CAMERA = (640, 480)
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
    # an arm its own cable pulls in OTHER_TIMELINE (the east one)
    "regional_east_0.6": ("regional_stiffness", "east", 'name = "regional_stiffness"\n'
                          'region = "east"\nscale = 0.6', "scale", 0.6),
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
    # a drift the body holds on both timelines: creep_0.5's truth tips over in frame 6
    # (docs/diagnosis.md, limits), and creep_0.3's softest frame is 4-6% above that fold
    "creep_0.2": ("viscoelastic_creep", None, 'name = "viscoelastic_creep"\n'
                  "relaxation = 0.2\ntime_constant_s = 0.5", "relaxation", 0.2),
    "creep_0.3": ("viscoelastic_creep", None, 'name = "viscoelastic_creep"\n'
                  "relaxation = 0.3\ntime_constant_s = 0.5", "relaxation", 0.3),
    "creep_0.5": ("viscoelastic_creep", None, 'name = "viscoelastic_creep"\n'
                  "relaxation = 0.5\ntime_constant_s = 0.5", "relaxation", 0.5),
    "depth_bias_0.01": ("depth_bias", None, 'name = "depth_bias"\nscale = 0.01', "scale",
                        0.01),
    "depth_bias_-0.02": ("depth_bias", None, 'name = "depth_bias"\nscale = -0.02', "scale",
                         -0.02),
    "extrinsic_x_3": ("extrinsic_offset", None, 'name = "extrinsic_offset"\n'
                      "translation_x_mm = 3.0", "translation_x_mm", 3.0),
    "extrinsic_rz_1": ("extrinsic_offset", None, 'name = "extrinsic_offset"\n'
                       "rotation_z_deg = 1.0", "rotation_z_deg", 1.0),
    # the truth's Neo-Hookean law against a robot file of another law (LAW_OF_ROBOT)
    "material_linear": ("material_nonlinearity", None, "", "blend", 1.0),
    "material_corotational": ("material_nonlinearity", None, "", "blend", 1.0),
    # a plate the lower arms rest on, the base block through a hole in it
    "support_-10": ("support_contact", None, 'name = "support_contact"\ntable_z_mm = -10.0',
                    "table_z_mm", -10.0),
    "support_-5.5": ("support_contact", None, 'name = "support_contact"\ntable_z_mm = -5.5',
                     "table_z_mm", -5.5),
    "hidden_mass_north": ("unexplained", "north", "load", None, None),
}
# The law of the study's bodies, and of the robot file diagnose is given (a copy of COARSE):
# a clean recording then differs from its model by the mesh alone. The material cases,
# {case: the robot file's law}, diagnose the clean case's recordings with another law (the
# default corotational one sags 0.6 mm more under gravity than the Neo-Hookean body:
# docs/diagnosis_history.md, tenth run); a blend concealed in the truth instead would make the truth
# the clean case's.
TRUTH_LAW = "neo-hookean"
COARSE_LAW = '[material]\nlaw = "corotational"'  # what the copies of COARSE replace
LAW_OF_ROBOT = {"material_linear": "linear", "material_corotational": "corotational"}
# A 40 g mass hidden on the north arm's elbow (outside the library: a regional load).
HIDDEN_LOAD = '[{ kind = "weight", point_mm = [0.0, 97.0, 40.0], force_n = 0.4 }]'
# A case diagnosed on recordings that publish markers is named with this suffix.
MARKED = "+markers"
# A case whose truth is the estimator's own model (the coarse mesh with quadratic elements
# and the robot file's law: no discretisation gap, camera noise only) is named with this
# suffix: what is wrong there is the method's, not the mesh's.
SELF = "+self"
# A case whose truth is the converged body (P2-P0 on the 4.8 mm mesh) is named with this
# suffix.
CONVERGED = "+converged"
# A case diagnosed with the 6.5 mm mesh's robot file (TRUTH_ROBOT) instead of COARSE is
# named with this suffix (after CONVERGED: its truth must be on another mesh).
FINER = "+finer"
# A case on OTHER_TIMELINE and OTHER_CAMERA is named with this suffix (right after the
# library's name: the others follow it).
OTHER = "+t2"
# A case seen by another camera than its timeline's (--camera WxH) carries "+camWxH" right
# after the library's name and OTHER.
CAMERA = re.compile(r"\+cam(\d+)x(\d+)")
MARKERS_TOML = "[markers]\npublish = true\nsigma_mm = 0.5\n\n"


def plain_case(case: str) -> str:
    """The library's case a study case is a variant of (without its suffixes)."""
    case = CAMERA.sub("", case)
    return (case.removesuffix(FINER).removesuffix(CONVERGED).removesuffix(SELF)
            .removesuffix(MARKED).removesuffix(OTHER))


def timeline(case: str) -> tuple:
    """The (actuation, frames) of a case's recording."""
    return OTHER_TIMELINE if plain_case(case) + OTHER in case else TIMELINE


def frame_count(case: str) -> int:
    return sum(repeat for _, repeat in timeline(case))


def camera_size(case: str) -> tuple[int, int]:
    """(width, height) of a case's camera: --camera's, else its timeline's."""
    if (size := CAMERA.search(case)) is not None:
        return int(size[1]), int(size[2])
    return OTHER_CAMERA if timeline(case) is OTHER_TIMELINE else (424, 240)


def coarse_variant(name: str, old: str, new: str, source: Path = COARSE) -> Path:
    """A copy of `source` (COARSE) in FOLDER with `old` replaced by `new` (its mesh path made
    absolute)."""
    text = source.read_text()
    if old not in text:
        raise SystemExit(f"{source} no longer has {old}; update the study's copy")
    mesh = re.search(r'^path = "(.*)"$', text, re.MULTILINE)
    path = FOLDER / name
    path.write_text(text.replace(old, new).replace(
        mesh.group(0), f'path = "{(source.parent / mesh.group(1)).resolve()}"'))
    return path


def converged_robot() -> Path:
    """The converged truth's robot file: FINE with the P2-P0 element."""
    return coarse_variant("diamond_converged.toml", "[material]",
                          'element = "p2-p0"\n\n[material]', FINE)


def self_robot() -> Path:
    """The study's robot file with quadratic elements: the model diagnose predicts with."""
    return coarse_variant(f"diamond_self_{TRUTH_LAW}.toml", COARSE_LAW,
                          f'element = "p2"\n\n[material]\nlaw = "{TRUTH_LAW}"')


def scenario_text(case: str, seed: int) -> str:
    body = CASES[plain_case(case)][2]
    truth = (self_robot() if case.endswith(SELF) else
             converged_robot() if case.endswith(CONVERGED) else TRUTH_ROBOT)
    robot = os.path.relpath(truth, FOLDER)
    law = "" if case.endswith(SELF) else f'law = "{TRUTH_LAW}"\n'
    load = f"load = {HIDDEN_LOAD}\n" if body == "load" else ""
    frames = "\n".join(f"[[frame]]\nactuation = {[float(v) for v in a]}\nrepeat = {n}\n{load}"
                       for a, n in timeline(case))
    effect = f"[[effect]]\n{body}\n\n" if body and body != "load" else ""
    width, height = camera_size(case)
    return (f'name = "{case}"\nrobot = "{robot}"\n{law}seed = {seed}\n'
            f"frame_interval_s = 0.5\n\n[camera]\nwidth = {width}\nheight = {height}\n\n"
            f"{MARKERS_TOML if MARKED in case else ''}{effect}{frames}")


def softforce(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "softforce_cli", *map(str, args)],
                          capture_output=True, text=True, check=False)


def recorded_frames(recording: Path) -> int:
    """Frames a study recording holds, from its truth file (0 when there is none)."""
    truth = truth_path_for(recording)
    return len(json.loads(truth.read_text())["frames"]) if truth.exists() else 0


def make_recording(case: str, seed: int, recording: Path) -> str | None:
    """Simulate a case's recording under a temporary name and rename it only when complete.

    `simulate` keeps the frames done when it is interrupted (a 3-frame recording once stood
    for a 20-frame case), so a recording is taken only with all the timeline's frames;
    returns an error line or None.
    """
    scenario = recording.with_suffix(".toml")
    scenario.write_text(scenario_text(case, seed))
    # this process's own name: two studies run at once never write into one file
    partial = recording.with_name(f"{recording.stem}.partial-{os.getpid()}.mcap")
    made = softforce("simulate", scenario, "-o", partial, "--force")
    if made.returncode != 0:
        return made.stderr.strip()[-300:]
    if (frames := recorded_frames(partial)) != frame_count(case):
        return f"simulate wrote {frames} of {frame_count(case)} frames"
    # the truth file first: a recording without its truth is remade, never read
    truth_path_for(partial).replace(truth_path_for(recording))
    partial.replace(recording)
    return None


def ensure_recording(case: str, seed: int, recording: Path) -> str | None:
    """Make the case's recording unless a complete one of the same scenario exists; an error
    line or None."""
    scenario = recording.with_suffix(".toml")
    if (recording.exists() and recorded_frames(recording) == frame_count(case)
            and scenario.exists()
            and scenario.read_text() == scenario_text(case, seed)):
        return None
    return make_recording(case, seed, recording)


def recorded_case(case: str) -> str:
    """The case whose recording a case reads: a case with its own robot file has the clean
    case's truth."""
    plain = plain_case(case)
    return ("clean" if plain in LAW_OF_ROBOT else plain) + case[len(plain):].removesuffix(FINER)


def robot_file(case: str) -> Path:
    """The robot file a case is diagnosed with: a copy of COARSE (of TRUTH_ROBOT for a
    FINER case) with the truth's law, or with another law for the material cases."""
    law = LAW_OF_ROBOT.get(plain_case(case), TRUTH_LAW)
    finer = case.endswith(FINER)
    return coarse_variant(f"diamond_{law}{'_6.5mm' if finer else ''}.toml", COARSE_LAW,
                          f'[material]\nlaw = "{law}"', TRUTH_ROBOT if finer else COARSE)


def run_case(case: str, seed: int) -> dict:
    name = f"{case}-s{seed}"
    recording = FOLDER / f"{recorded_case(case)}-s{seed}.mcap"
    if (error := ensure_recording(recorded_case(case), seed, recording)) is not None:
        return {"case": case, "seed": seed, "error": error}
    pose = FOLDER / "pose.json"
    pose.write_text(json.dumps(pose_from_truth(truth_path_for(recording))))
    # frames the truth reached by snapping through (docs/scenarios.md): not a smooth motion
    snaps = [frame["index"] for frame in json.loads(truth_path_for(recording).read_text())["frames"]
             if "snap_through_mm" in frame]
    output = FOLDER / f"{name}.out"
    shutil.rmtree(output, ignore_errors=True)
    began = time.perf_counter()
    run = softforce("diagnose", recording, "--robot", robot_file(case), "--calibration", pose, "-o",
                    output, "--cache", FOLDER / "cache")
    elapsed = time.perf_counter() - began
    if run.returncode != 0:
        return {"case": case, "seed": seed, "error": run.stderr.strip()[-300:]}
    document = json.loads((output / "diagnosis.json").read_text())
    expected, target, _, parameter, true_value = CASES[plain_case(case)]
    first = document["effects"][0] if document["effects"] else {}
    fitted_parameter = first.get("parameters", {}).get(parameter, {}) if parameter else {}
    return {
        "case": case, "seed": seed, "expected": expected, "verdict": document["verdict"],
        "label": first.get("label") if document["verdict"] not in ("none",) else None,
        "target_ok": (target is None or target in document["location"]["regions"][:1]
                      or target in (first.get("target"),)),
        "parameter": parameter, "true": true_value, "fitted": fitted_parameter.get("value"),
        "ci95": fitted_parameter.get("ci95"),
        "heldout_before_mm": first.get("heldout_rms_before_mm"),
        "heldout_after_mm": first.get("heldout_rms_after_mm"),
        # the floor of the residuals the first effect was judged on (the markers' for a
        # camera effect only they see)
        "noise_floor_mm": (document["evidence"]["markers"]["noise_floor_mm"]
                           if first.get("evidence", {}).get("channel") == "markers"
                           else document["noise_floor_mm"]),
        "channel": first.get("evidence", {}).get("channel", "clouds"),
        "regions": document["location"]["regions"], "seconds": round(elapsed, 1),
        "groups": document["indistinguishable_groups"], "truth_snaps": snaps,
    }


def table(rows: list[dict]) -> str:
    lines = ["| case | seed | verdict (expected) | fitted [95% interval] / true | held-out "
             "before -> after (mm) | floor (mm) | location |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['case']} | {r['seed']} | error: {r['error'][-80:]} | | | | |")
            continue
        # a group the data cannot tell apart names each of its effects (g / E)
        grouped = {label.split("[")[0] for group in r.get("groups", []) for label in group
                   if r["label"] in group}
        mark = "ok" if r["expected"] in {r["verdict"], *grouped} else "WRONG"
        # the fitted value of the expected effect on the expected target only (another
        # effect's or another region's "scale" is not it)
        named = (r["label"] or "").split("[")[0] == r["expected"] and r["target_ok"]
        interval = (f" [{r['ci95'][0]:.3g}, {r['ci95'][1]:.3g}]" if r.get("ci95") is not None
                    else "")
        value = (f"{r['fitted']:.3g}{interval} / {r['true']:.3g}" if named
                 and r["fitted"] is not None and r["true"] is not None else "-")
        snapped = (f", the truth snaps through at frame {', '.join(map(str, r['truth_snaps']))}"
                   if r.get("truth_snaps") else "")
        lines.append(f"| {r['case']} | {r['seed']} | {r['verdict']} ({r['expected']}, {mark}"
                     f"{snapped}) "
                     f"| {value} | {r['heldout_before_mm']} -> {r['heldout_after_mm']} | "
                     f"{r['noise_floor_mm']:.2f} | {', '.join(r['regions']) or '-'} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--cases", help="comma-separated case names (default all)")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--first-seed", type=int, default=1,
                        help="start at this seed (seeds FIRST..SEEDS)")
    parser.add_argument("--redo", action="store_true",
                        help="diagnose the chosen cases again (their recordings are kept)")
    parser.add_argument("--recordings-only", action="store_true",
                        help="only simulate the missing recordings (the long part), one by one")
    parser.add_argument("--table", action="store_true", help="print the table of what ran")
    parser.add_argument("--markers", action="store_true",
                        help="recordings with the markers published (cases NAME+markers)")
    parser.add_argument("--self", action="store_true", dest="own_model",
                        help="the truth is the estimator's own model (cases NAME+self)")
    parser.add_argument("--converged", action="store_true",
                        help="the truth is P2-P0 on the 4.8 mm mesh (cases NAME+converged)")
    parser.add_argument("--other-timeline", action="store_true",
                        help="the second timeline and a 640x480 camera (cases NAME+t2)")
    parser.add_argument("--camera", metavar="WxH",
                        help="another camera size than the timeline's (cases NAME+camWxH)")
    parser.add_argument("--finer-estimator", action="store_true",
                        help="with --converged: diagnose with the 6.5 mm mesh's robot file "
                        "(cases NAME+converged+finer)")
    args = parser.parse_args()
    if args.finer_estimator and not args.converged:
        parser.error("--finer-estimator needs --converged: the default truth is on the "
                     "6.5 mm mesh itself")
    FOLDER.mkdir(parents=True, exist_ok=True)
    rows = read_results()
    if args.table:
        print(table([rows[key] for key in sorted(rows, key=_order)]))
        return
    cases = args.cases.split(",") if args.cases else list(CASES)
    if unknown := [c for c in cases if c not in CASES]:
        raise SystemExit(f"unknown case(s): {', '.join(unknown)}")
    if args.other_timeline:
        cases = [c + OTHER for c in cases]
    if args.camera:
        if (size := re.fullmatch(r"(\d+)x(\d+)", args.camera)) is None:
            parser.error(f"--camera {args.camera}: expected WIDTHxHEIGHT, e.g. 640x480")
        cases = [f"{c}+cam{size[1]}x{size[2]}" for c in cases]
    if args.markers:
        cases = [c + MARKED for c in cases]
    if args.own_model:
        cases = [c + SELF for c in cases]
    if args.converged:
        cases = [c + CONVERGED for c in cases]
    if args.finer_estimator:
        cases = [c + FINER for c in cases]
    for seed in range(args.first_seed, args.seeds + 1):
        for case in cases:
            if args.recordings_only:
                recorded = recorded_case(case)
                error = ensure_recording(recorded, seed, FOLDER / f"{recorded}-s{seed}.mcap")
                print(f"{case}-s{seed}: {error or 'recorded'}", flush=True)
                continue
            if (case, seed) in rows and "error" not in rows[case, seed] and not args.redo:
                continue
            row = run_case(case, seed)
            # read again: another study may have added rows in the minutes this case took
            rows = read_results() | {(case, seed): row}
            atomic_write_text(RESULTS, "".join(json.dumps(r) + "\n" for r in rows.values()),
                              force=True)
            print(json.dumps(row), flush=True)


def read_results() -> dict[tuple[str, int], dict]:
    """One row per (case, seed), the latest; a case that failed is tried again."""
    if not RESULTS.exists():
        return {}
    return {(r["case"], r["seed"]): r for r in map(json.loads, RESULTS.read_text().splitlines())}


def _order(key: tuple[str, int]) -> tuple[int, int]:
    """Table order: by seed, then as the cases are listed."""
    case, seed = key
    plain = plain_case(case)
    order = list(CASES).index(plain) if plain in CASES else len(CASES)
    return seed, 2 * order + (plain != case)


if __name__ == "__main__":
    main()
