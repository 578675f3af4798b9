"""Lazy reading of RGB-D recordings: RgbdFrames one at a time, and a summary of them.

Frames are the groups of messages that share a log time (docs/recordings.md). A finished
recording is read through its chunk index in log-time order, one chunk at a time, so memory does
not grow with the recording's length. A recording without a summary section (cut short by a
crash or a full disk) or with a damaged one is scanned from the start instead. Either way a
damaged chunk (mcap_chunks.py) costs only the frames it holds: they are skipped, counted in a
RecordingWarning, and every other frame is returned. Topics other than softforce's are ignored.
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from mcap.records import Channel, Message, Metadata, Schema
from mcap.summary import Summary
from mcap.writer import MCAP0_MAGIC

from softforce_cli.camera.frame import Actuation, RgbdFrame
from softforce_cli.camera.intrinsics import CameraIntrinsics
from softforce_cli.camera.rectification import rectified
from softforce_cli.errors import RecordingError
from softforce_cli.io import recording_format as fmt
from softforce_cli.io.mcap_chunks import (
    ChunkTable,
    Damage,
    RecordingWarning,
    file_size,
    indexed_messages,
    indexed_metadata,
    salvaged_summary,
    trusted_summary,
)
from softforce_cli.io.mcap_scan import ChunkFinder, scanned_records

__all__ = ["RecordingSummary", "RecordingWarning", "TopicSummary", "iter_frames", "read_summary"]

_EXPECTED_SCHEMAS = {
    fmt.COLOR_TOPIC: ("protobuf", (fmt.RAW_IMAGE, fmt.COMPRESSED_IMAGE)),
    fmt.DEPTH_TOPIC: ("protobuf", (fmt.RAW_IMAGE, fmt.COMPRESSED_IMAGE)),
    fmt.CAMERA_INFO_TOPIC: ("protobuf", ("foxglove.CameraCalibration",)),
    fmt.ACTUATION_TOPIC: ("json", None),
    fmt.MARKERS_TOPIC: ("json", None),
}


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
            "distortion": None if k.distortion is None else {
                "model": k.distortion.model, "coefficients": list(k.distortion.coefficients)},
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
    (RecordingWarning) when the file is truncated or damaged (the frames of damaged chunks are
    skipped and counted, every other frame is yielded) or frames are incomplete. Frames
    through a distorting lens (camera_info's distortion model and D) come rectified: the
    pinhole image of their K (camera.rectification).
    """
    with open_recording(path) as recording:
        for frame in frames_from_messages(path, recording_messages(recording, {})):
            yield rectified(frame)


@dataclass
class OpenRecording:
    """An MCAP file opened for reading: its trusted summary (None: scan it) and its damage."""

    path: Path
    stream: BinaryIO
    size: int
    summary: Summary | None
    chunks: ChunkTable
    index_state: str  # "" (indexed), "no index", "damaged index" or "unchunked"
    damage: Damage


@contextlib.contextmanager
def open_recording(path: Path) -> Iterator[OpenRecording]:
    """Open `path`, check it is MCAP and whether its index can be trusted.

    An OSError while reading (a failing disk, a vanished network share) becomes a
    RecordingError naming the file.
    """
    path = Path(path)
    if not path.is_file():
        state = "is a directory" if path.is_dir() else "does not exist"
        raise RecordingError(f"recording {path} {state}")
    try:
        with open(path, "rb") as stream:
            if stream.read(len(MCAP0_MAGIC)) != MCAP0_MAGIC:
                raise RecordingError(
                    f"{path} is not an MCAP file (wrong magic bytes); record one with "
                    "`softforce record` or `softforce simulate`"
                )
            size = file_size(stream)
            summary, chunks, state = trusted_summary(stream, size)
            if summary is not None and not chunks:
                summary, state = None, "unchunked"  # scanning is the lazy way to read it
            if state in ("no index", "damaged index"):
                why = (
                    "has no index (was the recording cut short?)"
                    if state == "no index"
                    else "has a damaged index (its CRC does not match)"
                )
                warnings.warn(
                    f"{path} {why}; reading it from the start", RecordingWarning, stacklevel=4
                )
            yield OpenRecording(path, stream, size, summary, chunks, state, Damage(path))
    except OSError as error:
        raise RecordingError(
            f"cannot read {path} ({error.strerror or error}); check the file and the disk"
        ) from error


