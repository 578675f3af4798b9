"""MCAP recordings: round trips, summary, interruption safety, truncation, bad input, CLI info."""

from __future__ import annotations

import io
import json
import signal
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from mcap.reader import make_reader
from mcap.writer import Writer as McapWriter
from mcap_protobuf.decoder import DecoderFactory
from mcap_protobuf.schema import register_schema
from PIL import Image
from typer.testing import CliRunner

from softforce_cli import __version__
from softforce_cli.camera.frame import Actuation, Markers, RgbdFrame
from softforce_cli.camera.intrinsics import CameraIntrinsics
from softforce_cli.camera.lens import LensDistortion
from softforce_cli.camera.rectification import rectified
from softforce_cli.cli import record_commands
from softforce_cli.errors import OutputExistsError, RecordingError
from softforce_cli.io import recording_format as fmt
from softforce_cli.io.mcap_reader import RecordingWarning, iter_frames, read_summary
from softforce_cli.io.mcap_writer import RecordingWriter, write_recording

INTRINSICS = CameraIntrinsics(width=64, height=48, fx=60.25, fy=61.5, cx=31.75, cy=23.25)
T0_NS = 1_700_000_000_123_456_789  # a unix time, to check nanosecond precision survives
PERIOD_NS = 33_333_333


def make_frames(n: int, seed: int = 0, *, with_extras: bool = True) -> list[RgbdFrame]:
    rng = np.random.default_rng(seed)
    frames = []
    for i in range(n):
        actuation = Actuation(("north", "east"), "displacement", np.array([0.5 * i, 1.25]))
        markers = Markers(("apex", "tip"), rng.normal(0.0, 100.0, (2, 3)))
        frames.append(
            RgbdFrame(
                time_ns=T0_NS + i * PERIOD_NS,
                color=rng.integers(0, 256, (48, 64, 3), dtype=np.uint8),
                depth_mm=rng.integers(0, 65536, (48, 64), dtype=np.uint16),
                intrinsics=INTRINSICS,
                actuation=actuation if with_extras else None,
                markers=markers if with_extras else None,
            )
        )
    return frames


def assert_same_frame(got: RgbdFrame, want: RgbdFrame) -> None:
    assert got.time_ns == want.time_ns
    np.testing.assert_array_equal(got.color, want.color)
    np.testing.assert_array_equal(got.depth_mm, want.depth_mm)
    assert got.color.dtype == np.uint8 and got.depth_mm.dtype == np.uint16
    assert got.intrinsics == want.intrinsics
    if want.actuation is None:
        assert got.actuation is None
    else:
        assert got.actuation.names == want.actuation.names
        assert got.actuation.control == want.actuation.control
        np.testing.assert_array_equal(got.actuation.values, want.actuation.values)
    if want.markers is None:
        assert got.markers is None
    else:
        assert got.markers.ids == want.markers.ids
        np.testing.assert_array_equal(got.markers.positions_mm, want.markers.positions_mm)


def raise_after(frames: list[RgbdFrame], n: int, error: BaseException):
    yield from frames[:n]
    raise error


@pytest.fixture
def recording(tmp_path: Path) -> tuple[Path, list[RgbdFrame]]:
    frames = make_frames(12)
    path = tmp_path / "rec.mcap"
    write_recording(frames, path, metadata={"scenario": "press.toml"})
    return path, frames


def test_round_trip_is_exact(recording):
    path, frames = recording
    got = list(iter_frames(path))
    assert len(got) == len(frames)
    for g, w in zip(got, frames, strict=True):
        assert_same_frame(g, w)


def test_frames_without_extras_have_no_optional_topics(tmp_path):
    frames = make_frames(3, with_extras=False)
    write_recording(frames, tmp_path / "plain.mcap")
    for g, w in zip(iter_frames(tmp_path / "plain.mcap"), frames, strict=True):
        assert_same_frame(g, w)
    topics = {t.topic for t in read_summary(tmp_path / "plain.mcap").topics}
    assert topics == set(fmt.REQUIRED_TOPICS)


