"""Lazy reading of RGB-D recordings: RgbdFrames one at a time, and a summary from the index.

Frames are the groups of messages that share a log time (DESIGN.md section 5). A finished
recording is read through its chunk index in log-time order, one chunk at a time, so memory does
not grow with the recording's length. A recording without a summary section (cut short by a
crash or a full disk) is scanned from the start instead: every frame before the damage is
returned, and a RecordingWarning says where reading stopped. Topics other than softforce's are
ignored.
"""

from __future__ import annotations

import contextlib
import struct
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import numpy as np
import zstandard
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.summary import Summary
from mcap.writer import MCAP0_MAGIC

from softforce_cli.camera.frame import RgbdFrame
from softforce_cli.camera.intrinsics import CameraIntrinsics
from softforce_cli.errors import RecordingError
from softforce_cli.io import recording_format as fmt

# What a damaged file raises inside the mcap library: short reads, bad lengths, CRC mismatches,
# undecodable chunk data.
_DAMAGE_ERRORS = (McapError, struct.error, ValueError, EOFError, OSError, zstandard.ZstdError)

_EXPECTED_SCHEMAS = {
    fmt.COLOR_TOPIC: ("protobuf", "foxglove.RawImage"),
    fmt.DEPTH_TOPIC: ("protobuf", "foxglove.RawImage"),
    fmt.CAMERA_INFO_TOPIC: ("protobuf", "foxglove.CameraCalibration"),
    fmt.ACTUATION_TOPIC: ("json", None),
    fmt.MARKERS_TOPIC: ("json", None),
}


class RecordingWarning(UserWarning):
    """A recording was read only in part: truncated, damaged, or with incomplete frames."""


@dataclass(frozen=True)
class TopicSummary:
    topic: str
    schema: str
    message_encoding: str
    message_count: int


@dataclass(frozen=True)
class RecordingSummary:
    """What a recording holds, read from its summary section (or a scan when it has none).

    frame_count   : frames with colour, depth and camera_info (the smallest of their counts).
    start_time_ns : log time of the first frame; end_time_ns that of the last.
    intrinsics    : of the first frame (its size is the recording's resolution).
    metadata      : metadata records by name, e.g. metadata["softforce"]["softforce_version"].
    indexed       : False when the file had no summary section and was scanned.
    """

    path: Path
    frame_count: int
    start_time_ns: int
    end_time_ns: int
    intrinsics: CameraIntrinsics
    topics: tuple[TopicSummary, ...]
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    actuation_names: tuple[str, ...] | None = None
    actuation_control: str | None = None
    marker_ids: tuple[str, ...] | None = None
    indexed: bool = True

    @property
    def duration_s(self) -> float:
        return (self.end_time_ns - self.start_time_ns) * 1e-9

    @property
    def frame_rate_hz(self) -> float | None:
        """Mean frame rate, None with fewer than two frames."""
        if self.frame_count < 2 or self.end_time_ns == self.start_time_ns:
            return None
        return (self.frame_count - 1) / self.duration_s

    def to_dict(self) -> dict:
        """A JSON-ready description (the document of `softforce record info --json`)."""
        k = self.intrinsics
        return {
            "path": str(self.path),
            "frames": self.frame_count,
            "duration_s": self.duration_s,
            "frame_rate_hz": self.frame_rate_hz,
            "start_time_ns": self.start_time_ns,
            "end_time_ns": self.end_time_ns,
            "resolution": {"width": k.width, "height": k.height},
            "intrinsics": {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy},
            "actuation": None
            if self.actuation_names is None
            else {"names": list(self.actuation_names), "control": self.actuation_control},
            "marker_ids": None if self.marker_ids is None else list(self.marker_ids),
            "topics": [vars(topic) for topic in self.topics],
            "metadata": self.metadata,
            "indexed": self.indexed,
        }


def iter_frames(path: Path) -> Iterator[RgbdFrame]:
    """Yield the frames of the recording `path` in time order, one at a time.

    Raises RecordingError for a missing file, a file that is not MCAP, a recording without the
    colour, depth or camera_info topic, and frames whose depth and colour sizes differ. Warns
    (RecordingWarning) when the file is truncated or frames are incomplete.
    """
    with open_recording(path) as (stream, reader, summary):
        if summary is not None:
            channels = check_channels(path, summary.channels, summary.schemas)
            messages = indexed_messages(path, reader, channels)
        else:
            messages = scanned_messages(path, stream, {})
        yield from frames_from_messages(path, messages)


@contextlib.contextmanager
def open_recording(path: Path) -> Iterator[tuple[BinaryIO, SeekingReader, Summary | None]]:
    """Open `path` and check it is MCAP; yield (stream, its reader, its Summary or None)."""
    path = Path(path)
    if not path.is_file():
        state = "is a directory" if path.is_dir() else "does not exist"
        raise RecordingError(f"recording {path} {state}")
    with open(path, "rb") as stream:
        if stream.read(len(MCAP0_MAGIC)) != MCAP0_MAGIC:
            raise RecordingError(
                f"{path} is not an MCAP file (wrong magic bytes); record one with "
                "`softforce record` or `softforce simulate`"
            )
        stream.seek(0)
        reader = SeekingReader(stream)
        try:
            summary = reader.get_summary()
        except _DAMAGE_ERRORS:
            summary = None
        if summary is not None and not summary.chunk_indexes:
            summary = None  # an unchunked file: scanning is the lazy way to read it
        if summary is None:
            warnings.warn(
                f"{path} has no index (was the recording cut short?); reading it from the start",
                RecordingWarning,
                stacklevel=4,
            )
        yield stream, reader, summary


