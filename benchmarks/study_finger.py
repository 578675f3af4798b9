"""Sensing on another robot than the Diamond: a cable-driven finger.

    python benchmarks/study_finger.py    # about 1-2 minutes on 2 cores

Every other study senses the Diamond, whose four cables stay taut under its own weight. A
finger is the other common cable-driven soft robot: a 90 x 24 x 20 mm beam out of a clamped
block, with three antagonistic cables (top, bottom, left), each a straight chord from the
block to the tip, so that pulling one curls the finger and slackens the others. E = 0.6 MPa,
nu = 0.45, its own weight.

- the estimator: P2 on a 7 mm mesh (486 nodes, 1,512 tetrahedra), corotational;
- the truth: P2 on a 4 mm mesh (1,623 nodes, 6,179 tetrahedra), Neo-Hookean, seen by the
  virtual D415 (640x480, noise) from the side and above (the camera straight above sees a
  probe pressing the top face end-on, and not at all: docs/vision.md);
- calibrated from a markers recording (nine markers, sigma 0.5 mm) like a user would, and
  sensed with that calibration and, apart, with the truth's camera pose;
- probes of 0.15-0.3 N on the top face, one on the side face, two at once, at three
  actuations;
- through the estimator's full model and through its reduced model (`softforce model
  reduce` with the defaults, trained once, about a minute);
- `softforce diagnose` on two recordings of ramps and holds on each cable (17 states, each
  held two frames, markers published): a clean one, and one whose truth conceals a 2 mm
  slack on the top cable.

Writes out/study_finger/ (meshes, robot files, scenarios, recordings, sense outputs,
results.json); docs/sensing_studies.md ("Another robot: a finger") quotes it.
"""

from __future__ import annotations

import json
import sys
import time
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

OUT = ROOT / "out" / "study_finger"
ESTIMATOR_MESH_MM = 7.0
TRUTH_MESH_MM = 4.0
TARE_FRAMES = 3
CABLES = {"top": (0.0, 56.0), "bottom": (0.0, 44.0), "left": (8.0, 50.0)}  # (y, z) mm
MARKERS = {"tip_l": (88, 10, 60), "tip_r": (88, -10, 60), "mid_l": (45, 10, 60),
           "mid_r": (45, -10, 60), "side_l": (65, 12, 50), "side_r": (65, -12, 50),
           "base_c": (-10, 0, 70), "base_l": (-10, 15, 70), "base_r": (-18, -15, 70)}
CAMERA = """[camera]
width = 640
height = 480
position_mm = [60.0, -330.0, 400.0]
look_at_mm = [40.0, 0.0, 50.0]
up_hint = [0.0, 0.0, 1.0]

[scene]
table_z_mm = 0.0
"""
# (actuation top, bottom, left in mm, frames, probes as (point_mm, force_n))
PROBE_FRAMES = [
    ((3, 0, 0), 3, []),
    ((3, 0, 0), 3, [((75, 0, 60), 0.15)]),
    ((3, 0, 0), 3, [((75, 0, 60), 0.3)]),
    ((3, 0, 0), 2, []),
    ((3, 0, 0), 3, [((40, 6, 60), 0.3)]),
    ((0, 0, 4), 2, []),
    ((0, 0, 4), 3, [((85, -6, 60), 0.2)]),
    ((0, 0, 4), 3, [((60, -12, 50), 0.2)]),
    ((2, 0, 2), 2, []),
    ((2, 0, 2), 3, [((80, 0, 60), 0.15), ((30, -5, 60), 0.25)]),
]
MARKER_ACTUATIONS = [((0, 0, 0), 2), ((4, 0, 0), 1), ((0, 3, 0), 1), ((0, 0, 5), 1),
                     ((3, 0, 3), 1)]
# diagnose: loading and unloading ramps on each cable, every state held two frames
DIAGNOSE_ACTUATIONS = [(0, 0, 0), (2, 0, 0), (4, 0, 0), (6, 0, 0), (4, 0, 0), (2, 0, 0),
                       (0, 0, 0), (0, 0, 3), (0, 0, 6), (0, 0, 3), (0, 0, 0), (0, 3, 0),
                       (0, 5, 0), (0, 3, 0), (0, 0, 0), (3, 0, 3), (0, 0, 0)]
