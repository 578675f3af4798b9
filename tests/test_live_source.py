"""LiveSource: every frame of a 30 fps camera recorded while a slower consumer sees the newest.

Cameras are paced in real time: a Python generator at 30 fps, and pyrealsense2's software_device
fed at 30 fps from a thread (software_device -> syncer -> align -> rgbd_frames_from_framesets).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from softforce_cli.camera.frame import RgbdFrame
from softforce_cli.camera.intrinsics import CameraIntrinsics
from softforce_cli.camera.lens import LensDistortion
from softforce_cli.camera.live_source import QUEUE_FRAMES, LiveSource, record_live
from softforce_cli.camera.realsense import CaptureProgress, rgbd_frames_from_framesets
from softforce_cli.camera.rectification import rectified
from softforce_cli.cli import record_commands
from softforce_cli.errors import CameraError, OutputExistsError, RecordingError
from softforce_cli.io import mcap_writer
from softforce_cli.io.mcap_reader import (
    frames_from_messages,
    iter_frames,
    open_recording,
    recording_messages,
)
from tests.realsense_fakes import FPS, PERIOD_MS, T0_MS, SoftwareCamera

T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 33_333_333
CONSUMER_S = 0.060  # a force-sensing step slower than the camera's 33 ms
FULL_K = CameraIntrinsics(640, 480, fx=615.0, fy=615.0, cx=319.5, cy=239.5)
SMALL_K = CameraIntrinsics(64, 48, fx=52.0, fy=53.0, cx=32.0, cy=24.0)


def noisy_images(k: CameraIntrinsics, n: int, seed: int = 0) -> list[tuple[np.ndarray, ...]]:
    """n (depth_mm (h, w) uint16, color (h, w, 3) uint8) pairs with RealSense-like noise: a
    tilted wall at 800 mm with 1.5 mm depth noise and a colour ramp with 3 levels of noise, which
    compress as poorly as real frames do (about 0.9 MB per 640x480 frame)."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0 : k.height, 0 : k.width]
    wall_mm = 800.0 + 0.1 * cols
    ramp = np.stack([cols % 256, rows % 256, (cols + rows) % 256], axis=-1)
    return [
        (
            (wall_mm + rng.normal(0, 1.5, wall_mm.shape)).astype(np.uint16),
            np.clip(ramp + rng.normal(0, 3, ramp.shape), 0, 255).astype(np.uint8),
        )
        for _ in range(n)
    ]


def frame_at(index: int, images: list, k: CameraIntrinsics, time_ns: int | None = None):
    depth, color = images[index % len(images)]
    time_ns = T0_NS + index * PERIOD_NS if time_ns is None else time_ns
    return RgbdFrame(time_ns=time_ns, color=color, depth_mm=depth, intrinsics=k)


def index_of(frame: RgbdFrame) -> int:
    return (frame.time_ns - T0_NS) // PERIOD_NS


class PacedCamera:
    """A camera iterator that yields frame i at i/30 s after its first frame; None: endless.

    Records the thread it ran on and whether it was closed (the RealSense pipeline's stop).
    """

    def __init__(
        self, n: int | None, k: CameraIntrinsics = SMALL_K, fail: BaseException | None = None
    ):
        self.n, self.k, self.fail = n, k, fail
        self.images = noisy_images(k, 4)
        self.thread: str | None = None
        self.stopped = threading.Event()
        self.frames = self._frames()

    def __iter__(self) -> Iterator[RgbdFrame]:
        return self.frames

    def __next__(self) -> RgbdFrame:
        return next(self.frames)

    def close(self) -> None:
        self.frames.close()

    def _frames(self) -> Iterator[RgbdFrame]:
        self.thread = threading.current_thread().name
        start = time.monotonic()
        try:
            index = 0
            while self.n is None or index < self.n:
                time.sleep(max(0.0, start + index / FPS - time.monotonic()))
                yield frame_at(index, self.images, self.k)
                index += 1
            if self.fail is not None:
                raise self.fail
        finally:
            self.stopped.set()


def recorded_times(path: Path) -> list[int]:
    return [frame.time_ns for frame in iter_frames(path)]


