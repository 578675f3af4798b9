"""How much of a probe's misread intensity is the estimator's model (docs/sensing_studies.md).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/sensing_model_check.py [ROBOT.toml]

For the first frame of each single-probe hold of the 12-location probes study
(benchmarks/study_sensing.py --probes-only, which must have run), the estimator's robot (the
coarse P2 Diamond by default) is loaded with the truth's own force at the truth's contact
point, at the study's actuation, and its marker motions and cable tension changes are set
against the truth's (the locking-free body's, from the recording's truth file). A model that
moves its markers r times as far as the truth reads a force about 1 / r times the true one.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.study_sensing import OUT  # noqa: E402
from softforce_cli.fem.statics import PointLoads, solve_equilibrium  # noqa: E402
from softforce_cli.model.robot import load_robot  # noqa: E402

ROBOT = ROOT / "sample_data" / "diamond" / "diamond_p2.toml"
TRUTH = OUT / "probes_640.truth.json"


def main() -> None:
    robot = load_robot(Path(sys.argv[1]) if len(sys.argv) > 1 else ROBOT)
    frames = json.loads(TRUTH.read_text())["frames"]
    rest = frames[0]
    inputs = robot.cable_inputs(np.array(rest["actuation"]["values"]))
    unloaded = solve_equilibrium(robot.fe_model, inputs)
    ids = list(robot.marker_ids)

    def truth_markers(frame: dict) -> np.ndarray:
        return np.array([frame["markers"][i]["robot_mm"] for i in ids])

    model_rest = robot.marker_points.positions(unloaded.positions_mm)
    gap = np.linalg.norm(model_rest - truth_markers(rest), axis=1)
    print(f"unloaded: markers {np.sqrt(np.mean(gap**2)):.2f} mm RMS from the truth; tensions "
          f"{unloaded.cable_tensions_n.round(3)} N, truth {np.round(rest['cable_tensions_n'], 3)}")
    print("frame | probe rest point (mm) | force (N) | marker motion model / truth | largest "
          "truth marker motion (mm) | model's (mm)")
    previous: list = []
    for frame in frames:
        contacts = frame["contacts"]
        starts_hold = len(contacts) == 1 and contacts != previous
        previous = contacts
        if not starts_hold:
            continue
        contact = contacts[0]
        loads = PointLoads(robot.attach(np.array([contact["rest_point_mm"]])),
                           np.array([contact["force_n"]]))
        loaded = solve_equilibrium(robot.fe_model, inputs, loads, start_mm=unloaded.positions_mm)
        model = robot.marker_points.positions(loaded.positions_mm) - model_rest
        truth = truth_markers(frame) - truth_markers(rest)
        largest = int(np.argmax(np.linalg.norm(truth, axis=1)))
        print(f"{frame['index']} | {np.round(contact['rest_point_mm']).astype(int).tolist()} | "
              f"{contact['magnitude_n']} | {np.linalg.norm(model) / np.linalg.norm(truth):.2f} | "
              f"{ids[largest]} {np.linalg.norm(truth[largest]):.1f} | "
              f"{np.linalg.norm(model[largest]):.1f}")


if __name__ == "__main__":
    main()
