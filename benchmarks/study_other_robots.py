"""Sensing and diagnosis on robots other than the Diamond: a finger and a trunk.

    python benchmarks/study_other_robots.py [--robot finger|trunk]   # 2-4 minutes each

Every other study senses the Diamond, whose four cables stay taut under its own weight and
which stands on its table. Two other common cable-driven soft robots:

- the finger: a 90 x 24 x 20 mm beam out of a clamped 20 x 40 x 40 mm block, E = 0.6 MPa,
  three antagonistic cables (top, bottom, left), each a straight chord from the block to
  the tip, so that pulling one curls the finger and slackens the others; the table 30 mm
  under the block;
- the trunk: a cylinder of 10 mm radius and 140 mm hanging from a clamped head, E = 0.3
  MPa, three cables at 120 degrees, 7 mm off its axis, each through guides at 5, 40, 80 and
  120 mm; nothing under its tip for 60 mm.

For each: the estimator is P2 on a coarse mesh with the corotational law, the truth P2 on a
finer mesh (another mesh) with the Neo-Hookean law, seen by the virtual D415 at 640x480
with its noise, from where the probes' rods are seen from the side (a probe seen end-on is
not found, docs/vision.md); the camera is calibrated from a markers recording (sigma 0.5
mm) like a user would, and, apart, taken from the truth; each is sensed through its full
model and through its reduced model (`softforce model reduce` with the defaults, trained
once, about a minute); then `softforce diagnose` runs on a clean recording of ramps and
holds on each cable and on one whose truth conceals a 2 mm slack on the first cable.

Writes out/study_other_robots/ROBOT/ (meshes, robot files, scenarios, recordings, outputs,
results.json); docs/sensing_studies.md ("Other robots") and docs/diagnosis.md (Limits)
quote it.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import gmsh
import meshio

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from softforce_cli.calibration.recording_markers import markers_from_recording  # noqa: E402
from softforce_cli.calibration.result import result_to_json  # noqa: E402
from softforce_cli.calibration.robust import calibrate_checked  # noqa: E402
from softforce_cli.diagnosis.run import DiagnoseInputs, run_diagnosis  # noqa: E402
from softforce_cli.estimation.session import run_sensing  # noqa: E402
from softforce_cli.estimation.setup import SenseInputs, prepare_sensing  # noqa: E402
from softforce_cli.estimation.truth_errors import compare_with_truth, pose_from_truth, read_truth  # noqa: E402
from softforce_cli.fem.reduction.rom_file import save_reduction  # noqa: E402
from softforce_cli.fem.reduction.train import train_robot  # noqa: E402
from softforce_cli.model.procedural import solid_mesh  # noqa: E402
from softforce_cli.model.robot import load_robot  # noqa: E402
from softforce_cli.sim.simulate import simulate  # noqa: E402

OUT = ROOT / "out" / "study_other_robots"
TARE_FRAMES = 3
Point = tuple[float, float, float]
# (actuation in mm, frames, probes as (point_mm, force_n))
Frames = list[tuple[tuple[float, ...], int, list[tuple[Point, float]]]]


@dataclass(frozen=True)
class Design:
    """A robot of the study: its solid, meshes, robot file's contents, camera and timelines.

    cables: name -> (path points, distal first; pull point), mm.
    """

    name: str
    build: Callable[[], None]
    estimator_mesh_mm: float
    truth_mesh_mm: float
    young_modulus_mpa: float
    fixed_box_mm: tuple[float, ...]
    cables: dict[str, tuple[list[Point], Point]]
    markers: dict[str, Point]
    camera: str
    probe_frames: Frames
    marker_actuations: list[tuple[tuple[float, ...], int]]


def build_finger() -> None:
    """A 20 x 40 x 40 mm block (clamped) and the 91 x 24 x 20 mm beam out of it along +x,
    its top face at z = 60 mm, in the current gmsh model."""
    occ = gmsh.model.occ
    block = occ.addBox(-20, -20, 30, 20, 40, 40)
    beam = occ.addBox(-1, -12, 40, 91, 24, 20)
    occ.fuse([(3, block)], [(3, beam)])
    occ.synchronize()


def build_trunk() -> None:
    """A cylinder of radius 10 mm from z = 0 to 140 mm under a 30 x 30 x 12 mm head
    (clamped), in the current gmsh model."""
    occ = gmsh.model.occ
    body = occ.addCylinder(0, 0, 0, 0, 0, 140, 10)
    head = occ.addBox(-15, -15, 140, 30, 30, 12)
    occ.fuse([(3, head)], [(3, body)])
    occ.synchronize()


def _trunk_cable(angle_deg: float) -> tuple[list[Point], Point]:
    x = round(7 * math.cos(math.radians(angle_deg)), 3)
    y = round(7 * math.sin(math.radians(angle_deg)), 3)
    return [(x, y, z) for z in (5.0, 40.0, 80.0, 120.0)], (x, y, 148.0)


def _on_trunk(angle_deg: float, z: float) -> Point:
    return (round(10 * math.cos(math.radians(angle_deg)), 3),
            round(10 * math.sin(math.radians(angle_deg)), 3), z)


def _camera(position: Point, look_at: Point, table_z: float) -> str:
    return (f"[camera]\nwidth = 640\nheight = 480\nposition_mm = {list(position)}\n"
            f"look_at_mm = {list(look_at)}\nup_hint = [0.0, 0.0, 1.0]\n\n"
            f"[scene]\ntable_z_mm = {table_z}\n")


DESIGNS = {
    "finger": Design(
        "finger", build_finger, 7.0, 4.0, 0.6, (-21.0, -21.0, 29.0, -8.0, 21.0, 71.0),
        {name: ([(86.0, y, z)], (-15.0, y, z))
         for name, (y, z) in {"top": (0.0, 56.0), "bottom": (0.0, 44.0),
                              "left": (8.0, 50.0)}.items()},
        {"tip_l": (88, 10, 60), "tip_r": (88, -10, 60), "mid_l": (45, 10, 60),
         "mid_r": (45, -10, 60), "side_l": (65, 12, 50), "side_r": (65, -12, 50),
         "base_c": (-10, 0, 70), "base_l": (-10, 15, 70), "base_r": (-18, -15, 70)},
        _camera((60.0, -330.0, 400.0), (40.0, 0.0, 50.0), 0.0),
        [((3, 0, 0), 3, []),
         ((3, 0, 0), 3, [((75, 0, 60), 0.15)]),
         ((3, 0, 0), 3, [((75, 0, 60), 0.3)]),
         ((3, 0, 0), 2, []),
         ((3, 0, 0), 3, [((40, 6, 60), 0.3)]),
         ((0, 0, 4), 2, []),
         ((0, 0, 4), 3, [((85, -6, 60), 0.2)]),
         ((0, 0, 4), 3, [((60, -12, 50), 0.2)]),
         ((2, 0, 2), 2, []),
         ((2, 0, 2), 3, [((80, 0, 60), 0.15), ((30, -5, 60), 0.25)])],
        [((0, 0, 0), 2), ((4, 0, 0), 1), ((0, 3, 0), 1), ((0, 0, 5), 1), ((3, 0, 3), 1)]),
    "trunk": Design(
        "trunk", build_trunk, 6.0, 3.5, 0.3, (-16.0, -16.0, 143.0, 16.0, 16.0, 153.0),
        {name: _trunk_cable(angle) for name, angle in (("a", 90.0), ("b", 210.0),
                                                       ("c", 330.0))},
        {f"m{i}": _on_trunk(angle, z) for i, (angle, z) in enumerate(
            [(270, 20), (270, 60), (270, 100), (0, 40), (180, 80), (315, 130), (225, 10)])},
        # 45 degrees between -y and +x: the probes pushing from -y and from +x are seen from
        # the side (46 degrees off their rods)
        _camera((270.0, -270.0, 160.0), (0.0, 0.0, 70.0), -60.0),
        [((2, 0, 0), 3, []),
         ((2, 0, 0), 3, [((0, -10, 30), 0.05)]),
         ((2, 0, 0), 3, [((0, -10, 30), 0.1)]),
         ((2, 0, 0), 1, []),
         ((2, 0, 0), 3, [((0, -10, 70), 0.15)]),
         ((0, 3, 0), 2, []),
         ((0, 3, 0), 3, [((10, 0, 40), 0.08)]),
         ((0, 3, 0), 3, [((10, 0, 20), 0.06)]),
         ((1, 1, 1), 2, []),
         ((1, 1, 1), 3, [((0, -10, 20), 0.05), ((10, 0, 90), 0.12)])],
        [((0, 0, 0), 2), ((4, 0, 0), 1), ((0, 4, 0), 1), ((0, 0, 4), 1), ((3, 0, 3), 1)]),
}
# diagnose: loading and unloading ramps on each cable, every state held two frames
DIAGNOSE_ACTUATIONS = [(0, 0, 0), (2, 0, 0), (4, 0, 0), (6, 0, 0), (4, 0, 0), (2, 0, 0),
                       (0, 0, 0), (0, 0, 3), (0, 0, 6), (0, 0, 3), (0, 0, 0), (0, 3, 0),
                       (0, 5, 0), (0, 3, 0), (0, 0, 0), (3, 0, 3), (0, 0, 0)]
SLACK_MM = 2.0


def robot_toml(design: Design, mesh_file: str) -> str:
    text = (f'name = "{design.name}"\n\n[mesh]\npath = "{mesh_file}"\nelement = "p2"\n\n'
            f'[material]\nlaw = "corotational"\nyoung_modulus_mpa = {design.young_modulus_mpa}\n'
            "poisson_ratio = 0.45\ndensity_kg_m3 = 1070.0\n"
            "gravity_mm_s2 = [0.0, 0.0, -9810.0]\n\n"
            f"[[fixed]]\nbox_mm = {list(design.fixed_box_mm)}\n")
    for name, (path, pull) in design.cables.items():
        text += (f'\n[[cable]]\nname = "{name}"\npath_mm = {[list(p) for p in path]}\n'
                 f'pull_point_mm = {list(pull)}\ncontrol = "displacement"\n'
                 "min = 0.0\nmax = 10.0\n")
    text += "\n[features]\ncount = 80\n"
    for name, point in design.markers.items():
        text += f'\n[[marker]]\nid = "{name}"\nposition_mm = {[float(v) for v in point]}\n'
    return text


def write_robots(design: Design, folder: Path) -> Path:
    """The estimator's robot file (and the truth's beside it), meshed once."""
    for name, size in (("estimator", design.estimator_mesh_mm),
                       ("truth", design.truth_mesh_mm)):
        mesh = folder / f"{name}.vtu"
        if not mesh.exists():
            nodes, tets = solid_mesh(design.build, size, f"the {design.name}")
            meshio.write(mesh, meshio.Mesh(nodes, [("tetra", tets)]))
        (folder / f"{name}.toml").write_text(robot_toml(design, mesh.name))
    return folder / "estimator.toml"


def reduced_robot(estimator: Path) -> Path:
    """The estimator's robot file through its reduced model, trained once."""
    model = estimator.with_suffix(".rom.npz")
    if not model.exists():
        began = time.perf_counter()
        save_reduction(model, train_robot(load_robot(estimator)))
        print(f"trained {model} in {time.perf_counter() - began:.0f} s", file=sys.stderr)
    robot = estimator.with_name(estimator.stem + "_reduced.toml")
    robot.write_text(estimator.read_text().replace(
        'element = "p2"\n', f'element = "p2"\nreduced = "{model.name}"\n'))
    return robot


