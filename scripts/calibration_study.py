"""Accuracy study of `softforce calibrate` (docs/calibration.md): rewrites the study section.

    .venv/bin/python scripts/calibration_study.py [--seeds 20] [--doc docs/calibration.md]

1. The paper's simulation protocol (Table I): the estimation model generates the markers
   (coarse mesh, corotational), the paper's R, T; force control with the paper's forces and
   displacement control; 5 and 9 markers; noise-free.
2. Cross-model truth: the fine mesh (~4x the tetrahedra) with a Neo-Hookean law generates the
   markers, the coarse corotational model estimates; camera ~580 mm above; noise-free.
3. Marker noise sigma = 0.5 and 1 mm, `--seeds` seeds, 9 markers, on both truths: median and
   90th percentile of the errors; outliers flagged on clean data (false positives).
4. One gross outlier (10 or 20 mm, random direction) on each of the 9 markers, sigma 0, 0.5,
   1 mm: detected (flagged marker = the bad one) and excluded with --robust.
5. Fig. 6: residual per iteration, 5 and 9 markers, with and without the rigid projection.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from softforce_cli.calibration.calibrate import CalibrationSettings, calibrate  # noqa: E402
from softforce_cli.calibration.plot import save_residual_plot  # noqa: E402
from softforce_cli.calibration.rigid import rotation_angle_deg  # noqa: E402
from softforce_cli.calibration.robust import calibrate_checked  # noqa: E402
from softforce_cli.calibration.synthetic import (  # noqa: E402
    FIVE_MARKERS,
    PAPER_FORCES_N,
    observed_markers,
    overhead_transform,
    paper_transform,
    with_controls,
    with_law,
)
from softforce_cli.fem.allocator import keep_freed_memory  # noqa: E402
from softforce_cli.fem.statics import solve_equilibrium  # noqa: E402
from softforce_cli.model.robot import load_robot  # noqa: E402

COARSE = ROOT / "sample_data" / "diamond" / "diamond.toml"
FINE = ROOT / "sample_data" / "diamond_fine" / "diamond.toml"
DISPLACEMENT_MM = np.array([6.0, 2.0, 4.0, 9.0])
BEGIN, END = "<!-- calibration-study:begin -->", "<!-- calibration-study:end -->"


def errors(result, truth, actuation, robot_mm):
    """Rotation (deg), translation (mm), mapping error at the markers (mm: RMS over the true
    robot-frame marker positions of how far the estimated transform misplaces them), and the
    largest actuation error (mm)."""
    rotation = rotation_angle_deg(result.robot_from_camera.rotation.T @ truth.rotation)
    translation = float(np.linalg.norm(result.robot_from_camera.translation_mm
                                       - truth.translation_mm))
    camera = truth.inverse().apply(robot_mm)
    mapping = float(np.sqrt(np.mean(np.sum(
        (result.robot_from_camera.apply(camera) - robot_mm) ** 2, axis=1))))
    act = float(np.abs(result.actuation - actuation).max())
    return rotation, translation, mapping, act


def table_one(coarse) -> list[str]:
    truth = paper_transform()
    lines = ["| control | markers | residual RMS (mm) | R max element error | T error / abs T "
             "| actuation max rel. error | iterations | time (s) |",
             "|---|---|---|---|---|---|---|---|"]
    forced = with_controls(coarse, ("force",) * 4, 0.0, 5.0)
    for robot, actuation, label in ((forced, PAPER_FORCES_N, "force (N)"),
                                    (coarse, DISPLACEMENT_MM, "displacement (mm)")):
        x = solve_equilibrium(robot.fe_model, robot.cable_inputs(actuation)).positions_mm
        for ids in (FIVE_MARKERS, robot.marker_ids):
            result = calibrate(robot, observed_markers(robot, x, truth, ids))
            transform = result.robot_from_camera
            lines.append(
                f"| {label} {np.round(actuation, 2).tolist()} | {len(ids)} | "
                f"{result.residual_rms_mm:.1e} | "
                f"{np.abs(transform.rotation - truth.rotation).max():.1e} | "
                f"{_relative(transform.translation_mm, truth.translation_mm):.1e} | "
                f"{np.abs(result.actuation - actuation).max() / np.abs(actuation).max():.1e} | "
                f"{len(result.residual_history_mm)} | {result.elapsed_s:.2f} |")
    return lines


def _relative(estimate: np.ndarray, truth: np.ndarray) -> float:
    return float(np.linalg.norm(estimate - truth) / np.linalg.norm(truth))


def cross_model(coarse, fine_truth, x_fine) -> list[str]:
    truth = overhead_transform()
    lines = ["| markers | residual RMS (mm) | rotation error (deg) | translation error (mm) | "
             "mapping error at the markers (mm) | actuation error max (mm) | estimated "
             "actuation (mm) | time (s) |", "|---|---|---|---|---|---|---|---|"]
    robot_mm = fine_truth.marker_points.positions(x_fine)
    for ids in (FIVE_MARKERS, coarse.marker_ids):
        result = calibrate(coarse, observed_markers(fine_truth, x_fine, truth, ids))
        r, t, m, a = errors(result, truth, DISPLACEMENT_MM, robot_mm)
        lines.append(f"| {len(ids)} | {result.residual_rms_mm:.3f} | {r:.3f} | {t:.3f} | "
                     f"{m:.3f} | {a:.3f} | {np.round(result.actuation, 3).tolist()} | "
                     f"{result.elapsed_s:.2f} |")
    return lines


def noise_study(coarse, truths, seeds: int) -> list[str]:
    transform = overhead_transform()
    lines = ["| truth | sigma (mm) | rotation error (deg) | translation error (mm) | mapping "
             "error at the markers (mm) | actuation error max (mm) | residual RMS (mm) | "
             "flagged outliers | time median / p90 (s) |", "|---|---|---|---|---|---|---|---|---|"]
    for label, robot, x in truths:
        robot_mm = robot.marker_points.positions(x)
        for sigma in (0.5, 1.0):
            rows, flagged, times = [], 0, []
            for seed in range(seeds):
                rng = np.random.default_rng(seed)
                observed = observed_markers(robot, x, transform, sigma_mm=sigma, rng=rng)
                result = calibrate_checked(coarse, observed)
                rows.append((*errors(result, transform, DISPLACEMENT_MM, robot_mm),
                             result.residual_rms_mm))
                flagged += bool(result.outliers)
                times.append(result.elapsed_s)
            values = np.array(rows)
            median, p90 = np.median(values, axis=0), np.percentile(values, 90, axis=0)
            cells = " | ".join(f"{m:.3f} / {p:.3f}" for m, p in zip(median, p90, strict=True))
            lines.append(f"| {label} | {sigma} | {cells} | {flagged}/{seeds} | "
                         f"{np.median(times):.2f} / {np.percentile(times, 90):.2f} |")
    return lines


def outlier_study(coarse, fine_truth, x_fine) -> list[str]:
    transform = overhead_transform()
    lines = ["| sigma (mm) | outlier (mm) | detected | excluded, residual RMS median (mm) | "
             "time median (s) |", "|---|---|---|---|---|"]
    rng = np.random.default_rng(100)
    for sigma in (0.0, 0.5, 1.0):
        for size in (10.0, 20.0):
            hits, residuals, times = 0, [], []
            for bad, marker_id in enumerate(coarse.marker_ids):
                observed = observed_markers(fine_truth, x_fine, transform, sigma_mm=sigma,
                                            rng=rng) if sigma else observed_markers(
                    fine_truth, x_fine, transform)
                direction = rng.standard_normal(3)
                positions = observed.positions_mm.copy()
                positions[bad] += size * direction / np.linalg.norm(direction)
                result = calibrate_checked(coarse, type(observed)(observed.ids, positions),
                                           exclude_outliers=True)
                hits += result.excluded == (marker_id,)
                residuals.append(result.residual_rms_mm)
                times.append(result.elapsed_s)
            lines.append(f"| {sigma} | {size:.0f} | {hits}/{len(coarse.marker_ids)} | "
                         f"{np.median(residuals):.2f} | {np.median(times):.2f} |")
    return lines


def figure(coarse, path: Path) -> None:
    forced = with_controls(coarse, ("force",) * 4, 0.0, 5.0)
    x = solve_equilibrium(forced.fe_model, forced.cable_inputs(PAPER_FORCES_N)).positions_mm
    histories = {}
    for ids in (FIVE_MARKERS, forced.marker_ids):
        observed = observed_markers(forced, x, paper_transform(), ids)
        histories[f"{len(ids)} markers"] = calibrate(forced, observed).residual_history_mm
        paper = calibrate(forced, observed, CalibrationSettings(project_rigid=False,
                                                                outer_iterations=40))
        histories[f"{len(ids)} markers, paper's alternation"] = paper.residual_history_mm
    save_residual_plot(histories, path, force=True,
                       title="Residual per iteration (Table I protocol, paper forces)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--doc", type=Path, default=ROOT / "docs" / "calibration.md")
    parser.add_argument("--figure", type=Path,
                        default=ROOT / "docs" / "figures" / "calibration_residual.png")
    args = parser.parse_args()
    keep_freed_memory()
    started = time.perf_counter()
    coarse = load_robot(COARSE)
    fine_truth = with_law(coarse, "neo-hookean", load_robot(FINE).mesh)
    x_fine = solve_equilibrium(fine_truth.fe_model,
                               fine_truth.cable_inputs(DISPLACEMENT_MM)).positions_mm
    x_coarse = solve_equilibrium(coarse.fe_model,
                                 coarse.cable_inputs(DISPLACEMENT_MM)).positions_mm
    sections = [
        "### 1. The paper's simulation protocol (Table I): same model generates and estimates",
        "", *table_one(coarse), "",
        "### 2. Cross-model truth (fine mesh, Neo-Hookean), noise-free, displacement "
        f"{DISPLACEMENT_MM.tolist()} mm", "", *cross_model(coarse, fine_truth, x_fine), "",
        f"### 3. Marker noise, 9 markers, {args.seeds} seeds: median / 90th percentile", "",
        *noise_study(coarse, [("same model", coarse, x_coarse),
                              ("fine + Neo-Hookean", fine_truth, x_fine)], args.seeds), "",
        "### 4. One gross outlier among 9 markers (each marker in turn, random direction), "
        "`--robust`", "", *outlier_study(coarse, fine_truth, x_fine), "",
    ]
    figure(coarse, args.figure)
    sections += [f"![residual per iteration](figures/{args.figure.name})", "",
                 f"Generated by `.venv/bin/python scripts/calibration_study.py --seeds "
                 f"{args.seeds}` in {time.perf_counter() - started:.0f} s."]
    text = "\n".join(sections)
    print(text)
    if args.doc.exists():
        doc = args.doc.read_text()
        if BEGIN in doc and END in doc:
            head, rest = doc.split(BEGIN, 1)
            args.doc.write_text(f"{head}{BEGIN}\n{text}\n{END}{rest.split(END, 1)[1]}")


if __name__ == "__main__":
    main()