def check_channels(
    path: Path, channels: dict[int, Channel], schemas: dict[int, Schema]
) -> dict[int, Channel]:
    """Channels of softforce topics, checked; RecordingError when a required one is missing."""
    ours = {cid: ch for cid, ch in channels.items() if ch.topic in _EXPECTED_SCHEMAS}
    present = {ch.topic for ch in ours.values()}
    for topic in fmt.REQUIRED_TOPICS:
        if topic not in present:
            raise RecordingError(
                f"{path} has no {topic} topic; a softforce recording needs "
                f"{', '.join(fmt.REQUIRED_TOPICS)}"
            )
    for channel in ours.values():
        _check_schema(path, channel, schemas.get(channel.schema_id))
    return ours


def _check_schema(path: Path, channel: Channel, schema: Schema | None) -> None:
    encoding, schema_name = _EXPECTED_SCHEMAS[channel.topic]
    actual = schema.name if schema is not None else "no schema"
    if channel.message_encoding != encoding or (schema_name and actual != schema_name):
        expected = f"{schema_name} ({encoding})" if schema_name else encoding
        raise RecordingError(
            f"{path}: topic {channel.topic} holds {actual} ({channel.message_encoding}) "
            f"messages; softforce reads {expected}"
        )


def indexed_messages(
    path: Path, reader: SeekingReader, channels: dict[int, Channel]
) -> Iterator[tuple[str, int, bytes]]:
    """(topic, log_time, data) of softforce topics in log-time order, chunk by chunk."""
    topics = [ch.topic for ch in channels.values()]
    try:
        for _, channel, message in reader.iter_messages(topics=topics, log_time_order=True):
            yield channel.topic, message.log_time, message.data
    except _DAMAGE_ERRORS as error:
        _warn_damage(path, error)


def scanned_messages(
    path: Path, stream: BinaryIO, metadata: dict[str, dict[str, str]]
) -> Iterator[tuple[str, int, bytes]]:
    """(topic, log_time, data) of softforce topics in file order, read up to any damage.

    Metadata records met on the way are stored into `metadata`.
    """
    channels: dict[int, Channel] = {}
    schemas: dict[int, Schema] = {}
    stream.seek(0)
    try:
        for record in StreamReader(stream, skip_magic=False).records:
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel) and record.topic in _EXPECTED_SCHEMAS:
                if record.id not in channels:
                    _check_schema(path, record, schemas.get(record.schema_id))
                channels[record.id] = record
            elif isinstance(record, Message) and record.channel_id in channels:
                yield channels[record.channel_id].topic, record.log_time, record.data
            elif isinstance(record, Metadata):
                metadata[record.name] = dict(record.metadata)
    except _DAMAGE_ERRORS as error:
        _warn_damage(path, error)
    present = {ch.topic for ch in channels.values()}
    for topic in fmt.REQUIRED_TOPICS:
        if topic not in present:
            raise RecordingError(f"{path} has no {topic} topic (in its readable part)")


def _warn_damage(path: Path, error: BaseException) -> None:
    detail = f"{type(error).__name__}: {error}" if str(error) else type(error).__name__
    warnings.warn(
        f"{path} is damaged or truncated ({detail}); read the frames before the damage",
        RecordingWarning,
        stacklevel=4,
    )


def frames_from_messages(
    path: Path, messages: Iterator[tuple[str, int, bytes]]
) -> Iterator[RgbdFrame]:
    """Group messages by log time into frames; skip (and count) groups missing an image."""
    assembler = _FrameAssembler(path)
    group_time: int | None = None
    parts: dict[str, bytes] = {}
    for topic, log_time, data in messages:
        if log_time != group_time:
            if parts and (frame := assembler.assemble(group_time, parts)) is not None:
                yield frame
            group_time, parts = log_time, {}
        parts[topic] = data
    if parts and (frame := assembler.assemble(group_time, parts)) is not None:
        yield frame
    assembler.finish()


