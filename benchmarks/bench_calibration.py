"""Calibration speed on the coarse default robot (issue: calibration, Algorithm 1).

`run()` returns rows for benchmarks/run.py (benchmarks.timing.BenchRow); alone, it prints them:

    .venv/bin/python scripts/bench_calibration.py

The case is the paper's simulation protocol: 9 markers observed from the paper's Table I pose,
cables at 6, 2, 4, 9 mm (displacement control) and the paper's forces (force control).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.timing import BenchRow, median_time  # noqa: E402
from softforce_cli.calibration.calibrate import calibrate  # noqa: E402
from softforce_cli.calibration.synthetic import (  # noqa: E402
    PAPER_FORCES_N,
    observed_markers,
    paper_transform,
    with_controls,
)
from softforce_cli.fem.statics import solve_equilibrium  # noqa: E402
from softforce_cli.model.robot import load_robot  # noqa: E402

COARSE = ROOT / "sample_data" / "diamond" / "diamond.toml"
DISPLACEMENT_MM = np.array([6.0, 2.0, 4.0, 9.0])
REPEATS = 5


def _case(robot, actuation):
    positions = solve_equilibrium(robot.fe_model, robot.cable_inputs(actuation)).positions_mm
    return observed_markers(robot, positions, paper_transform())


def run() -> list[BenchRow]:
    robot = load_robot(COARSE)
    observed = _case(robot, DISPLACEMENT_MM)
    calibrate(robot, observed)  # warm-up: symbolic factorisation, caches
    iterations: list[float] = []
    single_update: list[float] = []
    counts: list[int] = []
    totals = []
    for _ in range(REPEATS):
        reports = []
        result = calibrate(robot, observed, progress=reports.append)
        totals.append(result.elapsed_s)
        iterations += result.iteration_durations_s
        single_update += [d for d, r in zip(result.iteration_durations_s, reports, strict=True)
                          if r.fe_updates == 1]
        counts.append(len(result.residual_history_mm))
    outer_s = float(np.median(iterations))
    cycle_s = float(np.median(single_update))
    total_s = float(np.median(totals))
    sizes = f"{robot.mesh.tet_count} tets, 9 markers, 4 cables"
    rows = [
        BenchRow("Calibration: one FE update + SVD + QP (an outer iteration at 1 update)",
                 cycle_s, len(single_update), ">= 25 Hz", f"{1 / cycle_s:.0f} Hz",
                 f"{sizes}; paper: 22 Hz with 5 markers"),
        BenchRow("Calibration: outer iteration, all (1-3 FE updates each)", outer_s,
                 len(iterations), "", f"{1 / outer_s:.0f} Hz",
                 f"median over {REPEATS} calibrations of {int(np.median(counts))} iterations"),
        BenchRow("Calibration: whole, displacement 6,2,4,9 mm (robot loaded)", total_s, REPEATS,
                 "< 2 s", f"{total_s:.2f} s", "from the rest shape; residual < 1e-9 mm"),
    ]
    forced = with_controls(robot, ("force",) * 4, 0.0, 5.0)
    observed_force = _case(forced, PAPER_FORCES_N)
    force_s = median_time(lambda: calibrate(forced, observed_force), repeats=3)
    rows.append(BenchRow("Calibration: whole, paper forces 1.2,1,1,1.2 N", force_s, 3, "< 2 s",
                         f"{force_s:.2f} s", "force control: more FE updates (soft sway)"))

    def cold() -> None:
        fresh = load_robot(COARSE)
        calibrate(fresh, observed)

    cold_s = median_time(cold, repeats=3, warmup=0)
    rows.append(BenchRow("Calibration: whole, including loading the robot file", cold_s, 3,
                         "< 2 s", f"{cold_s:.2f} s", "mesh read, attachments, first "
                         "symbolic factorisation"))
    return rows


def main() -> None:
    from softforce_cli.fem.allocator import keep_freed_memory

    keep_freed_memory()
    started = time.perf_counter()
    for row in run():
        print(f"{row.name}: {row.median_s * 1e3:.1f} ms ({row.result}; target {row.target or '-'})"
              f" - {row.notes}")
    print(f"({time.perf_counter() - started:.0f} s)")


if __name__ == "__main__":
    main()
