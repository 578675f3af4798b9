"""RealSense capture through pyrealsense2, live or from a .bag/.db3 file, as RgbdFrames.

Both sources stream depth (z16) and colour, align depth to colour with `rs.align`, convert
depth to millimetres (uint16) with the frame's own depth units, and take the intrinsics of the
colour stream. The iterators are lazy: the device or file streams while they are consumed,
and stops when they are exhausted or closed.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyrealsense2 as rs

from softforce_cli.camera.frame import RgbdFrame
from softforce_cli.camera.intrinsics import CameraIntrinsics
from softforce_cli.camera.lens import LensDistortion, LensModelError
from softforce_cli.errors import CameraError, RecordingError

NO_DEVICE_MESSAGE = "no RealSense device found; connect one or use --from FILE"
PRESETS = {
    name: getattr(rs.rs400_visual_preset, name)
    for name in ("default", "high_accuracy", "high_density", "medium_density", "hand")
}
FILE_SUFFIXES = (".bag", ".db3")

# How long a stalled stream may stay silent before the capture gives up.
LIVE_TIMEOUT_MS = 5000  # covers the device's start-up and auto-exposure settling
PLAYBACK_STALL_S = 10.0  # non-real-time playback delivers as fast as it reads the file
PLAYBACK_POLL_MS = 100  # how often a waiting playback checks whether the file has ended


@dataclass(frozen=True)
class StreamSettings:
    """Requested live streams: the same size and rate for depth and colour."""

    width: int = 640
    height: int = 480
    fps: int = 30
    preset: str | None = None  # a key of PRESETS, e.g. "high_accuracy"; None keeps the device's


@dataclass(frozen=True)
class CaptureProgress:
    """Where a capture stands, after each frame it yields.

    frames    : frames yielded so far.
    dropped   : frames the camera numbered but that never arrived (gaps in colour frame numbers).
    skipped   : framesets left out: without both images, repeated, or not later in time.
    elapsed_s : frame time since the first frame.
    total_s   : length of the file played back; None when live.
    """

    frames: int
    dropped: int
    skipped: int
    elapsed_s: float
    total_s: float | None = None


ProgressCallback = Callable[[CaptureProgress], None]


def iter_live_frames(
    settings: StreamSettings = StreamSettings(),
    *,
    duration_s: float | None = None,
    on_progress: ProgressCallback | None = None,
) -> Iterator[RgbdFrame]:
    """Stream aligned RGB-D frames from the first connected RealSense.

    Raises CameraError at once when no device is connected. Streaming starts with the first
    frame asked for and stops after `duration_s` seconds of frames (None: until closed).
    """
    if settings.preset is not None and settings.preset not in PRESETS:
        raise ValueError(f"unknown preset {settings.preset!r}; choose one of {list(PRESETS)}")
    context = rs.context()
    if len(context.query_devices()) == 0:
        raise CameraError(NO_DEVICE_MESSAGE)
    return _live_frames(context, settings, duration_s, on_progress)


def iter_file_frames(
    path: Path,
    *,
    duration_s: float | None = None,
    on_progress: ProgressCallback | None = None,
) -> Iterator[RgbdFrame]:
    """Play a RealSense recording (.bag or .db3) back, as fast as it can be read, frame by frame.

    Raises RecordingError at once when the file is missing, is not a RealSense recording, or
    lacks a depth or a colour stream.
    """
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"{path} does not exist")
    if path.suffix.lower() not in FILE_SUFFIXES:
        raise RecordingError(f"{path} is not a RealSense recording (.bag or .db3)")
    pipeline, config = rs.pipeline(), rs.config()
    config.enable_device_from_file(str(path), repeat_playback=False)
    config.enable_stream(rs.stream.depth)
    config.enable_stream(rs.stream.color)
    try:
        resolved = config.resolve(rs.pipeline_wrapper(pipeline))
    except RuntimeError as error:
        reason = str(error).split("Reason: ")[-1]
        raise RecordingError(
            f"cannot play {path} back as a RealSense recording with depth and colour ({reason})"
        ) from error
    playback = resolved.get_device().as_playback()
    # Non-real-time playback waits for the consumer; set before starting, or the first
    # frames are read (and dropped) before the setting takes effect.
    playback.set_real_time(False)
    total_s = playback.get_duration().total_seconds()
    framesets = _playback_framesets(pipeline, config, playback)
    return rgbd_frames_from_framesets(
        framesets, duration_s=duration_s, total_s=total_s, on_progress=on_progress
    )


def rgbd_frames_from_framesets(
    framesets: Iterable[rs.composite_frame],
    *,
    duration_s: float | None = None,
    total_s: float | None = None,
    on_progress: ProgressCallback | None = None,
) -> Iterator[RgbdFrame]:
    """Align each depth+colour frameset to colour and convert it; skip incomplete sets.

    Frame times are the colour frames' timestamps. A frameset is skipped when it lacks depth or
    colour, repeats the previous colour frame, or is not later than the previous frame.
    """
    align = rs.align(rs.stream.color)
    count, dropped, skipped = 0, 0, 0
    first_ns: int | None = None
    last_number: int | None = None
    last_ns: int | None = None
    for frameset in framesets:
        if not frameset.get_depth_frame() or not frameset.get_color_frame():
            skipped += 1
            continue
        number = frameset.get_color_frame().get_frame_number()
        if last_number is not None and number == last_number:
            skipped += 1
            continue
        frame = rgbd_frame_from_aligned(align.process(frameset))
        if last_ns is not None and frame.time_ns <= last_ns:
            skipped += 1
            continue
        first_ns = frame.time_ns if first_ns is None else first_ns
        elapsed_s = (frame.time_ns - first_ns) * 1e-9
        if duration_s is not None and elapsed_s >= duration_s:
            return
        if last_number is not None and number > last_number + 1:
            dropped += number - last_number - 1
        last_number, last_ns = number, frame.time_ns
        count += 1
        yield frame
        if on_progress is not None:
            on_progress(CaptureProgress(count, dropped, skipped, elapsed_s, total_s))


def rgbd_frame_from_aligned(frameset: rs.composite_frame) -> RgbdFrame:
    """Copy an aligned frameset (depth already aligned to colour) into an RgbdFrame."""
    depth_frame = frameset.get_depth_frame()
    color_frame = frameset.get_color_frame()
    profile = color_frame.get_profile().as_video_stream_profile()
    color = rgb_from_color_data(
        np.asanyarray(color_frame.get_data()), profile.format(), where="the colour stream"
    )
    depth_mm = depth_mm_from_raw(np.asanyarray(depth_frame.get_data()), depth_frame.get_units())
    return RgbdFrame(
        time_ns=round(color_frame.get_timestamp() * 1e6),
        color=color,
        depth_mm=depth_mm,
        intrinsics=intrinsics_from_rs(profile.get_intrinsics()),
    )


def depth_mm_from_raw(raw: np.ndarray, depth_units_m: float) -> np.ndarray:
    """(h, w) uint16 device depth in units of `depth_units_m` metres -> (h, w) uint16 mm.

    Rounded to the nearest millimetre; depths beyond 65.535 m saturate; 0 stays 0 (no data).
    A copy: the result does not share memory with the frame.
    """
    scale = float(depth_units_m) * 1000.0
    if abs(scale - 1.0) < 1e-6:  # the usual 1 mm units (stored as float32 0.001)
        return np.array(raw, dtype=np.uint16)
    depth_mm = np.rint(np.asarray(raw, dtype=np.float64) * scale)
    return np.clip(depth_mm, 0, np.iinfo(np.uint16).max).astype(np.uint16)


def rgb_from_color_data(data: np.ndarray, color_format: rs.format, where: str) -> np.ndarray:
    """(h, w, 3|4) uint8 colour in `color_format` -> (h, w, 3) uint8 RGB (a copy)."""
    if color_format == rs.format.rgb8:
        return np.array(data, dtype=np.uint8)
    if color_format == rs.format.bgr8:
        return np.ascontiguousarray(data[..., ::-1])
    if color_format == rs.format.rgba8:
        return np.ascontiguousarray(data[..., :3])
    if color_format == rs.format.bgra8:
        return np.ascontiguousarray(data[..., 2::-1])
    raise RecordingError(
        f"{where} is in format {color_format.name}; softforce reads rgb8, bgr8, rgba8 or bgra8"
    )


def intrinsics_from_rs(intrinsics: rs.intrinsics) -> CameraIntrinsics:
    """pyrealsense2 intrinsics -> CameraIntrinsics with the stream's lens distortion
    (camera.lens; None when its coefficients are all 0, as a D415's or D435's colour stream
    reports). RecordingError for a model softforce does not know (ftheta: the T265's)."""
    try:
        # "none" with coefficients would be an odd stream: its coefficients are read as
        # OpenCV's
        model = intrinsics.model.name
        lens = LensDistortion.from_camera_info("plumb_bob" if model == "none" else model,
                                               intrinsics.coeffs)
    except LensModelError as error:
        raise RecordingError(f"the colour stream's lens: {error}") from error
    return CameraIntrinsics(
        width=int(intrinsics.width),
        height=int(intrinsics.height),
        fx=float(intrinsics.fx),
        fy=float(intrinsics.fy),
        cx=float(intrinsics.ppx),
        cy=float(intrinsics.ppy),
        distortion=lens,
    )


def _live_frames(
    context: rs.context,
    settings: StreamSettings,
    duration_s: float | None,
    on_progress: ProgressCallback | None,
) -> Iterator[RgbdFrame]:
    pipeline, config = rs.pipeline(context), rs.config()
    w, h, fps = settings.width, settings.height, settings.fps
    config.enable_stream(rs.stream.depth, w, h, rs.format.z16, fps)
    config.enable_stream(rs.stream.color, w, h, rs.format.rgb8, fps)
    try:
        profile = pipeline.start(config)
    except RuntimeError as error:
        raise CameraError(
            f"the RealSense cannot stream depth and colour at {w}x{h} and {fps} fps ({error}); "
            "try another --width/--height/--fps"
        ) from error
    try:
        if settings.preset is not None:
            _apply_preset(profile.get_device(), settings.preset)
        yield from rgbd_frames_from_framesets(
            _live_framesets(pipeline), duration_s=duration_s, on_progress=on_progress
        )
    finally:
        pipeline.stop()


def _apply_preset(device: rs.device, preset: str) -> None:
    sensor = device.first_depth_sensor()
    if not sensor.supports(rs.option.visual_preset):
        raise CameraError(f"this RealSense has no visual presets; leave out --preset {preset}")
    sensor.set_option(rs.option.visual_preset, float(int(PRESETS[preset])))


def _live_framesets(pipeline: rs.pipeline) -> Iterator[rs.composite_frame]:
    while True:
        try:
            yield pipeline.wait_for_frames(LIVE_TIMEOUT_MS)
        except RuntimeError as error:
            raise CameraError(
                f"no frames from the RealSense for {LIVE_TIMEOUT_MS / 1000:g} s ({error}); "
                "check its USB 3 connection"
            ) from error


def _playback_framesets(
    pipeline: rs.pipeline, config: rs.config, playback: rs.playback
) -> Iterator[rs.composite_frame]:
    """Framesets of a file until playback stops; RecordingError if it stalls.

    Playback starts paused and resumes once the pipeline runs: the pipeline starts the depth
    sensor before the colour one, and frames read in between would go unpaired.
    """
    playback.pause()
    pipeline.start(config)
    try:
        # resume() waits for the file reader, which may already be waiting for this loop to
        # take a frameset (when the pause came too late): resume from another thread.
        threading.Thread(target=playback.resume, daemon=True).start()
        waited_s = 0.0
        while True:
            ok, frameset = pipeline.try_wait_for_frames(PLAYBACK_POLL_MS)
            if ok:
                waited_s = 0.0
                yield frameset
            elif playback.current_status() == rs.playback_status.stopped:
                return
            else:
                waited_s += PLAYBACK_POLL_MS / 1000
                if waited_s >= PLAYBACK_STALL_S:
                    raise RecordingError(
                        f"playback of {playback.file_name()} stalled for {waited_s:.0f} s "
                        "before its end"
                    )
    finally:
        pipeline.stop()