def recording_messages(
    recording: OpenRecording, metadata: dict[str, dict[str, str]]
) -> Iterator[tuple[str, int, bytes, str]]:
    """(topic, log_time, data, schema name) of softforce topics, in log-time order when
    indexed.

    Metadata records are stored into `metadata`. Damage is reported as one RecordingWarning
    once the messages are exhausted.
    """
    stream, size, damage = recording.stream, recording.size, recording.damage
    if recording.summary is not None:
        summary = recording.summary
        channels = check_channels(recording.path, summary.channels, summary.schemas)
        metadata.update(indexed_metadata(stream, size, summary, damage))
        finder = ChunkFinder(stream, size)
        for message in indexed_messages(
            stream, size, recording.chunks, set(channels), damage, finder
        ):
            channel = channels[message.channel_id]
            yield (channel.topic, message.log_time, message.data,
                   _schema_name(channel, summary.schemas))
    else:
        yield from _scanned_messages(recording, metadata)
    damage.warn()


def check_channels(
    path: Path, channels: dict[int, Channel], schemas: dict[int, Schema]
) -> dict[int, Channel]:
    """Channels of softforce topics, checked; RecordingError when a required one is missing."""
    ours = {cid: ch for cid, ch in channels.items() if ch.topic in _EXPECTED_SCHEMAS}
    present = {ch.topic for ch in ours.values()}
    for topic in fmt.REQUIRED_TOPICS:
        if topic not in present:
            bag = any(ch.message_encoding == "cdr" for ch in channels.values())
            raise RecordingError(
                f"{path} has no {topic} topic; a softforce recording needs "
                f"{', '.join(fmt.REQUIRED_TOPICS)}" + (
                    ". It is a ROS 2 bag: convert it with softforce record --from "
                    f"{path.name} -o REC.mcap" if bag else "")
            )
    for channel in ours.values():
        _check_schema(path, channel, schemas.get(channel.schema_id))
    return ours


def _schema_name(channel: Channel, schemas: dict[int, Schema]) -> str:
    schema = schemas.get(channel.schema_id)
    return schema.name if schema is not None else ""


def _check_schema(path: Path, channel: Channel, schema: Schema | None) -> None:
    encoding, schema_names = _EXPECTED_SCHEMAS[channel.topic]
    actual = schema.name if schema is not None else "no schema"
    if channel.message_encoding != encoding or (schema_names and actual not in schema_names):
        expected = (f"{' or '.join(schema_names)} ({encoding})" if schema_names
                    else encoding)
        raise RecordingError(
            f"{path}: topic {channel.topic} holds {actual} ({channel.message_encoding}) "
            f"messages; softforce reads {expected}"
        )


def _scanned_messages(
    recording: OpenRecording, metadata: dict[str, dict[str, str]]
) -> Iterator[tuple[str, int, bytes, str]]:
    """Messages (as recording_messages) in file order, read past damaged chunks; metadata
    stored into `metadata`."""
    path = recording.path
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    if recording.index_state == "damaged index":
        # Channels are defined once, in the first chunk; if that chunk is the damaged one, the
        # copies in the summary section may still name the channels of the later chunks.
        salvaged = salvaged_summary(recording.stream, recording.size)
        schemas.update(salvaged.schemas)
        for channel in salvaged.channels.values():
            if channel.topic in _EXPECTED_SCHEMAS:
                channels[channel.id] = channel
    for record in scanned_records(recording.stream, recording.size, recording.damage):
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel) and record.topic in _EXPECTED_SCHEMAS:
            _check_schema(path, record, schemas.get(record.schema_id))
            channels[record.id] = record
        elif isinstance(record, Message) and record.channel_id in channels:
            channel = channels[record.channel_id]
            yield channel.topic, record.log_time, record.data, _schema_name(channel, schemas)
        elif isinstance(record, Metadata):
            metadata[record.name] = dict(record.metadata)
    present = {ch.topic for ch in channels.values()}
    for topic in fmt.REQUIRED_TOPICS:
        if topic not in present:
            recording.damage.warn()
            raise RecordingError(
                f"{path} has no {topic} topic (in its readable part); a softforce recording "
                f"needs {', '.join(fmt.REQUIRED_TOPICS)}"
            )


