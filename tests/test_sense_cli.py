"""`softforce sense` as a user runs it: the output files' contract, the sample's accuracy, and bad
inputs."""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from mcap_protobuf.schema import register_schema

from softforce_cli.calibration.result import read_calibration
from softforce_cli.camera.frame import Actuation
from softforce_cli.errors import SensingError
from softforce_cli.estimation.results import FrameEstimate
from softforce_cli.estimation.sensing import ForceSensor
from softforce_cli.estimation.settings import EstimationSettings, SenseSettings
from softforce_cli.estimation.summary import POOR_FIT_MM, SenseSummary
from softforce_cli.estimation.truth_errors import compare_with_truth, pose_from_truth, read_truth
from softforce_cli.io import recording_format as fmt
from softforce_cli.io.mcap_reader import iter_frames
from softforce_cli.io.mcap_writer import write_recording
from softforce_cli.model.robot import load_robot
from softforce_cli.vision.settings import VisionSettings
from tests.cli_runner import assert_one_line_error, softforce
from tests.conftest import ROOT, SAMPLE_ROBOT

PROBES = ROOT / "sample_data" / "recordings" / "probes.mcap"
P2_ROBOT = ROOT / "sample_data" / "diamond" / "diamond_p2.toml"
CONTACTS_HEADER = "frame,time_s,contact,feature,x_mm,y_mm,z_mm,force_n,fx_n,fy_n,fz_n,residual_mm"
FRAMES_HEADER = ("frame,time_s,status,contacts,points_kept,features_matched,features_hidden,"
                 "fit_rms_mm,total_ms")


def pose_calibration(truth_file: Path, folder: Path, **extra) -> Path:
    """A pose-only calibration (docs/calibration.md allows it) from a truth file's camera."""
    path = folder / "pose.json"
    path.write_text(json.dumps({**pose_from_truth(truth_file), **extra}))
    return path


@pytest.fixture(scope="module")
def probes_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sense")
    calibration = pose_calibration(PROBES.with_suffix("").with_suffix(".truth.json"), folder)
    result = softforce("sense", PROBES, "--robot", SAMPLE_ROBOT, "--calibration", calibration,
                       "-o", folder / "out")
    return result, folder / "out", calibration


def test_sense_writes_the_three_files_of_the_contract(probes_run):
    result, out, _ = probes_run
    assert result.returncode == 0, result.stderr
    # the P1 sample robot without a fitted E: the user is told that it reads forces low
    assert "warning:" in result.stderr and "lock" in result.stderr
    contacts = (out / "contacts.csv").read_text().splitlines()
    frames = list(csv.reader((out / "frames.csv").read_text().splitlines()))
    assert contacts[0] == CONTACTS_HEADER
    assert ",".join(frames[0]).startswith(FRAMES_HEADER)
    assert [row[0] for row in frames[1:]] == ["0", "1", "2", "3"]
    document = json.loads((out / "sense.json").read_text())
    assert {"recording", "robot", "calibration", "settings", "frames", "summary"} <= set(document)
    assert [f["frame"] for f in document["frames"]] == [0, 1, 2, 3]
    assert document["summary"]["frames"] == 4
    assert document["summary"]["poor_fit_frames"] == []
    # the 424x240 sample: every pixel, the paper's counts scaled to its coarser image (as
    # test_default_settings_are_scaled_to_the_recording_camera finds them in the pipeline)
    camera = document["camera"]
    assert (camera["width"], camera["height"], camera["decimation"]) == (424, 240, 1)
    assert (camera["outlier_min_neighbours"], camera["contact_min_neighbours"]) == (9, 1)
    assert 500 < camera["robot_distance_mm"] < 600
    for frame, row in zip(document["frames"], frames[1:], strict=True):
        assert frame["status"] == row[2]
        assert len(frame["contacts"]) == int(row[3])
        assert set(frame["timings_ms"]) >= {"cloud", "segmentation", "matching"}
    rows = list(csv.DictReader((out / "contacts.csv").read_text().splitlines()))
    assert len(rows) == sum(len(f["contacts"]) for f in document["frames"])
    # without --tare the sensor zeroes itself on the first frame, which shows no contact,
    # and stops at the second, which shows one
    assert document["tare_frames"] == "auto"
    assert [f["status"] for f in document["frames"]] == ["tare", "ok", "ok", "ok"]
    assert [len(f["contacts"]) for f in document["frames"]] == [0, 1, 1, 2]
    # the live table under the progress bar ends on the last frame's contacts
    table = result.stderr[result.stderr.rindex("contacts in the latest frame"):]
    for contact in document["frames"][-1]["contacts"]:
        assert f"{contact['force_n']:.3f}" in table
    # off a terminal the table's last line ends before the next message (it had joined it)
    assert any(line.startswith("wrote ") for line in result.stderr.splitlines())


