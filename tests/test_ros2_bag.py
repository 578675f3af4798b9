"""ROS 2 bags of a RealSense (io/ros2_bag.py, `softforce record --from BAG`).

The bags are written here as `ros2 bag record` writes realsense-ros's topics: an MCAP with
ros2msg schemas through Foxglove's mcap_ros2 writer, and a rosbag2 SQLite file with the
messages CDR-encoded by mcap_ros2's serializer (an independent encoder of the same format).
"""

from __future__ import annotations

import io
import sqlite3
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from mcap_ros2._dynamic import serialize_dynamic
from mcap_ros2.writer import Writer as Ros2Writer
from PIL import Image

from softforce_cli.camera.lens import LensDistortion
from softforce_cli.errors import RecordingError
from softforce_cli.io.mcap_reader import iter_frames, read_summary
from softforce_cli.io.ros2_bag import (
    CAMERA_INFO,
    COMPRESSED,
    DEFINITIONS,
    IMAGE,
    is_ros2_bag,
    iter_bag_frames,
)
from tests.cli_runner import assert_one_line_error, softforce
from tests.test_fuzz_harness import call_reader, classify, fuzz_cases, report, run_cli

NS = "/camera/camera"
T0 = 1_700_000_000_000_000_000
PERIOD = 33_333_333
W, H = 32, 24
K = [30.0, 0.0, 15.5, 0.0, 31.0, 11.5, 0.0, 0.0, 1.0]
D = [0.05, -0.01, 0.0, 0.0, 0.0]


def header(time_ns: int) -> dict:
    return {"stamp": {"sec": time_ns // 10**9, "nanosec": time_ns % 10**9},
            "frame_id": "camera_color_optical_frame"}


def colour_of(i: int) -> np.ndarray:
    return np.full((H, W, 3), (10 * i, 100, 200), np.uint8)


def depth_of(i: int) -> np.ndarray:
    return (500 + 10 * i + np.arange(W * H).reshape(H, W) % 7).astype(np.uint16)


def bag_messages(frames: int, *, depth_offset_ns: int = 3_000_000, skip_depth=(),
                 compressed=False, namespace=NS, period=PERIOD
                 ) -> list[tuple[str, str, int, dict]]:
    """(topic, type, log time, message) as realsense-ros publishes them: colour (rgb8, or
    jpeg when compressed), aligned depth 16UC1 stamped depth_offset_ns later, camera_info."""
    messages = []
    for i in range(frames):
        t = T0 + i * period
        messages.append((f"{namespace}/color/camera_info", CAMERA_INFO, t, {
            "header": header(t), "height": H, "width": W, "distortion_model": "plumb_bob",
            "d": D, "k": K, "r": [1.0, 0, 0, 0, 1, 0, 0, 0, 1],
            "p": [30.0, 0, 15.5, 0, 0, 31.0, 11.5, 0, 0, 0, 1, 0], "binning_x": 0,
            "binning_y": 0, "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0,
                                    "do_rectify": False}}))
        if compressed:
            stream = io.BytesIO()
            Image.fromarray(colour_of(i)).save(stream, format="png")
            messages.append((f"{namespace}/color/image_raw/compressed", COMPRESSED, t, {
                "header": header(t), "format": "png", "data": stream.getvalue()}))
        else:
            messages.append((f"{namespace}/color/image_raw", IMAGE, t, {
                "header": header(t), "height": H, "width": W, "encoding": "rgb8",
                "is_bigendian": 0, "step": 3 * W, "data": colour_of(i).tobytes()}))
        if i not in skip_depth:
            td = t + depth_offset_ns
            messages.append((f"{namespace}/aligned_depth_to_color/image_raw", IMAGE, td, {
                "header": header(td), "height": H, "width": W, "encoding": "16UC1",
                "is_bigendian": 0, "step": 2 * W, "data": depth_of(i).tobytes()}))
    messages.append(("/tf", "std_msgs/msg/String", T0, {"data": "ignored"}))
    return messages