def test_summary_from_index(recording):
    path, _ = recording
    summary = read_summary(path)
    assert summary.indexed
    assert summary.frame_count == 12
    assert summary.start_time_ns == T0_NS
    assert summary.end_time_ns == T0_NS + 11 * PERIOD_NS
    assert summary.duration_s == pytest.approx(11 * PERIOD_NS * 1e-9, abs=1e-12)
    assert summary.frame_rate_hz == pytest.approx(1e9 / PERIOD_NS)
    assert summary.intrinsics == INTRINSICS
    assert summary.metadata["softforce"] == {
        "softforce_version": __version__,
        "scenario": "press.toml",
    }
    assert summary.actuation_names == ("north", "east")
    assert summary.actuation_control == "displacement"
    assert summary.marker_ids == ("apex", "tip")
    counts = {t.topic: t.message_count for t in summary.topics}
    assert counts == dict.fromkeys(fmt.FRAME_TOPICS, 12)
    schemas = {t.topic: t.schema for t in summary.topics}
    assert schemas[fmt.COLOR_TOPIC] == schemas[fmt.DEPTH_TOPIC] == "foxglove.RawImage"
    assert schemas[fmt.CAMERA_INFO_TOPIC] == "foxglove.CameraCalibration"
    document = summary.to_dict()
    assert json.loads(json.dumps(document)) == document
    assert document["resolution"] == {"width": 64, "height": 48}


def test_file_is_foxglove_compatible(recording):
    """Decode with mcap-protobuf's own decoder (not ours): the layout Foxglove expects."""
    path, frames = recording
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary.statistics.chunk_count == len(frames)  # one chunk per frame: lazy reads
        header = reader.get_header()
        assert header.library.startswith("softforce/")
        seen = {}
        for schema, channel, message, decoded in reader.iter_decoded_messages(
            topics=list(fmt.REQUIRED_TOPICS)
        ):
            seen.setdefault(channel.topic, (schema, message, decoded))
    _, message, color = seen[fmt.COLOR_TOPIC]
    assert (color.encoding, color.width, color.height, color.step) == ("rgb8", 64, 48, 192)
    assert color.frame_id == "camera_color_optical_frame"
    assert color.timestamp.ToNanoseconds() == message.log_time == T0_NS
    np.testing.assert_array_equal(
        np.frombuffer(color.data, np.uint8).reshape(48, 64, 3), frames[0].color
    )
    _, _, depth = seen[fmt.DEPTH_TOPIC]
    assert (depth.encoding, depth.step) == ("16UC1", 128)
    np.testing.assert_array_equal(
        np.frombuffer(depth.data, "<u2").reshape(48, 64), frames[0].depth_mm
    )
    _, _, info = seen[fmt.CAMERA_INFO_TOPIC]
    k = INTRINSICS
    assert list(info.K) == [k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1]
    assert list(info.P) == [k.fx, 0, k.cx, 0, 0, k.fy, k.cy, 0, 0, 0, 1, 0]
    assert (info.distortion_model, list(info.D)) == ("plumb_bob", [0.0] * 5)
    assert (info.width, info.height, info.frame_id) == (64, 48, "camera_color_optical_frame")
    with open(path, "rb") as stream:
        summary = make_reader(stream).get_summary()
    for channel in summary.channels.values():
        if channel.topic in (fmt.ACTUATION_TOPIC, fmt.MARKERS_TOPIC):
            assert channel.message_encoding == "json"
            assert summary.schemas[channel.schema_id].encoding == "jsonschema"


def test_messages_of_a_frame_share_log_time(recording):
    path, frames = recording
    with open(path, "rb") as stream:
        times = {}
        for _, channel, message in make_reader(stream).iter_messages():
            times.setdefault(message.log_time, set()).add(channel.topic)
    assert sorted(times) == [f.time_ns for f in frames]
    assert all(topics == set(fmt.FRAME_TOPICS) for topics in times.values())


def test_iteration_is_lazy_and_can_stop_early(recording):
    path, frames = recording
    iterator = iter_frames(path)
    assert_same_frame(next(iterator), frames[0])
    assert_same_frame(next(iterator), frames[1])
    iterator.close()  # closes the file; no warning, no error


def test_interrupted_recording_keeps_its_frames(tmp_path):
    frames = make_frames(8)
    path = tmp_path / "cut.mcap"
    with pytest.raises(KeyboardInterrupt):
        write_recording(raise_after(frames, 5, KeyboardInterrupt()), path)
    summary = read_summary(path)
    assert summary.indexed and summary.frame_count == 5
    for g, w in zip(iter_frames(path), frames[:5], strict=True):
        assert_same_frame(g, w)
    assert [p.name for p in tmp_path.iterdir()] == ["cut.mcap"]  # no temporary file left