def test_the_p2_robot_locates_and_weighs_the_sample_probes(tmp_path):
    """The whole chain against the recording's independent truth (P2 on another mesh,
    Neo-Hookean, the virtual D415's noise), as the demo senses it with the truth's camera
    pose: every probe located within 2 mm and weighed within 20% (0.4-1.6 mm and 2-15%
    on 2026-11-30, the three seen contacts where the line of sight meets the skin, the
    hidden tip at its node)."""
    truth_file = PROBES.with_suffix("").with_suffix(".truth.json")
    result = softforce("sense", PROBES, "--robot", P2_ROBOT, "--calibration",
                       pose_calibration(truth_file, tmp_path), "--tare", "1", "--updates", "6",
                       "-o", tmp_path / "out")
    assert result.returncode == 0, result.stderr
    document = json.loads((tmp_path / "out" / "sense.json").read_text())
    comparison = compare_with_truth(document, read_truth(truth_file))
    assert len(comparison.paired) == 4 and not comparison.missed
    assert not comparison.phantoms and not comparison.split
    for contact in comparison.paired:
        assert contact.location_error_mm < 2.0
        assert contact.relative_error < 0.20


def test_sense_refuses_to_overwrite_without_force(probes_run):
    _, out, calibration = probes_run
    before = (out / "sense.json").read_text()
    result = softforce("sense", PROBES, "--robot", SAMPLE_ROBOT, "--calibration", calibration,
                       "-o", out)
    assert_one_line_error(result, "--force")
    assert (out / "sense.json").read_text() == before


@pytest.mark.parametrize(("args", "fragment"), [
    (["--frames", "5"], "START:STOP"),
    (["--frames", "3:1"], "START < STOP"),
    (["--contact-point", "0,0,110"], "--direction"),
    (["--contact-point", "0,0", "--direction", "0,0,-1"], "3 comma-separated numbers"),
    (["--contact-point", "0,0,110", "--direction", "0,0,0"], "zero"),
    (["--force-model", "spring"], "force_model"),
    # a point in metres (or another frame) had been attached by extrapolating an element
    (["--contact-point", "0,0,1e4", "--direction", "0,0,-1"], "outside the robot, 9874 mm"),
    (["--robot-rgb", "300,0,0"], "each of R, G, B is 0-255"),
])
def test_bad_options_fail_with_one_line(probes_run, tmp_path, args, fragment):
    _, _, calibration = probes_run
    result = softforce("sense", PROBES, "--robot", SAMPLE_ROBOT, "--calibration", calibration,
                       "-o", tmp_path / "out", *args)
    assert_one_line_error(result, fragment)
    assert not (tmp_path / "out" / "sense.json").exists()


def test_calibration_of_another_robot_is_refused(tmp_path):
    calibration = pose_calibration(PROBES.with_suffix("").with_suffix(".truth.json"), tmp_path,
                                   robot={"name": "trunk", "file": "trunk.toml"})
    result = softforce("sense", PROBES, "--robot", SAMPLE_ROBOT, "--calibration", calibration,
                       "-o", tmp_path / "out")
    assert_one_line_error(result, "'trunk'")


