"""A sense run against its recording's ground truth, through estimation.truth_errors."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from softforce_cli.estimation.truth_errors import TruthComparison, compare_with_truth, read_truth
from softforce_cli.report.loading import ReportError, SenseRun


@dataclass(frozen=True)
class TruthReport:
    """comparison: paired, missed and phantom contacts; true_times_s (t,) and
    true_forces_n (t,) list every true contact of the compared frames (time, magnitude)."""

    path: Path
    comparison: TruthComparison
    true_times_s: np.ndarray
    true_forces_n: np.ndarray

    @property
    def statistics(self) -> dict[str, Any]:
        return self.comparison.summary()


def sense_document(run: SenseRun) -> dict[str, Any]:
    """The "frames" of sense.json as compare_with_truth reads them, rebuilt from the CSVs
    (which an interrupted run leaves whole, unlike sense.json's last frame)."""
    contacts = run.contacts
    frames = []
    for index, status in zip(run.frames["frame"].astype(int), run.frames["status"], strict=True):
        rows = contacts["frame"] == index
        positions = np.column_stack([contacts[k][rows] for k in ("x_mm", "y_mm", "z_mm")])
        vectors = np.column_stack([contacts[k][rows] for k in ("fx_n", "fy_n", "fz_n")])
        frames.append({"frame": int(index), "status": str(status), "contacts": [
            {"position_mm": p.tolist(), "force_n": float(f), "force_vector_n": v.tolist()}
            for p, f, v in zip(positions, contacts["force_n"][rows], vectors, strict=True)]})
    return {"frames": frames}


def compare_run_with_truth(run: SenseRun, truth_file: Path) -> TruthReport:
    """ReportError when the truth file does not cover the run's frames."""
    truth = read_truth(truth_file)
    document = sense_document(run)
    try:
        true_frames = {f["index"]: f for f in truth["frames"]}
        compared = [true_frames[f["frame"]] for f in document["frames"] if f["status"] == "ok"]
        comparison = compare_with_truth(document, truth)
    except (KeyError, TypeError) as error:
        raise ReportError(f"{truth_file}: not the ground truth of this run's frames (no "
                          f"{error} there); is it the truth of another recording?") from error
    times = [f["time_s"] for f in compared for _ in f["contacts"]]
    forces = [c["magnitude_n"] for f in compared for c in f["contacts"]]
    return TruthReport(Path(truth_file), comparison, np.array(times, dtype=float),
                       np.array(forces, dtype=float))
