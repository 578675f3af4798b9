"""The softforce recording format (docs/recordings.md): topic names and per-message codecs.

Pure functions between the parts of an RgbdFrame and the bytes of one MCAP message; the MCAP
container itself is handled by mcap_writer.py and mcap_reader.py.

| topic                                      | schema                       | encoding  |
|--------------------------------------------|------------------------------|-----------|
| /camera/color/image_raw                    | foxglove.RawImage, rgb8      | protobuf  |
| /camera/aligned_depth_to_color/image_raw   | foxglove.RawImage, 16UC1 mm  | protobuf  |
| /camera/color/camera_info                  | foxglove.CameraCalibration   | protobuf  |
| /robot/actuation                           | softforce.Actuation          | json      |
| /markers                                   | softforce.Markers            | json      |
"""

from __future__ import annotations

import io
import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from google.protobuf.message import DecodeError
from google.protobuf.timestamp_pb2 import Timestamp
from PIL import Image

from softforce_cli.camera.frame import Actuation, Markers
from softforce_cli.camera.intrinsics import CameraIntrinsics
from softforce_cli.camera.lens import LensDistortion, LensModelError
from softforce_cli.errors import RecordingError

COLOR_TOPIC = "/camera/color/image_raw"
DEPTH_TOPIC = "/camera/aligned_depth_to_color/image_raw"
CAMERA_INFO_TOPIC = "/camera/color/camera_info"
ACTUATION_TOPIC = "/robot/actuation"
MARKERS_TOPIC = "/markers"

REQUIRED_TOPICS = (COLOR_TOPIC, DEPTH_TOPIC, CAMERA_INFO_TOPIC)
FRAME_TOPICS = (*REQUIRED_TOPICS, ACTUATION_TOPIC, MARKERS_TOPIC)

OPTICAL_FRAME_ID = "camera_color_optical_frame"
# the image topics' schemas: raw (softforce's own) or compressed, as another tool may write
RAW_IMAGE = "foxglove.RawImage"
COMPRESSED_IMAGE = "foxglove.CompressedImage"
# Another tool's colour and depth images of one frame, each logged or stamped at its own
# time: half a frame at 30 fps apart at most (realsense-ros stamps an aligned depth image
# with the depth frame's time, a few milliseconds from the colour frame's)
IMAGE_PAIR_TOLERANCE_NS = 16_000_000
# colour may be lossy; depth only png (16-bit greyscale, mm)
COMPRESSED_COLOR_FORMATS = ("jpeg", "png", "webp")
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
METADATA_NAME = "softforce"
CONTROL_MODES = ("displacement", "force")

COLOR_ENCODING = "rgb8"
DEPTH_ENCODINGS = ("16UC1", "mono16")  # mono16 is Foxglove's alias of the same layout
# What other tools write, read too (softforce writes rgb8 and 16UC1): the channels' order
# (the bytes per pixel, and which of them are R, G, B), and depth in metres as 32-bit floats
# (ROS REP 118), rounded to the millimetre
COLOR_LAYOUTS = {"rgb8": (3, [0, 1, 2]), "bgr8": (3, [2, 1, 0]),
                 "rgba8": (4, [0, 1, 2]), "bgra8": (4, [2, 1, 0])}
DEPTH_METRES_ENCODING = "32FC1"

ACTUATION_SCHEMA_NAME = "softforce.Actuation"
ACTUATION_JSON_SCHEMA = {
    "title": ACTUATION_SCHEMA_NAME,
    "description": "Actuator inputs of one frame: cable displacements in mm or forces in N.",
    "type": "object",
    "properties": {
        "names": {"type": "array", "items": {"type": "string"}},
        "control": {"type": "string", "enum": list(CONTROL_MODES)},
        "values": {"type": "array", "items": {"type": "number"}},
    },
    "required": ["names", "control", "values"],
}
MARKERS_SCHEMA_NAME = "softforce.Markers"
MARKERS_JSON_SCHEMA = {
    "title": MARKERS_SCHEMA_NAME,
    "description": "Observed marker positions in mm in the camera optical frame.",
    "type": "object",
    "properties": {
        "ids": {"type": "array", "items": {"type": "string"}},
        "positions_mm": {
            "type": "array",
            "items": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3},
        },
    },
    "required": ["ids", "positions_mm"],
}


