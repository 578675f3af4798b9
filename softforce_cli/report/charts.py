"""The report's 2D figures as data: what each plots, independent of how it is drawn.

figures_png.py draws a Chart with matplotlib, page.py with plotly; both read only these
dataclasses, so the PNG and the HTML show the same numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from softforce_cli.estimation.results import STAGES
from softforce_cli.report.diagnosis_file import Diagnosis
from softforce_cli.report.loading import SenseRun
from softforce_cli.report.truth import TruthReport


@dataclass(frozen=True)
class Trace:
    """One series: kind "line" (lines and markers), "markers" or "bar"."""

    name: str
    x: np.ndarray
    y: np.ndarray
    kind: str = "line"


@dataclass(frozen=True)
class Chart:
    """key: the PNG's file stem; stacked: bars stacked; reference: (value, label) of a
    horizontal line; diagonal: draw y = x (estimated vs true)."""

    key: str
    title: str
    x_label: str
    y_label: str
    traces: tuple[Trace, ...]
    stacked: bool = False
    reference: tuple[float, str] | None = None
    diagonal: bool = False


def sense_charts(run: SenseRun, truth: TruthReport | None) -> list[Chart]:
    charts = [force_chart(run, truth), residual_chart(run), feature_chart(run),
              timing_chart(run)]
    if truth is not None and len(truth.comparison.paired):
        charts.append(truth_chart(truth))
    return charts


def force_chart(run: SenseRun, truth: TruthReport | None) -> Chart:
    """Force intensity over time, one line per contact track (and the true forces)."""
    contacts = run.contacts
    traces = []
    for index in np.unique(contacts["contact"]).astype(int):
        rows = contacts["contact"] == index
        traces.append(Trace(f"contact {index}", contacts["time_s"][rows],
                            contacts["force_n"][rows]))
    if truth is not None:
        traces.append(Trace("true contacts", truth.true_times_s, truth.true_forces_n,
                            kind="markers"))
    return Chart("forces", "Contact force intensity over time", "time (s)", "force (N)",
                 tuple(traces))


def residual_chart(run: SenseRun) -> Chart:
    """The fit's normal residual: the frame's RMS and each contact's local RMS."""
    ok = run.ok
    traces = [Trace("frame fit RMS", run.frames["time_s"][ok], run.frames["fit_rms_mm"][ok])]
    if len(run.contacts):
        traces.append(Trace("near each contact", run.contacts["time_s"],
                            run.contacts["residual_mm"], kind="markers"))
    return Chart("residual", "Fit residual over time", "time (s)", "normal residual RMS (mm)",
                 tuple(traces))


def feature_chart(run: SenseRun) -> Chart:
    names = [n for n in ("features_matched", "features_hidden", "features_rejected")
             if n in run.frames.names]
    traces = tuple(Trace(n.removeprefix("features_"), run.frames["time_s"], run.frames[n])
                   for n in names)
    return Chart("features", "Feature points matched, hidden and rejected", "time (s)",
                 "feature points", traces)


def timing_chart(run: SenseRun) -> Chart:
    """Milliseconds per pipeline stage in each frame, stacked (frames.csv's STAGE_ms)."""
    frames = run.frames
    stages = [s for s in STAGES if f"{s}_ms" in frames.names]
    traces = tuple(Trace(s, frames["frame"], frames[f"{s}_ms"], kind="bar") for s in stages)
    if not traces:  # a frames.csv with only the contract's columns: the total
        traces = (Trace("total", frames["frame"], frames["total_ms"], kind="bar"),)
    return Chart("timings", "Time per frame by stage", "frame", "time (ms)", traces,
                 stacked=True)


def truth_chart(truth: TruthReport) -> Chart:
    paired = truth.comparison.paired
    true = np.array([p.true_force_n for p in paired])
    estimated = np.array([p.estimated_force_n for p in paired])
    return Chart("truth", "Estimated against true force (located contacts)", "true force (N)",
                 "estimated force (N)", (Trace("located contacts", true, estimated,
                                               kind="markers"),), diagonal=True)


def diagnose_charts(diagnosis: Diagnosis) -> list[Chart]:
    """Held-out residual before and after each ranked effect, against the noise floor: the
    point clouds' effects, and those judged on the markers (their own residuals and floor,
    evidence.markers) in a chart of their own."""
    charts = []
    evidence = diagnosis.extra.get("evidence")
    markers = evidence.get("markers") if isinstance(evidence, dict) else None
    markers = markers if isinstance(markers, dict) else {}
    for channel, key, floor, title in (
            ("clouds", "effects", diagnosis.noise_floor_mm, ""),
            ("markers", "marker_effects", float(markers.get("noise_floor_mm") or math.nan),
             " (the markers' residuals)")):
        effects = [e for e in diagnosis.effects if e.channel == channel]
        if not effects:
            continue
        names = np.array([e.label for e in effects])
        before = np.array([e.heldout_rms_before_mm for e in effects])
        after = np.array([e.heldout_rms_after_mm for e in effects])
        charts.append(Chart(key, f"Held-out residual before and after each effect{title}",
                            "effect", "held-out residual RMS (mm)",
                            (Trace("before", names, before, kind="bar"),
                             Trace("after", names, after, kind="bar")),
                            reference=(floor, "noise floor") if np.isfinite(floor) else None))
    return charts