def test_stop_on_interrupt_reports_it(tmp_path):
    frames = make_frames(6)
    result = write_recording(
        raise_after(frames, 4, KeyboardInterrupt()), tmp_path / "r.mcap", stop_on_interrupt=True
    )
    assert (result.frames, result.interrupted) == (4, True)
    assert read_summary(tmp_path / "r.mcap").frame_count == 4


def test_camera_failure_keeps_frames_and_propagates(tmp_path):
    frames = make_frames(6)
    with pytest.raises(RuntimeError, match="camera unplugged"):
        write_recording(
            raise_after(frames, 3, RuntimeError("camera unplugged")), tmp_path / "r.mcap"
        )
    assert len(list(iter_frames(tmp_path / "r.mcap"))) == 3


def test_interruption_before_any_frame_leaves_existing_file(tmp_path):
    path = tmp_path / "old.mcap"
    path.write_bytes(b"previous recording")
    result = write_recording(
        raise_after([], 0, KeyboardInterrupt()), path, force=True, stop_on_interrupt=True
    )
    assert (result.frames, result.interrupted) == (0, True)
    assert path.read_bytes() == b"previous recording"
    assert [p.name for p in tmp_path.iterdir()] == ["old.mcap"]


def _write_with_frame_4_interrupted(writer: RecordingWriter, frames: list, interrupt,
                                    calls: list) -> None:
    """Write frames 0-3, then frame 4 with interrupt() called before its third message
    (camera_info: actuation and markers written); `calls` receives every message tried."""
    for frame in frames[:4]:
        writer.write_frame(frame)
    add_message = writer._writer.add_message

    def add(**kwargs):
        calls.append(kwargs)
        if len(calls) == 3:
            interrupt()
        add_message(**kwargs)

    writer._writer.add_message = add
    writer.write_frame(frames[4])


def _crash() -> None:
    raise KeyboardInterrupt


def test_interruption_inside_a_frame_drops_only_that_frame(tmp_path):
    """An interruption raised between two messages of frame 4 (as a crash would cut it):
    frames 0-3 stay whole, frame 4 is skipped."""
    frames = make_frames(6)
    path = tmp_path / "mid.mcap"
    with pytest.raises(KeyboardInterrupt), RecordingWriter(path) as writer:
        _write_with_frame_4_interrupted(writer, frames, _crash, [])
    assert read_summary(path).frame_count == 4
    with pytest.warns(RecordingWarning, match="skipped 1 incomplete"):
        got = list(iter_frames(path))
    for g, w in zip(got, frames[:4], strict=True):
        assert_same_frame(g, w)


def test_a_signal_inside_a_frame_lands_after_it(tmp_path):
    """A real SIGINT between two messages of frame 4 waits until frame 4 is whole."""
    # Python's own handler, which a process started in the background (SIGINT ignored) lacks
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    frames = make_frames(6)
    path = tmp_path / "held.mcap"
    calls: list = []
    try:
        with pytest.raises(KeyboardInterrupt), RecordingWriter(path) as writer:
            _write_with_frame_4_interrupted(
                writer, frames, lambda: signal.raise_signal(signal.SIGINT), calls)
            writer.write_frame(frames[5])  # not reached: the signal lands once 4 is written
    finally:
        signal.signal(signal.SIGINT, previous)
    assert len(calls) == 5
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = list(iter_frames(path))
    assert len(got) == 5
    for g, w in zip(got, frames[:5], strict=True):
        assert_same_frame(g, w)


def test_truncated_file_yields_its_readable_frames(recording, tmp_path):
    path, frames = recording
    data = path.read_bytes()
    cut = tmp_path / "half.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = list(iter_frames(cut))
    messages = [str(w.message) for w in caught]
    assert len(messages) == 2
    assert "has no index" in messages[0] and "damaged or truncated" in messages[1]
    assert 3 <= len(got) < len(frames)  # each frame is ~15 kB, so about half survive
    for g, w in zip(got, frames, strict=False):
        assert_same_frame(g, w)
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        summary = read_summary(cut)
    assert not summary.indexed and summary.frame_count == len(got)
    assert summary.metadata["softforce"]["scenario"] == "press.toml"

    no_footer = tmp_path / "no_footer.mcap"
    no_footer.write_bytes(data[:-20])  # only the footer is lost: every frame survives
    with pytest.warns(RecordingWarning):
        assert len(list(iter_frames(no_footer))) == len(frames)


