"""Fakes of a RealSense for tests without hardware: a depth + colour software_device.

Shared by test_realsense.py (capture, align, playback) and test_live_source.py (live source).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyrealsense2 as rs

from softforce_cli.camera.intrinsics import CameraIntrinsics

W, H, FPS = 64, 48, 30
PERIOD_MS = 1000.0 / FPS
T0_MS = 1_700_000_000_000.0  # global-time timestamps are unix milliseconds
DEPTH_K = CameraIntrinsics(W, H, fx=50.0, fy=50.0, cx=31.5, cy=23.5)
COLOR_K = CameraIntrinsics(W, H, fx=52.0, fy=53.0, cx=32.0, cy=24.0)


def rs_intrinsics(k: CameraIntrinsics) -> rs.intrinsics:
    out = rs.intrinsics()
    out.width, out.height, out.fx, out.fy, out.ppx, out.ppy = (
        k.width, k.height, k.fx, k.fy, k.cx, k.cy,
    )  # fmt: skip
    out.model, out.coeffs = rs.distortion.brown_conrady, [0.0] * 5
    return out


@dataclass
class SoftwareCamera:
    """A depth + colour software_device whose frames the test writes itself.

    The syncer pairs frames by timestamp using the actual-fps metadata: without it, software
    frames report a bogus rate (frame number / timestamp) and stay unpaired. A syncer cannot
    pair the very first frame of each stream (it does not yet know the other stream exists).
    """

    depth_k: CameraIntrinsics = DEPTH_K
    color_k: CameraIntrinsics = COLOR_K
    depth_units_m: float = 0.001
    record_to: Path | None = None
    keep: list = field(default_factory=list)  # pixel buffers must outlive their frames

    def __post_init__(self) -> None:
        self.device = rs.software_device()
        self.depth_sensor = self.device.add_sensor("Depth")
        self.color_sensor = self.device.add_sensor("Color")
        self.depth_sensor.add_read_only_option(rs.option.depth_units, self.depth_units_m)
        self.depth_profile = self.depth_sensor.add_video_stream(
            self._stream(rs.stream.depth, rs.format.z16, 2, self.depth_k, uid=0)
        ).as_video_stream_profile()
        self.color_profile = self.color_sensor.add_video_stream(
            self._stream(rs.stream.color, rs.format.rgb8, 3, self.color_k, uid=1)
        ).as_video_stream_profile()
        identity = rs.extrinsics()
        identity.rotation, identity.translation = [1, 0, 0, 0, 1, 0, 0, 0, 1], [0, 0, 0]
        self.depth_profile.register_extrinsics_to(self.color_profile, identity)
        for sensor in (self.depth_sensor, self.color_sensor):
            sensor.set_metadata(rs.frame_metadata_value.actual_fps, FPS * 1000)
        self.recorder = rs.recorder(str(self.record_to), self.device) if self.record_to else None
        self.syncer = rs.syncer(100)
        self.depth_sensor.open(self.depth_profile)
        self.color_sensor.open(self.color_profile)
        self.depth_sensor.start(self.syncer)
        self.color_sensor.start(self.syncer)

    @staticmethod
    def _stream(kind, pixel_format, bpp, k, uid) -> rs.video_stream:
        stream = rs.video_stream()
        stream.type, stream.index, stream.uid, stream.fmt, stream.bpp = (
            kind, 0, uid, pixel_format, bpp,
        )  # fmt: skip
        stream.width, stream.height, stream.fps = k.width, k.height, FPS
        stream.intrinsics = rs_intrinsics(k)
        return stream

    def push(self, number: int, depth_raw: np.ndarray, color: np.ndarray) -> None:
        timestamp = T0_MS + number * PERIOD_MS
        for sensor, profile, pixels, bpp in (
            (self.depth_sensor, self.depth_profile, depth_raw, 2),
            (self.color_sensor, self.color_profile, color, 3),
        ):
            pixels = np.ascontiguousarray(pixels)
            self.keep.append(pixels)
            frame = rs.software_video_frame()
            frame.pixels, frame.bpp, frame.stride = pixels, bpp, pixels.shape[1] * bpp
            frame.timestamp, frame.frame_number = timestamp, number
            frame.domain = rs.timestamp_domain.global_time
            frame.profile = profile
            if sensor is self.depth_sensor:
                frame.depth_units = self.depth_units_m
            sensor.on_video_frame(frame)

    def framesets(self) -> list[rs.composite_frame]:
        out = []
        while True:
            ok, frameset = self.syncer.try_wait_for_frames(100)
            if not ok:
                return out
            out.append(frameset)

    def close(self) -> None:
        for sensor in (self.depth_sensor, self.color_sensor):
            sensor.stop()
            sensor.close()
        if self.recorder is not None:
            self.recorder.pause()
            self.recorder = None  # the recorder writes and closes its file when released