SLACK = '\n[[effect]]\nname = "cable_slack"\ncable = "top"\nslack_mm = 2.0\n'


def build_finger() -> None:
    """The finger's solid in the current gmsh model: a 20 x 40 x 40 mm block (clamped) and
    the 91 x 24 x 20 mm beam out of it along +x, its top face at z = 60 mm."""
    occ = gmsh.model.occ
    block = occ.addBox(-20, -20, 30, 20, 40, 40)
    beam = occ.addBox(-1, -12, 40, 91, 24, 20)
    occ.fuse([(3, block)], [(3, beam)])
    occ.synchronize()


def robot_toml(mesh_file: str) -> str:
    text = f"""name = "finger"

[mesh]
path = "{mesh_file}"
element = "p2"

[material]
law = "corotational"
young_modulus_mpa = 0.6
poisson_ratio = 0.45
density_kg_m3 = 1070.0
gravity_mm_s2 = [0.0, 0.0, -9810.0]

[[fixed]]
box_mm = [-21.0, -21.0, 29.0, -8.0, 21.0, 71.0]
"""
    for name, (y, z) in CABLES.items():
        text += (f'\n[[cable]]\nname = "{name}"\npath_mm = [[86.0, {y}, {z}]]\n'
                 f'pull_point_mm = [-15.0, {y}, {z}]\ncontrol = "displacement"\n'
                 "min = 0.0\nmax = 10.0\n")
    text += "\n[features]\ncount = 80\n"
    for name, point in MARKERS.items():
        text += f'\n[[marker]]\nid = "{name}"\nposition_mm = {[float(v) for v in point]}\n'
    return text


def write_robots() -> tuple[Path, Path]:
    """(estimator, truth) robot files, meshed once."""
    OUT.mkdir(parents=True, exist_ok=True)
    files = []
    for name, size in (("finger_p2", ESTIMATOR_MESH_MM), ("finger_truth", TRUTH_MESH_MM)):
        mesh = OUT / f"{name}.vtu"
        if not mesh.exists():
            nodes, tets = solid_mesh(build_finger, size, "the finger")
            meshio.write(mesh, meshio.Mesh(nodes, [("tetra", tets)]))
        robot = OUT / f"{name}.toml"
        robot.write_text(robot_toml(mesh.name))
        files.append(robot)
    return files[0], files[1]


def reduced_robot(estimator: Path) -> Path:
    """The estimator's robot file through its reduced model, trained once."""
    model = estimator.with_suffix(".rom.npz")
    if not model.exists():
        began = time.perf_counter()
        save_reduction(model, train_robot(load_robot(estimator)))
        print(f"trained {model.name} in {time.perf_counter() - began:.0f} s", file=sys.stderr)
    robot = estimator.with_name(estimator.stem + "_reduced.toml")
    robot.write_text(estimator.read_text().replace(
        'element = "p2"\n', f'element = "p2"\nreduced = "{model.name}"\n'))
    return robot


def scenario(name: str, seed: int, frames: list, markers: bool, effects: str = "",
             interval_s: float = 0.0333) -> str:
    text = (f'name = "{name}"\nrobot = "finger_truth.toml"\nlaw = "neo-hookean"\n'
            f"seed = {seed}\nframe_interval_s = {interval_s}\n\n{CAMERA}")
    if markers:
        text += "\n[markers]\npublish = true\nsigma_mm = 0.5\n"
    text += effects
    for actuation, repeat, *probes in frames:
        text += f"\n[[frame]]\nactuation = {[float(v) for v in actuation]}\nrepeat = {repeat}\n"
        if probes and probes[0]:
            loads = ", ".join(f'{{ kind = "probe", point_mm = {[float(v) for v in point]}, '
                              f"force_n = {force} }}" for point, force in probes[0])
            text += f"load = [{loads}]\n"
    return text


def recording(name: str, text: str) -> Path:
    """Simulate a scenario once; later runs reuse the recording."""
    path = OUT / f"{name}.mcap"
    if not path.exists():
        (OUT / f"{name}.toml").write_text(text)
        began = time.perf_counter()
        simulate(OUT / f"{name}.toml", path)
        print(f"simulated {name} in {time.perf_counter() - began:.0f} s", file=sys.stderr)
    return path