def write_mcap_bag(path: Path, messages) -> Path:
    with open(path, "wb") as stream:
        writer = Ros2Writer(stream)
        schemas = {}
        for topic, kind, time_ns, message in sorted(messages, key=lambda m: m[2]):
            if kind not in schemas:
                schemas[kind] = writer.register_msgdef(kind, DEFINITIONS.get(kind, "string data"))
            writer.write_message(topic, schemas[kind], message, log_time=time_ns)
        writer.finish()
    return path


def write_db3_bag(path: Path, messages) -> Path:
    """A rosbag2 SQLite file (the tables of ROS 2 Humble's sqlite3 storage)."""
    connection = sqlite3.connect(path)
    connection.executescript(
        "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,"
        " serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);"
        "CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,"
        " timestamp INTEGER NOT NULL, data BLOB NOT NULL);")
    ids: dict[str, int] = {}
    for topic, kind, time_ns, message in messages:
        if topic not in ids:
            ids[topic] = len(ids) + 1
            connection.execute("INSERT INTO topics VALUES (?, ?, ?, 'cdr', '')",
                               (ids[topic], topic, kind))
        encode = serialize_dynamic(kind, DEFINITIONS.get(kind, "string data"))[kind]
        connection.execute("INSERT INTO messages(topic_id, timestamp, data) VALUES (?, ?, ?)",
                           (ids[topic], time_ns, encode(message)))
    connection.commit()
    connection.close()
    return path


@pytest.mark.parametrize("write", [write_mcap_bag, write_db3_bag])
def test_a_realsense_ros_bag_reads_as_frames(tmp_path, write):
    """Colour and aligned depth paired by stamp (3 ms apart), the colour's stamp the frame's
    time, the calibration's lens kept; a colour image without depth is skipped."""
    path = write(tmp_path / f"bag{'.mcap' if write is write_mcap_bag else '.db3'}",
                 bag_messages(5, skip_depth=(2,)))
    assert is_ros2_bag(path)
    frames = list(iter_bag_frames(path))
    assert [f.time_ns for f in frames] == [T0 + i * PERIOD for i in (0, 1, 3, 4)]
    for frame, i in zip(frames, (0, 1, 3, 4), strict=True):
        np.testing.assert_array_equal(frame.color, colour_of(i))
        np.testing.assert_array_equal(frame.depth_mm, depth_of(i))
        k = frame.intrinsics
        assert (k.width, k.height, k.fx, k.fy, k.cx, k.cy) == (W, H, 30.0, 31.0, 15.5, 11.5)
        assert k.distortion == LensDistortion("plumb_bob", tuple(D))


