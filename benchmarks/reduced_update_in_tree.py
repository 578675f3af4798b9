"""The reduced model's update, static solves and calibration, and the full P1 model's solve
and update, as the source tree TREE computes them.

Compares two versions of the code on the same cached reduced model (out/bench_reduced/ of
this checkout, linked into the other tree, so nothing is retrained): run it in turn for each
tree, several times, since on a shared machine only timings taken in turn are comparable
(docs/reduced_model.md):

    mkdir /tmp/before && git archive COMMIT softforce_cli benchmarks | tar -x -C /tmp/before
    ln -s "$PWD/out" "$PWD/sample_data" /tmp/before/
    for i in 1 2 3; do for tree in /tmp/before .; do
        OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/reduced_update_in_tree.py $tree
    done; done
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path


def main(tree: Path) -> None:
    sys.path.insert(0, str(tree))
    bench = importlib.import_module("benchmarks.bench_reduced")
    if not Path(bench.__file__).resolve().is_relative_to(tree):
        raise SystemExit(f"{tree}: its benchmarks/bench_reduced.py was not the one imported")
    statics = importlib.import_module("softforce_cli.fem.statics")
    fem = importlib.import_module("benchmarks.bench_fem")
    calibration = importlib.import_module("softforce_cli.calibration.calibrate")
    synthetic = importlib.import_module("softforce_cli.calibration.synthetic")
    _, reduced = bench.reduced_robot()
    model = reduced.fe_model
    inputs = reduced.cable_inputs(bench.ACTUATION)
    equilibrium = statics.solve_equilibrium(model, inputs)
    update = bench.update_callable(reduced, equilibrium.positions_mm,
                                   equilibrium.cable_tensions_n)
    update_s = bench.median_time(update, repeats=200, warmup=5)
    solve_s = bench.median_time(lambda: statics.solve_equilibrium(model, inputs), repeats=10)
    near = statics.solve_equilibrium(model, reduced.cable_inputs(bench.ACTUATION - [0.5, 0, 0, 0]))
    warm_s = bench.median_time(lambda: statics.solve_equilibrium(
        model, inputs, start_mm=near.positions_mm), repeats=10)
    positions = statics.solve_equilibrium(
        model, reduced.cable_inputs(bench.CALIBRATION_MM)).positions_mm
    observed = synthetic.observed_markers(reduced, positions, synthetic.paper_transform())
    calibrate_s = bench.median_time(lambda: calibration.calibrate(reduced, observed), repeats=3)
    p1 = fem.load_robot(fem.COARSE)
    p1_update, _ = fem.sensing_update(p1)
    p1_update_s = bench.median_time(p1_update, repeats=40, warmup=3)
    p1_inputs = p1.cable_inputs(fem.ACTUATION)
    p1_solve_s = bench.median_time(lambda: statics.solve_equilibrium(p1.fe_model, p1_inputs),
                                   repeats=5)
    print(f"{tree}: update {update_s * 1e3:.1f} ms, static solve from rest "
          f"{solve_s * 1e3:.0f} ms, from 0.5 mm away {warm_s * 1e3:.0f} ms, calibration "
          f"{calibrate_s:.2f} s; full p1: solve {p1_solve_s * 1e3:.0f} ms, update "
          f"{p1_update_s * 1e3:.1f} ms", flush=True)

if __name__ == "__main__":
    if len(sys.argv) != 2 or not (Path(sys.argv[1]) / "softforce_cli").is_dir():
        raise SystemExit("usage: reduced_update_in_tree.py TREE (a softforce source tree)")
    main(Path(sys.argv[1]).resolve())
