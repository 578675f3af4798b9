"""The plate under the Diamond (support_contact) on the exact model diagnose refits with
(docs/diagnosis_history.md, fourteenth run).

starts: Newton iterations of the coarse P2 Diamond (Neo-Hookean, as the study's robot file)
at one state with a plate at each height, started from the nominal equilibrium (the plate
deep in the hanging body) and from the contact solved on the state's linearisation
(diagnosis.support: the refit's start since the fourteenth run).

scan: the exact model's absolute residual (RMS over the frames, mm) against the plate's
height on a recording of benchmarks/study_diagnosis.py (its states from the study's cache).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/plate_check.py starts \
        [--inputs 0,6,0,6] [-12 -10 ...]
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/plate_check.py scan \
        [--case support_-5.5-s4] [-7.5 -5.5 ...]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import softforce_cli.diagnosis.pipeline as pipeline
from benchmarks.law_blend_check import robot_with_law
from softforce_cli.diagnosis.fitting import Candidate
from softforce_cli.diagnosis.hypotheses import hypotheses
from softforce_cli.diagnosis.run import DiagnoseInputs, run_diagnosis
from softforce_cli.diagnosis.sensitivities import column_set
from softforce_cli.diagnosis.solves import SETTINGS, SolveCache, StateSolutions
from softforce_cli.diagnosis.support import SupportBasis, support_basis
from softforce_cli.errors import SolverError
from softforce_cli.fem.statics import solve_equilibrium
from softforce_cli.model.effect_physics import fe_model_with_effects
from softforce_cli.model.effects import make_effect
from softforce_cli.model.robot import Robot

STUDY = Path(__file__).resolve().parents[1] / "out" / "study_diagnosis"
# what the refit allows a direct solve (diagnosis.refit.DIRECT_SETTINGS), and more
ITERATIONS = 60


class _ExactModelBuiltError(Exception):
    """The diagnosis has built its exact model."""


def plate(robot: Robot, support: SupportBasis) -> Candidate:
    """The plate diagnose screens and refits for `robot` (diagnosis.hypotheses)."""
    return Candidate(tuple(h for h in hypotheses(robot, column_set(robot), support)
                           if h.name == "support_contact"))


def starts(inputs: np.ndarray, heights: list[float]) -> None:
    with tempfile.TemporaryDirectory() as folder:
        robot = robot_with_law("neo-hookean", Path(folder))
        cable_inputs = robot.cable_inputs(inputs)
        nominal = solve_equilibrium(robot.nominal_fe_model, cable_inputs, settings=SETTINGS)
        count = robot.fe_model.node_count
        solutions = StateSolutions(robot, "p1", inputs[None], nominal.positions_mm[None],
                                   nominal.cable_tensions_n[None],
                                   np.zeros((1, 0, count, 3)), None, column_set(robot))
        support = support_basis(solutions, SolveCache(None))
    settings = dataclasses.replace(SETTINGS, max_iterations=ITERATIONS)
    print(f"inputs {inputs}, plate nodes {len(support.nodes)}")
    for height in heights:
        model = fe_model_with_effects(robot, (make_effect("support_contact",
                                                          table_z_mm=height),))
        contact = nominal.positions_mm + robot.fe_mesh.from_corners(
            support.motion_mm(height)[0])
        cells = []
        for start in (nominal.positions_mm, contact):
            began = time.perf_counter()
            try:
                solved = solve_equilibrium(model, cable_inputs, start_mm=start,
                                           settings=settings)
                cells.append(f"{solved.iterations} iterations ({solved.residual_history_n[0]:.0f}"
                             f" N first), {time.perf_counter() - began:.1f} s")
            except SolverError:
                cells.append(f"not in {ITERATIONS}")
        print(f"plate {height:6.2f} mm: from the nominal equilibrium {cells[0]}; "
              f"from the contact {cells[1]}", flush=True)


def scan(case: str, heights: list[float]) -> None:
    """Builds the diagnosis of the study's recording `case` up to its exact model (the states
    from the study's cache), then evaluates the plate at each height."""
    captured = {}
    build = pipeline.ExactModel

    def capture(*args):
        captured["exact"] = build(*args)
        raise _ExactModelBuiltError  # the exact model is all this needs

    pipeline.ExactModel = capture
    try:
        with tempfile.TemporaryDirectory() as folder, contextlib.suppress(_ExactModelBuiltError):
            run_diagnosis(DiagnoseInputs((STUDY / f"{case}.mcap",),
                                         STUDY / "diamond_neo-hookean.toml", STUDY / "pose.json",
                                         Path(folder), cache=STUDY / "cache"),
                          lambda *args: None)
    finally:
        pipeline.ExactModel = build
    exact = captured["exact"]
    candidate = plate(exact.solutions.robot, exact.basis.support)
    print(f"{case}: no plate {exact.nominal_field.rms():.3f} mm")
    for height in heights:
        prediction = exact.predict(candidate, np.array([height]))
        print(f"plate {height:6.2f} mm: {exact.field(prediction).rms():.3f} mm", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("mode", choices=("starts", "scan"))
    parser.add_argument("--case", default="support_-5.5-s4", help="scan: the recording")
    parser.add_argument("--inputs", default="0,6,0,6")
    parser.add_argument("heights", nargs="*", type=float)
    args = parser.parse_intermixed_args()
    if args.mode == "starts":
        starts(np.array([float(v) for v in args.inputs.split(",")]),
               args.heights or [-12.0, -10.0, -8.7, -7.0, -5.5])
    else:
        scan(args.case, args.heights or [-7.5, -6.5, -5.5, -5.0, -4.5, -4.0, -3.8, -3.6,
                                         -3.58])


if __name__ == "__main__":
    main()
