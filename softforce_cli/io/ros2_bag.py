"""ROS 2 bags of a RealSense (realsense-ros with `align_depth.enable:=true`) as RgbdFrames.

A roboticist records a RealSense with `ros2 bag record`: a rosbag2 folder whose data file is
an MCAP (the default from ROS 2 Jazzy) or a SQLite `.db3` (before), holding CDR-encoded
`sensor_msgs/msg/Image` (or `CompressedImage`) and `CameraInfo` messages. This module reads
such a file into the frames `softforce record --from` writes into a softforce recording:

- the colour image topic is the one whose name ends in `color/image_raw` (realsense-ros:
  `/camera/camera/color/image_raw`; `.../compressed` when only that was recorded), the depth
  the one ending in `aligned_depth_to_color/image_raw` (or `.../compressedDepth`), the
  calibration the `CameraInfo` ending in `color/camera_info`;
- a colour and a depth image make a frame when each is the other's nearest by header stamp
  and they lie within recording_format.IMAGE_PAIR_TOLERANCE_NS (16 ms) of each other (the
  colour's stamp is the frame's time); an image without such a partner is skipped and
  counted, as are frames before the first calibration;
- the calibration holds until the next one (its lens, camera.lens, goes into the recording).

A `.db3` that librealsense wrote (its topics under `/device_0/`) is not a ROS 2 bag of
realsense-ros: camera.realsense plays it back.
"""

from __future__ import annotations

import re
import sqlite3
import warnings
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from mcap_ros2._dynamic import generate_dynamic

from softforce_cli.camera.frame import RgbdFrame
from softforce_cli.camera.intrinsics import CameraIntrinsics
from softforce_cli.camera.realsense import CaptureProgress
from softforce_cli.errors import RecordingError
from softforce_cli.io import recording_format as fmt
from softforce_cli.io.mcap_reader import RecordingWarning

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
# the message definitions (ROS 2's sensor_msgs, unchanged since Foxy), for bags that do not
# carry them: a .db3 before ROS 2 Iron
_HEADER = """
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id"""
DEFINITIONS = {
    IMAGE: """std_msgs/Header header
uint32 height
uint32 width
string encoding
uint8 is_bigendian
uint32 step
uint8[] data""" + _HEADER,
    COMPRESSED: """std_msgs/Header header
string format
uint8[] data""" + _HEADER,
    CAMERA_INFO: """std_msgs/Header header
uint32 height
uint32 width
string distortion_model
float64[] d
float64[9] k
float64[9] r
float64[12] p
uint32 binning_x
uint32 binning_y
sensor_msgs/RegionOfInterest roi""" + _HEADER + """
================================================================================
MSG: sensor_msgs/RegionOfInterest
uint32 x_offset
uint32 y_offset
uint32 height
uint32 width
bool do_rectify""",
}
# each role's topic: (the camera's namespace)(the name realsense-ros gives it), and its types
TOPIC_PATTERNS = {
    "colour": (r"^(.*/)color/image_raw(/compressed)?$", (IMAGE, COMPRESSED)),
    "depth": (r"^(.*/)aligned_depth_to_color/image_raw(/compressedDepth)?$",
              (IMAGE, COMPRESSED)),
    "camera_info": (r"^(.*/)color/camera_info$", (CAMERA_INFO,)),
}
SUFFIXES = (".mcap", ".db3")

ProgressCallback = Callable[[CaptureProgress], None]


@dataclass(frozen=True)
class BagTopic:
    name: str
    type: str
    definition: str  # the concatenated ROS 2 message definition


def is_ros2_bag(path: Path) -> bool:
    """Whether `path` is a ROS 2 bag this module reads (a rosbag2 folder or one of its data
    files): MCAP with the ros2 profile's ros2msg schemas, or SQLite that librealsense did not
    write."""
    try:
        topics = bag_topics(bag_files(path)[0])
    except RecordingError:
        return False
    # librealsense's own: its streams under /device_0/, beside /file_version and the like
    return bool(topics) and not any(t.name.startswith("/device_") for t in topics)


def bag_files(path: Path) -> list[Path]:
    """The data files of a ROS 2 bag: the file itself, or a rosbag2 folder's .mcap or .db3
    files in name order (a long recording is split into several); RecordingError for none."""
    path = Path(path)
    if not path.exists():
        raise RecordingError(f"{path} does not exist")
    if path.is_file():
        return [path]
    files = sorted(f for f in path.iterdir() if f.suffix.lower() in SUFFIXES)
    if not files:
        raise RecordingError(f"{path} holds no .mcap or .db3 file of a ROS 2 bag")
    return files