def test_file_cut_before_first_frame_is_an_error(recording, tmp_path):
    path, _ = recording
    cut = tmp_path / "stub.mcap"
    cut.write_bytes(path.read_bytes()[:100])
    with pytest.warns(RecordingWarning), pytest.raises(RecordingError, match="has no"):
        list(iter_frames(cut))


def _with_distortion(info: bytes, distortion: tuple[float, ...],
                     model: str = "plumb_bob") -> bytes:
    if not distortion:
        return info
    message = CameraCalibration.FromString(info)
    del message.D[:]
    message.D.extend(distortion)
    message.distortion_model = model
    return message.SerializeToString()


def compressed(pixels: np.ndarray, format: str, data: bytes | None = None) -> bytes:
    """A serialized foxglove.CompressedImage of pixels (h, w, 3) uint8 or (h, w) uint16 in
    format ('jpeg' at quality 95; ROS's compressedDepth: a 12-byte header, then the png);
    data: these bytes instead."""
    if data is None:
        stream = io.BytesIO()
        kind = "png" if "compressedDepth" in format else format
        Image.fromarray(pixels).save(stream, format=kind, quality=95)
        header = b"\0" * 12 if "compressedDepth" in format else b""
        data = header + stream.getvalue()
    return CompressedImage(format=format, data=data).SerializeToString()


def write_custom(
    path: Path,
    frames: list[RgbdFrame],
    *,
    topics=fmt.FRAME_TOPICS,
    extra=True,
    depth_size=None,
    depth_delay_ns=0,
    color_format=None,
    depth_format=None,
    compressed_data=None,
    color_encoding="rgb8",
    depth_encoding="16UC1",
    distortion=(),
    distortion_model="plumb_bob",
    actuation_on_change=False,
) -> None:
    """A recording written with the bare mcap writer: extra topics, missing or odd ones,
    colour and depth in other encodings (an unknown one relabels the rgb8 bytes), or as
    foxglove.CompressedImage of color_format and depth_format (compressed_data: its bytes
    instead of the image's); depth_delay_ns: depth logged that much after the rest."""
    with open(path, "wb") as stream:
        writer = McapWriter(stream)
        writer.start()
        image_schema = register_schema(writer, RawImage)
        info_schema = register_schema(writer, CameraCalibration)
        compressed_schema = register_schema(writer, CompressedImage)
        ids = {}
        for topic in topics:
            schema = {
                fmt.COLOR_TOPIC: image_schema if color_format is None else compressed_schema,
                fmt.DEPTH_TOPIC: image_schema if depth_format is None else compressed_schema,
                fmt.CAMERA_INFO_TOPIC: info_schema,
            }.get(topic, image_schema)
            if topic in (fmt.ACTUATION_TOPIC, fmt.MARKERS_TOPIC):
                ids[topic] = writer.register_channel(topic, "json", 0)
            else:
                ids[topic] = writer.register_channel(topic, "protobuf", schema)
        tf = writer.register_channel("/tf", "json", 0)
        for frame in frames:
            t = frame.time_ns
            depth = frame.depth_mm if depth_size is None else np.zeros(depth_size, np.uint16)
            color = fmt.encode_color(frame.color, t)
            if color_encoding != "rgb8":
                message = RawImage.FromString(color)
                message.encoding = color_encoding
                if color_encoding in fmt.COLOR_LAYOUTS:
                    channels, rgb = fmt.COLOR_LAYOUTS[color_encoding]
                    pixels = np.full((*frame.color.shape[:2], channels), 255, np.uint8)
                    pixels[:, :, rgb] = frame.color
                    message.data, message.step = pixels.tobytes(), channels * pixels.shape[1]
                color = message.SerializeToString()
            depth_data = fmt.encode_depth(depth, t)
            if depth_encoding == "32FC1":  # metres; no depth as NaN, as ROS drivers write it
                metres = np.where(depth > 0, depth / 1000.0, np.nan).astype("<f4")
                message = RawImage.FromString(depth_data)
                message.encoding, message.data = "32FC1", metres.tobytes()
                message.step = 4 * depth.shape[1]
                depth_data = message.SerializeToString()
            if color_format is not None:
                color = compressed(frame.color, color_format, compressed_data)
            if depth_format is not None:
                depth_data = compressed(depth, depth_format, compressed_data)
            data = {
                fmt.COLOR_TOPIC: color,
                fmt.DEPTH_TOPIC: depth_data,
                fmt.CAMERA_INFO_TOPIC: _with_distortion(fmt.encode_camera_info(
                    frame.intrinsics, t), distortion, distortion_model),
                fmt.ACTUATION_TOPIC: None if frame.actuation is None
                else fmt.encode_actuation(frame.actuation),
                fmt.MARKERS_TOPIC: fmt.encode_markers(frame.markers),
            }
            if extra:
                writer.add_message(tf, t - 1000, b'{"x": 1}', t - 1000)
            if actuation_on_change:  # logged when it changes, at a time of its own
                if frame.actuation is not None:
                    writer.add_message(ids[fmt.ACTUATION_TOPIC], t - 500_000,
                                       data[fmt.ACTUATION_TOPIC], t - 500_000)
                data.pop(fmt.ACTUATION_TOPIC)
            for topic in topics:
                if topic in data:
                    at = t + depth_delay_ns if topic == fmt.DEPTH_TOPIC else t
                    writer.add_message(ids[topic], at, data[topic], at)
            if extra:
                writer.add_message(tf, t, b'{"x": 2}', t)
        writer.finish()