def timestamp_from_ns(time_ns: int) -> Timestamp:
    seconds, nanos = divmod(int(time_ns), 1_000_000_000)
    return Timestamp(seconds=seconds, nanos=nanos)


def encode_color(color: np.ndarray, time_ns: int) -> bytes:
    """(h, w, 3) uint8 RGB -> serialized foxglove.RawImage rgb8."""
    height, width = color.shape[:2]
    return RawImage(
        timestamp=timestamp_from_ns(time_ns),
        frame_id=OPTICAL_FRAME_ID,
        width=width,
        height=height,
        encoding=COLOR_ENCODING,
        step=3 * width,
        data=np.ascontiguousarray(color, dtype=np.uint8).tobytes(),
    ).SerializeToString()


def encode_depth(depth_mm: np.ndarray, time_ns: int) -> bytes:
    """(h, w) uint16 depth in mm -> serialized foxglove.RawImage 16UC1 (little-endian)."""
    height, width = depth_mm.shape
    return RawImage(
        timestamp=timestamp_from_ns(time_ns),
        frame_id=OPTICAL_FRAME_ID,
        width=width,
        height=height,
        encoding="16UC1",
        step=2 * width,
        data=np.ascontiguousarray(depth_mm, dtype="<u2").tobytes(),
    ).SerializeToString()