def test_slow_consumer_sees_recent_frames_and_every_frame_is_recorded(tmp_path):
    """3 s of 640x480 noisy frames at 30 fps, a consumer that needs 60 ms per frame."""
    out = tmp_path / "live.mcap"
    camera = PacedCamera(90, FULL_K)
    lags, seen = [], []
    with LiveSource(camera, record_to=out) as source:
        for frame in source.latest():
            # frames captured after this one, right after it was handed over: 0, or 1 when
            # the next frame came in between; more would mean the consumer is served old frames
            lags.append(source.stats.captured - 1 - index_of(frame))
            seen.append(index_of(frame))
            time.sleep(CONSUMER_S)
    stats = source.stats
    assert camera.thread == "live-capture" and camera.stopped.is_set()
    assert (stats.captured, stats.recorded, stats.dropped) == (90, 90, 0)
    assert stats.queue_peak < QUEUE_FRAMES
    assert recorded_times(out) == [T0_NS + i * PERIOD_NS for i in range(90)]
    assert seen == sorted(set(seen)) and seen[-1] == 89
    assert stats.delivered == len(seen) and stats.delivered + stats.skipped_by_consumer == 90
    assert stats.skipped_by_consumer >= 20  # about 40: the consumer runs at half the camera's rate
    assert max(lags) <= 2, lags


def test_software_device_through_align_into_a_live_recording(tmp_path):
    """The real pyrealsense2 path: frames pushed at 30 fps by a thread, as a camera would."""
    camera = SoftwareCamera(depth_k=FULL_K, color_k=FULL_K)
    images = noisy_images(FULL_K, 4, seed=1)
    n = 45

    def push() -> None:
        start = time.monotonic()
        for number in range(n):
            time.sleep(max(0.0, start + number / FPS - time.monotonic()))
            camera.push(number, *images[number % len(images)])

    def framesets(pusher: threading.Thread):
        while True:
            done = not pusher.is_alive()  # before the wait: a last push is still collected
            ok, frameset = camera.syncer.try_wait_for_frames(100)
            if ok:
                yield frameset
            elif done:
                return

    pusher = threading.Thread(target=push)
    out = tmp_path / "sw.mcap"
    seen = []
    pusher.start()
    try:
        frames = rgbd_frames_from_framesets(framesets(pusher))
        with LiveSource(frames, record_to=out) as source:
            for frame in source.latest():
                seen.append(frame.time_ns)
                time.sleep(CONSUMER_S)
    finally:
        pusher.join()
        camera.close()
    stats = source.stats
    want = [round((T0_MS + number * PERIOD_MS) * 1e6) for number in range(1, n)]
    assert (stats.captured, stats.recorded, stats.dropped) == (n - 1, n - 1, 0)  # first unpaired
    recorded = list(iter_frames(out))
    assert [frame.time_ns for frame in recorded] == want
    for frame in recorded[::10]:
        number = round((frame.time_ns / 1e6 - T0_MS) / PERIOD_MS)
        np.testing.assert_array_equal(frame.color, images[number % len(images)][1])
        assert frame.intrinsics == FULL_K
    assert stats.skipped_by_consumer > 0 and set(seen) < set(want) and seen[-1] == want[-1]


@pytest.mark.parametrize("consumer", ["latest", "wait"])
def test_camera_error_reaches_the_consumer_as_itself(tmp_path, consumer):
    error = CameraError("no frames from the RealSense for 5 s; check its USB 3 connection")
    camera = PacedCamera(3, fail=error)
    out = tmp_path / "cut.mcap"
    with pytest.raises(CameraError) as caught, LiveSource(camera, record_to=out) as source:
        if consumer == "wait":
            source.wait()
        for _ in source.latest():
            time.sleep(CONSUMER_S)
    assert caught.value is error
    assert source.closed and source.stats.recorded == 3
    assert recorded_times(out) == [T0_NS + i * PERIOD_NS for i in range(3)]


def test_ctrl_c_in_the_consumer_leaves_a_readable_recording(tmp_path):
    camera = PacedCamera(None)
    out = tmp_path / "stopped.mcap"
    with pytest.raises(KeyboardInterrupt), LiveSource(camera, record_to=out) as source:
        for count, _ in enumerate(source.latest(), start=1):
            time.sleep(CONSUMER_S)
            if count == 5:
                raise KeyboardInterrupt
    stats = source.stats
    assert camera.stopped.is_set() and stats.captured >= 5
    assert stats.recorded == stats.captured and stats.dropped == 0
    assert recorded_times(out) == [T0_NS + i * PERIOD_NS for i in range(stats.captured)]
    assert [p.name for p in tmp_path.iterdir()] == ["stopped.mcap"]  # no temporary file left


def test_writer_error_reaches_the_consumer_and_keeps_earlier_frames(tmp_path):
    images = noisy_images(SMALL_K, 1)
    times = [T0_NS, T0_NS + PERIOD_NS, T0_NS + PERIOD_NS, T0_NS + 3 * PERIOD_NS]
    frames = iter([frame_at(i, images, SMALL_K, t) for i, t in enumerate(times)])
    out = tmp_path / "bad.mcap"
    with (
        pytest.raises(RecordingError, match="does not come after"),
        LiveSource(frames, record_to=out) as source,
    ):
        for _ in source.latest():
            time.sleep(CONSUMER_S)
    assert source.stats.captured == 4 and source.stats.recorded == 2
    assert recorded_times(out) == times[:2]