def test_extra_topics_are_ignored(tmp_path):
    frames = make_frames(4)
    path = tmp_path / "extra.mcap"
    write_custom(path, frames)
    got = list(iter_frames(path))
    for g, w in zip(got, frames, strict=True):
        assert_same_frame(g, w)
    summary = read_summary(path)
    assert summary.frame_count == 4
    assert {t.topic: t.message_count for t in summary.topics}["/tf"] == 8


def test_actuation_holds_until_it_changes(tmp_path):
    """Another tool may log the inputs only when they change, at log times of their own:
    each frame takes the last inputs before it, and no frame is counted incomplete."""
    frames = make_frames(5)
    changes = {0: None, 1: np.array([2.0, 1.0]), 2: None, 3: None, 4: np.array([4.0, 0.0])}
    logged = [
        RgbdFrame(f.time_ns, f.color, f.depth_mm, f.intrinsics,
                  None if changes[i] is None else Actuation(("north", "east"), "displacement",
                                                           changes[i]), f.markers)
        for i, f in enumerate(frames)]
    path = tmp_path / "sparse.mcap"
    write_custom(path, logged, actuation_on_change=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = list(iter_frames(path))
    assert [g.time_ns for g in got] == [f.time_ns for f in frames]
    assert got[0].actuation is None
    held = [g.actuation.values.tolist() for g in got[1:]]
    assert held == [[2.0, 1.0], [2.0, 1.0], [2.0, 1.0], [4.0, 0.0]]
    assert read_summary(path).frame_count == 5


def test_lens_distortion_is_applied_or_said_once(tmp_path):
    """camera_info with distortion coefficients (another tool's, a lens that distorts): a
    model softforce knows is rectified away (tests/test_lens.py), another is said once per
    recording and the images read through K alone."""
    frames = make_frames(3)
    lens = (0.1, -0.05, 0.0, 0.0, 0.0)
    write_custom(tmp_path / "distorted.mcap", frames, distortion=lens)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RecordingWarning)
        got = list(iter_frames(tmp_path / "distorted.mcap"))
    for g, w in zip(got, frames, strict=True):
        through = replace(w, intrinsics=replace(
            w.intrinsics, distortion=LensDistortion("plumb_bob", lens)))
        assert_same_frame(g, rectified(through))
    assert not np.array_equal(got[0].depth_mm, frames[0].depth_mm)
    path = tmp_path / "unknown.mcap"
    write_custom(path, frames, distortion=(0.1,) * 6, distortion_model="fisheye62")
    with pytest.warns(RecordingWarning, match="fisheye62") as caught:
        got = list(iter_frames(path))
    assert sum("distortion" in str(w.message) for w in caught) == 1
    for g, w in zip(got, frames, strict=True):
        assert_same_frame(g, w)
    write_custom(tmp_path / "plain.mcap", frames, distortion=(0.0,) * 5)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RecordingWarning)
        list(iter_frames(tmp_path / "plain.mcap"))


