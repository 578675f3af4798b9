"""`softforce report` on a real sense run and a hand-made diagnose folder: what it writes, the
numbers it shows against independent computations, re-export, damaged and bad inputs."""

from __future__ import annotations

import csv
import io
import json
import shutil

import numpy as np
import pytest
from rich.console import Console

from softforce_cli.cli import report_terminal as terminal
from softforce_cli.report.build import build_report
from softforce_cli.report.export import available_tables, select_columns, table_text
from softforce_cli.report.loading import ReportError, load_run
from softforce_cli.report.overview import camera_line, sense_overview
from softforce_cli.report.reconstruction import frame_cable_inputs, sensed_shape
from softforce_cli.report.truth import compare_run_with_truth
from tests.cli_runner import assert_one_line_error, softforce
from tests.report_fixtures import DIAGNOSIS, PROBES_TRUTH, diagnose_folder, sense_folder


@pytest.fixture(scope="module")
def sense_out(tmp_path_factory):
    return sense_folder(tmp_path_factory.getbasetemp() / "report_inputs")


@pytest.fixture(scope="module")
def html_run(sense_out):
    """The default report, as a user runs it."""
    result = softforce("report", sense_out)
    return result, sense_out / "report"


def _external_resources(page: str) -> list[str]:
    """src/href of the page's script, link and img tags that are not inline data."""
    from html.parser import HTMLParser

    found = []

    class Tags(HTMLParser):
        def handle_starttag(self, tag, attrs):
            for name, value in attrs:
                if tag in ("script", "link", "img") and name in ("src", "href") \
                        and not (value or "").startswith("data:"):
                    found.append(value)

    Tags().feed(page)
    return found


def _csv_rows(path):
    return list(csv.DictReader(path.read_text().splitlines()))


def test_report_writes_the_page_and_a_png_per_figure(html_run):
    result, out = html_run
    assert result.returncode == 0, result.stderr
    page = (out / "report.html").read_text()
    assert "<script" in page and "Plotly.newPlot" in page
    # self-contained: no tag loads a script, stylesheet or image from anywhere
    assert _external_resources(page) == []
    for key in ("forces", "contacts", "residual", "features", "timings", "truth"):
        png = out / f"{key}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", key
        assert f'id="figure-{key}"' in page, key


def test_terminal_summary_shows_the_runs_numbers(html_run, sense_out):
    result, _ = html_run
    rows = _csv_rows(sense_out / "contacts.csv")
    frames = _csv_rows(sense_out / "frames.csv")
    largest = max(float(r["force_n"]) for r in rows)
    assert f"{len(frames)} frames" in result.stdout
    assert f"{largest:.4f}" in result.stdout  # the force range per contact
    assert "tare" in result.stdout  # the skipped frame and why
    assert "against the ground truth" in result.stdout
    camera = json.loads((sense_out / "sense.json").read_text())["camera"]
    # what the vision made of the camera (the 424x240 sample: every pixel, counts 9 / 1)
    assert (f"camera {camera['width']}x{camera['height']}, fx {camera['fx']:.1f} px" in
            " ".join(result.stdout.split()))
    assert "every pixel, neighbours 9 / 1" in " ".join(result.stdout.split())


def test_the_camera_line_reads_the_entry_or_nothing():
    entry = {"width": 1280, "height": 720, "fx": 915.62, "robot_distance_mm": 540.4,
             "decimation": 2, "outlier_min_neighbours": 20, "contact_min_neighbours": 3}
    assert camera_line(entry) == ("1280x720, fx 915.6 px, robot 540 mm away: 2x2 pixel "
                                  "blocks, neighbours 20 / 3")
    assert camera_line(None) is None
    assert camera_line({**entry, "fx": "wide"}) is None
    assert camera_line({"width": 1280}) is None


def test_truth_statistics_match_a_direct_computation(sense_out):
    """Located contacts and their location errors recomputed here from the two files: each
    true contact against the nearest estimate of its frame."""
    run = load_run(sense_out).sense
    report = compare_run_with_truth(run, PROBES_TRUTH)
    truth = {f["index"]: f for f in json.loads(PROBES_TRUTH.read_text())["frames"]}
    rows = _csv_rows(sense_out / "contacts.csv")
    errors = []
    for frame in {int(r["frame"]) for r in rows}:
        estimates = np.array([[float(r[k]) for k in ("x_mm", "y_mm", "z_mm")]
                              for r in rows if int(r["frame"]) == frame])
        true = np.array([c["point_mm"] for c in truth[frame]["contacts"]])
        distance = np.linalg.norm(true[:, None] - estimates[None], axis=2)
        errors.extend(distance.min(axis=1))  # each true contact: its nearest estimate
    stats = report.statistics
    assert stats["located"] == sum(e <= 20.0 for e in errors)
    assert stats["location_error_max_mm"] == pytest.approx(max(errors), abs=1e-3)
    assert stats["true_contacts"] == sum(len(truth[f]["contacts"]) for f in (1, 2, 3))


