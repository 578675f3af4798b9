"""Writes tests/data/probes_truth_features.json: the sample probes' truth at the estimator's
feature points, for tests/test_intensity_truth.py.

    OPENBLAS_NUM_THREADS=1 python benchmarks/intensity_fixture.py

The truth is that of sample_data/scenarios/probes.toml (the locking-free P2 body on its own
6.5 mm mesh, Neo-Hookean; its states do not depend on the camera), solved by
benchmarks/study_sweep.py and cached there (out/study_sweep/truth_states.pkl; about 3
minutes the first time). For each state (unloaded, 0.15 N, 0.25 N, 0.25 N + 0.2 N) the file
keeps where the truth body carries the material points of the coarse P2 robot's feature
points (sample_data/diamond/diamond_p2.toml, robot frame, mm), and each probe's force: what
a perfect camera and a perfect contact detector would give the estimator, so a test can
score the intensity stage alone against a truth it was not built from.
"""

from __future__ import annotations

import json
import pickle
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from study_sweep import OUT, SCENARIO, recordings  # noqa: E402

from softforce_cli.io.atomic import atomic_write_text  # noqa: E402
from softforce_cli.model.robot import load_robot  # noqa: E402
from softforce_cli.sim.ground_truth import truth_robot  # noqa: E402
from softforce_cli.sim.scenario import load_scenario  # noqa: E402

ESTIMATOR = ROOT / "sample_data" / "diamond" / "diamond_p2.toml"
FIXTURE = ROOT / "tests" / "data" / "probes_truth_features.json"


def fixture_document(estimator_file: Path) -> dict:
    """The truth's states at the feature points of the robot file estimator_file (under the
    repository), and each probe's force."""
    paths = recordings(640, 480)
    states = pickle.loads((OUT / "truth_states.pkl").read_bytes())
    truth = truth_robot(load_scenario(paths[0.0, 3].with_suffix(".toml")))
    estimator = load_robot(estimator_file)
    rest = estimator.mesh.nodes_mm[estimator.feature_nodes]
    at_features = truth.attach(rest)
    frames = []
    for (frame, _), state in states.items():
        frames.append({
            "actuation": list(frame.actuation),
            "features_mm": np.round(at_features.positions(state.equilibrium.positions_mm),
                                    5).tolist(),
            "contacts": [{"rest_point_mm": c.rest_point_mm.round(5).tolist(),
                          "point_mm": c.point_mm.round(5).tolist(),
                          "force_n": c.force_n.round(7).tolist()} for c in state.contacts],
        })
    return {
        "scenario": str(SCENARIO.relative_to(ROOT)),
        "truth": {"element": truth.element_name, "law": truth.material.law,
                  "tetrahedra": len(truth.mesh.tets)},
        "estimator": str(estimator_file.resolve().relative_to(ROOT)),
        "feature_rest_mm": rest.round(5).tolist(),
        "frames": sorted(frames, key=lambda f: (len(f["contacts"]),
                                                sum(np.linalg.norm(c["force_n"])
                                                    for c in f["contacts"]))),
    }


def main() -> None:
    document = fixture_document(ESTIMATOR)
    FIXTURE.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(FIXTURE, json.dumps(document), force=True)
    print(f"wrote {FIXTURE} ({len(document['frames'])} states)")


if __name__ == "__main__":
    main()