def test_a_full_queue_drops_frames_from_the_recording_and_counts_them(tmp_path, monkeypatch):
    write_frame = mcap_writer.RecordingWriter.write_frame

    def slow_write(self, frame):  # a writer at 20 fps behind a 30 fps camera
        time.sleep(0.05)
        write_frame(self, frame)

    monkeypatch.setattr(mcap_writer.RecordingWriter, "write_frame", slow_write)
    out = tmp_path / "slow.mcap"
    with LiveSource(PacedCamera(30), record_to=out, queue_frames=4) as source:
        for _ in source.latest():
            pass  # a consumer faster than the camera: it would see every frame
    stats = source.stats
    assert stats.captured == 30 and stats.dropped > 0
    assert stats.recorded + stats.dropped == 30 and stats.queue_peak <= 4
    # held back while the writer lagged by 2 frames or more, it missed frames
    assert stats.consumer_held_s > 0 and stats.skipped_by_consumer > 0
    times = recorded_times(out)
    assert len(times) == stats.recorded and times == sorted(times) and times[0] == T0_NS


def test_existing_output_is_refused_before_the_camera_starts(tmp_path):
    out = tmp_path / "taken.mcap"
    out.write_bytes(b"keep me")
    camera = PacedCamera(3)
    with pytest.raises(OutputExistsError, match="already exists; pass --force"):
        LiveSource(camera, record_to=out)
    assert camera.thread is None and out.read_bytes() == b"keep me"
    with LiveSource(camera, record_to=out, force=True) as source:
        source.wait()
    assert len(recorded_times(out)) == 3


def test_no_frame_writes_nothing_and_no_recording_only_serves_frames(tmp_path):
    out = tmp_path / "empty.mcap"
    with LiveSource(PacedCamera(0), record_to=out) as source:
        assert list(source.latest()) == []
    assert not list(tmp_path.iterdir()) and source.stats.recorded == 0
    with LiveSource(PacedCamera(4)) as source:
        last = list(source.latest())[-1]
    assert index_of(last) == 3 and source.stats.captured == 4 and source.stats.recorded == 0
    with pytest.raises(RuntimeError, match="start the LiveSource first"):
        next(LiveSource(PacedCamera(1)).latest())


def test_a_lens_is_rectified_for_the_consumer_and_recorded_as_captured(tmp_path):
    """A camera whose lens distorts (a D455's colour stream): the consumer gets the pinhole
    image (camera.rectification), the recording the camera's own frames and lens."""
    lens = LensDistortion("plumb_bob", (-0.2, 0.05, 0.0, 0.0, 0.0))
    camera = PacedCamera(3, replace(SMALL_K, distortion=lens))
    with LiveSource(camera, record_to=tmp_path / "lens.mcap") as source:
        served = list(source.latest())
    assert served and all(frame.intrinsics.distortion is None for frame in served)
    with open_recording(tmp_path / "lens.mcap") as recording:
        kept = list(frames_from_messages(tmp_path / "lens.mcap",
                                         recording_messages(recording, {})))
    assert [frame.intrinsics.distortion for frame in kept] == [lens] * 3
    for frame in served:
        raw = kept[index_of(frame)]
        np.testing.assert_array_equal(frame.depth_mm, rectified(raw).depth_mm)
        assert not np.array_equal(frame.depth_mm, raw.depth_mm)


def test_record_live_reports_an_interrupt_from_the_camera(tmp_path):
    out = tmp_path / "rec.mcap"
    result = record_live(PacedCamera(6, fail=KeyboardInterrupt()), out, stop_on_interrupt=True)
    assert result.interrupted and result.frames == 6 and result.stats.dropped == 0
    assert len(recorded_times(out)) == 6
    with pytest.raises(KeyboardInterrupt):
        record_live(PacedCamera(1, fail=KeyboardInterrupt()), tmp_path / "again.mcap")


def test_record_cli_live_writes_off_the_capture_thread(tmp_path, monkeypatch):
    cameras: list[PacedCamera] = []

    def live_frames(settings, duration_s=None, on_progress=None):
        camera = PacedCamera(15)
        cameras.append(camera)
        for count, frame in enumerate(camera, start=1):
            if on_progress is not None:
                on_progress(CaptureProgress(count, 0, 0, count / FPS, None))
            yield frame

    monkeypatch.setattr(record_commands, "iter_live_frames", live_frames)
    out = tmp_path / "live.mcap"
    result = CliRunner().invoke(record_commands.app, ["--live", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert f"wrote {out}: 15 frames" in result.stdout and "0 dropped" in result.stdout
    assert cameras[0].thread == "live-capture"
    assert recorded_times(out) == [T0_NS + i * PERIOD_NS for i in range(15)]