def bag_topics(path: Path) -> list[BagTopic]:
    """The topics of a ROS 2 bag's data file with their types; RecordingError when it is not
    one."""
    path = Path(path)
    if path.suffix.lower() == ".db3":
        with _sqlite(path) as connection:
            try:
                rows = connection.execute("SELECT name, type FROM topics").fetchall()
            except (sqlite3.Error, UnicodeDecodeError) as error:
                raise RecordingError(f"{path} is not a rosbag2 database ({error})") from error
        return [BagTopic(name, kind, DEFINITIONS.get(kind, "")) for name, kind in rows
                if isinstance(name, str) and isinstance(kind, str)]  # not a damaged row
    try:
        with open(path, "rb") as stream:
            summary = make_reader(stream).get_summary()
    except MemoryError:
        raise
    except Exception as error:  # mcap's reader raises many kinds on a damaged file
        raise RecordingError(f"{path} is not a readable MCAP file ({error})") from error
    if summary is None:
        raise RecordingError(f"{path} has no summary section; it was not finished")
    schemas = summary.schemas
    return [BagTopic(channel.topic, schemas[channel.schema_id].name,
                     schemas[channel.schema_id].data.decode(errors="replace"))
            for channel in summary.channels.values()
            if channel.message_encoding == "cdr" and channel.schema_id in schemas
            and schemas[channel.schema_id].encoding == "ros2msg"]


def iter_bag_frames(path: Path, *, duration_s: float | None = None,
                    on_progress: ProgressCallback | None = None) -> Iterator[RgbdFrame]:
    """The RGB-D frames of a ROS 2 bag of a RealSense (a rosbag2 folder or a data file; the
    module's rules), frame by frame.

    Raises RecordingError at once when it is not such a bag or lacks one of the three
    topics; stops after `duration_s` seconds of frames (None: the whole bag).
    """
    files = bag_files(path)
    chosen = _chosen_topics(Path(path), bag_topics(files[0]))
    return _frames(files, chosen, duration_s, on_progress)


def _chosen_topics(path: Path, topics: list[BagTopic]) -> dict[str, BagTopic]:
    """The colour, depth and camera_info topics (TOPIC_PATTERNS) of the bag's one camera; an
    uncompressed image topic is preferred to its compressed one. RecordingError naming the
    image topics it has otherwise."""
    chosen = {}
    for role, (pattern, kinds) in TOPIC_PATTERNS.items():
        found = [(topic, match.group(1)) for topic in topics
                 if topic.type in kinds and (match := re.match(pattern, topic.name))]
        cameras = {namespace for _, namespace in found}
        if len(cameras) != 1:
            images = sorted(t.name for t in topics if t.type in (IMAGE, COMPRESSED, CAMERA_INFO))
            name = pattern.removeprefix("^(.*/)").split("(")[0].rstrip("$")
            raise RecordingError(
                f"{path} has {'no' if not cameras else 'more than one camera with a'} {role} topic "
                f"(a name ending in {name}; its image topics: {', '.join(images) or 'none'}): "
                "record one RealSense a bag, with realsense-ros's align_depth.enable:=true")
        chosen[role] = min((topic for topic, _ in found), key=lambda t: t.type != IMAGE)
    return chosen


def _frames(files: list[Path], chosen: dict[str, BagTopic], duration_s: float | None,
            on_progress: ProgressCallback | None) -> Iterator[RgbdFrame]:
    count = skipped = 0
    first_ns = last_ns = None
    for path, intrinsics, pairs, dropped in _image_pairs(files, chosen):
        skipped += dropped
        for colour, depth in pairs:
            time_ns = colour[0]
            if intrinsics is None or (last_ns is not None and time_ns <= last_ns):
                skipped += 1  # before the first calibration, or not later in time
                continue
            first_ns = time_ns if first_ns is None else first_ns
            elapsed_s = (time_ns - first_ns) * 1e-9
            if duration_s is not None and elapsed_s >= duration_s:
                return
            last_ns = time_ns
            count += 1
            color, depth_mm = _pixels(colour, "colour", path), _pixels(depth, "depth", path)
            fmt.check_sizes(f"{path}: the frame stamped {time_ns} ns", color, depth_mm,
                            intrinsics)
            yield RgbdFrame(time_ns=time_ns, color=color, depth_mm=depth_mm,
                            intrinsics=intrinsics)
            if on_progress is not None:
                on_progress(CaptureProgress(count, 0, skipped, elapsed_s, None))