def frames_from_messages(
    path: Path, messages: Iterator[tuple[str, int, bytes, str]]
) -> Iterator[RgbdFrame]:
    """Group messages by log time into frames (_paired_groups); skip (and count) groups
    missing an image."""
    assembler = _FrameAssembler(path)
    for time_ns, parts in _paired_groups(_log_time_groups(messages, assembler.schemas)):
        if (frame := assembler.assemble(time_ns, parts)) is not None:
            yield frame
    assembler.finish()


def _log_time_groups(messages: Iterator[tuple[str, int, bytes, str]], schemas: dict[str, str]
                     ) -> Iterator[tuple[int, dict[str, bytes]]]:
    """(log time, {topic: data}) of each run of messages sharing a log time; each topic's
    schema name noted into `schemas`."""
    group_time: int | None = None
    parts: dict[str, bytes] = {}
    for topic, log_time, data, schema in messages:
        schemas[topic] = schema
        if log_time != group_time:
            if parts:
                yield group_time, parts
            group_time, parts = log_time, {}
        parts[topic] = data
    if parts:
        yield group_time, parts


def _paired_groups(groups: Iterator[tuple[int, dict[str, bytes]]]
                   ) -> Iterator[tuple[int, dict[str, bytes]]]:
    """Log-time groups, a group holding one of the two images joined by the next one that
    holds the other within fmt.IMAGE_PAIR_TOLERANCE_NS (another tool may log each image at
    its own receive time), and by calibration or inputs logged in between; the pair takes
    the colour image's time. Not when the group after it holds an image like the first one's
    nearer to it (frames shorter than the tolerance, at 60-90 fps): then the first is alone.
    softforce's own frames share one log time and pass as they are."""
    images = {fmt.COLOR_TOPIC, fmt.DEPTH_TOPIC}
    half: tuple[int, dict[str, bytes]] | None = None
    groups = iter(groups)
    ahead = next(groups, None)
    while ahead is not None:
        (time_ns, parts), ahead = ahead, next(groups, None)
        if half is not None:
            half_time, half_parts = half
            near = time_ns - half_time <= fmt.IMAGE_PAIR_TOLERANCE_NS
            if near and not parts.keys() & images:
                half_parts.update(parts)  # calibration or inputs before the other image
                continue
            kind = half_parts.keys() & images
            nearer = (ahead is not None and ahead[1].keys() & images == kind
                      and ahead[0] - time_ns < time_ns - half_time)
            if near and parts.keys() & images == images - kind and not nearer:
                yield (half_time if fmt.COLOR_TOPIC in half_parts else time_ns,
                       {**half_parts, **parts})
                half = None
                continue
            yield half
            half = None
        if len(parts.keys() & images) == 1:
            half = (time_ns, parts)
        else:
            yield time_ns, parts
    if half is not None:
        yield half