@pytest.mark.parametrize(("color_encoding", "depth_encoding"),
                         [("bgr8", "16UC1"), ("rgba8", "16UC1"), ("bgra8", "32FC1"),
                          ("rgb8", "32FC1")])
def test_other_tools_encodings_read_as_the_same_frames(tmp_path, color_encoding,
                                                      depth_encoding):
    """Colour as bgr8, rgba8 or bgra8 and depth as 32FC1 in metres (what ROS drivers and
    OpenCV write; ROS REP 118) read as the rgb8 and 16UC1 millimetres softforce writes."""
    frames = make_frames(3)
    path = tmp_path / "other.mcap"
    write_custom(path, frames, color_encoding=color_encoding, depth_encoding=depth_encoding)
    for got, want in zip(iter_frames(path), frames, strict=True):
        assert_same_frame(got, want)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"topics": (fmt.COLOR_TOPIC, fmt.CAMERA_INFO_TOPIC)}, "has no /camera/aligned_depth"),
        ({"topics": (fmt.COLOR_TOPIC, fmt.DEPTH_TOPIC)}, "has no /camera/color/camera_info"),
        ({"topics": (fmt.DEPTH_TOPIC, fmt.CAMERA_INFO_TOPIC)}, "has no /camera/color/image_raw"),
        ({"depth_size": (24, 32)}, "depth is 32x24 but colour is 64x48"),
        ({"color_format": "jpeg", "compressed_data": b"\xff\xd8"},
         "is not a readable jpeg image"),
        ({"color_format": "png", "compressed_data": b"\xff\xd8\xff"},
         "is not a readable png image"),
        ({"color_format": "tiff"}, "compressed as 'tiff'; softforce reads jpeg or png or webp"),
        ({"depth_format": "jpeg", "compressed_data": b"\xff\xd8"},
         "compressed as 'jpeg'; softforce reads png there"),
        ({"color_encoding": "yuv422"}, "encoding 'yuv422'; softforce reads rgb8, bgr8"),
    ],
)
def test_bad_recordings_are_rejected(tmp_path, kwargs, message):
    path = tmp_path / "bad.mcap"
    write_custom(path, make_frames(2), **kwargs)
    with pytest.raises(RecordingError, match=message):
        list(iter_frames(path))
    if "depth_size" not in kwargs and "color_encoding" not in kwargs:
        with pytest.raises(RecordingError, match=message):
            read_summary(path)


@pytest.mark.parametrize(("color_format", "depth_format"),
                         [("png", "png"), ("jpeg", "16UC1; compressedDepth png"),
                          ("webp", "png")])
def test_compressed_images_are_read(tmp_path, color_format, depth_format):
    """foxglove.CompressedImage on the image topics, as Foxglove and ROS tools record to save
    space: png colour and depth are the frame's to the bit, jpeg and webp colour within a
    few levels of it (on a smooth image; random pixels are tens of levels off)."""
    rows, columns = np.mgrid[0:48, 0:64]
    smooth = np.stack([4 * columns, 5 * rows, 2 * (rows + columns)], axis=-1).astype(np.uint8)
    frames = [replace(f, color=smooth) for f in make_frames(3)]
    path = tmp_path / "compressed.mcap"
    write_custom(path, frames, color_format=color_format, depth_format=depth_format)
    got = list(iter_frames(path))
    assert len(got) == 3 and read_summary(path).frame_count == 3
    for g, w in zip(got, frames, strict=True):
        np.testing.assert_array_equal(g.depth_mm, w.depth_mm)
        assert g.color.shape == w.color.shape and g.color.dtype == np.uint8
        error = np.abs(g.color.astype(int) - w.color.astype(int))
        if color_format == "png":
            assert error.max() == 0
        else:
            assert 0 < error.mean() < 3