def encode_camera_info(intrinsics: CameraIntrinsics, time_ns: int) -> bytes:
    """Intrinsics -> serialized foxglove.CameraCalibration: K, and the lens' distortion model
    and coefficients (plumb_bob with zero coefficients for a pinhole image)."""
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    lens = intrinsics.distortion
    return CameraCalibration(
        timestamp=timestamp_from_ns(time_ns),
        frame_id=OPTICAL_FRAME_ID,
        width=intrinsics.width,
        height=intrinsics.height,
        distortion_model="plumb_bob" if lens is None else lens.model,
        D=[0.0] * 5 if lens is None else list(lens.coefficients),
        K=[fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        P=[fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
    ).SerializeToString()


def encode_actuation(actuation: Actuation) -> bytes:
    document = {
        "names": list(actuation.names),
        "control": actuation.control,
        "values": [float(v) for v in np.asarray(actuation.values, dtype=float)],
    }
    return json.dumps(document).encode()


def encode_markers(markers: Markers) -> bytes:
    positions = np.asarray(markers.positions_mm, dtype=float).reshape(-1, 3)
    document = {"ids": list(markers.ids), "positions_mm": positions.tolist()}
    return json.dumps(document).encode()


def _decompressed(message: Any, what: str, formats: tuple[str, ...]) -> Image.Image:
    """A compressed image message decoded (Pillow); RecordingError for a format not in
    formats or data that is not an image of it. ROS's compressedDepth ("16UC1;
    compressedDepth png") puts a 12-byte header before its png, which is skipped."""
    fmt = message.format.strip().lower()
    name = "png" if "compresseddepth" in fmt else {"jpg": "jpeg"}.get(fmt, fmt)
    if name not in formats:
        raise RecordingError(f"{what} is compressed as {message.format!r}; softforce reads "
                             f"{' or '.join(formats)} there")
    payload = bytes(message.data)
    start = payload.find(PNG_SIGNATURE, 0, 12 + len(PNG_SIGNATURE)) if name == "png" else 0
    try:
        image = Image.open(io.BytesIO(payload[max(start, 0):]))
        image.load()
    except MemoryError:
        raise
    except Exception as error:  # Pillow's decoders raise many kinds on damaged data
        raise RecordingError(f"{what} is not a readable {name} image ({error})") from error
    if image.format is None or image.format.lower() != name:
        raise RecordingError(f"{what} says {name} but holds {image.format or 'no'} image data")
    return image


def _parse(schema: type, data: bytes, what: str) -> Any:
    """Serialized protobuf `data` as a message of the foxglove `schema` class."""
    try:
        return schema.FromString(data)
    except DecodeError as error:
        raise RecordingError(f"{what} is not a valid foxglove.{schema.__name__} ({error})"
                             ) from error


def _image_rows(image: Any, bytes_per_pixel: int, what: str) -> np.ndarray:
    """(height, width * bytes_per_pixel) uint8 view of the image rows, padding dropped."""
    row_bytes = image.width * bytes_per_pixel
    if image.width == 0 or image.height == 0 or image.step < row_bytes:
        raise RecordingError(
            f"{what} has size {image.width}x{image.height} and row step {image.step} bytes; "
            f"expected a non-empty image with step >= {row_bytes}"
        )
    if len(image.data) < image.step * image.height:
        raise RecordingError(
            f"{what} holds {len(image.data)} bytes, fewer than {image.height} rows of "
            f"{image.step} bytes"
        )
    rows = np.frombuffer(image.data, dtype=np.uint8, count=image.step * image.height)
    return rows.reshape(image.height, image.step)[:, :row_bytes]


def decode_color(data: bytes, what: str = "colour image", schema: str = RAW_IMAGE) -> np.ndarray:
    """Serialized foxglove.RawImage rgb8 (or bgr8, rgba8, bgra8), or foxglove.CompressedImage
    (COMPRESSED_COLOR_FORMATS) -> (h, w, 3) uint8 RGB (a writable copy)."""
    if schema == COMPRESSED_IMAGE:
        return compressed_color(_parse(CompressedImage, data, what), what)
    return raw_color(_parse(RawImage, data, what), what)


def decode_depth(data: bytes, what: str = "depth image", schema: str = RAW_IMAGE) -> np.ndarray:
    """Serialized foxglove.RawImage 16UC1 (mm; or 32FC1, metres), or foxglove.CompressedImage
    as a 16-bit png (mm) -> (h, w) uint16 depth in mm (a writable copy; 0 where there is
    none: a float depth not finite or not positive)."""
    if schema == COMPRESSED_IMAGE:
        return compressed_depth(_parse(CompressedImage, data, what), what)
    return raw_depth(_parse(RawImage, data, what), what)


def decode_camera_info(data: bytes, what: str = "camera_info"
                       ) -> tuple[CameraIntrinsics, str | None]:
    """Serialized foxglove.CameraCalibration -> camera_intrinsics of it."""
    calibration = _parse(CameraCalibration, data, what)
    return camera_intrinsics(calibration.width, calibration.height, calibration.K,
                             calibration.distortion_model, calibration.D, what)


def unread_lens_message(path: Path | str, unread: str) -> str:
    """What a reader says once of a recording whose lens (camera_intrinsics' `unread`) it
    cannot take."""
    return (f"{path}: camera_info's {unread}: its images are read through K alone; rectify "
            "them first, or expect points off by the distortion at the edges")


def check_sizes(where: str, color: np.ndarray, depth: np.ndarray,
                intrinsics: CameraIntrinsics) -> None:
    """RecordingError unless a frame's colour (h, w, 3), depth (h, w) and calibration are of
    one size."""
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


# The pixels of an image message, whatever its schema: foxglove's RawImage and ROS's
# sensor_msgs/Image share encoding, width, height, step and data; foxglove's CompressedImage
# and ROS's share format and data.

def raw_color(image: Any, what: str) -> np.ndarray:
    """An uncompressed image message in COLOR_LAYOUTS -> (h, w, 3) uint8 RGB (a copy)."""
    if image.encoding not in COLOR_LAYOUTS:
        raise RecordingError(
            f"{what} has encoding '{image.encoding}'; softforce reads "
            f"{', '.join(COLOR_LAYOUTS)}"
        )
    channels, rgb = COLOR_LAYOUTS[image.encoding]
    rows = _image_rows(image, channels, what)
    return rows.reshape(image.height, image.width, channels)[:, :, rgb].copy()


def raw_depth(image: Any, what: str) -> np.ndarray:
    """An uncompressed depth image message (DEPTH_ENCODINGS in mm, or 32FC1 in metres) ->
    (h, w) uint16 mm (a copy; 0 where a float depth is not finite or not positive)."""
    if image.encoding in DEPTH_ENCODINGS:
        rows = _image_rows(image, 2, what)
        return np.ascontiguousarray(rows).view("<u2").astype(np.uint16)
    if image.encoding == DEPTH_METRES_ENCODING:
        metres = np.ascontiguousarray(_image_rows(image, 4, what)).view("<f4")
        with np.errstate(invalid="ignore"):
            mm = np.where(np.isfinite(metres) & (metres > 0), np.round(metres * 1000.0), 0.0)
        return np.clip(mm, 0, np.iinfo(np.uint16).max).astype(np.uint16)
    raise RecordingError(
        f"{what} has encoding '{image.encoding}'; softforce reads '16UC1' depth in mm "
        f"(or '{DEPTH_METRES_ENCODING}' in metres)"
    )


def compressed_color(message: Any, what: str) -> np.ndarray:
    """A compressed image message (COMPRESSED_COLOR_FORMATS) -> (h, w, 3) uint8 RGB."""
    image = _decompressed(message, what, COMPRESSED_COLOR_FORMATS)
    return np.array(image.convert("RGB"), dtype=np.uint8)


def compressed_depth(message: Any, what: str) -> np.ndarray:
    """A compressed depth message (a 16-bit greyscale png in mm) -> (h, w) uint16 mm."""
    image = _decompressed(message, what, ("png",))
    if image.mode not in ("I;16", "I;16B", "I"):
        raise RecordingError(f"{what} is a {image.mode} png; softforce reads compressed "
                             "depth as a 16-bit greyscale png in mm")
    return np.array(image, dtype=np.uint16)


def camera_intrinsics(width: int, height: int, K: Iterable[float], distortion_model: str,
                      D: Iterable[float], what: str
                      ) -> tuple[CameraIntrinsics, str | None]:
    """A calibration message's image size, camera matrix K (9 values, row by row) and lens
    (camera.lens) -> the intrinsics, and why the distortion could not be taken (an unknown
    model: the image is then read through K alone), None when it could."""
    K = list(K)
    if len(K) != 9 or not np.all(np.isfinite(K)) or K[0] <= 0.0 or K[4] <= 0.0:
        raise RecordingError(
            f"{what} has no usable camera matrix K (got {K}); the camera is uncalibrated"
        )
    if width == 0 or height == 0:
        raise RecordingError(f"{what} gives no image size (width and height are 0)")
    try:
        lens, unread = LensDistortion.from_camera_info(distortion_model, D), None
    except LensModelError as error:
        lens, unread = None, str(error)
    intrinsics = CameraIntrinsics(width=int(width), height=int(height), fx=float(K[0]),
                                  fy=float(K[4]), cx=float(K[2]), cy=float(K[5]),
                                  distortion=lens)
    return intrinsics, unread


def _load_json(data: bytes, what: str) -> dict:
    try:
        document = json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise RecordingError(f"{what} is not valid JSON ({error})") from error
    if not isinstance(document, dict):
        raise RecordingError(f"{what} should be a JSON object, got {type(document).__name__}")
    return document


def decode_actuation(data: bytes, what: str = "actuation message") -> Actuation:
    document = _load_json(data, what)
    try:
        names = tuple(str(name) for name in document["names"])
        control = str(document["control"])
        values = np.asarray(document["values"], dtype=float).reshape(-1)
    except (KeyError, TypeError, ValueError) as error:
        raise RecordingError(
            f"{what} should hold 'names', 'control' and numeric 'values' ({error!r})"
        ) from error
    if control not in CONTROL_MODES:
        raise RecordingError(f"{what} has control '{control}'; expected one of {CONTROL_MODES}")
    if len(names) != len(values):
        raise RecordingError(f"{what} has {len(names)} names but {len(values)} values")
    if not np.all(np.isfinite(values)):
        raise RecordingError(f"{what} has a value that is not a finite number: {values.tolist()}")
    return Actuation(names=names, control=control, values=values)


def decode_markers(data: bytes, what: str = "markers message") -> Markers:
    document = _load_json(data, what)
    try:
        ids = tuple(str(marker_id) for marker_id in document["ids"])
        positions = np.asarray(document["positions_mm"], dtype=float).reshape(-1, 3)
    except (KeyError, TypeError, ValueError) as error:
        raise RecordingError(
            f"{what} should hold 'ids' and 'positions_mm' as [[x, y, z], ...] ({error!r})"
        ) from error
    if len(ids) != len(positions):
        raise RecordingError(f"{what} has {len(ids)} ids but {len(positions)} positions")
    if not np.all(np.isfinite(positions)):
        unseen = [i for i, p in zip(ids, positions, strict=True) if not np.all(np.isfinite(p))]
        raise RecordingError(f"{what} has marker(s) {', '.join(unseen)} at a position that is not "
                             "finite; a marker not seen in a frame is left out of its message")
    return Markers(ids=ids, positions_mm=positions)