@pytest.mark.parametrize("names", [(), None])
def test_a_robot_without_cables_is_sensed(tmp_path, names):
    """A passive soft body (no [[cable]]): its recording's /robot/actuation names no cable,
    or there is none. Both are sensed (an empty actuation had been refused as
    "displacement-controlled but the robot file's cables are -controlled"); the QP then
    has only the contacts' forces as unknowns."""
    text = SAMPLE_ROBOT.read_text().replace(
        'path = "diamond_coarse.vtu"', f'path = "{SAMPLE_ROBOT.parent / "diamond_coarse.vtu"}"')
    start, end = text.index("[[cable]]"), text.index("[features]")
    robot = tmp_path / "passive.toml"
    robot.write_text(text[:start] + text[end:])
    recording = tmp_path / "passive.mcap"
    actuation = None if names is None else Actuation(names, "displacement", np.zeros(0))
    write_recording((dataclasses.replace(f, actuation=actuation) for f in iter_frames(PROBES)),
                    recording)
    calibration = pose_calibration(PROBES.with_suffix("").with_suffix(".truth.json"), tmp_path)
    result = softforce("sense", recording, "--robot", robot, "--calibration", calibration,
                       "-o", tmp_path / "out", "--tare", "1")
    assert result.returncode == 0, result.stderr
    rows = csv.DictReader((tmp_path / "out" / "frames.csv").read_text().splitlines())
    statuses = [row["status"] for row in rows]
    # the Diamond without its cables sags away from the actuated recording: one frame
    # matches too few features; the point is that it runs
    assert statuses[0] == "tare" and statuses.count("ok") >= 2
    frames = json.loads((tmp_path / "out" / "sense.json").read_text())["frames"]
    assert all(frame["cable_tensions_n"] == [] for frame in frames)


def test_cables_listed_in_another_order_are_read_by_name(probes_run, tmp_path):
    """A recording from another tool may list the cables in another order than the robot
    file (DESIGN fixes the names, not their order): its /robot/actuation is read by name
    and senses exactly as the recording in the robot's order (it was refused before)."""
    _, out, calibration = probes_run

    def reversed_actuation(frame):
        a = frame.actuation
        return dataclasses.replace(frame, actuation=Actuation(a.names[::-1], a.control,
                                                              a.values[::-1].copy()))

    recording = tmp_path / "reversed.mcap"
    write_recording((reversed_actuation(f) for f in iter_frames(PROBES)), recording)
    assert next(iter_frames(recording)).actuation.names[0] == "east"
    result = softforce("sense", recording, "--robot", SAMPLE_ROBOT, "--calibration",
                       calibration, "-o", tmp_path / "out")
    assert result.returncode == 0, result.stderr
    assert ((tmp_path / "out" / "contacts.csv").read_text()
            == (out / "contacts.csv").read_text())