def test_the_csv_rebuilt_run_scores_as_sense_json_does(sense_out):
    """The report scores the run rebuilt from its CSVs (whole after an interruption): every
    field the scoring reads, the force vectors that a split contact's parts add included,
    comes back, so its statistics are sense.json's."""
    from softforce_cli.estimation.truth_errors import compare_with_truth, read_truth
    from softforce_cli.report.truth import sense_document

    run = load_run(sense_out).sense
    rebuilt = sense_document(run)
    document = json.loads((sense_out / "sense.json").read_text())
    for mine, theirs in zip(rebuilt["frames"], document["frames"], strict=True):
        assert len(mine["contacts"]) == len(theirs["contacts"])
        for a, b in zip(mine["contacts"], theirs["contacts"], strict=True):
            np.testing.assert_allclose(a["force_vector_n"], b["force_vector_n"], atol=1e-6)
    truth = read_truth(PROBES_TRUTH)
    assert (compare_run_with_truth(run, PROBES_TRUTH).statistics
            == compare_with_truth(document, truth).summary())


def test_rebuilt_shape_matches_the_recorded_actuation(sense_out, sample_robot):
    """The shape under the sensed cable tensions (force control: the fallback without the
    recording) against an independent solve: the recording's own cable displacements
    (displacement control) of that frame."""
    from softforce_cli.fem.statics import solve_equilibrium

    run = load_run(sense_out).sense
    frame = json.loads(PROBES_TRUTH.read_text())["frames"][1]
    tensions = frame_cable_inputs(sample_robot, None, run.cable_tensions[1])
    shape = sensed_shape(sample_robot, tensions, np.zeros((0, 3)), np.zeros((0, 3)))
    recorded = solve_equilibrium(sample_robot.fe_model,
                                 sample_robot.cable_inputs(np.array(frame["actuation"]["values"])))
    moved = np.linalg.norm(recorded.positions_mm - sample_robot.rest_nodes_mm, axis=1).max()
    gap = np.linalg.norm(shape.positions_mm - recorded.positions_mm, axis=1).max()
    assert moved > 5.0  # the cables bend the robot: the comparison is not trivial
    assert gap < 0.1 * moved


def test_csv_and_json_reexport_keep_the_chosen_columns(sense_out, tmp_path):
    result = softforce("report", sense_out, "--format", "csv", "--columns", "frame,force_n")
    assert result.returncode == 0, result.stderr
    original = _csv_rows(sense_out / "contacts.csv")
    exported = list(csv.DictReader(io.StringIO(result.stdout)))
    assert list(exported[0]) == ["frame", "force_n"]
    assert [int(r["frame"]) for r in exported] == [int(r["frame"]) for r in original]
    assert [float(r["force_n"]) for r in exported] == [float(r["force_n"]) for r in original]
    run = load_run(sense_out)
    frames = json.loads(table_text(select_columns(available_tables(run, None)["frames"],
                                                  "frames", ["frame", "status"]), "json"))
    assert frames == [{"frame": int(r["frame"]), "status": r["status"]}
                      for r in _csv_rows(sense_out / "frames.csv")]


@pytest.mark.parametrize(("ending", "note"), [
    ({"interrupted": True}, "the run was interrupted after 4 frames"),
    ({"error": "error line of the reader"},
     "the run ended on an error after 4 frames, before the recording's end: error line"),
])
def test_a_run_that_ended_early_says_so(sense_out, tmp_path, ending, note):
    """sense.json's summary says the run stopped before the recording's end (Ctrl-C, or a
    frame the reader refused): the report notes it, in the terminal and on the page."""
    early = tmp_path / "early"
    shutil.copytree(sense_out, early, ignore=shutil.ignore_patterns("report"))
    document = json.loads((early / "sense.json").read_text())
    document["summary"].update(ending)
    (early / "sense.json").write_text(json.dumps(document))
    assert document["summary"]["frames"] == 4
    run = load_run(early).sense
    assert [n for n in run.notes if n.startswith(note)]
    build_report(load_run(early), tmp_path / "report")
    assert note.split(",")[0] in (tmp_path / "report" / "report.html").read_text()
    assert not load_run(sense_out).sense.notes  # a whole run has none


