"""`softforce report --mcap`: the recording replayed with its results as foxglove schemas, read
back with the mcap library's reader and the protobuf schemas."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from softforce_cli.io import replay_writer as topics
from softforce_cli.io.mcap_reader import iter_frames
from tests.cli_runner import softforce
from tests.report_fixtures import PROBES_TRUTH, sense_folder
from tests.test_sense_cli import PROBES

RESULT_TOPICS = {
    topics.TF_TOPIC: "foxglove.FrameTransform",
    topics.ROBOT_POINTS_TOPIC: "foxglove.PointCloud",
    topics.OBJECT_POINTS_TOPIC: "foxglove.PointCloud",
    topics.SURFACE_TOPIC: "foxglove.SceneUpdate",
    topics.FORCES_TOPIC: "foxglove.SceneUpdate",
}

FORCE_SCALE = 1e-3


def with_true_forces(sense: Path, folder: Path) -> Path:
    """A copy of a sense run whose contacts carry the frame's first true force scaled by
    FORCE_SCALE: sense's own forces on the probes can be all zero, which draws no arrow;
    scaled down, they deform the robot by micrometres, so the shape stays the sensed one,
    while the arrows (scaled to the largest force) are drawn full length."""
    shutil.copytree(sense, folder, ignore=shutil.ignore_patterns("report"))
    truth = {f["index"]: f for f in json.loads(PROBES_TRUTH.read_text())["frames"]}
    rows = _rows(folder / "contacts.csv")
    for row in rows:
        force = FORCE_SCALE * np.array(truth[int(row["frame"])]["contacts"][0]["force_n"])
        row.update(force_n=f"{np.linalg.norm(force):.9f}",
                   **{k: f"{v:.9f}" for k, v in zip(("fx_n", "fy_n", "fz_n"), force,
                                                     strict=True)})
    with open(folder / "contacts.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return folder


@pytest.fixture(scope="module")
def replay(tmp_path_factory):
    base = tmp_path_factory.mktemp("replay")
    sense = with_true_forces(sense_folder(tmp_path_factory.getbasetemp() / "report_inputs"),
                             base / "sense")
    path = base / "replay.mcap"
    result = softforce("report", sense, "--format", "json", "-o", path.with_suffix(".json"),
                       "--mcap", path)
    assert result.returncode == 0, result.stderr
    messages: dict[str, list] = {}
    schemas = {}
    with open(path, "rb") as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        for schema, channel, _, proto in reader.iter_decoded_messages(topics=list(RESULT_TOPICS)):
            messages.setdefault(channel.topic, []).append(proto)
            schemas[channel.topic] = schema.name
    return sense, path, messages, schemas


def _rows(path):
    return list(csv.DictReader(path.read_text().splitlines()))


def _points_mm(cloud) -> np.ndarray:
    return 1e3 * np.frombuffer(cloud.data, dtype="<f4").reshape(-1, 3).astype(float)


def test_replay_holds_the_recording_and_one_result_message_per_frame(replay):
    _, path, messages, schemas = replay
    assert schemas == RESULT_TOPICS
    originals, replayed = list(iter_frames(PROBES)), list(iter_frames(path))
    assert len(replayed) == len(originals) == 4
    for a, b in zip(originals, replayed, strict=True):
        assert a.time_ns == b.time_ns
        np.testing.assert_array_equal(a.depth_mm, b.depth_mm)
        np.testing.assert_array_equal(a.actuation.values, b.actuation.values)
    assert all(len(messages[topic]) == 4 for topic in RESULT_TOPICS)


def test_points_are_segmented_as_sense_segmented_them(replay):
    """The replay runs the vision stage again on the rebuilt shape: its robot and object
    point counts are those sense wrote in frames.csv."""
    sense, _, messages, _ = replay
    frames = _rows(sense / "frames.csv")
    robot = [len(_points_mm(c)) for c in messages[topics.ROBOT_POINTS_TOPIC]]
    objects = [len(_points_mm(c)) for c in messages[topics.OBJECT_POINTS_TOPIC]]
    assert robot == [int(f["robot_points"]) for f in frames]
    assert objects == [int(f["object_points"]) for f in frames]


def test_surface_lies_on_the_observed_robot_points(replay, sample_robot):
    """The rebuilt surface against the depth camera's robot points (independent data): the
    median distance from a point to the nearest surface vertex is a few mm (the coarse P1
    model locks, docs/locking.md)."""
    _, _, messages, _ = replay
    for update, cloud in zip(messages[topics.SURFACE_TOPIC][1:],
                             messages[topics.ROBOT_POINTS_TOPIC][1:], strict=True):
        (entity,) = update.entities
        (triangles,) = entity.triangles
        vertices = 1e3 * np.array([[p.x, p.y, p.z] for p in triangles.points])
        assert len(triangles.indices) == 3 * len(sample_robot.mesh.surface_faces)
        assert len(vertices) == len(sample_robot.mesh.surface_nodes)
        distance, _ = cKDTree(vertices).query(_points_mm(cloud))
        assert np.median(distance) < 6.0


def test_arrows_end_at_the_contacts_along_their_forces(replay):
    sense, _, messages, _ = replay
    contacts = _rows(sense / "contacts.csv")
    pushes = [c for c in contacts if float(c["force_n"]) > 0]  # every one, see the fixture
    arrows = [(u.entities[0].timestamp.ToNanoseconds() * 1e-9, a)
              for u in messages[topics.FORCES_TOPIC] for a in u.entities[0].arrows]
    assert len(arrows) == len(pushes) >= 1
    for (time_s, arrow), contact in zip(arrows, pushes, strict=True):
        assert time_s == pytest.approx(float(contact["time_s"]), abs=1e-6)
        q = arrow.pose.orientation
        direction = Rotation.from_quat([q.x, q.y, q.z, q.w]).apply([1.0, 0.0, 0.0])
        length = arrow.shaft_length + arrow.head_length
        p = arrow.pose.position
        tip_mm = 1e3 * (np.array([p.x, p.y, p.z]) + length * direction)
        position = np.array([float(contact[k]) for k in ("x_mm", "y_mm", "z_mm")])
        force = np.array([float(contact[k]) for k in ("fx_n", "fy_n", "fz_n")])
        np.testing.assert_allclose(tip_mm, position, atol=1e-3)
        np.testing.assert_allclose(direction, force / np.linalg.norm(force), atol=1e-6)


def test_camera_pose_is_the_calibration(replay):
    camera = json.loads(PROBES_TRUTH.read_text())["camera"]
    _, _, messages, _ = replay
    transform = messages[topics.TF_TOPIC][0]
    assert (transform.parent_frame_id, transform.child_frame_id) == (
        "robot", "camera_color_optical_frame")
    q = transform.rotation
    np.testing.assert_allclose(Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix(),
                               camera["rotation"], atol=1e-9)
    t = transform.translation
    np.testing.assert_allclose(1e3 * np.array([t.x, t.y, t.z]), camera["translation_mm"],
                               atol=1e-9)
