"""The reduced model's update and static solve as the source tree TREE computes them.

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
    _, reduced = bench.reduced_robot()
    model = reduced.fe_model
    inputs = reduced.cable_inputs(bench.ACTUATION)
    equilibrium = statics.solve_equilibrium(model, inputs)
    update = bench.update_callable(reduced, equilibrium.positions_mm,
                                   equilibrium.cable_tensions_n)
    update_s = bench.median_time(update, repeats=200, warmup=5)
    solve_s = bench.median_time(lambda: statics.solve_equilibrium(model, inputs), repeats=10)
    print(f"{tree}: update {update_s * 1e3:.1f} ms, static solve from rest "
          f"{solve_s * 1e3:.0f} ms")


if __name__ == "__main__":
    if len(sys.argv) != 2 or not (Path(sys.argv[1]) / "softforce_cli").is_dir():
        raise SystemExit("usage: reduced_update_in_tree.py TREE (a softforce source tree)")
    main(Path(sys.argv[1]).resolve())