def test_a_bag_folder_with_compressed_colour_reads_too(tmp_path):
    folder = tmp_path / "rosbag2_2026_12_01"
    folder.mkdir()
    (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    write_mcap_bag(folder / "rosbag2_2026_12_01_0.mcap", bag_messages(3, compressed=True))
    frames = list(iter_bag_frames(folder))
    assert len(frames) == 3
    np.testing.assert_array_equal(frames[2].color, colour_of(2))


def test_at_90_fps_each_colour_takes_its_nearest_depth(tmp_path):
    """Frames 11 ms apart, shorter than the 16 ms a pair may span: a depth image 8 ms before
    the first colour one (its own colour image not in the bag) is passed over for the one
    3 ms after it, and every frame keeps its own depth."""
    period = 11_111_111
    messages = bag_messages(4, period=period)
    early = T0 - 8_000_000
    messages.append((f"{NS}/aligned_depth_to_color/image_raw", IMAGE, early, {
        "header": header(early), "height": H, "width": W, "encoding": "16UC1",
        "is_bigendian": 0, "step": 2 * W, "data": depth_of(99).tobytes()}))
    frames = list(iter_bag_frames(write_mcap_bag(tmp_path / "fast.mcap", messages)))
    assert [f.time_ns for f in frames] == [T0 + i * period for i in range(4)]
    for i, frame in enumerate(frames):
        np.testing.assert_array_equal(frame.depth_mm, depth_of(i))


def test_depth_half_a_frame_from_every_colour_is_not_paired(tmp_path):
    """16.6 ms after one colour image and 16.7 ms before the next: neither within the 16 ms
    a pair may be apart (20 ms after would pair with the next colour image, 13 ms away)."""
    path = write_mcap_bag(tmp_path / "late.mcap", bag_messages(4, depth_offset_ns=16_600_000))
    assert list(iter_bag_frames(path)) == []


@pytest.mark.parametrize(("messages", "message"), [
    (lambda: [m for m in bag_messages(2) if "aligned_depth" not in m[0]],
     "has no depth topic .*aligned_depth_to_color/image_raw.*align_depth.enable:=true"),
    (lambda: bag_messages(2) + bag_messages(2, namespace="/arm/camera"),
     "more than one camera with a colour topic"),
])
def test_a_bag_without_one_cameras_aligned_streams_is_refused(tmp_path, messages, message):
    path = write_mcap_bag(tmp_path / "bad.mcap", messages())
    with pytest.raises(RecordingError, match=message):
        iter_bag_frames(path)


def test_a_librealsense_db3_is_not_taken_for_a_ros2_bag(tmp_path):
    path = write_db3_bag(tmp_path / "librealsense.db3", [
        ("/file_version", "std_msgs/msg/String", T0, {"data": "4"}),
        ("/device_0/sensor_1/Color_0/image/data", IMAGE, T0, bag_messages(1)[1][3])])
    assert not is_ros2_bag(path)
    assert not is_ros2_bag(tmp_path / "missing.mcap")


def test_record_converts_a_ros2_bag_with_its_actuation(tmp_path):
    bag = write_mcap_bag(tmp_path / "bag.mcap", bag_messages(4))
    actuation = tmp_path / "act.csv"
    actuation.write_text("time_s,north_mm,east_mm\n0.0,1.0,2.0\n0.05,3.0,4.0\n")
    out = tmp_path / "rec.mcap"
    result = softforce("record", "--from", bag, "--actuation", actuation, "-o", out)
    assert result.returncode == 0, result.stderr
    frames = list(iter_frames(out))  # rectified: the lens came along
    assert len(frames) == 4 and read_summary(out).intrinsics.distortion is not None
    assert [list(f.actuation.values) for f in frames] == [[1.0, 2.0], [1.0, 2.0],
                                                          [3.0, 4.0], [3.0, 4.0]]
    # sensed as it is, the bag says how to convert it
    read_as_recording = softforce("record", "info", bag)
    assert_one_line_error(read_as_recording, "It is a ROS 2 bag: convert it with softforce "
                                             "record --from bag.mcap -o REC.mcap")
    folder_missing = softforce("record", "--from", tmp_path / "none", "-o", tmp_path / "x.mcap")
    assert_one_line_error(folder_missing, "does not exist")
    depthless = write_mcap_bag(tmp_path / "depthless.mcap",
                               [m for m in bag_messages(2) if "aligned" not in m[0]])
    refused = softforce("record", "--from", depthless, "-o", tmp_path / "y.mcap")
    assert_one_line_error(refused, "align_depth.enable:=true")


@pytest.mark.parametrize("write", [write_mcap_bag, write_db3_bag])
def test_damaged_bags_never_crash(tmp_path, write):
    """Cut short or with bytes flipped, a bag converts its readable frames or stops in one
    error line, never a traceback (the fuzz harness' rules, tests/test_fuzz_harness.py)."""
    suffix = ".mcap" if write is write_mcap_bag else ".db3"
    whole = write(tmp_path / f"whole{suffix}", bag_messages(4)).read_bytes()
    rng = np.random.default_rng(5)
    counts = Counter()
    for case in range(fuzz_cases(12)):
        damaged = bytearray(whole)
        if case % 2:
            for index in rng.integers(0, len(whole), 30):
                damaged[index] ^= 0xFF
        else:
            del damaged[int(rng.integers(10, len(whole))):]
        path = tmp_path / f"damaged{case}{suffix}"
        path.write_bytes(bytes(damaged))
        counts[f"frames {call_reader(lambda p: list(iter_bag_frames(p)), path)}"] += 1
        out = tmp_path / f"out{case}.mcap"
        counts[f"record {classify(run_cli('record', '--from', path, '-o', out))}"] += 1
    report(f"ROS 2 bag ({suffix})", counts)
    assert sum(counts.values()) == 2 * fuzz_cases(12)