class _FrameAssembler:
    """Decode the messages of one log time into an RgbdFrame, remembering the last intrinsics."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.intrinsics: CameraIntrinsics | None = None
        self.frames = 0
        self.incomplete = 0

    def assemble(self, time_ns: int, parts: dict[str, bytes]) -> RgbdFrame | None:
        where = f"{self.path} at log time {time_ns} ns"
        if fmt.CAMERA_INFO_TOPIC in parts:
            self.intrinsics = fmt.decode_camera_info(parts[fmt.CAMERA_INFO_TOPIC], where)
        if fmt.COLOR_TOPIC not in parts or fmt.DEPTH_TOPIC not in parts or not self.intrinsics:
            self.incomplete += 1
            return None
        color = fmt.decode_color(parts[fmt.COLOR_TOPIC], f"colour image of {where}")
        depth = fmt.decode_depth(parts[fmt.DEPTH_TOPIC], f"depth image of {where}")
        _check_sizes(where, color, depth, self.intrinsics)
        actuation = parts.get(fmt.ACTUATION_TOPIC)
        markers = parts.get(fmt.MARKERS_TOPIC)
        self.frames += 1
        return RgbdFrame(
            time_ns=time_ns,
            color=color,
            depth_mm=depth,
            intrinsics=self.intrinsics,
            actuation=None if actuation is None else fmt.decode_actuation(actuation, where),
            markers=None if markers is None else fmt.decode_markers(markers, where),
        )

    def finish(self) -> None:
        if self.incomplete and not self.frames:
            raise RecordingError(
                f"{self.path} has no complete frame: no log time carries a colour image, a "
                "depth image and camera_info together (softforce logs all messages of a "
                "frame at the same time)"
            )
        if self.incomplete:
            warnings.warn(
                f"{self.path}: skipped {self.incomplete} incomplete frame(s) lacking colour, "
                "depth or camera_info",
                RecordingWarning,
                stacklevel=3,
            )


def _check_sizes(
    where: str, color: np.ndarray, depth: np.ndarray, intrinsics: CameraIntrinsics
) -> None:
    color_hw, depth_hw = color.shape[:2], depth.shape
    if color_hw != depth_hw:
        raise RecordingError(
            f"{where}: depth is {depth_hw[1]}x{depth_hw[0]} but colour is "
            f"{color_hw[1]}x{color_hw[0]}; depth must be aligned to colour"
        )
    if (intrinsics.height, intrinsics.width) != color_hw:
        raise RecordingError(
            f"{where}: camera_info is for {intrinsics.width}x{intrinsics.height} images but "
            f"colour is {color_hw[1]}x{color_hw[0]}"
        )


def read_summary(path: Path) -> RecordingSummary:
    """Summarize the recording `path` from its summary section (a scan when it has none)."""
    with open_recording(path) as (stream, reader, summary):
        if summary is not None:
            return _summary_from_index(path, reader, summary)
        return _summary_from_scan(path, stream)


def _summary_from_index(path: Path, reader: SeekingReader, summary: Summary) -> RecordingSummary:
    channels = check_channels(path, summary.channels, summary.schemas)
    counts = summary.statistics.channel_message_counts if summary.statistics else {}
    schemas = {sid: schema.name for sid, schema in summary.schemas.items()}
    topics = tuple(
        TopicSummary(ch.topic, schemas.get(ch.schema_id, ""), ch.message_encoding, counts[cid])
        for cid, ch in sorted(summary.channels.items())
    )
    by_topic = {t.topic: t.message_count for t in topics}
    metadata = {record.name: dict(record.metadata) for record in reader.iter_metadata()}
    first = _first_frame(path, indexed_messages(path, reader, channels))
    last = reader.iter_messages(topics=[fmt.COLOR_TOPIC], log_time_order=True, reverse=True)
    end_ns = next((message.log_time for _, _, message in last), first.time_ns)
    frame_count = min(by_topic[topic] for topic in fmt.REQUIRED_TOPICS)
    return _make_summary(path, first, end_ns, frame_count, topics, metadata, indexed=True)


def _summary_from_scan(path: Path, stream: BinaryIO) -> RecordingSummary:
    """Summary of an unindexed recording: one pass over every readable frame."""
    metadata: dict[str, dict[str, str]] = {}
    first: RgbdFrame | None = None
    end_ns, count = 0, 0
    for frame in frames_from_messages(path, scanned_messages(path, stream, metadata)):
        first = first or frame
        end_ns, count = frame.time_ns, count + 1
    if first is None:
        raise RecordingError(f"{path} holds no readable frame")
    topics = tuple(
        TopicSummary(topic, schema, "protobuf", count)
        for topic, schema in zip(
            fmt.REQUIRED_TOPICS,
            ("foxglove.RawImage", "foxglove.RawImage", "foxglove.CameraCalibration"),
            strict=True,
        )
    )
    return _make_summary(path, first, end_ns, count, topics, metadata, indexed=False)


def _first_frame(path: Path, messages: Iterator[tuple[str, int, bytes]]) -> RgbdFrame:
    frames = frames_from_messages(path, messages)
    try:
        return next(frames)
    except StopIteration:
        raise RecordingError(f"{path} holds no frame") from None
    finally:
        frames.close()


def _make_summary(
    path: Path, first: RgbdFrame, end_ns: int, count: int, topics: tuple, metadata: dict, **flags
) -> RecordingSummary:
    actuation, markers = first.actuation, first.markers
    return RecordingSummary(
        path=Path(path),
        frame_count=count,
        start_time_ns=first.time_ns,
        end_time_ns=end_ns,
        intrinsics=first.intrinsics,
        topics=topics,
        metadata=metadata,
        actuation_names=actuation.names if actuation else None,
        actuation_control=actuation.control if actuation else None,
        marker_ids=markers.ids if markers else None,
        **flags,
    )