def _image_pairs(files: list[Path], chosen: dict[str, BagTopic]
                 ) -> Iterator[tuple[Path, CameraIntrinsics | None, list[tuple], int]]:
    """(file, the calibration then, the image pairs _paired made, the images it passed over)
    after each image message of the bag, and once more at its end."""
    decoders = {topic.name: _decoder(files[0], topic) for topic in chosen.values()}
    roles = {topic.name: role for role, topic in chosen.items()}
    pending: dict[str, deque] = {"colour": deque(), "depth": deque()}
    intrinsics = None
    path = files[0]
    for path, name, data in _bag_messages(files, list(roles)):
        role = roles[name]
        what = f"{path}: a {role} message on {name}"
        try:
            message = decoders[name](data)
        except Exception as error:  # the CDR reader raises many kinds on damaged data
            raise RecordingError(f"{what} is not a valid {chosen[role].type} ({error})"
                                 ) from error
        if role == "camera_info":
            told = intrinsics is not None
            intrinsics, unread = fmt.camera_intrinsics(message.width, message.height,
                                                       message.k, message.distortion_model,
                                                       message.d, what)
            if unread is not None and not told:
                warnings.warn(fmt.unread_lens_message(path, unread), RecordingWarning,
                              stacklevel=2)
            continue
        pending[role].append((_stamp_ns(message), message, chosen[role].type))
        yield path, intrinsics, *_paired(pending["colour"], pending["depth"])
    yield path, intrinsics, *_paired(pending["colour"], pending["depth"], ended=True)


def _decoder(path: Path, topic: BagTopic) -> Callable[[bytes], Any]:
    """The CDR decoder of a topic's messages, from its message definition."""
    try:
        return generate_dynamic(topic.type, topic.definition)[topic.type]
    except Exception as error:  # the definition parser raises many kinds on bad text
        raise RecordingError(f"{path}: the message definition of {topic.name}'s "
                             f"{topic.type} cannot be read ({error})") from error


def _paired(colours: deque, depths: deque, ended: bool = False) -> tuple[list[tuple], int]:
    """The (colour, depth) pairs the pending images (stamp, message, type), each stream in
    stamp order, make: each the nearest of the other stream's, within
    fmt.IMAGE_PAIR_TOLERANCE_NS, taken off the queues; and how many images were passed over,
    no image of the other stream near them. The earlier of the two first images waits for
    its stream's next one, which may lie nearer the other (at 60-90 fps a frame is shorter
    than the tolerance), unless the bag has ended."""
    pairs, dropped = [], 0
    while colours and depths:
        gap = colours[0][0] - depths[0][0]
        earlier, other = (depths, colours) if gap > 0 else (colours, depths)
        if len(earlier) < 2 and not ended:
            break
        if len(earlier) > 1 and abs(earlier[1][0] - other[0][0]) < abs(gap):
            earlier.popleft()  # its next image is the nearer one
            dropped += 1
        elif abs(gap) <= fmt.IMAGE_PAIR_TOLERANCE_NS:
            pairs.append((colours.popleft(), depths.popleft()))
        else:
            earlier.popleft()
            dropped += 1
    return pairs, dropped


def _pixels(item: tuple, role: str, path: Path) -> np.ndarray:
    """A pending image (stamp, message, type) -> (h, w, 3) uint8 RGB colour or (h, w)
    uint16 depth in mm."""
    _, message, kind = item
    what = f"{path}: the {role} image stamped {item[0]} ns"
    if getattr(message, "is_bigendian", 0):
        raise RecordingError(f"{what} is big-endian; softforce reads little-endian images")
    if role == "colour":
        return (fmt.raw_color(message, what) if kind == IMAGE
                else fmt.compressed_color(message, what))
    return fmt.raw_depth(message, what) if kind == IMAGE else fmt.compressed_depth(message, what)


def _stamp_ns(message) -> int:
    """A ROS message's header stamp in nanoseconds."""
    stamp = message.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _bag_messages(files: list[Path], topics: list[str]) -> Iterator[tuple[Path, str, bytes]]:
    """(file, topic, CDR bytes) of the given topics, file by file, in log-time order."""
    for path in files:
        try:
            if path.suffix.lower() == ".db3":
                with _sqlite(path) as connection:
                    marks = ",".join("?" * len(topics))
                    for name, data in connection.execute(
                            "SELECT topics.name, messages.data FROM messages JOIN topics ON "
                            f"messages.topic_id = topics.id WHERE topics.name IN ({marks}) "
                            "ORDER BY messages.timestamp", topics):
                        yield path, name, data
                continue
            with open(path, "rb") as stream:
                for _, channel, message in make_reader(stream).iter_messages(
                        topics=topics, log_time_order=True):
                    yield path, channel.topic, message.data
        except (MemoryError, RecordingError, GeneratorExit):
            raise
        except Exception as error:  # sqlite's and mcap's readers on a damaged file
            raise RecordingError(f"{path} is damaged ({error})") from error


def _sqlite(path: Path) -> closing[sqlite3.Connection]:
    try:
        return closing(sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True))
    except sqlite3.Error as error:
        raise RecordingError(f"{path} cannot be opened as a rosbag2 database ({error})"
                             ) from error