class _FrameAssembler:
    """Decode the messages of one log time into an RgbdFrame, remembering the last intrinsics
    and actuation: both hold until a message changes them, whether it came with a frame or at
    a log time of its own."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.intrinsics: CameraIntrinsics | None = None
        self.frames = 0
        self.incomplete = 0
        self.out_of_order = 0
        self.last_time_ns: int | None = None
        self.actuation: Actuation | None = None
        self.distortion_told = False
        self.schemas: dict[str, str] = {}  # each topic's schema name (its channel's)

    def assemble(self, time_ns: int, parts: dict[str, bytes]) -> RgbdFrame | None:
        where = f"{self.path} at log time {time_ns} ns"
        if fmt.CAMERA_INFO_TOPIC in parts:
            self.intrinsics, unread = fmt.decode_camera_info(parts[fmt.CAMERA_INFO_TOPIC],
                                                             where)
            if unread is not None and not self.distortion_told:
                self.distortion_told = True
                warnings.warn(fmt.unread_lens_message(self.path, unread), RecordingWarning,
                              stacklevel=3)
        if fmt.ACTUATION_TOPIC in parts:  # inputs hold until changed (docs/recordings.md)
            self.actuation = fmt.decode_actuation(parts[fmt.ACTUATION_TOPIC], where)
        if parts.keys() <= {fmt.CAMERA_INFO_TOPIC, fmt.ACTUATION_TOPIC}:
            return None  # calibration or inputs logged on their own: kept for the next frame
        if fmt.COLOR_TOPIC not in parts or fmt.DEPTH_TOPIC not in parts or not self.intrinsics:
            self.incomplete += 1
            return None
        if self.last_time_ns is not None and time_ns <= self.last_time_ns:
            self.out_of_order += 1  # a repeated or misplaced chunk of a damaged file
            return None
        self.last_time_ns = time_ns
        color = fmt.decode_color(parts[fmt.COLOR_TOPIC], f"colour image of {where}",
                                 self.schemas[fmt.COLOR_TOPIC])
        depth = fmt.decode_depth(parts[fmt.DEPTH_TOPIC], f"depth image of {where}",
                                 self.schemas[fmt.DEPTH_TOPIC])
        fmt.check_sizes(where, color, depth, self.intrinsics)
        markers = parts.get(fmt.MARKERS_TOPIC)
        self.frames += 1
        return RgbdFrame(
            time_ns=time_ns,
            color=color,
            depth_mm=depth,
            intrinsics=self.intrinsics,
            actuation=self.actuation,
            markers=None if markers is None else fmt.decode_markers(markers, where),
        )

    def finish(self) -> None:
        if self.incomplete and not self.frames:
            raise RecordingError(
                f"{self.path} has no complete frame: no log time carries a colour image, a "
                "depth image and camera_info together (softforce logs all messages of a "
                "frame at the same time)"
            )
        if not self.frames:
            raise RecordingError(
                f"{self.path} holds no readable frame; record it again or copy it anew"
            )
        if self.incomplete:
            warnings.warn(
                f"{self.path}: skipped {self.incomplete} incomplete frame(s) lacking colour, "
                "depth or camera_info",
                RecordingWarning,
                stacklevel=3,
            )
        if self.out_of_order:
            warnings.warn(
                f"{self.path}: skipped {self.out_of_order} frame(s) whose time repeats or goes "
                "back (a damaged file's misplaced chunks)",
                RecordingWarning,
                stacklevel=3,
            )


def read_summary(path: Path) -> RecordingSummary:
    """Summarize the recording `path`: its index, checked by reading every frame once.

    The frame count is that of the frames iter_frames yields (complete and readable), so that
    a damaged chunk shows in the count, and is warned about, here too.
    """
    with open_recording(path) as recording:
        metadata: dict[str, dict[str, str]] = {}
        first: RgbdFrame | None = None
        end_ns, count = 0, 0
        for frame in frames_from_messages(path, recording_messages(recording, metadata)):
            first = first or frame
            end_ns, count = frame.time_ns, count + 1
        if first is None:
            raise RecordingError(f"{path} holds no readable frame")
        summary = recording.summary
        if summary is not None:
            counts = summary.statistics.channel_message_counts if summary.statistics else {}
            schemas = {sid: schema.name for sid, schema in summary.schemas.items()}
            topics = tuple(
                TopicSummary(
                    ch.topic, schemas.get(ch.schema_id, ""), ch.message_encoding,
                    counts.get(cid, 0),
                )
                for cid, ch in sorted(summary.channels.items())
            )
        else:
            topics = tuple(
                TopicSummary(topic, schema, "protobuf", count)
                for topic, schema in zip(
                    fmt.REQUIRED_TOPICS,
                    ("foxglove.RawImage", "foxglove.RawImage", "foxglove.CameraCalibration"),
                    strict=True,
                )
            )
        return _make_summary(
            path, first, end_ns, count, topics, metadata, indexed=summary is not None
        )


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


def indexed_frame_count(path: Path) -> int | None:
    """The number of colour images the recording's index lists, without reading a frame (for
    progress bars); None when the file has no trusted index. May exceed the readable frames."""
    with open_recording(path) as recording:
        summary = recording.summary
        if summary is None or summary.statistics is None:
            return None
        counts = summary.statistics.channel_message_counts
        return next((counts.get(cid, 0) for cid, channel in summary.channels.items()
                     if channel.topic == fmt.COLOR_TOPIC), None)
