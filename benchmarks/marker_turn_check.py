"""What the markers would show of a camera turned about the vertical (docs/diagnosis.md,
limits): for each study recording (benchmarks/study_diagnosis.py), the 9 markers as the
camera saw them (from the truth file: the study's recordings publish no /markers), through
the given calibration, fitted rigidly (Kabsch, all frames pooled) onto the coarse P2 model's
nominal prediction; prints the fitted turn about the vertical and the whole rotation.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/marker_turn_check.py \
        extrinsic_rz_1-s2 clean-s1 hidden_mass_north-s1 regional_south_2-s1
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from softforce_cli.calibration.result import read_calibration
from softforce_cli.diagnosis.observations import observe_recordings
from softforce_cli.diagnosis.sensitivities import column_set
from softforce_cli.diagnosis.solves import SolveCache, solve_states
from softforce_cli.diagnosis.states import group_states
from softforce_cli.fem.attachment import attach_points
from softforce_cli.model.effects import frame_contexts
from softforce_cli.model.robot import load_robot

ROOT = Path(__file__).resolve().parents[1]
FOLDER = ROOT / "out" / "study_diagnosis"
ROBOT = ROOT / "sample_data" / "diamond" / "diamond.toml"


def rigid_fit(predicted: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), t (3,)) minimising |observed - (R predicted + t)| over points (m, 3)."""
    p_mean, q_mean = predicted.mean(axis=0), observed.mean(axis=0)
    u, _, vt = np.linalg.svd((predicted - p_mean).T @ (observed - q_mean))
    flip = np.sign(np.linalg.det(vt.T @ u.T))
    rotation = vt.T @ np.diag([1.0, 1.0, flip]) @ u.T
    return rotation, q_mean - rotation @ p_mean


def main() -> None:
    robot = load_robot(ROBOT)
    calibration = read_calibration(FOLDER / "pose.json")
    ids = [m.id for m in robot.config.markers]
    markers = attach_points(robot.mesh.nodes_mm, robot.mesh.tets,
                            np.array([m.position_mm for m in robot.config.markers]))
    for case in sys.argv[1:]:
        observations = observe_recordings([FOLDER / f"{case}.mcap"], robot,
                                          calibration.robot_from_camera)
        states = group_states(tuple(frame_contexts(observations.times_s,
                                                   observations.actuations)))
        solutions = solve_states(robot, states.actuation, SolveCache(FOLDER / "cache"),
                                 column_set(robot))
        truth = json.loads((FOLDER / f"{case}.truth.json").read_text())["frames"]
        predicted = np.concatenate([markers.positions(solutions.predicted_mm[s])
                                    for s in states.of_frame])
        observed = np.concatenate([calibration.robot_from_camera.apply(np.array(
            [frame["markers"][k]["observed_camera_mm"] for k in ids])) for frame in truth])
        rotation, translation = rigid_fit(predicted, observed)
        turn_z = np.degrees(np.arctan2(rotation[1, 0], rotation[0, 0]))
        whole = np.degrees(np.arccos(np.clip((np.trace(rotation) - 1) / 2, -1, 1)))
        after = observed - (predicted @ rotation.T + translation)
        print(f"{case}: turn about the vertical {turn_z:.3f} deg, whole rotation {whole:.3f} "
              f"deg, translation {np.round(translation, 2)} mm; marker RMS "
              f"{np.sqrt(np.mean(np.sum((observed - predicted)**2, axis=1))):.2f} -> "
              f"{np.sqrt(np.mean(np.sum(after**2, axis=1))):.2f} mm")


if __name__ == "__main__":
    main()