def write_as_another_tool(frames, path: Path) -> None:
    """The frames as another tool might log them within the format's contract
    (docs/recordings.md): colour bgr8, depth 32FC1 in metres (no depth as NaN), camera_info
    once, the inputs only when they change and at log times of their own (but the first), a
    /tf topic,
    lz4-compressed chunks of many frames, no softforce metadata."""
    with open(path, "wb") as stream:
        writer = McapWriter(stream, chunk_size=4 << 20, compression=CompressionType.LZ4)
        writer.start(profile="", library="another tool")
        image, info = register_schema(writer, RawImage), register_schema(writer, CameraCalibration)
        channels = {fmt.COLOR_TOPIC: writer.register_channel(fmt.COLOR_TOPIC, "protobuf", image),
                    fmt.DEPTH_TOPIC: writer.register_channel(fmt.DEPTH_TOPIC, "protobuf", image),
                    fmt.CAMERA_INFO_TOPIC: writer.register_channel(fmt.CAMERA_INFO_TOPIC,
                                                                   "protobuf", info),
                    fmt.ACTUATION_TOPIC: writer.register_channel(fmt.ACTUATION_TOPIC, "json", 0),
                    "/tf": writer.register_channel("/tf", "json", 0)}

        def log(topic: str, time_ns: int, data: bytes) -> None:
            writer.add_message(channels[topic], time_ns, data, time_ns)

        inputs = None
        for number, frame in enumerate(frames):
            t = frame.time_ns
            if number == 0:
                log(fmt.CAMERA_INFO_TOPIC, t, fmt.encode_camera_info(frame.intrinsics, t))
            if inputs is None or not np.array_equal(frame.actuation.values, inputs):
                inputs = frame.actuation.values
                log(fmt.ACTUATION_TOPIC, t - 1_000_000 if number else t,
                    fmt.encode_actuation(frame.actuation))
            log("/tf", t, b'{"x": 1}')
            depth_m = np.where(frame.depth_mm > 0, frame.depth_mm / 1000.0, np.nan)
            log(fmt.DEPTH_TOPIC, t, RawImage(
                timestamp=fmt.timestamp_from_ns(t), frame_id=fmt.OPTICAL_FRAME_ID,
                width=depth_m.shape[1], height=depth_m.shape[0], encoding="32FC1",
                step=4 * depth_m.shape[1], data=depth_m.astype("<f4").tobytes(),
            ).SerializeToString())
            log(fmt.COLOR_TOPIC, t, RawImage(
                timestamp=fmt.timestamp_from_ns(t), frame_id=fmt.OPTICAL_FRAME_ID,
                width=frame.color.shape[1], height=frame.color.shape[0], encoding="bgr8",
                step=3 * frame.color.shape[1], data=frame.color[:, :, ::-1].tobytes(),
            ).SerializeToString())
        writer.finish()


@pytest.mark.parametrize("name", ["probes", "diagnose_clean"])
def test_a_recording_another_tool_wrote_senses_as_softforces_own(name, tmp_path):
    """A sample recording logged as another tool might (write_as_another_tool; the clean
    diagnosis recording's inputs change every other frame): every frame read, the same
    fits and exactly the contacts of the recording softforce wrote."""
    original = ROOT / "sample_data" / "recordings" / f"{name}.mcap"
    calibration = pose_calibration(original.with_suffix("").with_suffix(".truth.json"), tmp_path)
    write_as_another_tool(iter_frames(original), tmp_path / "another_tool.mcap")
    for recording, out in ((original, "own"), (tmp_path / "another_tool.mcap", "another")):
        result = softforce("sense", recording, "--robot", SAMPLE_ROBOT, "--calibration",
                           calibration, "-o", tmp_path / out)
        assert result.returncode == 0, result.stderr
        assert "skipped" not in result.stderr

    def fits(out: str) -> list[list[str]]:
        rows = csv.reader((tmp_path / out / "frames.csv").read_text().splitlines())
        return [row[:FRAMES_HEADER.count(",")] for row in rows]

    assert len(fits("own")) == len(list(iter_frames(original))) + 1
    assert fits("another") == fits("own")
    assert ((tmp_path / "another" / "contacts.csv").read_text()
            == (tmp_path / "own" / "contacts.csv").read_text())


def test_actuation_values_are_put_in_the_robots_order():
    actuation = Actuation(("b", "c", "a"), "displacement", np.array([2.0, 3.0, 1.0]))
    np.testing.assert_array_equal(actuation.values_in(("a", "b", "c")), [1.0, 2.0, 3.0])
    for names in (("a", "b"), ("a", "b", "d"), ("a", "a", "b")):
        with pytest.raises(ValueError):
            actuation.values_in(names)