def scenario(design: Design, name: str, seed: int, frames: Frames, markers: bool,
             effects: str = "", interval_s: float = 0.0333) -> str:
    text = (f'name = "{design.name}_{name}"\nrobot = "truth.toml"\nlaw = "neo-hookean"\n'
            f"seed = {seed}\nframe_interval_s = {interval_s}\n\n{design.camera}")
    if markers:
        text += "\n[markers]\npublish = true\nsigma_mm = 0.5\n"
    text += effects
    for actuation, repeat, probes in frames:
        text += f"\n[[frame]]\nactuation = {[float(v) for v in actuation]}\nrepeat = {repeat}\n"
        if probes:
            loads = ", ".join(f'{{ kind = "probe", point_mm = {[float(v) for v in point]}, '
                              f"force_n = {force} }}" for point, force in probes)
            text += f"load = [{loads}]\n"
    return text


def recording(folder: Path, name: str, text: str) -> Path:
    """Simulate a scenario once; later runs reuse the recording."""
    path = folder / f"{name}.mcap"
    if not path.exists():
        (folder / f"{name}.toml").write_text(text)
        began = time.perf_counter()
        simulate(folder / f"{name}.toml", path)
        print(f"simulated {path} in {time.perf_counter() - began:.0f} s", file=sys.stderr)
    return path