@pytest.mark.parametrize("delay_ns", [3_000_000, -5_000_000, 15_000_000])
def test_images_logged_at_their_own_times_pair_up(tmp_path, delay_ns):
    """Another tool logs each image when it receives it: a depth image logged within 16 ms of
    its colour image (before or after) joins it, at the colour image's time."""
    frames = make_frames(4)
    path = tmp_path / "apart.mcap"
    write_custom(path, frames, depth_delay_ns=delay_ns)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RecordingWarning)  # nothing incomplete
        got = list(iter_frames(path))
    assert len(got) == 4
    for g, w in zip(got, frames, strict=True):
        assert_same_frame(g, w)
    # half a frame from both colour images around it: each image alone, all incomplete
    write_custom(tmp_path / "far.mcap", frames, depth_delay_ns=16_700_000)
    with pytest.raises(RecordingError, match="has no complete frame"):
        list(iter_frames(tmp_path / "far.mcap"))


def test_at_90_fps_an_image_pairs_with_its_nearest(tmp_path):
    """Frames 11 ms apart, each depth logged 3 ms after its colour, and a stray depth image
    8 ms before the first colour (its own colour not in the file): the stray one is alone
    (incomplete) and every colour keeps its own depth."""
    frames = [replace(f, time_ns=T0_NS + i * 11_111_111) for i, f in enumerate(make_frames(4))]
    path = tmp_path / "fast.mcap"
    with open(path, "wb") as stream:
        writer = McapWriter(stream)
        writer.start()
        image, info = register_schema(writer, RawImage), register_schema(writer, CameraCalibration)
        ids = {topic: writer.register_channel(topic, "protobuf", schema) for topic, schema in
               ((fmt.COLOR_TOPIC, image), (fmt.DEPTH_TOPIC, image), (fmt.CAMERA_INFO_TOPIC, info))}
        stray = frames[0].time_ns - 8_000_000
        writer.add_message(ids[fmt.DEPTH_TOPIC], stray, fmt.encode_depth(
            np.zeros((48, 64), np.uint16), stray), stray)
        for frame in frames:
            t = frame.time_ns
            writer.add_message(ids[fmt.CAMERA_INFO_TOPIC], t,
                               fmt.encode_camera_info(frame.intrinsics, t), t)
            writer.add_message(ids[fmt.COLOR_TOPIC], t, fmt.encode_color(frame.color, t), t)
            writer.add_message(ids[fmt.DEPTH_TOPIC], t + 3_000_000,
                               fmt.encode_depth(frame.depth_mm, t), t + 3_000_000)
        writer.finish()
    with pytest.warns(RecordingWarning, match="1 incomplete"):
        got = list(iter_frames(path))
    assert [g.time_ns for g in got] == [f.time_ns for f in frames]
    for g, w in zip(got, frames, strict=True):
        np.testing.assert_array_equal(g.depth_mm, w.depth_mm)