def test_missing_recording_and_settings_fail_with_one_line(probes_run, tmp_path):
    _, _, calibration = probes_run
    missing = softforce("sense", tmp_path / "none.mcap", "--robot", SAMPLE_ROBOT,
                        "--calibration", calibration, "-o", tmp_path / "out")
    assert_one_line_error(missing, "none.mcap")
    settings = tmp_path / "settings.toml"
    settings.write_text("[vision]\nvoxel_mm = -1.0\n")
    bad = softforce("sense", PROBES, "--robot", SAMPLE_ROBOT, "--calibration", calibration,
                    "-o", tmp_path / "out", "--settings", settings)
    assert_one_line_error(bad, "voxel_mm")
    settings.write_text("[vision]\nvoxel = 1.0\n")
    unknown = softforce("sense", PROBES, "--robot", SAMPLE_ROBOT, "--calibration", calibration,
                        "-o", tmp_path / "out", "--settings", settings)
    assert_one_line_error(unknown, "'voxel'")
    settings.write_text("[estimation]\nrelinearize_mm = -0.5\n")
    negative = softforce("sense", PROBES, "--robot", SAMPLE_ROBOT, "--calibration", calibration,
                         "-o", tmp_path / "out", "--settings", settings)
    assert_one_line_error(negative, "relinearize_mm")
    folder = softforce("sense", PROBES, "--robot", SAMPLE_ROBOT, "--calibration", calibration,
                       "-o", tmp_path / "out", "--settings", tmp_path)
    assert_one_line_error(folder, "is not a file")


def test_recording_without_actuation_is_refused_when_the_cables_need_it(tmp_path):
    bare = tmp_path / "bare.mcap"
    write_recording((dataclasses.replace(f, actuation=None) for f in iter_frames(PROBES)), bare)
    calibration = pose_calibration(PROBES.with_suffix("").with_suffix(".truth.json"), tmp_path)
    result = softforce("sense", bare, "--robot", SAMPLE_ROBOT, "--calibration", calibration,
                       "-o", tmp_path / "out")
    assert_one_line_error(result, "/robot/actuation")


def test_a_recording_that_starts_touched_is_not_zeroed(probes_run, tmp_path):
    """Automatic taring waits for a frame that shows no contact: from frame 1 on, the
    probes recording is touched in every frame, so nothing is tared."""
    _, _, calibration = probes_run
    result = softforce("sense", PROBES, "--robot", SAMPLE_ROBOT, "--calibration", calibration,
                       "--frames", "1:4", "-o", tmp_path / "out")
    assert result.returncode == 0, result.stderr
    document = json.loads((tmp_path / "out" / "sense.json").read_text())
    assert [f["status"] for f in document["frames"]] == ["ok", "ok", "ok"]
    assert [len(f["contacts"]) for f in document["frames"]] == [1, 1, 2]
    assert "starts touched: it never shows the robot free" in " ".join(result.stderr.split())


def test_a_recording_that_starts_touched_is_zeroed_when_first_seen_free(probes_run):
    """Automatic taring on a recording that starts touched: the sensor tares on the first
    frames that show the robot free, though contacts come between them (here the probes'
    free frame 0 shown after the touched frame 1, twice, between touched ones), up to
    AUTO_TARE_FRAMES; one that starts free stops taring at its first contact as before."""
    _, _, calibration = probes_run
    robot = load_robot(SAMPLE_ROBOT)
    frames = list(iter_frames(PROBES))[:3]

    def statuses(order: list[int]) -> tuple[list[str], int]:
        sensor = ForceSensor(robot, read_calibration(calibration).robot_from_camera,
                             frames[0].actuation.values, SenseSettings(), tare_frames=None)
        found = [sensor.process(i, frames[i]).status for i in order]
        return found, sensor.tare_left

    assert statuses([1, 0, 2, 0, 1]) == (["ok", "tare", "ok", "tare", "ok"], 1)
    assert statuses([0, 1, 0]) == (["tare", "ok", "ok"], 0)