def test_frames_that_fit_poorly_are_named(sense_out, tmp_path):
    """sense.json's summary names frames the model did not follow (poor_fit_frames): the
    report names them, in the terminal and on the page; a run without the entry (before
    2026-12-01) or with a malformed one names none."""
    poor = tmp_path / "poor"
    shutil.copytree(sense_out, poor, ignore=shutil.ignore_patterns("report"))
    document = json.loads((poor / "sense.json").read_text())
    document["summary"]["poor_fit_frames"] = [2, 3]
    (poor / "sense.json").write_text(json.dumps(document))
    assert sense_overview(load_run(poor).sense).poor_fit_frames == (2, 3)
    result = softforce("report", poor)
    assert result.returncode == 0, result.stderr
    assert "2 frame(s) fit the robot more than 5 mm worse than the first (2, 3)" in " ".join(
        result.stdout.split())
    assert "frames fitting poorly" in (poor / "report" / "report.html").read_text()
    for entry in (None, "2, 3"):
        document["summary"]["poor_fit_frames"] = entry
        (poor / "sense.json").write_text(json.dumps(document))
        assert sense_overview(load_run(poor).sense).poor_fit_frames == ()
    assert sense_overview(load_run(sense_out).sense).poor_fit_frames == ()


def test_an_interrupted_run_is_reported_as_far_as_it_went(sense_out, tmp_path):
    """frames.csv cut mid-row, contacts.csv ahead of it, sense.json cut: the whole rows are
    reported and each problem is noted."""
    cut = tmp_path / "cut"
    shutil.copytree(sense_out, cut, ignore=shutil.ignore_patterns("report"))
    frames = (cut / "frames.csv").read_text().splitlines()
    (cut / "frames.csv").write_text("\n".join(frames[:-1]) + "\n" + frames[-1][:15])
    text = (cut / "sense.json").read_text()
    (cut / "sense.json").write_text(text[: len(text) // 2])
    run = load_run(cut).sense
    assert len(run.frames) == len(frames) - 2
    last = int(frames[-1].split(",")[0])
    assert last not in run.contacts["frame"]
    assert len(run.notes) == 3 and run.header == {}
    overview = sense_overview(run)
    assert overview.frames == len(frames) - 2 and not overview.rate_measured
    report = build_report(load_run(cut), tmp_path / "report")
    assert "incomplete row" in (tmp_path / "report" / "report.html").read_text()
    assert report.truth is None  # the recording is named only by the cut sense.json


def test_diagnose_folder_report(tmp_path):
    folder = load_run(diagnose_folder(tmp_path / "diagnose"))
    assert folder.sense is None and folder.diagnose.diagnosis.verdict == "cable_slack"
    report = build_report(folder, tmp_path / "report")
    page = report.page.read_text()
    assert {p.name for p in report.pngs} == {"effects.png", "location.png"}
    assert "slack_north_mm" in page and "figure-location" in page
    assert page.count("<img alt=") == 2  # location projections + diagnose's own figure
    console = Console(width=150, record=True)
    console.print(terminal.diagnosis_summary(folder.diagnose.diagnosis))
    text = console.export_text()
    assert "verdict: cable_slack (at regions north; cables north)" in text
    assert "cable_slack (north)" in page and "region_rms_mm" in page
    assert "72 %" in text  # 1 - 0.9 / 3.2 of the held-out residual removed
    effects = available_tables(folder, None)["effects"]
    assert list(effects["value"]) == [2.1, 1.05]
    assert list(effects["ci95_hi"]) == [2.4, 1.12]


def test_an_effect_judged_on_the_markers_says_so(tmp_path):
    """A camera effect judged on the markers (docs/diagnosis.md, step 13) has the markers'
    held-out figures: its label says so wherever the report shows it."""
    folder = diagnose_folder(tmp_path / "diagnose")
    turned = {"name": "extrinsic_offset", "parameters": {
        "rotation_z_deg": {"value": 0.98, "ci95": [0.87, 1.09], "unit": "deg"}},
        "heldout_rms_before_mm": 0.95, "heldout_rms_after_mm": 0.69,
        "evidence": {"channel": "markers", "mode": "absolute"}}
    (folder / "diagnosis.json").write_text(json.dumps({
        **DIAGNOSIS, "verdict": "extrinsic_offset", "effects": [turned, *DIAGNOSIS["effects"]],
        "evidence": {**DIAGNOSIS["evidence"], "markers": {"noise_floor_mm": 0.44}}}))
    effects = load_run(folder).diagnose.diagnosis.effects
    assert [e.label for e in effects] == ["extrinsic_offset [markers]", "cable_slack (north)",
                                          "stiffness_scale"]
    report = build_report(load_run(folder), tmp_path / "report")
    assert "extrinsic_offset [markers]" in report.page.read_text()
    # its held-out bars are drawn against the markers' floor, not beside the clouds'
    assert {p.name for p in report.pngs} == {"effects.png", "marker_effects.png",
                                              "location.png"}


def test_a_pair_is_labelled_with_both_effects_and_its_targets_are_not_markup(tmp_path):
    """diagnose writes a pair's label with its targets in brackets; the report names both
    effects, and the terminal shows the brackets of its parameters as written."""
    folder = diagnose_folder(tmp_path / "diagnose")
    pair = {"name": "material_nonlinearity", "label": "cable_slack[north] + material_nonlinearity",
            "parameters": {
                "cable_slack[north].slack_mm": {"value": 3.02, "ci95": [2.96, 3.08], "unit": "mm"},
                "material_nonlinearity.blend": {"value": 0.89, "ci95": [0.56, 1.0], "unit": ""}},
            "heldout_rms_before_mm": 1.14, "heldout_rms_after_mm": 0.31,
            "evidence": {"mode": "absolute"}}
    (folder / "diagnosis.json").write_text(json.dumps({
        **DIAGNOSIS, "effects": [DIAGNOSIS["effects"][0], pair]}))
    effects = load_run(folder).diagnose.diagnosis.effects
    assert [e.label for e in effects] == [
        "cable_slack (north)", "cable_slack (north) + material_nonlinearity"]
    summary = terminal.diagnosis_summary(load_run(folder).diagnose.diagnosis)
    wide, narrow = Console(width=200, record=True), Console(width=80, record=True)
    wide.print(summary)
    narrow.print(summary)
    text = wide.export_text()
    assert "cable_slack (north) + material_nonlinearity" in text
    assert "cable_slack[north].slack_mm 3.02 mm [2.96, 3.08]" in text
    assert "…" not in narrow.export_text()  # a narrow terminal folds long cells


def test_bad_diagnosis_field_is_one_line(tmp_path):
    folder = diagnose_folder(tmp_path / "diagnose")
    broken = {k: v for k, v in DIAGNOSIS.items() if k != "noise_floor_mm"}
    (folder / "diagnosis.json").write_text(json.dumps(broken))
    with pytest.raises(ReportError, match="noise_floor_mm"):
        load_run(folder)
    (folder / "diagnosis.json").write_text(json.dumps({**DIAGNOSIS, "effects": [{"name": 3}]}))
    with pytest.raises(ReportError, match=r"effects\[0\]: the field 'parameters'"):
        load_run(folder)
    # diagnose writes null for a number that is not finite: read as NaN, not refused
    (folder / "diagnosis.json").write_text(json.dumps({**DIAGNOSIS, "noise_floor_mm": None}))
    assert np.isnan(load_run(folder).diagnose.diagnosis.noise_floor_mm)


def test_neither_sense_nor_diagnose_folder_is_one_line(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    assert_one_line_error(softforce("report", tmp_path), "neither a sense output")


def test_missing_robot_and_unknown_column_are_one_line(sense_out, tmp_path):
    moved = tmp_path / "moved"
    shutil.copytree(sense_out, moved, ignore=shutil.ignore_patterns("report"))
    document = json.loads((moved / "sense.json").read_text())
    document["robot"]["file"] = "gone/robot.toml"
    (moved / "sense.json").write_text(json.dumps(document))
    assert_one_line_error(softforce("report", moved), "--robot")
    assert not (moved / "report" / "report.html").exists()
    assert_one_line_error(softforce("report", moved, "--columns", "frame"), "--format csv")
    with pytest.raises(ReportError, match="no column 'speed'; its columns are frame,"):
        select_columns(load_run(moved).sense.contacts, "contacts", ["frame", "speed"])


def test_existing_report_is_not_overwritten_without_force(html_run, sense_out):
    _, out = html_run
    before = (out / "report.html").stat().st_mtime_ns
    assert_one_line_error(softforce("report", sense_out), "--force")
    assert (out / "report.html").stat().st_mtime_ns == before