@pytest.mark.parametrize("kind", ["jpeg", "png"])
def test_damaged_compressed_images_are_refused_in_a_line(tmp_path, kind):
    """Truncated or bit-flipped compressed colour: a RecordingError, never Pillow's own."""
    whole = CompressedImage.FromString(compressed(make_frames(1)[0].color, kind)).data
    rng = np.random.default_rng(3)
    flipped = bytearray(whole)
    for index in rng.integers(20, len(whole), 40):
        flipped[index] ^= 0xFF
    for damaged, must_fail in ((whole[: len(whole) // 2], True), (whole[:30], True),
                               (bytes(flipped), False)):
        path = tmp_path / "damaged.mcap"
        write_custom(path, make_frames(1), color_format=kind, compressed_data=damaged)
        try:
            list(iter_frames(path))
        except RecordingError as error:
            assert f"is not a readable {kind} image" in str(error)
        else:  # flipped bits may still decode (to other colours)
            assert not must_fail


def test_an_8_bit_depth_png_is_refused(tmp_path):
    frames = make_frames(1)
    path = tmp_path / "depth8.mcap"
    eight = [replace(f, depth_mm=(f.depth_mm >> 8).astype(np.uint8)) for f in frames]
    write_custom(path, eight, depth_format="png")
    with pytest.raises(RecordingError, match="is a L png; softforce reads compressed depth"):
        list(iter_frames(path))


@pytest.mark.parametrize(("index", "value"),
                         [(0, 0.0), (0, float("nan")), (4, float("inf")), (2, float("nan"))])
def test_camera_info_without_a_usable_finite_matrix_is_refused(index, value):
    # fx, fy or cx not a positive finite number: the camera is uncalibrated, not a crash
    info = CameraCalibration.FromString(
        fmt.encode_camera_info(CameraIntrinsics.from_fov(64, 48, 69.0), 0))
    K = list(info.K)
    K[index] = value
    info.ClearField("K")
    info.K.extend(K)
    with pytest.raises(RecordingError, match="no usable camera matrix K"):
        fmt.decode_camera_info(info.SerializeToString())


@pytest.mark.parametrize("value", [float("nan"), float("inf")])
def test_actuation_and_markers_that_are_not_finite_are_refused(value):
    # a NaN input reached the FE solve, which skipped the frame as a solver failure
    actuation = Actuation(("north", "west"), "displacement", np.array([3.0, value]))
    with pytest.raises(RecordingError, match="not a finite number"):
        fmt.decode_actuation(fmt.encode_actuation(actuation), "the frame")
    markers = Markers(("apex", "elbow"), np.array([[0.0, 0.0, 500.0], [value, 0.0, 500.0]]))
    with pytest.raises(RecordingError, match=r"marker\(s\) elbow at a position that is not"):
        fmt.decode_markers(fmt.encode_markers(markers), "the frame")


def test_missing_and_non_mcap_files(tmp_path):
    with pytest.raises(RecordingError, match="does not exist"):
        list(iter_frames(tmp_path / "nothing.mcap"))
    text = tmp_path / "notes.mcap"
    text.write_text("not a recording\n")
    with pytest.raises(RecordingError, match="is not an MCAP file"):
        read_summary(text)
    with pytest.raises(RecordingError, match="is a directory"):
        read_summary(tmp_path)


def test_writer_refuses_to_overwrite_and_bad_frames(tmp_path):
    path = tmp_path / "keep.mcap"
    path.write_bytes(b"keep me")
    with pytest.raises(OutputExistsError, match="--force"):
        RecordingWriter(path)
    assert path.read_bytes() == b"keep me"
    frames = make_frames(2)
    with pytest.raises(RecordingError, match="does not come after"):
        write_recording([frames[1], frames[0]], tmp_path / "order.mcap")
    bad = RgbdFrame(0, frames[0].color, frames[0].depth_mm.astype(np.float32), INTRINSICS)
    with pytest.raises(ValueError, match="uint16"):
        write_recording([bad], tmp_path / "dtype.mcap")
    assert not (tmp_path / "dtype.mcap").exists()


def test_cli_info_json_and_text(recording):
    path, _ = recording
    runner = CliRunner()
    result = runner.invoke(record_commands.app, ["info", str(path), "--json"])
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)  # exactly one JSON document on stdout
    assert document["frames"] == 12
    assert document["resolution"] == {"width": 64, "height": 48}
    assert document["intrinsics"] == {"fx": 60.25, "fy": 61.5, "cx": 31.75, "cy": 23.25}
    assert document["metadata"]["softforce"]["scenario"] == "press.toml"
    text = runner.invoke(record_commands.app, ["info", str(path)])
    assert text.exit_code == 0
    assert "64x48" in text.stdout and "fx 60.250" in text.stdout


def test_cli_info_shows_the_files_own_names_as_written(tmp_path):
    # a scenario or path with brackets is not rich markup: nothing of it is dropped
    path = tmp_path / "[take]" / "rec.mcap"
    path.parent.mkdir()
    write_recording(make_frames(2), path, metadata={"scenario": "[arm] press.toml"})
    text = CliRunner().invoke(record_commands.app, ["info", str(path)], terminal_width=250)
    assert text.exit_code == 0, text.output
    assert "scenario=[arm] press.toml" in text.stdout and "[take]" in text.stdout


def test_cli_info_on_truncated_file_warns_on_stderr_only(recording, tmp_path):
    path, _ = recording
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 2])
    result = CliRunner().invoke(record_commands.app, ["info", str(cut), "--json"])
    assert result.exit_code == 0
    assert json.loads(result.stdout)["indexed"] is False
    assert "warning:" in result.stderr


def test_warnings_are_warnings_not_prints(recording, tmp_path, capsys):
    path, _ = recording
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[:-20])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        list(iter_frames(cut))
    assert caught and all(issubclass(w.category, RecordingWarning) for w in caught)
    assert capsys.readouterr() == ("", "")