def test_a_frame_whose_fit_diverged_is_skipped_as_lost(probes_run, tmp_path):
    """A fit more than estimation.lost_fit_mm above the first frame's means the model lost
    the robot: the frame is skipped as `lost` (with its fit kept for the record), the model
    starts again unloaded, and the run goes on. With a threshold of 1 micrometre: the P1
    model reads the probes' frames 2 and 3 more than 1.5 mm worse than frame 1 (it locks)."""
    _, _, calibration = probes_run
    settings = tmp_path / "settings.toml"
    settings.write_text("[estimation]\nlost_fit_mm = 0.001\n")
    result = softforce("sense", PROBES, "--robot", SAMPLE_ROBOT, "--calibration", calibration,
                       "--frames", "1:4", "--tare", "0", "--settings", settings,
                       "-o", tmp_path / "out")
    assert result.returncode == 0, result.stderr
    document = json.loads((tmp_path / "out" / "sense.json").read_text())
    frames = document["frames"]
    assert [f["status"] for f in frames] == ["ok", "lost", "lost"]
    assert all(f["contacts"] == [] and f["fit_rms_mm"] > frames[0]["fit_rms_mm"] + 0.001
               for f in frames[1:])
    assert document["summary"]["skipped"] == {"lost": 2}
    settings.write_text("[estimation]\nlost_fit_mm = 0\n")
    refused = softforce("sense", PROBES, "--robot", SAMPLE_ROBOT, "--calibration", calibration,
                        "-o", tmp_path / "out2", "--settings", settings)
    assert_one_line_error(refused, "lost_fit_mm")


def test_frames_that_fit_far_worse_than_the_first_are_listed():
    """(SenseSummary.poor_fit_frames) An ok frame fitting more than POOR_FIT_MM worse than
    the run's first fit (a tare frame's here) is listed, and sense warns about it; a frame
    within it, a skipped frame (lost: the sensor's own test) and a frame with no fit are
    not."""
    summary = SenseSummary()
    for frame, status, fit in [(0, "tare", 1.2), (1, "ok", 1.2 + POOR_FIT_MM - 0.01),
                               (2, "ok", 1.2 + POOR_FIT_MM + 0.01), (3, "lost", 12.0),
                               (4, "nodepth", float("nan")), (5, "ok", 9.0)]:
        summary.add(FrameEstimate(frame, 0.1 * frame, status, fit_rms_mm=fit))
    assert summary.poor_fit_frames == [2, 5]
    assert summary.to_dict()["poor_fit_frames"] == [2, 5]


def test_a_lost_frame_does_not_join_the_tare(probes_run):
    """Taring on the probes' first three frames with a 1 micrometre lost threshold: frame 0
    is tared, frames 1 and 2 are lost (the P1 model's fit grows) and leave the tare as it
    was: two tare frames are still to come, and the offsets are frame 0's alone."""
    _, _, calibration = probes_run
    robot = load_robot(SAMPLE_ROBOT)
    frames = list(iter_frames(PROBES))[:4]

    def sensor(lost_fit_mm: float) -> ForceSensor:
        settings = SenseSettings(estimation=EstimationSettings(lost_fit_mm=lost_fit_mm))
        return ForceSensor(robot, read_calibration(calibration).robot_from_camera,
                           frames[0].actuation.values, settings, tare_frames=3)

    strict, lenient = sensor(0.001), sensor(100.0)
    statuses = [strict.process(i, frame).status for i, frame in enumerate(frames[1:4])]
    lenient.process(0, frames[1])
    assert statuses == ["tare", "lost", "lost"]
    assert strict.tare_left == 2
    # the same arithmetic in two sensors, to round-off (numpy's SIMD sums depend on the
    # arrays' alignment): a lost frame joining the tare would move them by 0.01-1 mm
    np.testing.assert_allclose(strict.tare_offsets_mm, lenient.tare_offsets_mm, rtol=0,
                               atol=1e-9)


@pytest.mark.parametrize(("table", "key", "value", "fragment"), [
    # match_search_mm = 1e308 had sized the line samples: a ValueError traceback
    ("vision", "match_search_mm", float("inf"), "must be at most 1500 mm"),
    ("vision", "match_search_mm", 1e308, "must be at most 1500 mm"),
    ("vision", "voxel_mm", float("nan"), "must be positive"),
    ("vision", "match_max_view_deg", 120.0, "must be at most 90"),
    ("vision", "match_max_view_deg", float("nan"), "must be positive"),
    ("estimation", "rematch_mm", float("nan"), "is not a number"),
])
def test_settings_that_are_not_finite_or_beyond_the_scene_are_refused(table, key, value,
                                                                       fragment):
    kind = VisionSettings if table == "vision" else EstimationSettings
    with pytest.raises((ValueError, SensingError), match=fragment):
        kind(**{key: value})