def sense(probes: Path, robot: Path, calibration: Path, output: Path) -> dict:
    prepared = prepare_sensing(SenseInputs(recording=probes, robot=robot,
                                           calibration=calibration, output=output,
                                           force=True, tare_frames=TARE_FRAMES))
    run_sensing(prepared.frames, prepared.sensor, output, prepared.header, force=True)
    document = json.loads((output / "sense.json").read_text())
    comparison = compare_with_truth(document, read_truth(probes.with_suffix(".truth.json")))
    contacts = [{"frame": p.frame, "true_n": p.true_force_n,
                 "estimated_n": round(p.estimated_force_n, 4),
                 "location_error_mm": round(p.location_error_mm, 2)}
                for p in comparison.paired]
    return {**comparison.summary(), "fps": document["summary"]["frames_per_s"],
            "contacts": contacts}


def diagnose(design: Design, folder: Path, estimator: Path, calibration: Path) -> dict:
    """The verdict, noise floor and first effect of `softforce diagnose` on the clean and
    the slack recordings."""
    first_cable = next(iter(design.cables))
    slack = (f'\n[[effect]]\nname = "cable_slack"\ncable = "{first_cable}"\n'
             f"slack_mm = {SLACK_MM}\n")
    frames: Frames = [(actuation, 2, []) for actuation in DIAGNOSE_ACTUATIONS]
    results = {}
    for seed, (name, effects) in enumerate((("clean", ""), ("slack", slack)), start=21):
        path = recording(folder, f"diagnose_{name}",
                         scenario(design, f"diagnose_{name}", seed, frames, True, effects, 0.5))
        began = time.perf_counter()
        result = run_diagnosis(DiagnoseInputs((path,), estimator, calibration,
                                              folder / f"diagnose_{name}", force=True),
                               lambda *_: None)
        document = json.loads((folder / f"diagnose_{name}" / "diagnosis.json").read_text())
        first = document["effects"][0] if document["effects"] else {}
        results[name] = {
            "verdict": result.verdict, "noise_floor_mm": document["noise_floor_mm"],
            "seconds": round(time.perf_counter() - began, 1), "location": document["location"],
            "first_effect": {key: first.get(key) for key in
                             ("name", "parameters", "heldout_rms_before_mm",
                              "heldout_rms_after_mm")},
            "summary": document["summary"]}
    return results


