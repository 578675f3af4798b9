"""A run folder -> the report's figures (PNG) and its page (HTML), in one output folder."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from softforce_cli.errors import ModelError, SolverError
from softforce_cli.estimation.summary import poor_fit_text
from softforce_cli.io.atomic import atomic_write_text, check_writable
from softforce_cli.model.robot import Robot, load_robot
from softforce_cli.report import page
from softforce_cli.report.charts import Chart, diagnose_charts, sense_charts
from softforce_cli.report.figures_png import save_chart_png, save_projections_png
from softforce_cli.report.loading import DiagnoseRun, ReportError, RunFolder, SenseRun
from softforce_cli.report.overview import STATUS_MEANINGS, Overview, sense_overview
from softforce_cli.report.paths import PAGE_NAME
from softforce_cli.report.scene import ContactScene, location_scene, sense_scene
from softforce_cli.report.sources import (
    ReportSources,
    recorded_actuation,
    recording_path,
    robot_path,
    sense_truth,
)
from softforce_cli.report.truth import TruthReport

Step = Callable[[str], None]


@dataclass(frozen=True)
class Report:
    """What was written (page, pngs) and what the terminal summary shows."""

    page: Path
    pngs: tuple[Path, ...]
    overview: Overview | None
    truth: TruthReport | None
    notes: tuple[str, ...]


def sense_robot(run: SenseRun, sources: ReportSources) -> Robot | None:
    """The robot the run used (sources.robot_path), loaded; None when the run names none."""
    path = robot_path(run, sources)
    return None if path is None else _load(path)


def build_report(folder: RunFolder, out_dir: Path, sources: ReportSources = ReportSources(),
                 force: bool = False, step: Step = lambda _: None) -> Report:
    """Write out_dir/report.html and one PNG per figure; nothing is overwritten without
    force (OutputExistsError before any work)."""
    out_dir = Path(out_dir)
    check_writable(out_dir / PAGE_NAME, force)
    sections: list[page.Section] = []
    pngs: list[Path] = []
    notes: list[str] = []
    overview = truth = None
    if folder.sense is not None:
        run = folder.sense
        notes += run.notes
        step("comparing with the ground truth")
        truth = sense_truth(run, sources)
        overview = sense_overview(run)
        step("rebuilding the robot's shape")
        robot = sense_robot(run, sources)
        recording = recording_path(run, sources)
        cables = robot.cable_specs if robot is not None else ()
        scene = _scene(run, robot, lambda frame: recorded_actuation(recording, frame, cables),
                       notes)
        sections += _sense_sections(run, overview, truth, notes)
        step("drawing the figures")
        sections += _figure_sections(sense_charts(run, truth), scene, out_dir, pngs, force)
    if folder.diagnose is not None:
        step("drawing the diagnosis")
        sections += _diagnose_sections(folder.diagnose, sources, out_dir, pngs, notes, force)
    if notes:
        sections.insert(0, page.Section("Notes on the files", "".join(
            page.paragraph(n, "note") for n in notes)))
    path = out_dir / PAGE_NAME
    atomic_write_text(path, page.page_html(f"softforce report: {folder.folder}", sections),
                      force=force)
    return Report(path, tuple(pngs), overview, truth, tuple(notes))


def _load(path: Path) -> Robot:
    try:
        return load_robot(path)
    except ModelError as error:
        raise ReportError(f"{error} (the report draws the robot from it; pass --robot "
                          "ROBOT.toml)") from error


def _scene(run: SenseRun, robot: Robot | None, actuation, notes: list[str]) -> ContactScene | None:
    if robot is None:
        notes.append("sense.json names no robot: no 3D view (pass --robot ROBOT.toml)")
        return None
    try:
        return sense_scene(run, robot, actuation)
    except SolverError as error:
        notes.append(f"the sensed shape could not be rebuilt ({error}): no 3D view")
        return None


def _figure_sections(charts: list[Chart], scene: ContactScene | None, out_dir: Path,
                     pngs: list[Path], force: bool) -> list[page.Section]:
    sections = []
    for chart in charts:
        png = out_dir / f"{chart.key}.png"
        save_chart_png(chart, png, force)
        pngs.append(png)
        sections.append(page.Section(chart.title, page.chart_div(chart)))
        if chart.key == "forces" and scene is not None:
            png = out_dir / "contacts.png"
            save_projections_png(scene, png, force)
            pngs.append(png)
            sections.append(page.Section("Contacts on the robot", page.scene_div(
                scene, "contacts") + page.image_tag(png, "projections (contacts.png)")))
    return sections


def _sense_sections(run: SenseRun, overview: Overview, truth: TruthReport | None,
                    notes: list[str]) -> list[page.Section]:
    inputs = [(key, run.input_path(key) or "unknown")
              for key in ("recording", "robot", "calibration")]
    rate = (f"{overview.frames_per_s:.2f} frames/s"
            + ("" if overview.rate_measured else " (from the frames' times)"))
    run_rows = [*inputs, ("frames processed", overview.frames), ("frames ok", overview.ok),
                ("duration", f"{overview.duration_s:.2f} s"), ("speed", rate)]
    if overview.camera is not None:
        run_rows.append(("camera", overview.camera))
    if overview.poor_fit_frames:
        run_rows.append(("frames fitting poorly", poor_fit_text(overview.poor_fit_frames)))
    body = page.table_html(None, run_rows)
    if overview.skipped:
        body += page.table_html(("status", "frames", "meaning"), [
            (s, n, STATUS_MEANINGS.get(s, "")) for s, n in overview.skipped.items()])
    body += page.table_html(
        ("contact", "frames", "min (N)", "median (N)", "max (N)", "from (s)", "to (s)"),
        [(c.contact, c.frames, f"{c.force_min_n:.4f}", f"{c.force_median_n:.4f}",
          f"{c.force_max_n:.4f}", f"{c.first_s:.2f}", f"{c.last_s:.2f}")
         for c in overview.contacts])
    body += page.table_html(("stage", "median (ms)"), [
        (s, f"{v:.2f}") for s, v in overview.stage_median_ms.items()])
    sections = [page.Section("Run", body)]
    if truth is not None:
        stats = truth.statistics
        sections.append(page.Section(
            f"Against the ground truth ({truth.path.name})",
            page.table_html(("statistic", "value"), [(k, v) for k, v in stats.items()])
            + page.paragraph("Intensity errors are relative (|estimated - true| / true) over "
                             "located contacts; a true contact is located by an estimate "
                             "within 20 mm, and further estimates within 20 mm of it add "
                             "to it; an estimate pushing more than 50 mN with no true "
                             "contact is a phantom.")))
    elif run.input_path("recording"):
        notes.append("no ground truth beside the recording: no comparison with the truth")
    return sections


def _diagnose_sections(run: DiagnoseRun, sources: ReportSources, out_dir: Path,
                       pngs: list[Path], notes: list[str], force: bool) -> list[page.Section]:
    diagnosis = run.diagnosis
    rows = [("verdict", diagnosis.verdict), ("noise floor", f"{diagnosis.noise_floor_mm:.3f} mm"),
            ("regions", ", ".join(map(str, diagnosis.location.regions)) or "none"),
            ("cables", ", ".join(map(str, diagnosis.location.cables)) or "none"),
            ("nodes", len(diagnosis.location.nodes))]
    rows += [(f"location: {key}", json.dumps(value))
             for key, value in diagnosis.location.extra.items()]
    rows += [(key, json.dumps(value)) for key, value in diagnosis.extra.items()]
    effects = [(e.label, f"{e.heldout_rms_before_mm:.3f}", f"{e.heldout_rms_after_mm:.3f}",
                f"{100 * e.improvement:.0f} %",
                "; ".join(f"{p.name} = {p.value:.4g} {p.unit} [{p.ci95[0]:.4g}, {p.ci95[1]:.4g}]"
                          for p in e.parameters),
                e.evidence if isinstance(e.evidence, str) else json.dumps(e.evidence))
               for e in diagnosis.effects]
    body = page.table_html(None, rows) + page.table_html(
        ("effect", "held-out before (mm)", "after (mm)", "removed", "parameters (95 % CI)",
         "evidence"), effects)
    sections = [page.Section("Diagnosis", body)]
    robot_file = sources.robot or run.fitted_robot
    scene = None
    if diagnosis.location.nodes and robot_file is not None:
        scene = location_scene(_load(Path(robot_file)), diagnosis.location.nodes,
                               f"where the mismatch concentrates ({Path(robot_file).name})")
    elif diagnosis.location.nodes:
        notes.append("no robot.fitted.toml in the diagnose folder: the located nodes are not "
                     "drawn (pass --robot ROBOT.toml)")
    for chart in diagnose_charts(diagnosis):
        png = out_dir / f"{chart.key}.png"
        save_chart_png(chart, png, force)
        pngs.append(png)
        sections.append(page.Section(chart.title, page.chart_div(chart)))
    if scene is not None:
        png = out_dir / "location.png"
        save_projections_png(scene, png, force)
        pngs.append(png)
        sections.append(page.Section("Location", page.scene_div(scene, "location")
                                     + page.image_tag(png, "projections (location.png)")))
    if run.figures:
        sections.append(page.Section("Figures of the diagnosis", "".join(
            page.image_tag(p, str(p.relative_to(run.folder))) for p in run.figures)))
    return sections