def sense(probes: Path, robot: Path, calibration: Path, name: str) -> dict:
    folder = OUT / name
    prepared = prepare_sensing(SenseInputs(recording=probes, robot=robot,
                                           calibration=calibration, output=folder,
                                           force=True, tare_frames=TARE_FRAMES))
    run_sensing(prepared.frames, prepared.sensor, folder, prepared.header, force=True)
    document = json.loads((folder / "sense.json").read_text())
    comparison = compare_with_truth(document, read_truth(probes.with_suffix(".truth.json")))
    contacts = [{"frame": p.frame, "true_n": p.true_force_n,
                 "estimated_n": round(p.estimated_force_n, 4),
                 "location_error_mm": round(p.location_error_mm, 2)}
                for p in comparison.paired]
    return {**comparison.summary(), "fps": document["summary"]["frames_per_s"],
            "contacts": contacts}


def diagnose(estimator: Path, calibration: Path) -> dict:
    """The verdict, noise floor and first effect of `softforce diagnose` on the clean and
    the slack recordings."""
    results = {}
    frames = [(a, 2, []) for a in DIAGNOSE_ACTUATIONS]
    for seed, (name, effects) in enumerate((("clean", ""), ("slack", SLACK)), start=21):
        path = recording(f"diagnose_{name}", scenario(f"finger_diagnose_{name}", seed, frames,
                                                      True, effects, interval_s=0.5))
        began = time.perf_counter()
        result = run_diagnosis(DiagnoseInputs((path,), estimator, calibration,
                                              OUT / f"diagnose_{name}", force=True),
                               lambda *_: None)
        document = json.loads((OUT / f"diagnose_{name}" / "diagnosis.json").read_text())
        first = document["effects"][0] if document["effects"] else {}
        results[name] = {
            "verdict": result.verdict, "noise_floor_mm": document["noise_floor_mm"],
            "seconds": round(time.perf_counter() - began, 1),
            "first_effect": {key: first.get(key) for key in
                             ("name", "parameters", "heldout_rms_before_mm",
                              "heldout_rms_after_mm")},
            "summary": document["summary"]}
    return results


def main() -> None:
    estimator, _ = write_robots()
    markers = recording("markers", scenario("finger_markers", 5,
                                            [(a, r, []) for a, r in MARKER_ACTUATIONS], True))
    probes = recording("probes", scenario("finger_probes", 6, PROBE_FRAMES, False))
    calibration = OUT / "calibration.json"
    result = calibrate_checked(load_robot(estimator),
                               markers_from_recording(markers, None).markers, source="study")
    calibration.write_text(result_to_json(result))
    pose = OUT / "pose_truth.json"
    pose.write_text(json.dumps(pose_from_truth(probes.with_suffix(".truth.json"))))
    reduced = reduced_robot(estimator)
    results = {"calibration_rms_mm": result.residual_rms_mm,
               "calibrated": sense(probes, estimator, calibration, "sense_calibrated"),
               "truth_pose": sense(probes, estimator, pose, "sense_truth_pose"),
               "reduced_calibrated": sense(probes, reduced, calibration,
                                           "sense_reduced_calibrated"),
               "reduced_truth_pose": sense(probes, reduced, pose, "sense_reduced_truth_pose"),
               "diagnose": diagnose(estimator, calibration)}
    (OUT / "results.json").write_text(json.dumps(results, indent=1))
    print("diagnose", json.dumps(results["diagnose"], indent=1))
    for name in results:
        if name in ("calibration_rms_mm", "diagnose"):
            continue
        summary = {k: v for k, v in results[name].items() if k != "contacts"}
        print(name, json.dumps(summary))
        for contact in results[name]["contacts"]:
            error = contact["estimated_n"] / contact["true_n"] - 1
            print(f"  frame {contact['frame']:2d}: {contact['true_n']:.2f} N read "
                  f"{contact['estimated_n']:.3f} ({100 * error:+.0f}%), "
                  f"{contact['location_error_mm']:.1f} mm off")


if __name__ == "__main__":
    main()