def study(design: Design) -> dict:
    folder = OUT / design.name
    folder.mkdir(parents=True, exist_ok=True)
    estimator = write_robots(design, folder)
    markers = recording(folder, "markers", scenario(
        design, "markers", 5, [(a, r, []) for a, r in design.marker_actuations], True))
    probes = recording(folder, "probes", scenario(design, "probes", 6, design.probe_frames,
                                                  False))
    calibration = folder / "calibration.json"
    result = calibrate_checked(load_robot(estimator),
                               markers_from_recording(markers, None).markers, source="study")
    calibration.write_text(result_to_json(result))
    pose = folder / "pose_truth.json"
    pose.write_text(json.dumps(pose_from_truth(probes.with_suffix(".truth.json"))))
    reduced = reduced_robot(estimator)
    results = {
        "calibration_rms_mm": result.residual_rms_mm,
        "calibrated": sense(probes, estimator, calibration, folder / "sense_calibrated"),
        "truth_pose": sense(probes, estimator, pose, folder / "sense_truth_pose"),
        "reduced_calibrated": sense(probes, reduced, calibration,
                                    folder / "sense_reduced_calibrated"),
        "reduced_truth_pose": sense(probes, reduced, pose, folder / "sense_reduced_truth_pose"),
        "diagnose": diagnose(design, folder, estimator, calibration)}
    (folder / "results.json").write_text(json.dumps(results, indent=1))
    return results


def report(name: str, results: dict) -> None:
    print(f"== {name}: calibration {results['calibration_rms_mm']:.2f} mm RMS")
    for run in ("calibrated", "truth_pose", "reduced_calibrated", "reduced_truth_pose"):
        print(run, json.dumps({k: v for k, v in results[run].items() if k != "contacts"}))
        for contact in results[run]["contacts"]:
            error = contact["estimated_n"] / contact["true_n"] - 1
            print(f"  frame {contact['frame']:2d}: {contact['true_n']:.2f} N read "
                  f"{contact['estimated_n']:.3f} ({100 * error:+.0f}%), "
                  f"{contact['location_error_mm']:.1f} mm off")
    print("diagnose", json.dumps(results["diagnose"], indent=1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--robot", choices=sorted(DESIGNS), action="append",
                        help="the robot(s) to study (default: all)")
    args = parser.parse_args()
    for name in args.robot or sorted(DESIGNS):
        report(name, study(DESIGNS[name]))


if __name__ == "__main__":
    main()
